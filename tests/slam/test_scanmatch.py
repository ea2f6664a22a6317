"""Correlative scan matching and the pose graph (the SLAM start on real logs) on scenes with a known answer."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import march_first_hit
from bayesmap.io.rosbag import compose_poses, invert_pose
from bayesmap.model.motion import compose, make_motion_params, odometry_controls
from bayesmap.progress import Progress
from bayesmap.slam import posegraph
from bayesmap.slam.scanmatch import (
    FIELD_SEED,
    LOCAL_MAP_DISTANCE,
    MATCH_LEVELS,
    MIN_HIT_FRACTION,
    MOTION_TAIL_WEIGHT,
    ScanData,
    add_to_fields,
    bound_span,
    bounded_lattice_argmax,
    correlative_path,
    empty_fields,
    lattice_scores,
    lattices,
    search,
    step_lattice,
    step_posterior,
)

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


def room_scans(num_poses=12, seed=0):
    """An 8 x 6 m room with a pillar and a side wall on 0.05 m cells; a robot drives an arc through it; exact
    readings (the first-hit distances) of 360 beams, one per degree (a laser scanner's
    spacing) at every true pose; odometry whose increments
    carry 3 cm and 0.03 rad errors per step (so it drifts by decimeters)."""
    rng = np.random.default_rng(seed)
    grid = Grid(shape=(160, 120), resolution=0.05, origin=(0.0, 0.0))
    walls = np.zeros(grid.shape, np.float32)
    walls[[0, -1], :] = 1
    walls[:, [0, -1]] = 1
    walls[60:70, 20:30] = 1  # a pillar (1.4 m below the path)
    walls[110, 0:60] = 1  # a side wall
    t = np.linspace(0, 1.2, num_poses)
    truth = np.stack([1.5 + 4.0 * t, 1.5 + 2.0 * np.sin(2.0 * t), 0.5 * np.cos(2.0 * t)], axis=1)
    beams, readings = exact_scans(walls, grid, truth)
    return grid, truth, noisy_odometry(truth, rng), beams, readings


def noisy_odometry(truth, rng):
    """Odometry chained from increments that carry 3 cm and 0.03 rad errors per step."""
    odometry = [truth[0]]
    for a, b in zip(truth[:-1], truth[1:]):
        inc = posegraph.relative(a, b) + rng.normal(0, [0.03, 0.03, 0.03])
        odometry.append(np.asarray(compose(jnp.asarray(odometry[-1]), jnp.asarray(inc))))
    return np.asarray(odometry, np.float64)


def exact_scans(walls, grid, truth, max_range=20.0):
    """360 beams, one per degree, with the exact first-hit distance at every pose of ``truth``."""
    beams = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    readings = np.stack([np.asarray(march_first_hit(jnp.asarray(walls), jnp.asarray(p[:2]),
                                                    jnp.asarray(p[2] + beams), grid, max_range)) for p in truth])
    return np.tile(beams, (len(truth), 1)), readings


@pytest.mark.parametrize("window", [None, 10.0])
def test_correlative_path_recovers_the_true_path(window):
    """Matching every scan against the field of the scans before it (all of them, or those of the last 10 m of
    travel) recovers the true path to 3 cm and 0.02 rad,
    where the odometry is off by decimeters. Tolerances: the field lives on 0.05 m cells, so a match is good to about
    half a cell (2.5 cm) plus the last search step (3 mm); over walls 1.5-4 m away that half cell is up to 0.017 rad
    of heading. A matcher that ignores the field, searches in the wrong frame or masks out its local map stays on the
    odometry."""
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    path = correlative_path(odometry[0], data, grid.resolution, window=window).path
    assert np.abs(odometry - truth)[:, :2].max() > 0.1
    assert np.abs(path - truth)[:, :2].max() < 0.03
    assert np.abs(path - truth)[:, 2].max() < 0.02


def corridor_scans():
    """An 18 m corridor, 2 m wide, with door recesses at uneven spacing on both sides, 31 scans of a laser reaching
    2.5 m down its middle with noisy odometry: ``(grid, truth (31, 3), odometry (31, 3), ScanData)``."""
    grid = Grid(shape=(440, 66), resolution=0.05, origin=(0.0, 0.0))
    walls = np.zeros(grid.shape, np.float32)
    walls[[0, -1], :] = 1
    walls[:, [10, 50]] = 1
    recesses = {(10, 5): ((30, 12), (70, 8), (95, 20), (150, 8), (190, 14), (230, 16), (290, 10), (330, 6), (370, 24)),
                (50, 55): ((45, 10), (120, 14), (175, 6), (210, 12), (260, 18), (310, 8), (350, 12), (400, 10))}
    for (wall, back), spans in recesses.items():  # cells, 0.3-1.2 m wide, 0.25 m deep
        for start, width in spans:
            walls[start:start + width, wall] = 0
            walls[start:start + width, back] = 1
            walls[[start, start + width - 1], min(wall, back):max(wall, back)] = 1
    truth = np.stack([np.linspace(1.0, 19.0, 31), np.full(31, 1.5), np.zeros(31)], axis=1)
    beams, readings = exact_scans(walls, grid, truth, max_range=2.5)
    odometry = noisy_odometry(truth, np.random.default_rng(1))
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 2.49, np.asarray(inc), np.asarray(cov))
    return grid, truth, odometry, data


def test_the_fields_follow_the_robot_down_a_corridor():
    """A robot drives 18 m down a 2 m corridor with door recesses at uneven spacing on both sides, its laser reaching
    2.5 m. On fields of +-3 m, which must follow it (they hold at least 2.25 m on every side, so every endpoint of
    the local map stays inside), the path is the one of +-30 m fields (no recentring needed in between), bit for
    bit: the fields are moved (the cells both windows cover) and filled (the others) as a rebuild from every scan
    would make them, and every cell coordinate is computed in one frame and shifted in integers. Fields that stayed
    at the first pose would hold no wall beyond x = 4 m; moved fields that kept a cell they should have cleared, or
    missed a scan that reaches a new cell, would change a match. Both paths are
    closer to the truth than half the odometry's error (the corridor leaves the along-track position to the
    recesses; the room test above measures accuracy). Run one scan per call, reporting each (a progress callback),
    the +-3 m fields give the same path, bit for bit: the window's moves carry over from call to call."""
    grid, truth, odometry, data = corridor_scans()
    small, small_cov, _ = correlative_path(odometry[0], data, grid.resolution, half_width=3.0)
    large, large_cov, _ = correlative_path(odometry[0], data, grid.resolution, half_width=30.0)
    np.testing.assert_array_equal(small, large)
    np.testing.assert_array_equal(small_cov, large_cov)
    seen = []
    np.testing.assert_array_equal(correlative_path(odometry[0], data, grid.resolution, half_width=3.0,
                                                   progress=seen.append).path, small)
    assert seen == [Progress("front end", done, 30, "scan") for done in range(31)]
    odometry_error = np.abs(odometry - truth)[:, :2].max()
    assert odometry_error > 0.4
    assert np.abs(small - truth)[:, :2].max() < odometry_error / 2


def test_steps_forced_to_the_odometry_and_a_front_end_resumed_from_a_prefix():
    """The other hypothesis at a step: scan 12 forced to the odometry's step from pose 11 (to float32 rounding of the
    composition, 1e-5 m over 10 m), its covariance the motion model's plus the lattice's floor, every pose before it
    the unforced front end's, bit for bit. Resumed from the unforced path at scan 12 (fields rebuilt from scans 0-11
    in the window the loop had moved to, on +-3 m fields that move down the corridor), the path and covariances are
    the forced run's from the first scan, bit for bit, and its progress starts at scan 11 of 30. An index outside
    the scans is named."""
    grid, truth, odometry, data = corridor_scans()
    base = correlative_path(odometry[0], data, grid.resolution, half_width=3.0)
    forced = correlative_path(odometry[0], data, grid.resolution, half_width=3.0, odometry_steps=[12])
    np.testing.assert_array_equal(forced.path[:12], base.path[:12])
    assert np.abs(forced.path[12:] - base.path[12:])[:, :2].max() > 1e-3  # the step differs
    step = posegraph.relative(forced.path[11], forced.path[12])
    np.testing.assert_allclose(step, data.increments[11], atol=1e-5)
    np.testing.assert_allclose(forced.step_cov[11], data.covs[11] + np.asarray(step_lattice()[-1]), rtol=1e-6)
    seen = []
    resumed = correlative_path(odometry[0], data, grid.resolution, half_width=3.0, odometry_steps=[12], prefix=base,
                               progress=seen.append)
    np.testing.assert_array_equal(resumed.path, forced.path)
    np.testing.assert_array_equal(resumed.step_cov, forced.step_cov)
    assert seen[0] == Progress("front end", 11, 30, "scan") and seen[-1] == Progress("front end", 30, 30, "scan")
    for bad in (0, 31, 2.5):
        with pytest.raises(BayesmapError, match=f"odometry step {bad!r}"):
            correlative_path(odometry[0], data, grid.resolution, odometry_steps=[bad])


def test_a_front_end_stopped_where_until_says_is_the_whole_runs_up_to_there():
    """``until`` sees the path matched so far after each block (one scan a block here: 30 steps), every pose and
    covariance the whole run's to the bit, and the run ends at the scan it returns: a scan before the block's last
    one (17 of 0..19) cuts the path there. Resumed from a prefix, the blocks start at its first forced scan."""
    grid, truth, odometry, data = corridor_scans()
    base = correlative_path(odometry[0], data, grid.resolution, half_width=3.0)
    whole = correlative_path(odometry[0], data, grid.resolution, half_width=3.0, odometry_steps=[12])
    seen = []

    def until(path, step_cov):
        np.testing.assert_array_equal(path, whole.path[:len(path)])
        np.testing.assert_array_equal(step_cov, whole.step_cov[:len(path) - 1])
        seen.append(len(path))
        return 17 if len(path) == 20 else None

    stopped = correlative_path(odometry[0], data, grid.resolution, half_width=3.0, odometry_steps=[12], prefix=base,
                               until=until)
    assert seen == list(range(13, 21))
    np.testing.assert_array_equal(stopped.path, whole.path[:18])
    np.testing.assert_array_equal(stopped.step_cov, whole.step_cov[:17])
    never = correlative_path(odometry[0], data, grid.resolution, half_width=3.0, until=lambda path, cov: None)
    np.testing.assert_array_equal(never.path, base.path)


def test_a_window_shorter_than_every_step_leaves_the_odometry():
    """With a local map of the last 1 micrometer of travel, no earlier scan is in any match's window, so each scan is
    placed at the motion model's mode, the odometry's prediction, up to the finest lattice step per scan (3 mm and
    0.8 mrad: the prior's curvature at that scale is below the float32 rounding of the scan's score), so the path
    stays a decimeter off the truth where the 10 m window recovers it to 3 cm: the window does exclude the scans
    beyond it."""
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    path = correlative_path(odometry[0], data, grid.resolution, window=1e-6).path
    steps = np.arange(len(path))[:, None] * np.array([0.003, 0.003, 0.0008]) + 1e-5
    assert np.all(np.abs(path - odometry) <= steps)
    assert np.abs(path - truth)[:, :2].max() > 0.1


def test_the_likelihood_power_weighs_the_scan_against_the_motion_model():
    """The match maximizes ``p S + L`` (``S`` the scan's field score, ``L`` the motion model's log-density): the same
    argmax as ``S + L'`` with every motion covariance multiplied by ``p`` (``L' = L / p + const``), so the two paths
    agree up to one step of the finest lattice per scan (3 mm, 0.8 mrad: float32 rounding can break a near-tie the
    other way, and a later match starts from the earlier one). The power matters: at 1e-6 the scan's pull is far below
    the prior's curvature even over the last lattice step (about 0.001 nats of motion density per step of heading, a
    few nats of scan score, against a million) and the path is the odometry's prediction (as with an empty window,
    test above), a decimeter off the truth; at 1 the path differs from the one at 0.1."""
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))

    def path(power, scale=1.0):
        data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov) * scale)
        return correlative_path(odometry[0], data, grid.resolution, half_width=6.0, likelihood_power=power).path

    steps = np.arange(len(truth))[:, None] * np.array([0.003, 0.003, 0.0008]) + 1e-5
    tempered, tiny = path(0.1), path(1e-6)
    assert np.all(np.abs(tempered - path(1.0, scale=0.1)) <= steps)
    assert np.all(np.abs(tiny - odometry) <= steps)
    assert np.abs(tiny - truth)[:, :2].max() > 0.1
    assert not np.array_equal(path(1.0), tempered)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(BayesmapError, match="likelihood_power"):
            path(bad)


def test_the_log_front_end_matches_at_the_problems_likelihood_power(monkeypatch):
    """run_log_slam's front end scores scans at the problem's own likelihood power (the power its target gives the
    readings; docs/slam.md), from the first odometry pose, on fields of FRONT_END_RESOLUTION, trusting matches
    above MIN_HIT_FRACTION: the call it makes."""
    from types import SimpleNamespace

    from bayesmap.slam import pipeline

    calls = []
    monkeypatch.setattr(pipeline, "correlative_path",
                        lambda first, data, resolution, **options: calls.append((first, data, resolution, options)))
    motion = make_motion_params((0.2, 0.1, 0.1, 0.05))
    problem = SimpleNamespace(odometry=np.array([[1.0, 2.0, 0.3], [1.5, 2.0, 0.3]]), likelihood_power=0.25,
                              motion=motion)
    pipeline.front_end(problem, "scans")
    pipeline.front_end(problem, "scans", min_hit_fraction=0.3, window=20.0)  # front_end_cv.py's settings
    (first, data, resolution, options), (_, _, _, chosen) = calls
    assert np.array_equal(first, [1.0, 2.0, 0.3]) and data == "scans"
    assert resolution == pipeline.FRONT_END_RESOLUTION
    assert options == {"likelihood_power": 0.25, "min_hit_fraction": MIN_HIT_FRACTION, "window": LOCAL_MAP_DISTANCE,
                       "progress": None, "levels": MATCH_LEVELS, "motion_tail": MOTION_TAIL_WEIGHT, "motion": motion,
                       "field_seed": FIELD_SEED, "odometry_steps": None, "prefix": None, "until": None}
    assert chosen == {"likelihood_power": 0.25, "min_hit_fraction": 0.3, "window": 20.0, "progress": None,
                      "levels": MATCH_LEVELS, "motion_tail": MOTION_TAIL_WEIGHT, "motion": motion,
                      "field_seed": FIELD_SEED, "odometry_steps": None, "prefix": None, "until": None}


@pytest.mark.parametrize("heading_error", [0.3, 0.5])
def test_the_motion_tail_lets_a_scan_match_far_from_an_outlying_odometry_step(heading_error):
    """Step 6 of the test room's odometry turns 0.3 or 0.5 rad more than the robot did, 6.5-8 standard deviations of
    the motion model's heading there, as a step that backed up can; the scans have 120 beams (one per 3 degrees) and
    the search scores them at the logs' likelihood power 0.1. With the motion model's Normal alone the search stays
    near the prediction, the match falls short of the least hit fraction and the path keeps the odometry's error
    (more than 0.3 m off); with the default tail (MOTION_TAIL_WEIGHT of the backward step's covariance) the scan is
    matched where it fits and every pose is within 5 cm and 0.02 rad of the truth (measured 4.3 cm and 0.009 rad:
    the sparser beams place a match less tightly than the test above's 360). A bad weight is an error."""
    grid, truth, odometry, beams, readings = room_scans()
    beams, readings = beams[:, ::3], readings[:, ::3]
    steps = posegraph.relative(odometry[:-1], odometry[1:])
    steps[6, 2] += heading_error
    outlying = [odometry[0]]
    for u in steps:
        outlying.append(np.asarray(compose(jnp.asarray(outlying[-1]), jnp.asarray(u))))
    inc, cov = odometry_controls(np.asarray(outlying), make_motion_params((0.1, 0.05, 0.1, 0.05)))
    assert heading_error > 6 * np.sqrt(cov[6, 2, 2])
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))

    def path(tail):
        return correlative_path(outlying[0], data, grid.resolution, likelihood_power=0.1, motion_tail=tail).path

    normal, tailed = path(0.0), path(MOTION_TAIL_WEIGHT)
    assert np.abs(normal - truth)[:, :2].max() > 0.3
    assert np.abs(tailed - truth)[:, :2].max() < 0.05
    assert np.abs(tailed - truth)[:, 2].max() < 0.02
    for bad in (-0.1, 1.0, True):
        with pytest.raises(BayesmapError, match="motion_tail"):
            path(bad)


def test_a_scan_that_misses_its_local_map_takes_the_odometrys_step():
    """Scan 6 of the test room reads clutter 0.3-1 m from the sensor on every beam (someone stands at the laser), so
    no pose puts its endpoints on the local map. With a least hit fraction of 0.3 its pose is the odometry's
    prediction from pose 5 (to float32 rounding), and the scans after it match the room again (3 cm and 0.02 rad, as
    in the test above; scan 7's local map holds the room's walls from scans 0-5 beside scan 6's clutter, so pose 6's
    3 cm odometry error does not carry over); trusting every match (0), scan 6 takes some other step, wherever its
    clutter fits best."""
    grid, truth, odometry, beams, readings = room_scans()
    readings[6] = np.random.default_rng(3).uniform(0.3, 1.0, readings.shape[1])
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    guarded, guarded_cov, _ = correlative_path(odometry[0], data, grid.resolution, min_hit_fraction=0.3)
    trusting = correlative_path(odometry[0], data, grid.resolution, min_hit_fraction=0.0).path
    followed = np.abs(posegraph.relative(guarded[5], guarded[6]) - inc[5])
    assert followed.max() < 1e-4
    assert np.abs(posegraph.relative(trusting[5], trusting[6]) - inc[5]).max() > 1e-3
    later = np.r_[np.arange(6), np.arange(7, len(truth))]
    assert np.abs(guarded - truth)[later, :2].max() < 0.03
    assert np.abs(guarded - truth)[later, 2].max() < 0.02
    # the step to the untrusted scan 6 has the motion model's covariance (plus the lattice's floor); a trusted step
    # is far tighter than the odometry
    np.testing.assert_allclose(guarded_cov[5], np.asarray(cov[5]) + np.asarray(step_lattice()[-1]), rtol=1e-5)
    assert np.all(guarded_cov[6, [0, 1], [0, 1]] < np.asarray(cov[6])[[0, 1], [0, 1]] / 4)


@pytest.mark.parametrize("heading", [0.0, 2.3])
def test_a_step_posterior_without_a_map_is_the_motion_models(heading):
    """With empty fields every candidate's scan score is the same, so the step's posterior is the motion model's
    Gaussian: its covariance, in the previous pose's frame, is the step's covariance (correlations included, the
    previous pose turned by 0 or 2.3 rad: a missing or wrong rotation into that frame fails), to the quadrature error
    of the 13 x 13 x 9 lattice plus its floor (measured 0.1-0.5 % on these standard deviations of 3-5 cm and 0.01 rad;
    the tolerance 2 % of each variance and 2 % of the scale of each covariance). Narrower than the lattice's
    innermost cell, a deterministic step reads as the floor."""
    grid = Grid(shape=(64, 64), resolution=0.05, origin=(0.0, 0.0))
    sd = np.array([0.05, 0.03, 0.01])
    corr = np.array([[1.0, 0.4, -0.3], [0.4, 1.0, 0.2], [-0.3, 0.2, 1.0]])
    cov = corr * np.outer(sd, sd)
    increment = np.array([0.3, 0.05, 0.1])
    prev = np.array([1.6, 1.6, heading])
    center = np.asarray(compose(jnp.asarray(prev), jnp.asarray(increment)))
    lattice = step_lattice()
    beams, ranges = jnp.linspace(-1.0, 1.0, 8), jnp.full(8, 2.0)
    got = np.asarray(step_posterior(empty_fields(grid), grid, jnp.asarray(center), jnp.asarray(prev),
                                    jnp.asarray(increment), jnp.asarray(cov), beams, ranges, ranges > 0, 0.1, lattice),
                     np.float64)
    want = cov + np.asarray(lattice[-1])
    np.testing.assert_allclose(got, want, atol=0.02 * np.outer(sd, sd).max(), rtol=0.02)
    np.testing.assert_allclose(np.diag(got), np.diag(want), rtol=0.02)
    fixed = step_posterior(empty_fields(grid), grid, jnp.asarray(center), jnp.asarray(prev), jnp.asarray(increment),
                           jnp.zeros((3, 3)), beams, ranges, ranges > 0, 0.1, lattice)
    np.testing.assert_allclose(np.asarray(fixed), np.asarray(lattice[-1]), rtol=1e-6)


def test_the_step_lattice_is_dense_near_the_match_and_checks_its_nodes():
    """STEP_POSTERIOR_NODES: 13 x 13 positions and 9 headings, the innermost nodes at 0.012 m and 0.005 rad, the
    outermost at 0.3 m and 0.05 rad, gaps growing outwards; the cell volumes tile the lattice's span (the widths of
    one axis sum to its extent)."""
    xy, theta, log_volume, floor = (np.asarray(a, np.float64) for a in step_lattice())
    x = np.unique(xy[:, 0])
    assert xy.shape == (169, 2) and theta.shape == (9,) and log_volume.shape == (169 * 9,)
    np.testing.assert_allclose([x[7], x[-1], theta[5], theta[-1]], [0.012, 0.3, 0.005, 0.05], rtol=1e-6)
    assert np.all(np.diff(np.diff(x[6:])) > 0)
    np.testing.assert_allclose(np.exp(log_volume).sum(), 0.6**2 * 0.1, rtol=1e-6)
    np.testing.assert_allclose(np.diag(floor), np.array([0.012, 0.012, 0.005]) ** 2 / 12)
    for bad in (((0.3, 0.012, 6), (0.005, 0.05, 4)), ((0.012, 0.3, 1), (0.005, 0.05, 4))):
        with pytest.raises(BayesmapError, match="step lattice nodes"):
            step_lattice(bad)


def test_correlative_path_checks_shapes():
    grid, truth, odometry, beams, readings = room_scans(num_poses=3)
    inc, cov = odometry_controls(odometry)
    with pytest.raises(BayesmapError, match="shapes disagree"):
        correlative_path(odometry[0], ScanData(beams[:, :10], readings, readings > 0, np.asarray(inc),
                                               np.asarray(cov)), grid.resolution)
    data = ScanData(beams, readings, readings > 0, np.asarray(inc), np.asarray(cov))
    for bad in (-0.1, 1.0, float("nan"), False):
        with pytest.raises(BayesmapError, match=f"min_hit_fraction .*{bad!r}"):
            correlative_path(odometry[0], data, grid.resolution, min_hit_fraction=bad)


def test_relative_inverts_compose():
    """relative(a, compose(a, d)) == d for random poses and increments (the pose graph's edge measurement is the
    motion model's increment), to float32 rounding."""
    rng = np.random.default_rng(1)
    a = rng.normal(0, 3, (50, 3))
    d = rng.normal(0, 1, (50, 3))
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    b = np.asarray(compose(jnp.asarray(a), jnp.asarray(d)))
    np.testing.assert_allclose(posegraph.relative(a, b), d, atol=1e-5)  # compose runs in float32


def square_loop():
    """Poses around a 4 x 4 m square, 1 m apart, heading along the path (16 poses)."""
    side = np.arange(4.0)
    xy = np.concatenate([np.stack([side, 0 * side], 1), np.stack([4 + 0 * side, side], 1),
                         np.stack([4 - side, 4 + 0 * side], 1), np.stack([0 * side, 4 - side], 1)])
    heading = np.repeat([0.0, np.pi / 2, np.pi, -np.pi / 2], 4)
    return np.concatenate([xy, heading[:, None]], axis=1)


def drifted_square_loop():
    """:func:`square_loop` (the truth), its sequential edges with a 0.15 rad heading error added at step 3, and the
    path those edges compose to (it ends over 0.5 m off)."""
    truth = square_loop()
    seq = posegraph.sequential_edges(truth)
    z = seq.z.copy()
    z[3, 2] += 0.15
    drifted = [truth[0]]
    for inc in z:
        drifted.append(np.asarray(compose(jnp.asarray(drifted[-1]), jnp.asarray(inc))))
    return truth, seq._replace(z=z), np.asarray(drifted)


def square_loop_with_a_false_match():
    """:func:`drifted_square_loop` and four loop edges, three measured exactly and the last (4 -> 12) a meter off
    along x, as a corridor matched along its axis: ``(truth, seq, drifted, loops)``."""
    truth, seq, drifted = drifted_square_loop()
    i, j = np.array([0, 1, 0, 4]), np.array([15, 15, 14, 12])
    measured = posegraph.relative(truth[i], truth[j])
    measured[3, 0] += 1.0
    return truth, seq, drifted, posegraph.Edges(i, j, measured, np.tile([0.05, 0.05, 0.02], (4, 1)))

def test_pose_graph_closes_a_loop():
    """A square loop whose sequential edges carry a 0.15 rad heading error at one step (the path ends over 0.5 m off):
    with one correct loop edge (last -> first) the optimized path is within 0.25 m of the truth everywhere (the
    heading error is spread over the loop's edges), and
    without it the error stays: the loop edge, not the optimizer, makes the difference."""
    truth, seq, drifted = drifted_square_loop()
    assert np.hypot(*(drifted - truth)[:, :2].T).max() > 0.5
    loop = posegraph.Edges(np.array([0]), np.array([15]), posegraph.relative(truth[:1], truth[15:]),
                           np.array([[0.01, 0.01, 0.005]]))
    closed = posegraph.optimize_pose_graph(drifted, posegraph.concat_edges(seq, loop))
    assert np.hypot(*(closed - truth)[:, :2].T).max() < 0.25
    open_path = posegraph.optimize_pose_graph(drifted, seq)
    assert np.hypot(*(open_path - truth)[:, :2].T).max() > 0.5


def test_a_loop_bends_the_path_at_the_step_the_front_end_could_not_pin_down():
    """The drifted square loop and one exact loop edge, the sequential edges at ``SEQUENTIAL_STD`` except the step
    that holds the 0.15 rad heading error, whose covariance (as the front end's step posterior gives one for a match
    it could not pin down) has a 0.1 rad heading deviation: the optimized path puts the error on that step and is
    within 2 cm of the truth everywhere (1.4 cm: the other steps' share of the loop's residual). With every step at
    ``SEQUENTIAL_STD`` the same loop spreads the error over all the steps, 0.17 m off at the worst pose."""
    truth, seq, drifted = drifted_square_loop()
    cov = np.tile(np.diag(np.square(posegraph.SEQUENTIAL_STD)), (len(seq.i), 1, 1))
    cov[3, 2, 2] = 0.1**2
    loop = posegraph.Edges(np.array([0]), np.array([15]), posegraph.relative(truth[:1], truth[15:]),
                           np.array([[0.01, 0.01, 0.005]]))
    steps = posegraph.optimize_pose_graph(drifted, posegraph.concat_edges(posegraph.with_covariances(seq, cov), loop))
    fixed = posegraph.optimize_pose_graph(drifted, posegraph.concat_edges(seq, loop))
    assert np.hypot(*(steps - truth)[:, :2].T).max() < 0.02
    assert np.hypot(*(fixed - truth)[:, :2].T).max() > 0.15


def test_the_loop_gate_drops_a_false_loop_match():
    """The square loop with the drifted sequential edges, three correct loop edges and one false one (a match a
    meter off, as a corridor matched along its axis): the gate finds it (its residual is tens of sigma, the true
    edges' a few) and drops only it, and the re-solved path is the solution of the graph without it (to 1 mm). The
    false edge matters: the robust solve that keeps it is twice as far from the truth on average (0.14 m against
    0.07 m, deterministic; the bound is 0.6 of it)."""
    truth, seq, drifted, loops = square_loop_with_a_false_match()
    robust = posegraph.optimize_pose_graph(drifted, posegraph.concat_edges(seq, loops))
    gated, kept, _ = posegraph.optimize_with_loop_gate(drifted, seq, loops)
    assert list(zip(kept.i, kept.j)) == [(0, 15), (1, 15), (0, 14)]
    true_loops = loops.take(slice(0, 3))
    clean = posegraph.optimize_pose_graph(drifted, posegraph.concat_edges(seq, true_loops))
    np.testing.assert_allclose(gated[:, :2], clean[:, :2], atol=1e-3)
    error, robust_error = (np.hypot(*(p - truth)[:, :2].T).mean() for p in (gated, robust))
    assert error < 0.6 * robust_error


def test_the_gate_keeps_the_hypothesis_without_the_false_loop_match():
    """The same graph: the false edge fails the pairwise consistency test with each true one (its cycles' squared
    norms are 40-53; the true edges' cycles close exactly here), so the maximal consistent sets are the three true
    edges and the false one alone, and weighed against each other and the empty set the true three take all the
    weight (each true edge left out costs its Gaussian density against the search window's uniform one)."""
    truth, seq, drifted, loops = square_loop_with_a_false_match()
    norms = posegraph.pairwise_consistency(seq, loops)
    gate = posegraph.CONSISTENCY_GATE
    assert np.all(norms[3, :3] > 2 * gate) and np.all(norms[:3, 3] > 2 * gate)
    assert norms[:3, :3].max() < gate / 4
    sets, count = posegraph.consistent_sets(norms)
    assert [c.tolist() for c in sets] == [[0, 1, 2], [3]] and count == 2
    _, kept, hypotheses = posegraph.optimize_with_loop_gate(drifted, seq, loops)
    assert hypotheses.sets[0].tolist() == [0, 1, 2] and hypotheses.weights[0] > 0.999
    assert {tuple(c.tolist()) for c in hypotheses.sets} == {(0, 1, 2), (3,), ()}
    assert hypotheses.weights.sum() == pytest.approx(1.0)


def correlated_covariances(count: int, seed: int = 0) -> np.ndarray:
    """``(count, 3, 3)`` covariances of relative poses with unequal x and y and correlated components (a step's
    posterior along a corridor: long along it, its heading tied to the sideways position), 1-12 cm and 0.005-0.05
    rad."""
    rng = np.random.default_rng(seed)
    factor = rng.normal(size=(count, 3, 3)) * np.array([0.06, 0.03, 0.02])[:, None]
    return factor @ np.swapaxes(factor, 1, 2) + np.diag([1e-4, 1e-4, 2.5e-5])


@pytest.mark.parametrize("kind", ["independent", "correlated"])
def test_the_cycle_norm_is_the_cycles_monte_carlo_covariance(kind):
    """``pairwise_consistency``'s first-order covariance of a cycle's error against the covariance of 4,000 cycles
    with every edge drawn with its noise (a 60-step arc of 0.3 m steps, three loop edges from its end back to its
    start; the sequential edges' noise independent per component, or a full covariance per edge, as the front end's
    step posteriors give them): a loop edge moved 5 cm sideways gives each cycle an error ``e``, and its squared norm
    under the two covariances agrees within 10 % (the sample covariance of 4,000 draws is within about 5 % at two
    standard errors; the rest is the first-order approximation's, at these noise levels under 2 %)."""
    rng = np.random.default_rng(0)
    t = np.linspace(0, 2.2 * np.pi, 61)
    path = np.stack([3 * np.cos(t), 3 * np.sin(t), posegraph.wrap_angle(t + np.pi / 2)], axis=1)
    seq = posegraph.sequential_edges(path)
    factors = np.broadcast_to(np.diag(posegraph.SEQUENTIAL_STD), (len(seq.i), 3, 3))
    if kind == "correlated":
        cov = correlated_covariances(len(seq.i)) / 4  # 0.5-6 cm: within the first order's reach
        seq, factors = posegraph.with_covariances(seq, cov), np.linalg.cholesky(cov)
    pairs = np.array([[2, 57], [5, 60], [1, 55]])
    loops = posegraph.Edges(pairs[:, 0], pairs[:, 1], posegraph.relative(path[pairs[:, 0]], path[pairs[:, 1]]),
                            np.tile(posegraph.LOOP_STD, (3, 1)))

    def cycle(seq_z, loop_z, a, b):
        """The cycle's end for edges ``seq_z`` ``(..., 60, 3)`` and ``loop_z`` ``(..., 3, 3)`` (draws at once)."""
        odometry = [np.zeros(seq_z.shape[:-2] + (3,))]
        for k in range(seq_z.shape[-2]):
            odometry.append(compose_poses(odometry[-1], seq_z[..., k, :]))
        at_jb = compose_poses(loop_z[..., a, :], posegraph.relative(odometry[pairs[a, 1]], odometry[pairs[b, 1]]))
        at_ib = compose_poses(at_jb, invert_pose(loop_z[..., b, :]))
        end = compose_poses(at_ib, posegraph.relative(odometry[pairs[b, 0]], odometry[pairs[a, 0]]))
        return np.concatenate([end[..., :2], posegraph.wrap_angle(end[..., 2:])], axis=-1)

    moved = loops.z.copy()
    moved[0] = compose_poses(moved[0], np.array([0.0, 0.05, 0.0]))
    norms = posegraph.pairwise_consistency(seq, loops._replace(z=moved))
    for a, b in [(0, 1), (0, 2)]:
        draws = cycle(seq.z + np.einsum("eij,nej->nei", factors, rng.standard_normal((4000, *seq.z.shape))),
                      loops.z + rng.standard_normal((4000, *loops.z.shape)) * loops.std, a, b)
        e = cycle(seq.z, moved, a, b)
        assert np.abs(e[:2]).max() > 0.04  # the cycle is open by the move
        assert norms[a, b] == pytest.approx(e @ np.linalg.solve(np.cov(draws.T), e), rel=0.1)
        assert norms[b, a] == pytest.approx(norms[a, b], rel=0.02)  # the cycle run the other way


@settings(max_examples=40, deadline=None)
@given(strategies.integers(1, 8).flatmap(
    lambda n: strategies.lists(strategies.booleans(), min_size=n * n, max_size=n * n)))
def test_consistent_sets_are_every_maximal_consistent_set(flags):
    """Against enumeration of every subset: the sets ``consistent_sets`` returns are exactly the subsets whose
    pairs all pass the gate and to which no other edge can be added, largest first."""
    n = int(round(len(flags) ** 0.5))
    norms = np.where(np.array(flags).reshape(n, n), 1.0, 100.0)
    ok = np.maximum(norms, norms.T) <= 10.0
    subsets = [c for r in range(1, n + 1) for c in itertools.combinations(range(n), r)
               if all(ok[p, q] for p, q in itertools.combinations(c, 2))]
    maximal = {c for c in subsets if not any(set(c) < set(d) for d in subsets)}
    sets, count = posegraph.consistent_sets(norms, gate=10.0)
    assert {tuple(c.tolist()) for c in sets} == maximal and count == len(maximal)
    assert [len(c) for c in sets] == sorted((len(c) for c in sets), reverse=True)


def test_one_loop_edges_evidence_is_its_predictive_density_given_the_odometry():
    """For one loop edge ``0 -> j`` on a chain of sequential edges, ``log_evidence`` with the edge true less with it
    false is ``log N(z; relative(x_0, x_j), R^T Sigma_j R + Sigma_loop) + log V``: the Gaussian predictive density of
    the measurement given the odometry (pose ``j``'s covariance from ``marginal_covariances`` of the chain, turned
    into pose 0's frame) against the search window's uniform density. Both are exact for the graph linearized at
    the odometry path (chained here in float64), so they agree to rounding."""
    truth, seq, _ = drifted_square_loop()
    drifted = posegraph.odometry_path(seq)  # starts at truth[0], the origin
    z = posegraph.relative(truth[:1], truth[14:15])
    loop = posegraph.Edges(np.array([0]), np.array([14]), z, np.array([[0.1, 0.1, 0.04]]))
    difference = (posegraph.log_evidence(drifted, seq, loop, [0])
                  - posegraph.log_evidence(drifted, seq, loop, np.zeros(0, np.int64)))
    cov_j = posegraph.marginal_covariances(drifted, seq)[14]
    c, s = np.cos(drifted[0, 2]), np.sin(drifted[0, 2])
    rotation = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    predictive = rotation.T @ cov_j @ rotation + np.diag(np.square(loop.std[0]))
    error = z[0] - posegraph.relative(drifted[0], drifted[14])
    error[2] = posegraph.wrap_angle(error[2])
    log_density = -0.5 * (error @ np.linalg.solve(predictive, error) + np.linalg.slogdet(2 * np.pi * predictive)[1])
    volume = 31 * 0.1 * 31 * 0.1 * 15 * 0.03  # LOOP_LEVELS' first lattice: +-15 steps of 0.1 m, +-7 of 0.03 rad
    assert difference == pytest.approx(log_density + np.log(volume), abs=1e-9)


def test_loop_candidates_respect_gap_and_radius():
    """Pairs (s, t): t - s >= LOOP_GAP and the poses within LOOP_RADIUS; on a path that returns to its start only
    the return is a candidate."""
    s = posegraph.LOOP_GAP + 10
    x = np.concatenate([np.arange(s // 2) * 1.0, (s // 2 - np.arange(s - s // 2)) * 1.0])
    path = np.stack([x, 0 * x, 0 * x], axis=1)
    pairs, half_widths = posegraph.loop_candidates(path)
    assert len(pairs) > 0
    assert np.all(pairs[:, 1] - pairs[:, 0] >= posegraph.LOOP_GAP)
    assert np.all(np.abs(x[pairs[:, 0]] - x[pairs[:, 1]]) < posegraph.LOOP_RADIUS)
    assert np.all(half_widths == 1.5)


def arc(steps=60, radius=3.0, turns=2.2):
    """Poses along an arc of ``turns * pi`` radians (0.3 m steps at the defaults), starting at the origin with heading
    0, heading along the path."""
    t = np.linspace(0, turns * np.pi, steps + 1)
    return np.stack([radius * np.sin(t), radius * (1 - np.cos(t)), posegraph.wrap_angle(t)], axis=1)


@pytest.mark.parametrize("kind", ["independent", "correlated"])
def test_a_chains_covariance_is_its_graphs_marginal_from_the_older_pose(kind):
    """``chain_covariances`` (prefix sums) for pairs ``(s, t)`` of a 60-step arc equals the pose graph's Laplace
    covariance of pose ``t`` in the graph of the sequential edges from ``s`` to ``t`` with pose ``s`` fixed
    (``marginal_covariances``: a sparse solve, another computation of the same first-order quantity), to rounding;
    the arc starts at the origin with heading 0, so the chain's frame is the world's. The edges' noise is
    independent per component, or a full covariance per edge (the front end's step posteriors,
    ``with_covariances``), which the chain turns into its own frame by the heading before each edge. Pairs
    with ``s > t`` or outside the chain are refused."""
    path = arc()
    seq = posegraph.sequential_edges(path)
    seq = seq._replace(std=seq.std * np.linspace(0.5, 2.0, len(seq.i))[:, None])  # every edge its own noise
    if kind == "correlated":
        seq = posegraph.with_covariances(seq, correlated_covariances(len(seq.i)))
    pairs = np.array([[0, 60], [10, 55], [30, 31], [7, 7]])
    cov = posegraph.chain_covariances(seq, pairs)
    for (s, t), c in zip(pairs, cov):
        if s == t:
            np.testing.assert_array_equal(c, 0.0)
            continue
        sub = seq.take(slice(s, t))._replace(i=seq.i[s:t] - s, j=seq.j[s:t] - s)
        np.testing.assert_allclose(c, posegraph.marginal_covariances(path[s:t + 1], sub)[-1], rtol=1e-9, atol=1e-12)
    for bad in ([[5, 4]], [[0, 61]], [[-1, 3]]):
        with pytest.raises(BayesmapError):
            posegraph.chain_covariances(seq, bad)


def test_the_first_rounds_loop_candidates_reach_as_far_as_the_chain_may_have_drifted():
    """A robot drives 20 m out and comes back 5 m to the side of where it went (in the estimate; a long loop's
    drift): at the standard radius (4 m) there is no candidate; sized by the chain's drift (the default sequential
    noise over 40-80 steps: meters), the scans of the way back are candidates (each paired with the scan of the way
    out beside it, at 5 m), within 4 m plus their drift (1.1-2.5 m), each searched over the window of
    ``LOOP_WINDOWS`` that covers it (1.5 or 3 m), and the search window's volume grows with it. With
    ``sigmas`` 0 the candidates are the standard ones."""
    out = np.stack([np.arange(41) * 0.5, np.zeros(41), np.zeros(41)], axis=1)
    back = np.stack([20.0 - np.arange(1, 41) * 0.5, np.full(40, 5.0), np.full(40, np.pi)], axis=1)
    path = np.concatenate([out, back])
    seq = posegraph.sequential_edges(path)
    assert len(posegraph.loop_candidates(path)[0]) == 0
    assert len(posegraph.loop_candidates(path, seq, sigmas=0.0)[0]) == 0
    pairs, half_widths = posegraph.loop_candidates(path, seq)
    assert len(pairs) >= 6 and np.all(pairs[:, 1] > 40)  # scans of the way back, 5 m beside the way out
    np.testing.assert_allclose(np.hypot(*(path[pairs[:, 0], :2] - path[pairs[:, 1], :2]).T), 5.0)
    drift = posegraph.LOOP_WINDOW_SIGMAS * np.sqrt(np.linalg.eigvalsh(
        posegraph.chain_covariances(seq, pairs)[:, :2, :2])[:, -1])
    assert np.all(drift > 1.0) and set(half_widths.tolist()) == {1.5, 3.0}  # the longer the loop, the wider
    assert np.all((half_widths >= drift) | (half_widths == posegraph.LOOP_WINDOWS[-1]))
    distance = np.hypot(*(path[pairs[:, 0], :2] - path[pairs[:, 1], :2]).T)
    assert np.all(distance < posegraph.LOOP_RADIUS + np.minimum(drift, posegraph.LOOP_WINDOWS[-1]))
    volumes = posegraph.window_volumes(posegraph.LOOP_WINDOWS)
    assert volumes[0] == pytest.approx(31 * 0.1 * 31 * 0.1 * 15 * 0.03)
    np.testing.assert_allclose(volumes / volumes[0], [1.0, 4.0, (61 * 0.2 / 3.1) ** 2])
    with pytest.raises(BayesmapError):
        posegraph.loop_levels(2.0)


def test_a_false_edges_evidence_is_uniform_over_its_own_search_window():
    """``log_evidence`` of a set that leaves a loop edge out falls by the log of that edge's window volume: searched
    over 6 m instead of 1.5 m, by ``log((12.2 / 3.1)^2)`` (the first lattices' areas; the headings are the same), and
    a chosen edge's term does not depend on its window."""
    truth, seq, drifted = drifted_square_loop()
    loop = posegraph.Edges(np.array([0]), np.array([14]), posegraph.relative(truth[:1], truth[14:15]),
                           np.array([[0.1, 0.1, 0.04]]))
    none = np.zeros(0, np.int64)
    narrow, wide = (posegraph.log_evidence(drifted, seq, loop, none, [w]) for w in (1.5, 6.0))
    assert narrow == pytest.approx(posegraph.log_evidence(drifted, seq, loop, none), abs=1e-12)
    assert narrow - wide == pytest.approx(2 * np.log(12.2 / 3.1), abs=1e-9)
    assert posegraph.log_evidence(drifted, seq, loop, [0], [6.0]) == posegraph.log_evidence(drifted, seq, loop, [0])


def test_a_wide_loop_search_finds_a_scan_the_standard_window_cannot_reach():
    """A scan of the room whose estimate is 2.2 m off (1.2 m in x, 1.8 m in y: outside the standard +-1.5 m square)
    matched against the local map of the first scans: searched over +-3 m it lands within a cell (5 cm; the room's
    axis-aligned walls are flat in score over a cell, see the registration test below) and 0.01 rad of its true pose;
    over +-1.5 m it does not (it can move at most 1.5 m plus the finer levels' 0.116 m along y). The progress
    reports count every candidate once, in order, across the two windows' searches."""
    grid, truth, odometry, beams, readings = room_scans(num_poses=30)
    data = ScanData(beams, readings, readings < 19.9, np.zeros((29, 3)), np.tile(np.eye(3), (29, 1, 1)))
    path = truth.copy()
    path[25, :2] += (1.2, 1.8)
    seen = []
    poses, quality = posegraph.match_loops(path, data, np.array([[0, 25], [0, 25]]), progress=seen.append,
                                           half_widths=[3.0, 1.5])
    assert np.hypot(*(poses[0, :2] - truth[25, :2])) < 0.05 and abs(poses[0, 2] - truth[25, 2]) < 0.01
    assert quality[0] >= posegraph.LOOP_MIN_HIT_FRACTION  # an accepted loop edge
    assert np.hypot(*(poses[1, :2] - truth[25, :2])) > 0.15  # 1.8 m less its reach of 1.616 m
    assert seen == [Progress("loop closure", done, 2, "scan") for done in range(3)]


def test_a_second_run_of_the_same_shapes_compiles_nothing(caplog):
    """The front end's loop and the loop matcher are compiled once per shape and setting, not once per call (a second
    SLAM run of a log in one process, the app's or a test's, reuses them): matching other readings of the same shapes
    logs no compilation at all, and gives another path (the readings do reach the compiled code). Before, both were
    jits of closures made per call, and the second run compiled them again."""
    import logging

    import jax

    grid, truth, odometry, beams, readings = room_scans(num_poses=8)
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))

    def run(ranges):
        data = ScanData(beams, ranges, ranges < 19.9, np.asarray(inc), np.asarray(cov))
        path = correlative_path(odometry[0], data, grid.resolution, half_width=6.0).path
        return path, posegraph.match_loops(path, data, np.array([[0, 4], [1, 6]]))

    first, _ = run(readings)
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        caplog.clear()
        second, _ = run(readings * 1.01)
    assert not [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
    assert not np.array_equal(first, second)


def test_loop_closure_reports_each_rounds_candidates(monkeypatch):
    """``close_loops`` with a progress callback: each round that has loop candidates is a stage ``"loop closure
    r/R"`` counting its candidates (here, with loops allowed 4 scans apart, scans 4, 7 and 10 of the room are
    matched in every round), from 0 up to the total; the result is that of a run without reports."""
    monkeypatch.setattr(posegraph, "LOOP_GAP", 4)
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    seen = []
    path, edges, _ = posegraph.close_loops(odometry, data, rounds=2, progress=seen.append)
    quiet_path, quiet_edges, _ = posegraph.close_loops(odometry, data, rounds=2)
    np.testing.assert_array_equal(path, quiet_path)
    np.testing.assert_array_equal(edges.j, quiet_edges.j)
    assert len(edges.i) > len(odometry) - 1  # loop edges were found, so both rounds ran
    assert seen == [Progress(f"loop closure {r}/2", done, 3, "scan") for r in (1, 2) for done in range(4)]


@pytest.mark.parametrize("width", posegraph.LOOP_WINDOWS)
def test_the_bounded_first_level_finds_the_whole_lattices_best(width):
    """``bounded_lattice_argmax`` (branch and bound over squares of translations) against scoring every candidate of
    the loop search's first level (``loop_levels(width)``): the same index and the same score to the bit, on the
    room's local map of scans 0, 2, 4 (local-map grid, +-16 m) for eight scans started up to 1.3 m and 0.1 rad off,
    two with endpoints past the grid's edge (started 15 m out), with squares of 4 x 4 translations scored 64 at a time
    (the default) and single candidates one at a time; and ``search`` with ``bound_span`` gives the pose and score of
    ``search`` without it. Boxes moved two cells off each beam's (no margin, the wrong side) fail it."""
    import jax

    from bayesmap.slam import scanmatch

    grid, truth, odometry, beams, readings = room_scans()
    beams, readings = jnp.asarray(beams), jnp.asarray(readings)
    returned = readings < 19.9
    local = posegraph.local_map_grid()
    shift = np.array([*truth[2, :2], 0.0])
    seen = np.array([0, 2, 4])
    fields = add_to_fields(empty_fields(local), local, jnp.asarray(truth[seen] - shift), beams[seen], readings[seen],
                           returned[seen])
    logs = (None,) + tuple(scanmatch.log_field(f) for f in fields[1:])
    levels = posegraph.loop_levels(width)
    steps = lattices(levels)
    (xy, theta), f = list(steps)[0]
    span = bound_span(levels[0][0], local.resolution)
    sizes = ((4, 64), (1, 1))  # (block, chunk): the default, and single candidates one at a time

    @jax.jit
    def both(start, angles, ranges, hits):
        scores = lattice_scores(logs[f], local, start, xy, theta, angles, ranges, hits, False, log_field=logs[f])
        bounded = [bounded_lattice_argmax(logs[f], local, start, xy, theta, angles, ranges, hits,
                                          bound_span(levels[0][0], local.resolution, block), block, chunk)
                   for block, chunk in sizes]
        plain = search(fields, local, start, angles, ranges, hits, steps, log_fields=logs)
        quick = search(fields, local, start, angles, ranges, hits, steps, log_fields=logs, bound_span=span)
        return scores, bounded, plain, quick

    rng = np.random.default_rng(3)
    for k, t in enumerate((1, 3, 5, 6, 7, 8, 9, 10)):
        start = truth[t] - shift + np.concatenate([rng.uniform(-1.3, 1.3, 2), rng.uniform(-0.1, 0.1, 1)])
        if k >= 6:
            start[:2] += 15.0  # endpoints past the local map's edge
        scores, bounded, plain, quick = both(jnp.asarray(start), beams[t], readings[t], returned[t])
        scores = np.asarray(scores)
        for (index, score), size in zip(bounded, sizes):
            assert int(index) == int(np.argmax(scores)) and float(score) == float(scores.max()), (k, t, size)
        np.testing.assert_array_equal(np.asarray(quick[0]), np.asarray(plain[0]))
        assert float(quick[1]) == float(plain[1])
    with pytest.raises(BayesmapError, match="bounded"):
        search(fields, local, jnp.asarray(start), beams[1], readings[1], returned[1], steps, bound_span=span)


def test_a_loop_closure_that_reads_kept_matches_gives_the_same_path_with_fewer_searches(monkeypatch):
    """``close_loops(matches=)``: a second path that is the first before scan 8 and moved after it (a branch, as
    ``pipeline.branched_start`` makes) takes the kept matches of the candidates whose inputs lie before scan 8 instead
    of searching them, and its loop closure equals one that searches every candidate, path and edges to the bit. With
    loops 4 scans apart and local maps of the scans +-2 around ``s``, the room's first round matches scans 4, 7, 10
    (against 0, 3, 6 or so): 4 and 7 have every input before scan 8. A kept match is found only where every input is
    the same to the bit: the scans before 8 moved by 1e-12 m are searched again."""
    monkeypatch.setattr(posegraph, "LOOP_GAP", 4)
    monkeypatch.setattr(posegraph, "LOOP_NEIGHBOURS", 2)
    searched = []
    match = posegraph.match_to_local_maps

    def counted(path, data, scans, *args, **kwargs):
        searched.append(len(np.asarray(scans).reshape(-1)))
        return match(path, data, scans, *args, **kwargs)

    monkeypatch.setattr(posegraph, "match_to_local_maps", counted)
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    matches = posegraph.LoopMatches()
    posegraph.close_loops(odometry, data, rounds=2, matches=matches)
    assert len(matches) == sum(searched) > 0 and matches.found == 0
    branch = odometry.copy()
    branch[8:, :2] += (0.04, -0.03)
    branch[8:, 2] += 0.02
    searched.clear()
    plain = posegraph.close_loops(branch, data, rounds=2)
    every = sum(searched)
    searched.clear()
    kept = posegraph.close_loops(branch, data, rounds=2, matches=matches)
    assert matches.found == every - sum(searched) >= 2  # scans 4 and 7 of the first round at least
    np.testing.assert_array_equal(kept.path, plain.path)
    for name in ("i", "j", "z", "std"):
        np.testing.assert_array_equal(getattr(kept.edges, name), getattr(plain.edges, name))
    nudged = branch.copy()
    nudged[:8, 0] += 1e-12
    found = matches.found
    posegraph.close_loops(nudged, data, rounds=1, matches=matches)
    assert matches.found == found


@pytest.mark.parametrize("angle, move", [(0.3, (2.0, -1.0)), (-1.0, (5.0, 3.0))])
def test_a_held_out_scan_is_registered_into_the_frame_of_the_map_it_is_scored_on(angle, move):
    """``evaluation.slammap.register_heldout`` (the registered columns of benchmarks/slam_map.py): held-out scans of
    the room (3, 5 and 8, one at a time), started 0.14 m and 0.04 rad off, land within 1 cm and 0.005 rad of their
    true poses carried into the map's frame, the truth turned by ``angle`` and moved by ``move``: they are matched
    against their neighbours at the map's poses, not against the truth (2-6 m away). Exact readings, so the only
    error is the matcher's: a few millimeters here; in the room's own axis-aligned frame up to 3 cm, where its
    cell-stepped walls line up with the fields' cells and the score is flat over a cell, so the frames are turned."""
    from bayesmap.evaluation.slammap import register_heldout

    grid, truth, odometry, beams, readings = room_scans(num_poses=12)
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    data = ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    frame = np.column_stack([truth[:, :2] @ rot.T + np.asarray(move), truth[:, 2] + angle])
    for held in (3, 5, 8):
        train, test = np.delete(np.arange(12), held), np.array([held])
        start = frame[test] + np.array([0.12, -0.07, 0.04])
        seen = []
        registered = register_heldout(frame, data, train, test, start, progress=seen.append)
        assert seen == [Progress("registration", done, 1, "scan") for done in (0, 1)]
        assert np.hypot(*(registered[0, :2] - frame[held, :2])) < 0.01
        assert abs(registered[0, 2] - frame[held, 2]) < 0.005
    with pytest.raises(BayesmapError, match=r"path must be \(12, 3\)"):
        register_heldout(frame[:5], data, train, test, start)
    with pytest.raises(BayesmapError, match="neighbours must index the 12 scans"):
        posegraph.match_to_local_maps(frame, data, test, np.array([[3, 12]]), start)


@pytest.mark.parametrize("masked", [False, True])
def test_search_scores_every_lattice_candidate_as_field_scores_does(masked):
    """The search's per-level scores (each beam's direction computed once per heading, the local map applied where
    the fields are read, the coarse level from a precomputed log field) against field_scores of the explicit
    candidates on a field masked the plain way: the same scores (float32: 1e-4 of their size, a sum of 360 logs;
    a candidate in the wrong order or a window applied to the wrong cells changes a score by whole log units) and
    so the same best candidate at every level."""
    from bayesmap.slam import scanmatch

    grid, truth, _, beams, readings = room_scans(num_poses=3)
    returned = readings < 30.0
    rng = np.random.default_rng(1)
    fields = scanmatch.add_to_fields(scanmatch.empty_fields(grid), grid, jnp.asarray(truth[:2]), beams[:2],
                                     readings[:2], returned[:2])
    stamps = jnp.asarray(rng.uniform(0, 10, grid.shape).astype(np.float32))
    window = (stamps, jnp.float32(5.0)) if masked else None
    plain = tuple(jnp.where(stamps >= 5.0, f, 0.0) for f in fields) if masked else fields
    center = jnp.asarray(truth[2] + [0.05, -0.04, 0.02], jnp.float32)
    for (xy, theta), f in scanmatch.lattices(scanmatch.MATCH_LEVELS):
        cands = jnp.concatenate([jnp.repeat(center[:2] + xy, len(theta), axis=0),
                                 jnp.tile(center[2] + theta, len(xy))[:, None]], axis=1)
        want = np.asarray(scanmatch.field_scores(plain[f], grid, cands, beams[2], readings[2], returned[2],
                                                 interpolate=f == 0))
        for log_field in (None, scanmatch.log_field(fields[f])):
            got = np.asarray(scanmatch.lattice_scores(fields[f], grid, center, xy, theta, beams[2], readings[2],
                                                      returned[2], f == 0, window, log_field))
            np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)
            assert np.argmax(got) == np.argmax(want)


@pytest.mark.parametrize("weight", [4.0, 8.0, 16.0])
def test_the_field_seed_descends_from_the_scans_own_best_fit_too(weight):
    """The search's first level scores the broad field; here it is the room's broad field times 0.02, so that its
    score tells the true pose from one 0.6 rad off by at most about a hundred nats, where the fine field tells them
    apart by hundreds (683 measured), as a broad field of clutter compresses a scan's fit. The prediction is 0.6 rad
    off and a Normal prior around it (0.05 m, 0.1 rad, times ``weight``: 72-288 nats at the truth) outweighs the
    first level's difference but not the fine one's. Without the field seed the search descends from the prior's
    side and ends more than 0.3 rad off; with it, it also descends from the scan's own best fit, ends within 0.03 m
    (the field's half cell, 0.025 m, plus the last search step) and 0.01 rad of the truth, and its score is the
    higher one (the fine field and the prior judge both descents)."""
    from bayesmap.slam import scanmatch

    grid, truth, _, beams, readings = room_scans(num_poses=3)
    returned = readings < 30.0
    fine, broad = scanmatch.add_to_fields(scanmatch.empty_fields(grid), grid, jnp.asarray(truth[:2]), beams[:2],
                                          readings[:2], returned[:2])
    fields = (fine, 0.02 * broad)
    predicted = jnp.asarray(truth[2] + [0.0, 0.0, 0.6], jnp.float32)

    def log_prior(cands):
        return -0.5 * weight * jnp.sum(((cands - predicted) / jnp.asarray([0.05, 0.05, 0.1])) ** 2, axis=-1)

    found = {seed: scanmatch.search(fields, grid, predicted, beams[2], readings[2], returned[2],
                                    scanmatch.lattices(scanmatch.MATCH_LEVELS), log_prior, field_seed=seed)
             for seed in (False, True)}
    assert abs(float(found[False][0][2]) - truth[2, 2]) > 0.3
    assert np.abs(np.asarray(found[True][0][:2]) - truth[2, :2]).max() < 0.03
    assert abs(float(found[True][0][2]) - truth[2, 2]) < 0.01
    assert float(found[True][1]) > float(found[False][1]) + 100


def test_fields_and_searches_of_two_shifted_windows_agree_to_the_bit():
    """Scans given in one frame, on two windows of it (shifted by whole cells, as the front end's fields move): the
    fields agree on every cell both cover, bit for bit, and so do the search's best pose and score and the hit
    fraction, whether a level interpolates the fine field or looks up the broad one, masked by a window of stamps
    or not. A shift applied in floats (the poses moved by a multiple of the cell size) rounds the cell coordinates
    differently; the path of the front end would then depend on where its square happens to be."""
    from bayesmap.slam import scanmatch

    room, truth, _, beams, readings = room_scans(num_poses=3)
    returned = readings < 30.0
    grid = Grid(shape=(200, 180), resolution=room.resolution, origin=(0.0, 0.0))  # the room's 160 x 120 cells and more
    shifts = (np.array([-20, -30], np.int32), np.array([-37, -41], np.int32))  # the room's cells, in each window
    fields, stamps = [], []
    for shift in shifts:
        fields.append(scanmatch.add_to_fields(scanmatch.empty_fields(grid), grid, jnp.asarray(truth[:2]), beams[:2],
                                              readings[:2], returned[:2], jnp.asarray(shift)))
        stamps.append(jnp.asarray(np.random.default_rng(1).uniform(0, 10, (300, 300)).astype(np.float32)
                                  [50 + shift[0]:250 + shift[0], 50 + shift[1]:230 + shift[1]]))  # one array's windows
    lo = np.maximum(*shifts)  # the frame's cells both windows cover (window cell w is the frame's w + shift)
    hi = np.minimum(*shifts) + grid.shape

    def common(array, shift):
        return np.asarray(array)[lo[0] - shift[0]:hi[0] - shift[0], lo[1] - shift[1]:hi[1] - shift[1]]

    for k in range(len(scanmatch.FIELDS)):
        assert np.asarray(fields[0][k]).max() > 0.5
        np.testing.assert_array_equal(common(fields[0][k], shifts[0]), common(fields[1][k], shifts[1]))
    center = jnp.asarray(truth[2] + [0.05, -0.04, 0.02], jnp.float32)
    levels = scanmatch.lattices(scanmatch.MATCH_LEVELS)
    for masked in (False, True):
        found = []
        for f, st, shift in zip(fields, stamps, shifts):
            window = (st, jnp.float32(5.0)) if masked else None
            best, score = scanmatch.search(f, grid, center, beams[2], readings[2], returned[2], levels,
                                           window=window, shift=jnp.asarray(shift))
            hits = scanmatch.hit_fraction(f, grid, best, beams[2], readings[2], returned[2], window,
                                          jnp.asarray(shift))
            found.append(np.asarray(jnp.concatenate([best, score[None], hits[None]])))
        np.testing.assert_array_equal(found[0], found[1])
        if not masked:
            assert np.abs(found[0][:2] - truth[2, :2]).max() < 0.03 and found[0][4] > 0.5


def test_a_loop_edges_posterior_is_its_matchs_density_without_a_motion_term():
    """posegraph.loop_posteriors in the room (exact readings, the true path): scan 9's match against the local map
    of scan 2's neighbours, placed by the edge's z, in scan 2's frame, is the step posterior of the same match under
    a motion model a kilometre wide (its log-density varies by under 1e-7 over the lattice), built from the same
    neighbours' fields: the local map, the frame and the placement are the loop closure's. At power 1 the
    position's spread is below 0.6 of power 0.1's (a Gaussian's would be sqrt(0.1) = 0.32; the lattice's floor and
    its cells hold it above that)."""
    _, truth, _, beams, readings = room_scans()
    data = ScanData(beams, readings, readings < 19.9, np.zeros((len(truth) - 1, 3)), np.zeros((len(truth) - 1, 3, 3)))
    loops = posegraph.Edges(np.array([2]), np.array([9]), posegraph.relative(truth[2:3], truth[9:10]),
                            np.full((1, 3), 0.1))
    cov = posegraph.loop_posteriors(truth, data, loops, 0.1)
    power_one = posegraph.loop_posteriors(truth, data, loops, 1.0)
    neighbours = posegraph.local_map_neighbours(np.array([2]), data.increments)[0]
    shift = np.array([truth[2, 0], truth[2, 1], 0.0])
    grid = posegraph.local_map_grid()
    fields = add_to_fields(empty_fields(grid), grid, jnp.asarray(truth[neighbours] - shift), beams[neighbours],
                           readings[neighbours], data.returned[neighbours])
    prev, center = jnp.asarray(truth[2] - shift), jnp.asarray(truth[9] - shift)
    broad = step_posterior(fields, grid, center, prev, jnp.asarray(posegraph.relative(truth[2], truth[9])),
                           jnp.eye(3) * 1e6, beams[9], readings[9], data.returned[9], 0.1, step_lattice())
    np.testing.assert_allclose(cov[0], np.asarray(broad), rtol=1e-4, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(cov[0]) > 0)
    spread = np.sqrt(np.trace(cov[0, :2, :2]))
    assert spread < 0.1 and np.sqrt(np.trace(power_one[0, :2, :2])) < 0.6 * spread
    with pytest.raises(BayesmapError, match=r"likelihood_power must be in \(0, 1\].*got 0.0"):
        posegraph.loop_posteriors(truth, data, loops, 0.0)
    with pytest.raises(BayesmapError, match=r"path must be \(12, 3\)"):
        posegraph.loop_posteriors(truth[:5], data, loops, 0.1)
