"""A package a user can install: the project builds as a wheel, the wheel carries the package data and the
`bayesmap` console script, it installs into a fresh virtual environment next to the lock's packages with `pip check`
passing, and its `bayesmap` command runs the demo with the tutorial's numbers, from a folder outside the source tree.

The lock's packages are not installed again: `make install` installs requirements.lock into the project's .venv (from
a fresh clone in CI, on every run), and reinstalling it here took 2 minutes. The fresh venv (no pip of its own)
instead gets a site-packages of symlinks to every package the project's environment has installed (the lock's),
leaving out the editable bayesmap (its `__editable__` .pth, which points at the source tree, and its dist-info), and
the test checks that `bayesmap` cannot be imported there before the wheel is installed. So the wheel, not the source
tree, is what runs, and `pip check` sees the wheel's requirements against the lock's versions. About 26 s on the
2-core machine (the wheel build, two pip runs and the demo's 100 sweeps). This is also the suite's test of `bayesmap
demo` end to end (its summary, posterior.png and report.html).

Not covered: installing requirements.lock into an empty venv (that is `make install`); `pip install .` with its build
isolation resolving the newest versions of the dependencies (checked by hand: 80 s, then `bayesmap demo` gave the
same "1 of 217 visible cells wrong"); and the Makefile's chromium install."""

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args, cwd, timeout):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    done = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert done.returncode == 0, f"{' '.join(map(str, args))} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


def _venv_with_the_installed_packages(venv, cwd):
    """A fresh venv (``--without-pip``) whose site-packages links every entry of this interpreter's site-packages
    (the lock's packages, pip among them) except bayesmap's own (the editable install). Returns its python."""
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=cwd, timeout=120)
    python = venv / "bin" / "python"
    purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=cwd,
                        timeout=60).strip())
    installed = Path(sysconfig.get_paths()["purelib"])
    assert purelib != installed and purelib.is_relative_to(venv)
    for entry in installed.iterdir():
        if "bayesmap" not in entry.name.lower():
            (purelib / entry.name).symlink_to(entry)
    return python


@pytest.mark.slow
def test_the_wheel_installs_next_to_the_locks_packages_and_runs_the_demo(tmp_path):
    source = tmp_path / "source"  # a clean copy: building leaves build/ and *.egg-info behind
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "requirements.lock"):
        shutil.copy2(ROOT / name, source / name)
    shutil.copytree(ROOT / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    wheels = tmp_path / "wheels"
    # the project's own pip and setuptools (both in the lock) build the wheel, offline
    _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "--wheel-dir", wheels,
          source], cwd=tmp_path, timeout=300)
    (wheel,) = wheels.glob("bayesmap-*.whl")
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
        (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
        assert "bayesmap = bayesmap.__main__:main" in whl.read(entry_points).decode()
    assert "bayesmap/data/tutorial.txt" in names and "bayesmap/cli.py" in names

    venv = tmp_path / "venv"
    python = _venv_with_the_installed_packages(venv, tmp_path)
    probe = "import importlib.util as u; print(u.find_spec('bayesmap'), u.find_spec('jax') is not None)"
    assert _run([python, "-c", probe], cwd=tmp_path, timeout=120).split() == ["None", "True"]
    pip = [python, "-m", "pip", "--disable-pip-version-check"]
    _run([*pip, "install", "--quiet", "--no-deps", wheel], cwd=tmp_path, timeout=300)
    _run([*pip, "check"], cwd=tmp_path, timeout=120)  # the lock's versions satisfy every requirement of the wheel

    work = tmp_path / "elsewhere"
    work.mkdir()
    bayesmap = venv / "bin" / "bayesmap"  # the wheel's console script
    out = _run([bayesmap, "demo", "--out", work / "out", "--sweeps", "100"], cwd=work, timeout=600)
    assert "2x2 block Gibbs" in out and "1 of 217 visible cells wrong" in out
    assert (work / "out" / "posterior.png").read_bytes()[:4] == b"\x89PNG"
    assert (work / "out" / "report.html").stat().st_size > 10_000
    assert "convert" in _run([bayesmap, "--help"], cwd=work, timeout=120)
    # the installed package is the wheel's (in the venv, with its data file), not the source tree's
    where = _run([python, "-c", "import bayesmap, rosbags; print(bayesmap.__file__)"], cwd=work, timeout=120)
    package = Path(where.strip()).parent
    assert package.is_relative_to(venv) and not package.is_symlink() and (package / "data" / "tutorial.txt").is_file()
