"""Tests for bayesmap.io.carmen: hand-made logs with known answers, every error case, real logs."""

from __future__ import annotations

import gzip
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import CarmenLog, Scan, beam_offsets, read_carmen

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "carmen"


def flaser(ranges, x, y, theta, ts=1.5, host="pippo"):
    r = " ".join(repr(float(v)) for v in ranges)
    return f"FLASER {len(ranges)} {r} {x} {y} {theta} {x} {y} {theta} {ts} {host} {ts}"


def write(tmp_path, lines, name="log.log", gz=False):
    data = ("\n".join(lines) + "\n").encode()
    if gz:
        data = gzip.compress(data)
    p = tmp_path / name
    p.write_bytes(data)
    return p


HEADER = [
    "# message formats defined: PARAM SYNC ODOM FLASER RLASER TRUEPOS",
    "PARAM robot_use_laser on nohost 0",
    "ODOM 0 0 0 0 0 0 0.000246 pippo 0.000246",
]


# --------------------------------------------------------------------------------------------
# hand-made logs with exact answers


def test_even_beam_count_exact_values(tmp_path):
    lines = HEADER + [
        flaser([1.0, 2.0, 3.0, 4.0], 1.0, 2.0, 0.5, ts=10.25),
        "ODOM 1 2 0.5 0 0 0 10.3 pippo 10.3",
        "NEFF 12.5",
        "RLASER 2 1.0 1.0 0 0 0 0 0 0 11 pippo 11",
        flaser([5.0, 6.0, 7.0, 8.0], -3.0, 4.0, -1.0, ts=11.75),
    ]
    log = read_carmen(write(tmp_path, lines))
    assert isinstance(log, CarmenLog)
    assert len(log) == 2
    assert log.path == str(tmp_path / "log.log")
    np.testing.assert_array_equal(log.ranges, [[1, 2, 3, 4], [5, 6, 7, 8]])
    np.testing.assert_array_equal(log.poses, [[1.0, 2.0, 0.5], [-3.0, 4.0, -1.0]])
    np.testing.assert_array_equal(log.timestamps, [10.25, 11.75])
    assert log.ranges.dtype == np.float64 and log.poses.dtype == np.float64
    assert log.angles.shape == (2, 4) and log.is_max_range.shape == (2, 4)
    assert log.is_max_range.dtype == bool
    # even n: spacing fov/n starting at -fov/2: offsets -pi/2, -pi/4, 0, pi/4
    expected_offsets = np.array([-math.pi / 2, -math.pi / 4, 0.0, math.pi / 4])
    np.testing.assert_allclose(log.angles[0], 0.5 + expected_offsets, atol=1e-15)
    np.testing.assert_allclose(log.angles[1], -1.0 + expected_offsets, atol=1e-15)


def test_odd_beam_count_includes_both_ends_and_endpoints(tmp_path):
    # 5 beams over pi: -pi/2, -pi/4, 0, pi/4, pi/2 relative to theta = pi/2 (facing +y)
    p = write(tmp_path, [flaser([2.0, 1.0, 3.0, 1.0, 4.0], 1.0, 2.0, math.pi / 2)])
    log = read_carmen(p)
    a = log.angles[0]
    assert a[0] == pytest.approx(0.0, abs=1e-15)  # first beam: theta - fov/2
    assert a[2] == pytest.approx(math.pi / 2)  # middle beam straight ahead
    assert a[4] == pytest.approx(math.pi)  # last beam: theta + fov/2
    e = log.endpoints(0)
    assert e.shape == (5, 2) and e.dtype == np.float64
    np.testing.assert_allclose(e[2], [1.0, 5.0], atol=1e-12)  # straight ahead, 3 m along +y
    np.testing.assert_allclose(e[0], [3.0, 2.0], atol=1e-12)  # 2 m along +x (theta - pi/2 = 0)
    np.testing.assert_allclose(e[4], [-3.0, 2.0], atol=1e-12)  # 4 m along -x
    np.testing.assert_allclose(e[1], [1 + math.sqrt(0.5), 2 + math.sqrt(0.5)], atol=1e-12)


def test_fov_parameter_changes_angles(tmp_path):
    p = write(tmp_path, [flaser([1.0, 1.0, 1.0], 0, 0, 0.0)])
    log = read_carmen(p, fov=math.radians(270))
    np.testing.assert_allclose(np.degrees(log.angles[0]), [-135.0, 0.0, 135.0])


def test_beam_offsets_rule():
    o180 = beam_offsets(180)
    assert o180.shape == (180,)
    assert o180[0] == pytest.approx(-math.pi / 2)
    assert o180[90] == pytest.approx(0.0, abs=1e-15)
    assert o180[-1] == pytest.approx(math.pi / 2 - math.pi / 180)
    np.testing.assert_allclose(np.diff(o180), math.pi / 180)
    o361 = beam_offsets(361)
    assert o361[0] == pytest.approx(-math.pi / 2)
    assert o361[180] == pytest.approx(0.0, abs=1e-15)
    assert o361[-1] == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(np.diff(o361), math.pi / 360)
    np.testing.assert_array_equal(beam_offsets(1), [0.0])
    with pytest.raises(BayesmapError, match="positive integer.*0"):
        beam_offsets(0)
    with pytest.raises(BayesmapError, match="fov"):
        beam_offsets(10, fov=-1.0)


def test_gzip_detected_by_magic_not_suffix(tmp_path):
    lines = HEADER + [flaser([1.0, 2.0, 3.0], 0.5, 0.25, 0.1), flaser([4.0, 5.0, 6.0], 1, 1, 0.2)]
    plain = read_carmen(write(tmp_path, lines, name="a.log"))
    gz_named_log = read_carmen(write(tmp_path, lines, name="b.log", gz=True))
    plain_named_gz = read_carmen(write(tmp_path, lines, name="c.log.gz"))
    gz = read_carmen(write(tmp_path, lines, name="d.log.gz", gz=True))
    for other in (gz_named_log, plain_named_gz, gz):
        np.testing.assert_array_equal(other.ranges, plain.ranges)
        np.testing.assert_array_equal(other.poses, plain.poses)
        np.testing.assert_array_equal(other.angles, plain.angles)
        np.testing.assert_array_equal(other.timestamps, plain.timestamps)


def test_accepts_crlf_and_missing_optional_trailing_fields(tmp_path):
    p = tmp_path / "crlf.log"
    p.write_bytes(b"PARAM a b\r\nFLASER 2 1.5 2.5 1 2 0.3 1 2 0.3 7.0\r\n")
    log = read_carmen(p)
    np.testing.assert_array_equal(log.ranges, [[1.5, 2.5]])
    np.testing.assert_array_equal(log.poses, [[1, 2, 0.3]])
    assert log.timestamps[0] == 7.0


def test_explicit_max_range(tmp_path):
    p = write(tmp_path, [flaser([1.0, 8.0, 9.5, 7.99], 0, 0, 0), flaser([8.0, 0.0, 2.0, 3.0], 0, 0, 0)])
    log = read_carmen(p, max_range=8.0)
    assert log.max_range == 8.0
    np.testing.assert_array_equal(
        log.is_max_range, [[False, True, True, False], [True, False, False, False]]
    )
    # zero is a valid (if odd) range and is not a max-range reading
    assert log.ranges[1, 1] == 0.0


def test_inferred_max_range_when_largest_value_repeats(tmp_path):
    p = write(tmp_path, [flaser([1.0, 50.0, 3.0, 50.0], 0, 0, 0), flaser([50.0, 2.0, 49.9, 4.0], 0, 0, 0)])
    log = read_carmen(p)
    assert log.max_range == 50.0
    np.testing.assert_array_equal(
        log.is_max_range, [[False, True, False, True], [True, False, False, False]]
    )


def test_no_max_range_inferred_when_largest_value_is_unique(tmp_path):
    p = write(tmp_path, [flaser([1.0, 2.0, 3.0, 4.0], 0, 0, 0), flaser([5.0, 2.0, 3.0, 4.0], 0, 0, 0)])
    log = read_carmen(p)
    assert log.max_range == math.inf
    assert not log.is_max_range.any()


def test_inferred_max_range_needs_a_tenth_of_a_percent(tmp_path):
    # 10 scans x 300 beams = 3000 beams: threshold is 3 beams at the largest value
    rows = [np.full(300, 2.0) for _ in range(10)]
    rows[0][:2] = 30.0
    p2 = write(tmp_path, [flaser(r, 0, 0, 0) for r in rows], name="two.log")
    assert read_carmen(p2).max_range == math.inf
    rows[5][7] = 30.0
    p3 = write(tmp_path, [flaser(r, 0, 0, 0) for r in rows], name="three.log")
    log = read_carmen(p3)
    assert log.max_range == 30.0
    assert log.is_max_range.sum() == 3


def test_scan_and_index_errors(tmp_path):
    p = write(tmp_path, [flaser([1.0, 2.0], 0, 0, 0, ts=3.0), flaser([3.0, 4.0], 5, 6, 0.7, ts=4.0)])
    log = read_carmen(p)
    s = log.scan(1)
    assert isinstance(s, Scan)
    np.testing.assert_array_equal(s.ranges, [3.0, 4.0])
    np.testing.assert_array_equal(s.pose, [5.0, 6.0, 0.7])
    np.testing.assert_allclose(s.angles, [0.7 - math.pi / 2, 0.7])
    assert s.timestamp == 4.0 and isinstance(s.timestamp, float)
    assert log.scan(np.int64(0)).timestamp == 3.0
    with pytest.raises(BayesmapError, match=r"index 2 .*2 scans"):
        log.scan(2)
    with pytest.raises(BayesmapError, match=r"index -1 .*2 scans.*negative"):
        log.scan(-1)
    with pytest.raises(BayesmapError, match=r"index 7 .*2 scans"):
        log.endpoints(7)
    with pytest.raises(BayesmapError, match="integer.*1.0"):
        log.scan(1.0)
    with pytest.raises(BayesmapError, match="integer.*True"):
        log.scan(True)


def test_arrays_are_read_only(tmp_path):
    log = read_carmen(write(tmp_path, [flaser([1.0, 2.0], 0, 0, 0)]))
    for arr in (log.ranges, log.poses, log.angles, log.timestamps, log.is_max_range, log.scan(0).ranges):
        with pytest.raises(ValueError):
            arr[...] = 0


def test_carmenlog_constructor_checks_shapes():
    z = np.zeros((2, 3))
    with pytest.raises(BayesmapError, match=r"poses.*\(2, 3\).*\(2, 2\)"):
        CarmenLog("x", z, np.zeros((2, 2)), z, np.zeros(2), 1.0, z.astype(bool))


# --------------------------------------------------------------------------------------------
# errors


def test_missing_file(tmp_path):
    p = tmp_path / "nope.log.gz"
    with pytest.raises(BayesmapError, match=r"nope\.log\.gz.*does not exist"):
        read_carmen(p)


def test_directory(tmp_path):
    with pytest.raises(BayesmapError, match=rf"{tmp_path.name}.*is a directory"):
        read_carmen(tmp_path)


def test_permission_denied_reported(tmp_path, monkeypatch):
    p = write(tmp_path, [flaser([1.0], 0, 0, 0)], name="secret.log")

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(p))

    import bayesmap.io.files

    monkeypatch.setattr(bayesmap.io.files, "open", denied, raising=False)
    with pytest.raises(BayesmapError, match=r"secret\.log.*permission denied"):
        read_carmen(p)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root ignores file modes")
def test_unreadable_file_mode(tmp_path):
    p = write(tmp_path, [flaser([1.0], 0, 0, 0)], name="locked.log")
    p.chmod(0)
    try:
        with pytest.raises(BayesmapError, match=r"locked\.log.*permission denied"):
            read_carmen(p)
    finally:
        p.chmod(0o600)


def test_binary_junk(tmp_path):
    p = tmp_path / "junk.log"
    p.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(BayesmapError, match=r"junk\.log.*binary"):
        read_carmen(p)


def test_binary_with_nul_bytes(tmp_path):
    p = tmp_path / "nul.log"
    p.write_bytes(b"FLASER 1 1.0 0 0 0 0 0 0 1\n\x00\x00\x00")
    with pytest.raises(BayesmapError, match=r"nul\.log.*binary"):
        read_carmen(p)


def test_truncated_gzip_made_here(tmp_path):
    lines = [flaser(np.linspace(1, 5, 180), i, 0, 0) for i in range(200)]
    full = gzip.compress(("\n".join(lines) + "\n").encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(full[: len(full) // 2])
    with pytest.raises(BayesmapError, match=r"cut\.log\.gz.*truncated"):
        read_carmen(p)
    # the last 8 bytes (CRC + size) missing is also a truncation, not a partial read
    p.write_bytes(full[:-4])
    with pytest.raises(BayesmapError, match=r"cut\.log\.gz.*truncated"):
        read_carmen(p)


def test_corrupt_gzip(tmp_path):
    p = tmp_path / "bad.gz"
    p.write_bytes(b"\x1f\x8b" + b"this is not deflate data at all" * 10)
    with pytest.raises(BayesmapError, match=r"bad\.gz.*gzip"):
        read_carmen(p)


def test_too_few_fields_names_line(tmp_path):
    lines = HEADER + [flaser([1.0, 2.0, 3.0], 0, 0, 0), "FLASER 3 1.0 2.0 3.0 0 0 0 0 0"]
    with pytest.raises(BayesmapError, match=r"log\.log:5: .*too few fields: 10, needs at least 12"):
        read_carmen(write(tmp_path, lines))


def test_too_many_ranges_for_count_names_line(tmp_path):
    line = flaser([1.0, 2.0, 3.0], 0, 0, 0).replace("FLASER 3", "FLASER 2", 1) + " extra junk"
    with pytest.raises(BayesmapError, match=r"log\.log:1: .*too many fields"):
        read_carmen(write(tmp_path, [line]))


def test_non_numeric_range_names_line_and_token(tmp_path):
    lines = HEADER + [flaser([1.0, 2.0, 3.0], 0, 0, 0).replace("2.0", "two", 1)]
    with pytest.raises(BayesmapError, match=r"log\.log:4: .*'two' \(range 2 of 3\) is not a number"):
        read_carmen(write(tmp_path, lines))


def test_non_numeric_pose_names_line_and_field(tmp_path):
    lines = ["FLASER 2 1.0 2.0 abc 0 0 0 0 0 1.0 host 1.0"]
    with pytest.raises(BayesmapError, match=r"log\.log:1: .*'abc' \(x\) is not a number"):
        read_carmen(write(tmp_path, lines))


def test_bad_beam_count_names_line(tmp_path):
    with pytest.raises(BayesmapError, match=r"log\.log:2: .*beam count 'x2' is not an integer"):
        read_carmen(write(tmp_path, ["# c", "FLASER x2 1 2 0 0 0 0 0 0 1"]))
    with pytest.raises(BayesmapError, match=r"log\.log:1: .*beam count 0"):
        read_carmen(write(tmp_path, ["FLASER 0 0 0 0 0 0 0 1"]))
    with pytest.raises(BayesmapError, match=r"log\.log:1: .*no beam count"):
        read_carmen(write(tmp_path, ["FLASER"]))


def test_mixed_beam_counts_names_line(tmp_path):
    lines = [flaser([1.0, 2.0, 3.0], 0, 0, 0), "ODOM 0 0 0 0 0 0 1 h 1", flaser([1.0, 2.0], 0, 0, 0)]
    with pytest.raises(BayesmapError, match=r"log\.log:3: .*2 beams .*line 1 has 3"):
        read_carmen(write(tmp_path, lines))


def test_no_flaser_lines(tmp_path):
    with pytest.raises(BayesmapError, match=r"odom\.log.*no FLASER lines"):
        read_carmen(write(tmp_path, HEADER + ["ODOM 1 1 1 0 0 0 2 h 2"], name="odom.log"))
    p = tmp_path / "empty.log.gz"
    p.write_bytes(gzip.compress(b""))
    with pytest.raises(BayesmapError, match=r"empty\.log\.gz.*no FLASER lines"):
        read_carmen(p)


@pytest.mark.parametrize("bad, what", [("nan", "nan"), ("inf", "inf"), ("-inf", "-inf")])
def test_non_finite_range_names_line(tmp_path, bad, what):
    lines = [flaser([1.0, 2.0], 0, 0, 0), f"FLASER 2 1.0 {bad} 0 0 0 0 0 0 1 h 1"]
    with pytest.raises(BayesmapError, match=rf"log\.log:2: range 2 of 2 is {what}, not a finite"):
        read_carmen(write(tmp_path, lines))


def test_negative_range_names_line(tmp_path):
    lines = [flaser([1.0, 2.0], 0, 0, 0), "# x", "FLASER 2 -0.5 1.0 0 0 0 0 0 0 1 h 1"]
    with pytest.raises(BayesmapError, match=r"log\.log:3: range 1 of 2 is -0\.5, which is negative"):
        read_carmen(write(tmp_path, lines))


def test_non_finite_pose_names_line(tmp_path):
    lines = ["FLASER 2 1.0 1.0 0 nan 0 0 0 0 1 h 1"]
    with pytest.raises(BayesmapError, match=r"log\.log:1: y is nan, not a finite"):
        read_carmen(write(tmp_path, lines))


@pytest.mark.parametrize("mr", [0.0, -1.0, math.inf, math.nan, "50"])
def test_bad_max_range_argument(tmp_path, mr):
    p = write(tmp_path, [flaser([1.0], 0, 0, 0)])
    with pytest.raises(BayesmapError, match="max_range"):
        read_carmen(p, max_range=mr)


@pytest.mark.parametrize("fov", [0.0, -1.0, 7.0, math.nan])
def test_bad_fov_argument(tmp_path, fov):
    p = write(tmp_path, [flaser([1.0], 0, 0, 0)])
    with pytest.raises(BayesmapError, match="fov"):
        read_carmen(p, fov=fov)


def test_errors_are_one_line(tmp_path):
    p = tmp_path / "cut.gz"
    p.write_bytes(gzip.compress(b"FLASER 1 1.0 0 0 0 0 0 0 1\n" * 1000)[:40])
    with pytest.raises(BayesmapError) as info:
        read_carmen(p)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


# --------------------------------------------------------------------------------------------
# real logs

REAL = {
    # name: (scans, beams, max range, beams at max range)
    "intel": (910, 180, 81.83, 4172),
    "aces": (440, 180, 50.0, 620),
    "csail": (406, 361, 81.91, 3907),
}


def _real(name):
    p = DATA / f"{name}-corrected.log.gz"
    if not p.exists():
        pytest.skip(f"real data not found at {p}")
    return p


@pytest.fixture(scope="module")
def real_logs():
    return {}


def _load(real_logs, name):
    if name not in real_logs:
        p = _real(name)
        t = time.perf_counter()
        real_logs[name] = (read_carmen(p), time.perf_counter() - t)
    return real_logs[name]


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_log_shapes_and_max_range(real_logs, name):
    scans, beams, max_range, n_max = REAL[name]
    log, seconds = _load(real_logs, name)
    assert seconds < 2.0
    assert len(log) == scans
    assert log.ranges.shape == (scans, beams) and log.angles.shape == (scans, beams)
    assert log.poses.shape == (scans, 3) and log.timestamps.shape == (scans,)
    assert np.isfinite(log.poses).all()
    assert np.isfinite(log.ranges).all() and (log.ranges >= 0).all()
    assert log.max_range == max_range
    assert int(log.is_max_range.sum()) == n_max
    np.testing.assert_array_equal(log.is_max_range, log.ranges >= max_range)
    # the robot moves: poses span several meters
    assert np.ptp(log.poses[:, 0]) > 5 and np.ptp(log.poses[:, 1]) > 5
    # first beam at theta - pi/2, world-frame endpoints consistent with angles
    np.testing.assert_allclose(log.angles[:, 0], log.poses[:, 2] - math.pi / 2, atol=1e-12)
    i = scans // 2
    e = log.endpoints(i)
    np.testing.assert_allclose(np.hypot(*(e - log.poses[i, :2]).T), log.ranges[i], rtol=1e-12)


def test_real_first_scan_values(real_logs):
    log, _ = _load(real_logs, "intel")
    s = log.scan(0)
    assert s.ranges[:3].tolist() == [1.09, 1.08, 1.08]
    assert s.timestamp == pytest.approx(32.9068)
    with pytest.raises(BayesmapError, match="index 910 .*910 scans"):
        log.scan(910)


def _alignment_cost(log, offsets, pairs, trunc=0.05):
    """Mean truncated nearest-neighbour distance between the endpoint clouds of scan pairs."""
    ok = ~log.is_max_range & (log.ranges < 30)
    cache = {}

    def pts(i):
        if i not in cache:
            a = log.poses[i, 2] + offsets
            r = log.ranges[i]
            xy = np.stack([log.poses[i, 0] + r * np.cos(a), log.poses[i, 1] + r * np.sin(a)], 1)
            cache[i] = xy[ok[i]]
        return cache[i]

    total, count = 0.0, 0
    for i, j in pairs:
        p, q = pts(i), pts(j)
        d2 = (p * p).sum(1)[:, None] + (q * q).sum(1)[None, :] - 2 * p @ q.T
        d = np.sqrt(np.maximum(d2.min(1), 0.0))
        total += np.minimum(d, trunc).sum()
        count += len(d)
    return total / count


@pytest.mark.parametrize("name, n_pairs", [("intel", 300), ("csail", 600)])
def test_real_beam_angle_rule_aligns_scans_best(real_logs, name, n_pairs):
    """Scans 0.5-3 m apart overlap best with the documented rule than with the alternatives."""
    log, _ = _load(real_logs, name)
    P = log.poses
    n = log.ranges.shape[1]
    d = np.hypot(P[:, None, 0] - P[None, :, 0], P[:, None, 1] - P[None, :, 1])
    ii, jj = np.nonzero(np.triu((d > 0.5) & (d < 3.0), 1))
    sel = np.random.default_rng(0).choice(len(ii), n_pairs, replace=False)
    pairs = list(zip(ii[sel], jj[sel]))
    k = np.arange(n)
    fov = math.pi
    ours = log.angles[0] - P[0, 2]
    np.testing.assert_allclose(ours, beam_offsets(n))
    alternatives = {
        "other spacing": -fov / 2 + k * fov / (n - 1) if n % 2 == 0 else -fov / 2 + k * fov / n,
        "half-beam centred": -fov / 2 + (k + 0.5) * fov / n,
        "end-aligned": -fov / 2 + (k + 1) * fov / n,
        "clockwise": fov / 2 - k * fov / (n - 1) if n % 2 else fov / 2 - k * fov / n,
    }
    cost = _alignment_cost(log, ours, pairs)
    for label, offsets in alternatives.items():
        assert cost < _alignment_cost(log, offsets, pairs), label


def test_real_truncated_gzip(tmp_path):
    p = _real("intel")
    cut = tmp_path / "intel-cut.log.gz"
    cut.write_bytes(p.read_bytes()[:50_000])
    with pytest.raises(BayesmapError, match=r"intel-cut\.log\.gz.*truncated"):
        read_carmen(cut)


# ---------------------------------------------------------------------------------------------------------------
# one outlier never sets the max range or the geometry
# ---------------------------------------------------------------------------------------------------------------


def test_inferred_max_range_survives_a_few_larger_values():
    from bayesmap.io.carmen import infer_max_range

    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.5, 20.0, 5000)
    ranges[:400] = 81.83  # saturation, 8 %
    assert infer_max_range(ranges) == 81.83
    for outliers in ([1000.0], [500.0, 82.0], [81.84, 90.0, 1e3]):
        assert infer_max_range(np.concatenate([ranges, outliers])) == 81.83
    # a frequent value is no saturation value when half the beams read more than it, or when as many beams read
    # more than it as read it (without a repeated maximum the log has no max-range readings)
    assert infer_max_range(np.concatenate([np.full(10, 3.0), rng.uniform(4, 9, 100)])) == math.inf
    assert infer_max_range(np.concatenate([np.full(10, 30.0), rng.uniform(1, 9, 100),
                                           np.full(5, 40.0) + np.arange(5)])) == math.inf
    assert infer_max_range(np.zeros(10)) == math.inf


@pytest.mark.parametrize("value, what", [
    ("1e26", "beyond any laser's reach"),
    ("1001", "beyond any laser's reach"),
    ("inf", "not a finite number"),
    ("-0.5", "negative"),
])
def test_an_implausible_range_is_refused_naming_file_line_and_value(tmp_path, value, what):
    p = write(tmp_path, [flaser([1.0, 2.0, 3.0], 0, 0, 0), flaser([1.0, value, 3.0], 0, 0, 0)])
    with pytest.raises(BayesmapError) as info:
        read_carmen(p)
    message = str(info.value)
    assert f"{p}:2:" in message and "range 2 of 3" in message and what in message and "\n" not in message


@pytest.mark.parametrize("index, value, what", [(3, "1e8", "x"), (4, "-2e7", "y"), (5, "1e7", "theta")])
def test_an_implausible_pose_is_refused(tmp_path, index, value, what):
    line = flaser([1.0, 2.0, 3.0], 0, 0, 0).split(" ")
    line[2 + index] = value
    p = write(tmp_path, [flaser([1.0, 2.0, 3.0], 0, 0, 0), " ".join(line)])
    with pytest.raises(BayesmapError, match=rf":2: {what} is .*corrupt"):
        read_carmen(p)


def test_a_log_of_zeros_is_refused(tmp_path):
    p = write(tmp_path, [flaser([0.0, 0.0], 0, 0, 0), flaser([0.0, 0.0], 1, 0, 0)])
    with pytest.raises(BayesmapError, match="all 4 ranges are 0 m"):
        read_carmen(p)


def test_csail_param_line_does_not_set_the_max_range(intel_log):
    """CSAIL's ``PARAM robot_front_laser_max 50`` contradicts its readings, whose "no return" value is 81.91 m."""
    path = intel_log.parent / "csail-corrected.log.gz"
    assert "PARAM robot_front_laser_max 50 " in gzip.open(path, "rt").read()
    log = read_carmen(path)
    assert log.max_range == 81.91 and log.is_max_range.sum() == 3907


def test_with_poses_turns_the_beams_with_the_heading():
    """A log moved to other poses keeps each beam's range and its angle relative to the heading: the endpoints are
    those of the old scan moved rigidly with the pose (to 1e-9 m), and a pose array of the wrong shape is refused."""
    ranges = np.array([[1.0, 2.0, 3.0], [2.0, 2.5, 1.5]])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.5]])
    offsets = np.array([-1.0, 0.0, 1.0])
    log = CarmenLog("x", ranges, poses, poses[:, 2:3] + offsets, np.arange(2.0), 10.0, ranges >= 10.0)
    new = np.array([[2.0, -1.0, 1.0], [0.0, 3.0, -2.0]])
    moved = log.with_poses(new)
    assert np.array_equal(moved.ranges, log.ranges)
    for i in range(2):
        turn = new[i, 2] - poses[i, 2]
        rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        expected = (log.endpoints(i) - poses[i, :2]) @ rot.T + new[i, :2]
        assert np.allclose(moved.endpoints(i), expected, atol=1e-9)
    with pytest.raises(BayesmapError, match=r"poses must be \(2, 3\)"):
        log.with_poses(new[:1])
