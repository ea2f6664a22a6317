"""Leave-one-log-out cross-validation of the map model's defaults for logs: the likelihood power (fixed, or
following the data: ``c`` readings per cell), the structured prior's run length, the sensor noise, the beam mixture's
random weight and the probability that a beam passes a wall cell, in the chord geometry with no range offset, at several
resolutions.

For each log (intel, aces, csail), resolution and setting of the grid, ``bayesmap.evaluation.heldout.evaluate_log``
maps every ``--step``-th scan of the log (every 10th of those held out) with bayesmap (cellwise, ``--sweeps``
sweeps) and with log-odds mapping, and scores both on the held-out beams: occupancy AUC and predictive NLL (nats per
beam). Every run is appended to ``--cache`` (JSON lines), so a second call only scores what is missing.

Selection: for each log held out, among the settings whose NLL is below log-odds' on every resolution of the other
logs, the one with the highest mean AUC margin over log-odds (bayesmap's AUC minus log-odds', every resolution of
the other logs weighted equally) is chosen and reported on the held-out log, at every resolution ("mean"); and by a
second rule ("tie-by-nll", :data:`TIE`): among those within 0.0005 of the highest mean margin, the one with the
lowest mean NLL margin over log-odds. The map target is a margin of at least 0.01 with a lower NLL than
log-odds' on every log and resolution. The last lines are the settings each rule chooses on every log; the tie
rule's is the defaults'.

A setting with ``readings_per_cell`` ``c > 0`` (``--readings-per-cell``) has no fixed power (``power`` 0 in its row):
its power is ``c`` over the mean number of returned readings per cell of the training scans
(``bayesmap.scenes.log_likelihood_power``), recorded as ``fitted_power``.

Every setting is stated in the world's or the sensor's units, never in cells: the run length in meters
(``bayesmap.model.prior.coupling_for_run_length``; 0 is the independent prior), the sensor noise in meters, the power,
the weights, the pass probability and the prior wall probability as numbers. Cached rows written before the pass
probability, the prior wall probability or the readings per cell was a setting (no ``pass_prob``, ``prior`` or
``readings_per_cell`` key) are read as ``pass_prob`` 0, ``prior`` 0.1 and ``readings_per_cell`` 0 (a fixed power),
the model they were run with. A run length shorter than two cells of a resolution is skipped at that resolution.

Usage: PYTHONPATH=src python benchmarks/map_cv.py [--logs intel,aces,csail] [--resolutions 0.1,0.2]
           [--powers 0.01,0.02,0.05,0.1] [--run-lengths 0,1] [--noises 0.05,0.1] [--z-rands 0.1]
           [--readings-per-cell 0.7,1] [--pass-probs 0] [--prior-wall-probs 0.1] [--step 2] [--sweeps 40]
           [--cache FILE.jsonl] [--json FILE]
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np
from seeded_logs import CORRECTED_LOGS

from bayesmap.evaluation.heldout import evaluate_log
from bayesmap.io.carmen import read_carmen
from bayesmap.model.prior import coupling_for_run_length
from bayesmap.model.sensor import BEAM_DEFAULTS
from bayesmap.scenes import LOG_PRIOR

OLD_PRIOR = 0.1
"""The prior wall probability of every cached row written before it was a setting (no ``prior`` key)."""

KEYS = ("log", "resolution", "power", "readings_per_cell", "run_length", "noise", "z_rand", "pass_prob", "prior",
        "step", "sweeps")
SETTING = ("power", "readings_per_cell", "run_length", "noise", "z_rand", "pass_prob", "prior")
"""A setting's keys, in the order of the tables."""


def floats(text: str) -> list[float]:
    """``"0.1,0.2"`` -> ``[0.1, 0.2]``."""
    return [float(v) for v in text.split(",") if v]


def sensor_params(z_rand: float) -> dict:
    """The beam mixture with ``z_rand`` in place of the default's; the hit weight takes up the difference."""
    params = dict(BEAM_DEFAULTS)
    params["z_hit"] = 1.0 - params["z_short"] - params["z_max"] - z_rand
    params["z_rand"] = z_rand
    return params


def run_one(log, setting: dict) -> dict:
    """Score one setting on one log (the row of the cache)."""
    res = setting["resolution"]
    coupling = coupling_for_run_length(setting["run_length"], res) if setting["run_length"] else 0.0
    scans = np.arange(0, len(log), setting["step"])
    start = time.perf_counter()
    by_density = setting["readings_per_cell"] > 0
    out = evaluate_log(log, scans, resolution=res, sweeps=setting["sweeps"], sensor_noise=setting["noise"],
                       geometry="chord", range_offset=0.0, coupling=coupling,
                       likelihood_power=None if by_density else setting["power"],
                       readings_per_cell=setting["readings_per_cell"] if by_density else None,
                       sensor_params=sensor_params(setting["z_rand"]), wall_pass_prob=setting["pass_prob"],
                       prior_wall_prob=setting["prior"])
    row = dict(setting, coupling=coupling, fitted_power=out["setup"]["likelihood_power"],
               auc=out["bayesmap"]["auc"], nll=out["bayesmap"]["nll"],
               logodds_auc=out["logodds"]["auc"], logodds_nll=out["logodds"]["nll"],
               seconds=round(time.perf_counter() - start, 1))
    print(json.dumps(row), flush=True)
    return row


def key(row: dict) -> tuple:
    return tuple(row[k] for k in KEYS)


def setting_of(row: dict) -> tuple:
    """A row's setting (:data:`SETTING`)."""
    return tuple(row[k] for k in SETTING)


TIE = 0.0005
"""Mean AUC margins closer than this tie (:func:`choose`): a second chain seed moves a setting's mean margin by up
to 0.0003 and one (log, resolution) pair's by up to 0.001 (README, "The prior wall probability")."""


def choose(rows: list[dict], logs: list[str], tie: float = 0.0) -> tuple:
    """The setting (:data:`SETTING`) with the highest mean AUC margin on ``logs``, every (log, resolution) weighted
    equally, among those with a lower NLL than log-odds' on each; settings missing a (log, resolution) of ``logs``
    are not eligible. With ``tie > 0``, among the eligible settings whose mean margin is within ``tie`` of the best,
    the one with the lowest mean NLL margin over log-odds (bayesmap's NLL minus log-odds')."""
    cells = {(r["log"], r["resolution"]) for r in rows if r["log"] in logs}
    by_setting: dict[tuple, dict] = {}
    for r in rows:
        if r["log"] in logs:
            margin = r["auc"] - r["logodds_auc"] if r["nll"] < r["logodds_nll"] else -np.inf
            by_setting.setdefault(setting_of(r), {})[
                (r["log"], r["resolution"])] = (margin, r["nll"] - r["logodds_nll"])
    eligible = {s: (np.mean([a for a, _ in m.values()]), np.mean([b for _, b in m.values()]))
                for s, m in by_setting.items() if set(m) == cells}
    if tie <= 0:
        return max(eligible, key=lambda s: eligible[s][0])
    best = max(v[0] for v in eligible.values())
    return min((s for s, v in eligible.items() if v[0] >= best - tie), key=lambda s: eligible[s][1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--resolutions", default="0.1,0.2")
    parser.add_argument("--powers", default="0.01,0.02,0.05,0.1")
    parser.add_argument("--readings-per-cell", default="")
    parser.add_argument("--run-lengths", default="0,1")
    parser.add_argument("--noises", default="0.05,0.1")
    parser.add_argument("--z-rands", default=str(BEAM_DEFAULTS["z_rand"]))
    parser.add_argument("--pass-probs", default="0")
    parser.add_argument("--prior-wall-probs", default=str(LOG_PRIOR))
    parser.add_argument("--step", type=int, default=2)
    parser.add_argument("--sweeps", type=int, default=40)
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    logs = args.logs.split(",")
    rows = []
    if args.cache and args.cache.exists():
        rows = [json.loads(line) for line in args.cache.read_text().splitlines() if line.strip()]
        rows = [dict(r, pass_prob=r.get("pass_prob", 0.0), prior=r.get("prior", OLD_PRIOR),
                     readings_per_cell=r.get("readings_per_cell", 0.0)) for r in rows]
    done = {key(r) for r in rows}
    for name in logs:
        log = None
        powers = [(p, 0.0) for p in floats(args.powers)] + [(0.0, c) for c in floats(args.readings_per_cell)]
        for res, (power, per_cell), length, noise, z_rand, pass_prob, prior in itertools.product(
                floats(args.resolutions), powers, floats(args.run_lengths), floats(args.noises),
                floats(args.z_rands), floats(args.pass_probs), floats(args.prior_wall_probs)):
            if length and length < 2 * res:
                continue
            setting = dict(log=name, resolution=res, power=power, readings_per_cell=per_cell, run_length=length,
                           noise=noise, z_rand=z_rand, pass_prob=pass_prob, prior=prior, step=args.step,
                           sweeps=args.sweeps)
            if key(setting) in done:
                continue
            log = log or read_carmen(CORRECTED_LOGS[name])
            row = run_one(log, setting)
            rows.append(row)
            done.add(key(row))
            if args.cache:
                with args.cache.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    rows = [r for r in rows if r["log"] in logs and r["step"] == args.step and r["sweeps"] == args.sweeps]
    lookup = {(r["log"], r["resolution"], *setting_of(r)): r for r in rows}
    resolutions = sorted({r["resolution"] for r in rows})
    rules = {"mean": 0.0, "tie-by-nll": TIE}
    print("\n| held out | rule | chosen on the others: power, readings per cell, run length (m), noise (m), z_rand, "
          "pass probability, prior wall probability | "
          + " | ".join(f"{res:g} m: AUC bayesmap / log-odds, NLL bayesmap / log-odds" for res in resolutions) + " |")
    print("|---|---|---|" + "---|" * len(resolutions))
    summary = {"folds": {rule: {} for rule in rules}, "rows": rows, "chosen_on_every_log": {}}
    for held, (rule, tie) in itertools.product(logs, rules.items()):
        setting = choose(rows, [n for n in logs if n != held], tie)
        cells = []
        for res in resolutions:
            r = lookup.get((held, res, *setting))
            cells.append("-" if r is None else f"{r['auc']:.3f} / {r['logodds_auc']:.3f}, "
                                                f"{r['nll']:.2f} / {r['logodds_nll']:.2f}")
        summary["folds"][rule][held] = setting
        print(f"| {held} | {rule} | {', '.join(f'{v:g}' for v in setting)} | " + " | ".join(cells) + " |")
    for rule, tie in rules.items():
        every = choose(rows, logs, tie)
        summary["chosen_on_every_log"][rule] = every
        power = f"readings per cell {every[1]:g}" if every[1] > 0 else f"power {every[0]:g}"
        print(f"\nChosen on every log ({rule}): {power}, run length {every[2]:g} m, noise {every[3]:g} m, "
              f"z_rand {every[4]:g}, pass probability {every[5]:g}, prior wall probability {every[6]:g}")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
