"""Leave-one-log-out cross-validation of ``cut_past_reading``: how far past its reading a beam still looks at the map.

For each log (intel, aces, csail), resolution and cut (meters; ``inf`` is the whole beam),
``bayesmap.evaluation.heldout.evaluate_log`` maps the log with every 10th scan held out (the log's defaults,
cellwise, ``--sweeps`` sweeps) and scores bayesmap on the held-out beams, scored whole whatever the cut: occupancy AUC
and predictive NLL (nats per beam), with the run's wall time and the table's (beam, cell) pairs.

Selection, for each log held out: the shortest cut whose mean NLL over the other logs and every resolution is no
higher than the whole beam's, and whose mean AUC there is no lower than the whole beam's minus :data:`AUC_SLACK`
(a shorter cut is cheaper; a cut no worse than whole beams on the logs it was chosen on is the aim). The held-out
log's scores at that cut are printed beside the whole beam's. The last line is the cut chosen on every log: the
default, :data:`bayesmap.scenes.LOG_CUT_PAST_READING`.

``--keyframes D,T`` maps only the training scans that are keyframes at ``D`` meters and ``T`` radians
(``bayesmap.slam.keyframes.select_keyframes``; the held-out scans and log-odds' training scans stay the same), so
that a keyframe rule's cost on the held-out scores is measured beside the cut's.

Every run is appended to ``--cache`` (JSON lines) and not repeated.

Usage: PYTHONPATH=src python benchmarks/cut_cv.py [--logs intel,aces,csail] [--resolutions 0.1,0.2]
           [--cuts 0.5,1,2,inf] [--sweeps 100] [--keyframes 0,0] [--cache FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from seeded_logs import CORRECTED_LOGS

from bayesmap.evaluation.heldout import evaluate_log
from bayesmap.io.carmen import read_carmen

AUC_SLACK = 0.0005
"""AUC differences below this count as equal: a second chain seed moves a log's held-out AUC by up to about
0.0003 (docs/validation/defaults.md, the map model's cross-validation)."""


def run_one(log, name: str, resolution: float, cut: float, sweeps: int, keyframes: tuple[float, float]) -> dict:
    """Score one (log, resolution, cut, keyframe thresholds): the row of the cache."""
    start = time.perf_counter()
    out = evaluate_log(log, resolution=resolution, sweeps=sweeps, cut_past_reading=cut,
                       keyframe_distance=keyframes[0], keyframe_turn=keyframes[1])
    return {"log": name, "resolution": resolution, "cut": cut, "sweeps": sweeps, "keyframes": list(keyframes),
            "train_scans": out["setup"]["keyframes"], "train_pairs": out["setup"]["train_pairs"],
            "auc": out["bayesmap"]["auc"], "nll": out["bayesmap"]["nll"],
            "logodds_auc": out["logodds"]["auc"], "logodds_nll": out["logodds"]["nll"],
            "seconds": round(time.perf_counter() - start, 1)}


def choose(rows: list[dict], logs: list[str], cuts: list[float]) -> float:
    """The shortest cut no worse than the whole beam on ``logs`` (module docstring); ``inf`` if none is."""
    def mean(cut, field):
        values = [r[field] for r in rows if r["log"] in logs and r["cut"] == cut]
        return float(np.mean(values)) if values else math.nan

    whole_nll, whole_auc = mean(math.inf, "nll"), mean(math.inf, "auc")
    for cut in sorted(c for c in cuts if math.isfinite(c)):
        if mean(cut, "nll") <= whole_nll and mean(cut, "auc") >= whole_auc - AUC_SLACK:
            return cut
    return math.inf


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--resolutions", default="0.1,0.2")
    parser.add_argument("--cuts", default="0.5,1,2,inf")
    parser.add_argument("--sweeps", type=int, default=100)
    parser.add_argument("--keyframes", default="0,0", help="keyframe distance (m) and turn (rad) of the training "
                        "scans; 0,0: every one")
    parser.add_argument("--cache", type=Path, default=Path("cut_cv.jsonl"))
    args = parser.parse_args(argv)
    logs = args.logs.split(",")
    resolutions = [float(v) for v in args.resolutions.split(",")]
    cuts = [float(v) for v in args.cuts.split(",")]
    keyframes = tuple(float(v) for v in args.keyframes.split(","))
    rows = [json.loads(line) for line in args.cache.read_text().splitlines()] if args.cache.exists() else []
    for r in rows:  # rows written before keyframes were a setting mapped every training scan
        r.setdefault("keyframes", [0.0, 0.0])
    rows = [r for r in rows if tuple(r["keyframes"]) == keyframes]
    done = {(r["log"], r["resolution"], r["cut"], r["sweeps"]) for r in rows}
    for name in logs:
        log = read_carmen(CORRECTED_LOGS[name])
        for resolution in resolutions:
            for cut in cuts:
                if (name, resolution, cut, args.sweeps) in done:
                    continue
                row = run_one(log, name, resolution, cut, args.sweeps, keyframes)
                rows.append(row)
                with args.cache.open("a") as f:
                    f.write(json.dumps(row) + "\n")
                print(json.dumps(row), flush=True)
    rows = [r for r in rows if r["sweeps"] == args.sweeps and r["log"] in logs and r["resolution"] in resolutions]
    print("\nlog       res   cut    AUC     NLL     log-odds AUC/NLL   seconds")
    for r in sorted(rows, key=lambda r: (r["log"], r["resolution"], r["cut"])):
        print(f"{r['log']:8s} {r['resolution']:.2f} {r['cut']:5.1f}  {r['auc']:.4f}  {r['nll']:.4f}  "
              f"{r['logodds_auc']:.4f}/{r['logodds_nll']:.4f}   {r['seconds']:6.1f}")
    print("\nheld out  chosen on the others   held-out AUC/NLL at it   at whole beams")
    chosen = []
    for held in logs:
        cut = choose(rows, [n for n in logs if n != held], cuts)
        chosen.append(cut)
        at = [r for r in rows if r["log"] == held and r["cut"] == cut]
        whole = [r for r in rows if r["log"] == held and r["cut"] == math.inf]
        print(f"{held:8s}  {cut:5.1f}   {np.mean([r['auc'] for r in at]):.4f}/{np.mean([r['nll'] for r in at]):.4f}"
              f"   {np.mean([r['auc'] for r in whole]):.4f}/{np.mean([r['nll'] for r in whole]):.4f}")
    print(f"\nchosen on every log: {choose(rows, logs, cuts)} (per held-out log: {chosen})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
