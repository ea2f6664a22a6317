"""The path's 95 % ellipses against what a calibrated posterior scores: a figure from ``karto_peer.py``'s records.

For each run of one or more ``karto_peer.py --methods bayesmap --cache DIR`` folders (each ``DIR/LOG-sSEED.json``),
the left panel draws the range of coverages that the run's posterior samples score when each is put in the truth's
place (:func:`bayesmap.evaluation.trajectory.coverage_rank`: lowest to highest, a tick at the median) and the truth's
own coverage as a dot, the runs grouped by log and scan rate, the target's band (85-99 %) shaded. The right panel is
the histogram of the truth's ranks among the samples (the probability integral transform of the coverage; Dawid
1984) in five bins, with the count a calibrated posterior would put in each (uniform over runs): a pile at 0 means
ellipses too narrow for the error, at 1 too wide. It also prints a table of the same figures.

Usage: PYTHONPATH=src python benchmarks/coverage_ranks.py DIR [DIR ...] --png OUT.png [--title TEXT] [--force]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import save_figure

BAND = (0.85, 0.99)
"""The target's band for the 95 % ellipses' coverage."""

BINS = 5
"""Bins of the rank histogram over [0, 1]."""


def load_runs(folders: list[Path]) -> list[dict]:
    """Every record with bayesmap's coverage rank in ``folders``, in (folder, file name) order: ``{"label", "coverage",
    "low", "median", "high", "rank"}``.

    Raises:
        BayesmapError: if a folder holds no such record (names it).
    """
    runs = []
    for folder in folders:
        found = 0
        for path in sorted(Path(folder).glob("*.json")):
            record = json.loads(path.read_text())
            scores = record.get("bayesmap", {})
            if "coverage_rank" not in scores:
                continue
            found += 1
            runs.append({"label": f"{record['log']} s{record['seed']}", "log": record["log"],
                         "coverage": scores["coverage"], "low": scores["samples_coverage_min"],
                         "median": scores["samples_coverage_median"], "high": scores["samples_coverage_max"],
                         "rank": scores["coverage_rank"]})
        if not found:
            raise BayesmapError(f"{str(folder)!r} holds no karto_peer.py record with bayesmap's coverage rank")
    return runs


def draw(runs: list[dict], title: str):
    """The two-panel figure (module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [3, 1]})
    x = np.arange(len(runs))
    left.axhspan(*BAND, color="0.9", label="target band, 85-99 %")
    left.vlines(x, [r["low"] for r in runs], [r["high"] for r in runs], color="tab:blue", lw=3, alpha=0.5,
                label="the posterior samples' coverage, lowest to highest")
    left.scatter(x, [r["median"] for r in runs], marker="_", s=80, color="tab:blue")
    outside = np.array([r["rank"] in (0.0, 1.0) for r in runs])
    cov = np.array([r["coverage"] for r in runs])
    left.scatter(x[~outside], cov[~outside], color="black", s=14, zorder=3, label="the truth's coverage")
    left.scatter(x[outside], cov[outside], color="tab:red", s=18, zorder=3,
                 label="the truth's, beyond every sample's")
    groups = [i for i in range(1, len(runs)) if runs[i]["log"] != runs[i - 1]["log"]]
    for i in groups:
        left.axvline(i - 0.5, color="0.6", lw=0.8)
    starts = [0, *groups]
    for a, b in zip(starts, [*groups, len(runs)]):  # each group's log above the panel
        left.text((a + b - 1) / 2, 1.01, runs[a]["log"], ha="center", va="bottom", fontsize=8,
                  transform=left.get_xaxis_transform())
    left.set_xticks([])
    left.set_xlim(-0.7, len(runs) - 0.3)
    left.set_ylim(min(0.4, cov.min() - 0.02), 1.01)
    left.set_ylabel("fraction of true positions inside the 95 % ellipses")
    left.set_xlabel("runs (odometry seeds), grouped by log and scan rate")
    left.legend(loc="lower left", fontsize=8)
    ranks = np.array([r["rank"] for r in runs])
    counts, edges = np.histogram(ranks, bins=BINS, range=(0.0, 1.0))
    right.bar(edges[:-1], counts, width=1.0 / BINS, align="edge", color="tab:blue", alpha=0.6, edgecolor="white")
    right.axhline(len(runs) / BINS, color="black", ls="--", lw=1, label="a calibrated posterior")
    right.set_xlim(0, 1)
    right.set_xlabel("the truth's rank among the samples")
    right.set_ylabel("runs")
    right.legend(loc="upper center", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig, counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path, help="karto_peer.py --cache folders")
    parser.add_argument("--png", type=Path, required=True, help="the figure to write")
    parser.add_argument("--title", default="The 95 % ellipses: the truth's coverage among the posterior samples'")
    parser.add_argument("--force", action="store_true", help="overwrite --png if it exists")
    args = parser.parse_args(argv)
    try:
        runs = load_runs(args.folders)
        fig, counts = draw(runs, args.title)
        save_figure(fig, args.png, overwrite=args.force)
    except BayesmapError as err:
        parser.exit(2, f"coverage_ranks.py: {err}\n")
    print("| run | coverage | samples' coverage, lowest-highest (median) | rank |")
    print("|---|---|---|---|")
    for r in runs:
        print(f"| {r['label']} | {r['coverage']:.3f} | {r['low']:.3f}-{r['high']:.3f} ({r['median']:.3f}) | "
              f"{r['rank']:.2f} |")
    print(f"ranks in {BINS} bins over [0, 1]: {', '.join(map(str, counts))} (a calibrated posterior: "
          f"{len(runs) / BINS:.1f} each)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
