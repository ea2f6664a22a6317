"""Fuzz every reader of bayesmap (CARMEN log, ROS map PGM + YAML, ASCII map) for longer than ``make test`` does.

Runs the properties of ``tests/io/test_fuzz_readers.py`` (the same mutations of slices of real files from
shared/data) for ``--cases N`` cases per reader and prints, per reader, how many cases read (with finite values
and the right geometry) and how many were refused with a one-line BayesmapError. Any other outcome (another
exception, a broken property, a case over the deadline) stops the run with hypothesis's report and exit code 1.

Usage: PYTHONPATH=src python benchmarks/fuzz_readers.py --cases 2000 [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "io")]

import test_fuzz_readers as fuzz  # noqa: E402  (the test module's strategies, from tests/ on sys.path)
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import seed as hypothesis_seed  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=2000, help="cases per reader (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="hypothesis seed (default 0)")
    parser.add_argument("--readers", default="carmen,rosmap,ascii", help="comma-separated subset")
    args = parser.parse_args()
    if args.cases < 1:
        parser.error(f"--cases must be >= 1, got {args.cases}")
    if not fuzz.INTEL.exists():
        print(f"shared data not found at {fuzz.SHARED_DATA}", file=sys.stderr)
        return 2
    config = settings(max_examples=args.cases, deadline=5000, database=None,
                      suppress_health_check=list(HealthCheck))
    tmp = Path(tempfile.mkdtemp(prefix="bayesmap-fuzz-"))

    @hypothesis_seed(args.seed)
    @config
    @given(data=fuzz.mutated("carmen"), compress=st.booleans())
    def carmen(data, compress):
        fuzz.check_carmen(tmp, data, compress)

    @hypothesis_seed(args.seed)
    @config
    @given(pgm=st.one_of(st.just(None), fuzz.mutated("pgm")), yaml=st.one_of(st.just(None), fuzz.mutated("yaml")))
    def rosmap(pgm, yaml):
        fuzz.check_rosmap(tmp, fuzz.base("pgm") if pgm is None else pgm, fuzz.base("yaml") if yaml is None else yaml)

    @hypothesis_seed(args.seed)
    @config
    @given(data=fuzz.mutated("ascii"))
    def ascii_map(data):
        fuzz.check_ascii(tmp, data)

    runs = {"carmen": carmen, "rosmap": rosmap, "ascii": ascii_map}
    failed = False
    for name in [n.strip() for n in args.readers.split(",") if n.strip()]:
        start = time.perf_counter()
        try:
            runs[name]()
        except Exception as err:  # hypothesis re-raises the falsifying case's error after printing it
            failed = True
            print(f"{name}: FAILED: {type(err).__name__}: {err}", file=sys.stderr)
        counts = fuzz.COUNTS.get(name, {"ok": 0, "refused": 0})
        total = counts["ok"] + counts["refused"]
        print(f"{name:<7} {total:>6} cases passed: {counts['ok']:>6} read, {counts['refused']:>6} refused with one "
              f"line  ({time.perf_counter() - start:.0f} s)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
