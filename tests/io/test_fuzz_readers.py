"""Fuzz tests of every reader (CARMEN log, ROS map PGM + YAML, ASCII map) over mutations of real files.

Property: on any mutation the reader returns a result with finite values and the right geometry, or raises
BayesmapError with a one-line message; never another exception, a hang (each case is bounded by hypothesis's
deadline on a small slice of a real file), or a silent change of geometry (the max range of a mutated CARMEN log
stays the real one, 81.83 m for Intel, and no reading sets the map's extent beyond the max range of a pose).

The budget here is small (``make test``); ``benchmarks/fuzz_readers.py --cases N`` runs the same properties
(``CASES`` below) for N cases each.
"""

import gzip
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayesmap.errors import BayesmapError
from helpers import SHARED_DATA

INTEL = SHARED_DATA / "carmen" / "intel-corrected.log.gz"
WILLOW = SHARED_DATA / "maps" / "willow-full.pgm"
TUTORIAL_MAP = Path(__file__).resolve().parents[2] / "src" / "bayesmap" / "data" / "tutorial.txt"
INTEL_MAX_RANGE = 81.83
NUM_SCANS = 30  # a slice of the real log: the first 30 scans (5,400 beams, 481 of them at the max range)

pytestmark = pytest.mark.skipif(not INTEL.exists() or not WILLOW.exists(), reason="shared data not present")

# Odd numbers a corrupt file may hold, and plain junk.
WEIRD = ["1000", "1e26", "1e308", "-1e308", "-1", "-0", "0", "nan", "NaN", "inf", "-inf", "81.84", "81.83", "500",
         "1e6", "-1e6", "1e-320", "abc", "", "0x10", "1e", "--1", "1_000", "٣", "\x00", "18446744073709551616",
         "180", "181", "1", "2", "99999999999999999999", "3.5e+02"]


def _one_line_error(err: BayesmapError) -> None:
    message = str(err)
    assert message and "\n" not in message and "\r" not in message, repr(message)


def _intel_slice() -> bytes:
    lines, scans = [], 0
    with gzip.open(INTEL, "rt") as handle:
        for line in handle:
            lines.append(line)
            scans += line.startswith("FLASER")
            if scans == NUM_SCANS:
                break
    return "".join(lines).encode()


_BASE: dict = {}


def base(name: str) -> bytes:
    """The unmutated slices of real files (read once)."""
    if name not in _BASE:
        if name == "carmen":
            _BASE[name] = _intel_slice()
        elif name == "pgm":
            from bayesmap.io.rosmap import encode_pgm, read_pgm

            _BASE[name] = encode_pgm(read_pgm(WILLOW)[200:260, 150:230])  # a 60 x 80 crop of Willow Garage
        elif name == "yaml":
            _BASE[name] = (b"image: map.pgm\nresolution: 0.05\norigin: [-10.0, -5.0, 0.0]\nnegate: 0\n"
                           b"occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
        else:
            _BASE[name] = TUTORIAL_MAP.read_bytes()
    return _BASE[name]


# ------------------------------------------------------------------------------------------------------------------
# mutations
# ------------------------------------------------------------------------------------------------------------------


@st.composite
def token_mutation(draw, data: bytes) -> bytes:
    """Replace, delete or duplicate one whitespace-separated token of one line, or insert a weird token."""
    lines = data.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    toks = lines[i].split(b" ")
    j = draw(st.integers(0, max(len(toks) - 1, 0)))
    kind = draw(st.sampled_from(["replace", "delete", "duplicate", "insert"]))
    value = draw(st.one_of(st.sampled_from(WEIRD),
                           st.floats(allow_nan=True, allow_infinity=True).map(repr),
                           st.integers(-10**20, 10**20).map(str))).encode()
    if kind == "replace":
        toks[j:j + 1] = [value]
    elif kind == "delete":
        del toks[j:j + 1]
    elif kind == "duplicate":
        toks[j:j] = toks[j:j + 1]
    else:
        toks.insert(j, value)
    lines[i] = b" ".join(toks)
    return b"\n".join(lines)


@st.composite
def byte_mutation(draw, data: bytes) -> bytes:
    """Truncate, flip a byte, insert random bytes, delete or duplicate a line."""
    kind = draw(st.sampled_from(["truncate", "flip", "insert", "drop_line", "dup_line", "empty"]))
    if kind == "truncate":
        return data[: draw(st.integers(0, len(data)))]
    if kind == "flip":
        k = draw(st.integers(0, len(data) - 1))
        return data[:k] + bytes([data[k] ^ draw(st.integers(1, 255))]) + data[k + 1:]
    if kind == "insert":
        k = draw(st.integers(0, len(data)))
        return data[:k] + draw(st.binary(min_size=1, max_size=8)) + data[k:]
    if kind == "empty":
        return b""
    lines = data.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    lines[i:i + 1] = [] if kind == "drop_line" else [lines[i], lines[i]]
    return b"\n".join(lines)


@st.composite
def mutated(draw, name: str, max_mutations: int = 3) -> bytes:
    data = base(name)
    for _ in range(draw(st.integers(1, max_mutations))):
        if not data:
            break
        data = draw(st.one_of(token_mutation(data), byte_mutation(data)))
    return data


# ------------------------------------------------------------------------------------------------------------------
# properties (also run by benchmarks/fuzz_readers.py)
# ------------------------------------------------------------------------------------------------------------------

COUNTS: dict = {}


def _count(name: str, outcome: str) -> None:
    COUNTS.setdefault(name, {"ok": 0, "refused": 0})[outcome] += 1


def check_carmen(tmp: Path, data: bytes, compress: bool) -> None:
    from bayesmap.geometry.grid import Grid
    from bayesmap.io.carmen import read_carmen

    path = tmp / ("fuzz.log.gz" if compress else "fuzz.log")
    path.write_bytes(gzip.compress(data, mtime=0) if compress else data)
    try:
        log = read_carmen(path)
    except BayesmapError as err:
        _one_line_error(err)
        _count("carmen", "refused")
        return
    assert np.all(np.isfinite(log.ranges)) and np.all(log.ranges >= 0)
    assert np.all(np.isfinite(log.poses)) and np.all(np.isfinite(log.angles))
    assert log.ranges.shape[1] == 180 and log.ranges.shape[0] <= NUM_SCANS + 3
    if len(log) >= NUM_SCANS - 5:  # enough of the log left: the max range is the real one, whatever one value says
        assert log.max_range == INTEL_MAX_RANGE, log
    # no reading sets the extent: every returned endpoint lies within the max range of its pose
    cap = log.max_range if math.isfinite(log.max_range) else float(log.ranges.max())
    returned = ~log.is_max_range
    assert np.all(log.ranges[returned] <= cap)
    ends = log.poses[:, None, :2] + log.ranges[..., None] * np.stack([np.cos(log.angles), np.sin(log.angles)], -1)
    grid = Grid.covering(np.vstack([ends[returned], log.poses[:, :2]]), resolution=0.1, margin=1.0)
    lo, hi = log.poses[:, :2].min(0) - cap - 1.2, log.poses[:, :2].max(0) + cap + 1.2
    xmin, xmax, ymin, ymax = grid.extent
    assert lo[0] <= xmin and xmax <= hi[0] and lo[1] <= ymin and ymax <= hi[1]
    _count("carmen", "ok")


def check_rosmap(tmp: Path, pgm: bytes, yaml: bytes) -> None:
    from bayesmap.io.rosmap import read_rosmap

    (tmp / "map.pgm").write_bytes(pgm)
    (tmp / "map.yaml").write_bytes(yaml)
    try:
        plan = read_rosmap(tmp / "map.yaml")
    except BayesmapError as err:
        _one_line_error(err)
        _count("rosmap", "refused")
        return
    occ = np.asarray(plan.occupancy)
    assert occ.shape == plan.grid.shape and occ.ndim == 2 and occ.size > 0
    assert np.all(np.isfinite(occ)) and np.all((occ >= 0) & (occ <= 1))
    assert math.isfinite(plan.grid.resolution) and plan.grid.resolution > 0
    assert all(math.isfinite(v) for v in plan.grid.origin)
    if pgm == base("pgm"):  # the image untouched: its geometry is the image's (cols, rows)
        assert plan.grid.shape == (80, 60)
    _count("rosmap", "ok")


def check_ascii(tmp: Path, data: bytes) -> None:
    from bayesmap.io.ascii import load_map

    (tmp / "map.txt").write_bytes(data)
    try:
        walls = load_map(tmp / "map.txt")
    except BayesmapError as err:
        _one_line_error(err)
        _count("ascii", "refused")
        return
    rows = [line.rstrip() for line in data.decode("utf-8").strip("\n").split("\n")]
    while rows and not rows[-1]:
        rows.pop()
    assert walls.shape == (len(rows), len(rows[0])) and walls.dtype == np.float32
    assert set(np.unique(walls)) <= {0.0, 1.0}
    _count("ascii", "ok")


# ------------------------------------------------------------------------------------------------------------------
# the tests: a small budget (about 20-40 s in all with the CLI cases)
# ------------------------------------------------------------------------------------------------------------------

FAST = dict(deadline=2000, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
            database=None)


@settings(max_examples=80, **FAST)
@given(data=mutated("carmen"), compress=st.booleans())
def test_fuzz_carmen(tmp_path, data, compress):
    check_carmen(tmp_path, data, compress)


@settings(max_examples=80, **FAST)
@given(pgm=st.one_of(st.just(None), mutated("pgm")), yaml=st.one_of(st.just(None), mutated("yaml")))
def test_fuzz_rosmap(tmp_path, pgm, yaml):
    check_rosmap(tmp_path, base("pgm") if pgm is None else pgm, base("yaml") if yaml is None else yaml)


@settings(max_examples=150, **FAST)
@given(data=mutated("ascii"))
def test_fuzz_ascii(tmp_path, data):
    check_ascii(tmp_path, data)


def test_the_unmutated_slices_read_as_the_real_files(tmp_path):
    """The base of every fuzz case reads, with the real geometry (so the properties above test something)."""
    check_carmen(tmp_path, base("carmen"), compress=True)
    check_rosmap(tmp_path, base("pgm"), base("yaml"))
    check_ascii(tmp_path, base("ascii"))
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(tmp_path / "fuzz.log.gz")
    assert len(log) == NUM_SCANS and log.max_range == INTEL_MAX_RANGE and log.is_max_range.sum() == 481


@pytest.mark.parametrize("value", ["1000", "1e26", "1e308", "500", "81.84"])
def test_one_outlier_never_moves_the_max_range(tmp_path, value):
    """One bigger value in a scan hid the real max range (81.83 m on Intel)."""
    from bayesmap.io.carmen import read_carmen

    lines = base("carmen").split(b"\n")
    i = [k for k, line in enumerate(lines) if line.startswith(b"FLASER")][3]
    toks = lines[i].split(b" ")
    toks[10] = value.encode()
    lines[i] = b" ".join(toks)
    (tmp_path / "one.log").write_bytes(b"\n".join(lines))
    try:
        log = read_carmen(tmp_path / "one.log")
    except BayesmapError as err:
        assert float(value) > 1000 and f":{i + 1}:" in str(err) and "range 9 of 180" in str(err)
        return
    assert log.max_range == INTEL_MAX_RANGE and log.is_max_range[3, 8]
    assert log.is_max_range.sum() == 481 + 1


@settings(max_examples=3, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=mutated("carmen", max_mutations=2))
def test_fuzz_infer_on_mutated_logs(tmp_path_factory, monkeypatch, capsys, data):
    """A small ``bayesmap infer`` (5 scans, log-odds or 2 sweeps) on a mutated log, in-process: outputs with finite
    values, or one line on stderr and exit code 2."""
    from helpers import run_cli

    tmp = tmp_path_factory.mktemp("infer")
    (tmp / "fuzz.log").write_bytes(data)
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", tmp / "fuzz.log", "--scans", "0:5",
                             "--resolution", "0.2", "--sweeps", "2", "--out", tmp / "out")
    if code != 0:
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
        return
    import json

    summary = json.loads((tmp / "out" / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert np.all(np.isfinite(np.load(tmp / "out" / "readings.npy")))
    posterior = np.load(tmp / "out" / "posterior.npy")
    assert np.all((posterior >= 0) & (posterior <= 1))
    assert summary["grid"]["shape"][0] * summary["grid"]["shape"][1] == posterior.size
