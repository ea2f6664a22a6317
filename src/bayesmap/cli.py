"""The ``bayesmap`` command line (typer).

User errors (bad files, values, folders) print one line ``error: ...`` on stderr and exit with code 2.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Optional

import typer

from bayesmap.errors import BayesmapError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Bayesian occupancy-grid mapping from range scans, with honest uncertainty.")

OUTPUT_FILES = ("posterior.npy", "readings.npy", "posterior.png", "summary.json")
DIAGNOSTICS_FILE = "diagnostics.npz"  # written with --chains >= 2
REPORT_FILE = "report.html"  # written by demo, and by infer --report


def _check_output_dir(out: Path, force: bool) -> None:
    """Fail before any work if ``out`` cannot be written or would overwrite files without ``--force``."""
    if out.exists() and not out.is_dir():
        raise BayesmapError(f"output folder {str(out)!r} exists and is not a folder")
    if out.is_dir() and not force:
        clash = [name for name in OUTPUT_FILES + (DIAGNOSTICS_FILE, REPORT_FILE) if (out / name).exists()]
        if clash:
            raise BayesmapError(f"{str(out / clash[0])!r} already exists; pass --force to replace bayesmap's outputs in {str(out)!r}")
    parent = out if out.is_dir() else out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"output folder {str(out)!r} cannot be written (no write permission on {str(parent)!r})")


def _write_outputs(out: Path, files: dict[str, bytes]) -> None:
    """Write all files into ``out`` whole or not at all: everything is staged in a temporary folder beside
    ``out`` first; only when all are written do they move into place (one rename each)."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    except OSError as err:
        raise BayesmapError(f"cannot write output folder {str(out)!r}: {err.strerror}") from None
    try:
        for name, data in files.items():
            (staging / name).write_bytes(data)
        if not out.exists():
            os.rename(staging, out)
            return
        for name in files:
            os.replace(staging / name, out / name)
    except OSError as err:
        raise BayesmapError(f"cannot write output folder {str(out)!r}: {err.strerror}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _npy(array) -> bytes:
    import numpy as np

    buf = io.BytesIO()
    np.save(buf, np.asarray(array))
    return buf.getvalue()


def _run_and_write(problem, sampler: str, sweeps: int, burn_in: Optional[int], seed: int, out: Path, force: bool,
                   title: str, chains: int = 1, report: bool = False) -> tuple[dict, list[str]]:
    """Run inference and write its outputs into ``out``; returns the summary and the names of the files written."""
    from bayesmap.plots import figure_bytes, plot_posterior
    from bayesmap.problem import run_inference

    _check_output_dir(out, force)
    result = run_inference(problem, sampler=sampler, sweeps=sweeps, burn_in=burn_in, seed=seed, chains=chains)
    fig = plot_posterior(problem.grid, result.posterior, truth=problem.truth, pos=problem.pos,
                         beam_angles=problem.beam_angles, readings=problem.readings,
                         max_range_mask=problem.max_range_mask, title=title)
    files = {
        "posterior.npy": _npy(result.posterior.astype("float32")),
        "readings.npy": _npy(problem.readings.astype("float32")),
        "posterior.png": figure_bytes(fig, "png"),
        "summary.json": (json.dumps(result.summary, indent=2) + "\n").encode(),
    }
    if result.diagnostics is not None:
        import numpy as np

        buf = io.BytesIO()
        np.savez(buf, r_hat=result.diagnostics["r_hat"], ess=result.diagnostics["ess"])
        files[DIAGNOSTICS_FILE] = buf.getvalue()
    if report:
        from bayesmap.report import build_report

        files[REPORT_FILE] = build_report(problem, result, title=title, seed=seed).encode("utf-8")
    _write_outputs(out, files)
    return result.summary, list(files)


def _print_summary(summary: dict, out: Path, written: list[str]) -> None:
    typer.echo(f"sampler:  {summary['sampler']} ({summary['sampler_description']})")
    typer.echo(f"data:     {summary['source']}, {summary['num_angles']} beams, grid {summary['grid']['shape'][0]} x "
               f"{summary['grid']['shape'][1]} cells of {summary['grid']['resolution']:g} m")
    typer.echo(f"sweeps:   {summary['sweeps']} (posterior mean over the last {summary['sweeps'] - summary['burn_in']})")
    typer.echo(f"runtime:  {summary['runtime_s']:.2f} s (compilation included)")
    if "wrong_visible_cells" in summary:
        typer.echo(f"accuracy: {summary['wrong_visible_cells']} of {summary['visible_cells']} visible cells wrong")
    if summary.get("chains", 1) > 1 and summary.get("r_hat_max") is not None:
        typer.echo(f"chains:   {summary['chains']}; over the {summary['cells_varying']} cells that change: worst split "
                   f"R-hat {summary['r_hat_max']:.3f}, smallest effective sample size {summary['ess_min']:.0f}")
    typer.echo(f"outputs:  {out}/ ({', '.join(written)})")


def _sampler_option(default: str):
    from bayesmap.problem import SAMPLERS

    return typer.Option(default, "--sampler", help=f"one of: {', '.join(SAMPLERS)}")


@app.command()
def demo(
    out: Path = typer.Option(Path("bayesmap-out"), "--out", help="output folder"),
    sweeps: int = typer.Option(100, help="number of Gibbs sweeps"),
    seed: int = typer.Option(0, help="seed of the chain (readings always use the tutorial's key 0)"),
    force: bool = typer.Option(False, "--force", help="replace bayesmap's outputs already in the folder"),
) -> None:
    """The tutorial map, readings simulated with the tutorial's key, 2x2 block Gibbs; prints a summary, writes figures
    and report.html."""
    from bayesmap.problem import tutorial_problem

    problem = tutorial_problem()
    summary, written = _run_and_write(problem, "block", sweeps, None, seed, out, force,
                                      title="Posterior wall probability, 2x2 block Gibbs (tutorial map)", report=True)
    _print_summary(summary, out, written)


@app.command()
def infer(
    map_file: Optional[Path] = typer.Option(None, "--map", help="ASCII map ('X' wall, '.' free); default the tutorial map"),
    log: Optional[Path] = typer.Option(None, "--log", help="a CARMEN log (.log or .log.gz) for a real scan"),
    scan: Optional[int] = typer.Option(None, "--scan", help="index of the scan in --log"),
    resolution: float = typer.Option(0.1, help="grid resolution for a real scan, meters per cell"),
    sampler: str = _sampler_option("block"),
    sweeps: int = typer.Option(100, help="number of Gibbs sweeps"),
    burn_in: Optional[int] = typer.Option(None, "--burn-in", help="sweeps dropped before averaging (default: half)"),
    prior_wall_prob: float = typer.Option(0.5, "--prior-wall-prob", help="prior probability that a cell is a wall"),
    sensor_noise: Optional[float] = typer.Option(None, "--sensor-noise", help="standard deviation of a reading, meters (default 0.2, the tutorial's; for --log half a cell)"),
    num_angles: int = typer.Option(100, "--num-angles", help="number of beams (simulated readings)"),
    pos: Optional[tuple[float, float]] = typer.Option(None, "--pos", help="sensor position X Y (simulated readings); default the map's center"),
    seed: int = typer.Option(0, help="seed of the simulated readings and of the chain"),
    chains: int = typer.Option(1, help="independent chains run at once; 2 or more add split R-hat and effective sample size per cell"),
    report: bool = typer.Option(False, "--report", help="also write report.html: settings, metrics, all figures and the chain's animation, offline"),
    out: Path = typer.Option(Path("bayesmap-out"), "--out", help="output folder"),
    force: bool = typer.Option(False, "--force", help="replace bayesmap's outputs already in the folder"),
) -> None:
    """Infer the walls from simulated readings on a map file, or from one real laser scan (--log FILE --scan N)."""
    from bayesmap.grid import load_map, tutorial_map
    from bayesmap.problem import scan_problem, tutorial_problem

    if log is not None:
        if map_file is not None:
            raise BayesmapError("give either --map or --log, not both")
        if scan is None:
            raise BayesmapError("--log needs --scan N (the index of the scan to map)")
        from bayesmap.io.carmen import read_carmen

        problem = scan_problem(read_carmen(log), scan, resolution=resolution, prior_wall_prob=prior_wall_prob,
                               sensor_noise=resolution / 2 if sensor_noise is None else sensor_noise)
        title = f"Posterior wall probability, {log.name} scan {scan}"
    else:
        if scan is not None:
            raise BayesmapError("--scan needs --log FILE")
        walls = load_map(map_file) if map_file is not None else tutorial_map()
        center = (float(walls.shape[0] // 2), float(walls.shape[1] // 2))  # the tutorial's GRID_SIZE // 2
        problem = tutorial_problem(walls, pos=pos if pos is not None else center, seed=seed,
                                   prior_wall_prob=prior_wall_prob, sensor_noise=0.2 if sensor_noise is None else sensor_noise, num_angles=num_angles,
                                   source=str(map_file) if map_file else "tutorial map")
        title = f"Posterior wall probability ({problem.source})"
    summary, written = _run_and_write(problem, sampler, sweeps, burn_in, seed, out, force, title=title,
                                      chains=chains, report=report)
    _print_summary(summary, out, written)


@app.command()
def bench(
    json_file: Optional[Path] = typer.Option(None, "--json", help="also write the figures as JSON to this file"),
    samplers: Optional[str] = typer.Option(None, "--samplers", help="comma-separated subset of: raster, incremental, outward, block, chromatic, chromatic-block"),
    sweeps: int = typer.Option(200, help="sweeps per timed chain of a fast sampler"),
    reference_sweeps: int = typer.Option(5, "--reference-sweeps", help="sweeps per timed chain of a reference sampler"),
    repeats: int = typer.Option(5, help="timed chains per sampler; the fastest counts"),
    chains: int = typer.Option(64, help="chains run at once for the throughput figure"),
    force: bool = typer.Option(False, "--force", help="replace the --json file if it exists"),
) -> None:
    """Fast samplers against the tutorial's reference samplers on the tutorial scene, in one process."""
    import platform

    from bayesmap.bench import format_table, run_bench
    from bayesmap.grid import write_atomic

    for name, value, least in (("--sweeps", sweeps, 1), ("--reference-sweeps", reference_sweeps, 1),
                               ("--repeats", repeats, 1), ("--chains", chains, 1)):
        if value < least:
            raise BayesmapError(f"{name} must be >= {least}, got {value}")
    if json_file is not None and json_file.exists() and not force:
        raise BayesmapError(f"{str(json_file)!r} already exists; pass --force to replace it")
    names = None if samplers is None else [n.strip() for n in samplers.split(",") if n.strip()]
    import jax

    typer.echo(f"bayesmap bench: tutorial scene (21 x 21, 100 beams, prior 0.5); jax {jax.__version__} on "
               f"{jax.default_backend()}, {os.cpu_count()} cores, {platform.processor() or platform.machine()}")
    results = run_bench(names, fast_sweeps=sweeps, reference_sweeps=reference_sweeps, repeats=repeats,
                        num_chains=chains, progress=lambda msg: typer.echo(f"  {msg} ...", err=True))
    typer.echo(format_table(results))
    if json_file is not None:
        write_atomic(json_file, json.dumps(results, indent=2) + "\n", overwrite=True)
        typer.echo(f"wrote {json_file}")


@app.command("app")
def explorer(
    host: str = typer.Option("127.0.0.1", help="interface to listen on (default: this machine only)"),
    port: int = typer.Option(8080, help="TCP port"),
    no_browser: bool = typer.Option(False, "--no-browser", help="do not open the page in a browser"),
) -> None:
    """The interactive map explorer, a local web app: draw walls, drag the sensor, run inference, browse samples.

    It serves its own scripts and contacts nothing on the network. Stop it with Ctrl+C."""
    from bayesmap.app import run_app

    typer.echo(f"bayesmap explorer at http://{host}:{port}/ (Ctrl+C stops it)")
    run_app(host=host, port=port, show=not no_browser)


def main() -> None:
    """Entry point: run the app, turning :class:`BayesmapError` into one line on stderr and exit code 2."""
    try:
        app(standalone_mode=False)
    except BayesmapError as err:
        typer.echo(f"error: {err}", err=True)
        sys.exit(2)
    except typer.Exit as ex:
        sys.exit(ex.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(1)
    except Exception as err:  # click usage errors
        import click

        if isinstance(err, click.ClickException):
            err.show()
            sys.exit(2)
        raise


if __name__ == "__main__":
    main()
