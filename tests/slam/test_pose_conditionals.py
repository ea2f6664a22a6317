"""The pose conditionals and the random walk's moves (bayesmap.slam.poses) against the SLAM model's assess, move for
move: exactness tests of the fast paths (ray traversals, batches, caches), compiled at the level of the test suite's
first pass. The chains' distributions (enumeration, quadrature) are in test_poses.py."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raycast import march_first_chord
from bayesmap.model import motion
from bayesmap.model.generative import log_joint_scans, replace_params
from bayesmap.model.slam import slam_args, slam_choices, slam_model
from bayesmap.slam.poses import (
    discrete_pose_gibbs,
    lattice_pose_mh,
    moved_segment,
    pose_log_conditional,
    random_walk_pose_mh,
    scan_log_likelihood,
    scans_log_likelihood,
    segment_log_ratio,
    segment_pose_mh,
    slam_data,
)
from helpers import random_slam_scene


@pytest.mark.parametrize("beam_model, seed", [("normal", 0), ("normal", 1), ("beam", 2), ("beam", 3)])
def test_pose_conditional_equals_assess_differences(beam_model, seed):
    """For every pose t >= 1 (the last one has no t+1 factor), the conditional at candidates minus at the current
    pose equals assess(path with pose_t = candidate) - assess(path). Float64, 1e-6 absolute on differences of log
    densities of size ~10-1000 (both sides are the same float64 arithmetic up to summation order, ~1e-12; a
    missing factor, a wrong frame or a wrong angle convention changes them by far more than 1e-6)."""
    check_pose_conditional_against_assess(seed, beam_model, "entry")


@pytest.mark.parametrize("seed", [1, 3, 6])
def test_pose_conditional_equals_assess_differences_in_the_chord_geometry(seed):
    """As above in the chord geometry (the pose moves cast the first wall cell's entry and exit by grid traversal,
    the model's assess takes them from the all-cells ray cast), beam model, 1e-6. The entry geometry's conditional
    differs from the chord's by more than 0.1 somewhere: the test can fail. Seeds 3 and 6 put candidates inside wall
    cells, where the first wall cell is the one the all-cells cast picks (a tie with the next cell, broken by flat
    index); a traversal that stopped at the sensor's own cell missed it there by 0.27 and 2.8 nats."""
    check_pose_conditional_against_assess(seed, "beam", "chord")


def test_pose_conditional_equals_assess_differences_with_beams_cut_past_their_readings():
    """As above with beams cut 0.6 cells past their readings and a third of the readings short, beam model, the
    scene of seed 5 (30 walls in 7 x 7 cells), 1e-6: the pose moves' traversal stops one cell past each beam's cut
    (march_first_chord's ``stops``), the model's assess cuts the all-cells ray cast. The stops change the
    traversal's own result for some beam (a wall it no longer reaches), so a stop placed short of the cut would
    change the conditional. Both geometries."""
    for geometry in ("entry", "chord"):
        assert check_pose_conditional_against_assess(5, "beam", geometry, cut_cells=0.6) > 0


def check_pose_conditional_against_assess(seed, beam_model, geometry, cut_cells=None):
    """Returns how many (candidate, beam) traversals the cut's stops ended before a wall they would have reached."""
    skipped = 0
    with enable_x64():
        params, path, walls, inc, cov, angles, y, step = random_slam_scene(seed, beam_model, geometry=geometry)
        if cut_cells is not None:  # and a third of the readings short (an obstacle the map does not hold)
            params = replace_params(params, cut_past_reading=cut_cells * params.grid.resolution)
            short = np.random.default_rng(seed).random(y.shape) < 0.3
            y = np.where(short, y * 0.3, y)
        data = slam_data(inc, cov, angles, y, params)
        entry_data = slam_data(inc, cov, angles, y, dataclasses.replace(params, geometry="entry"))
        assess = jax.jit(lambda p: slam_model.assess(slam_choices(p, walls, y),
                                                     slam_args(path[0], inc, cov, params, angles))[0])
        rng = np.random.default_rng(50 + seed)
        entry_gap = 0.0
        for t in range(1, len(path)):
            cands = np.concatenate([path[t:t + 1], path[t] + rng.normal(0, [step, step, 0.3], (6, 3))])
            got = np.asarray(pose_log_conditional(t, cands, path, walls, data))
            want = np.array([float(assess(jnp.asarray(path).at[t].set(c))) for c in cands[1:]])
            base = float(assess(jnp.asarray(path)))
            assert np.all(np.isfinite(want))
            np.testing.assert_allclose(got[1:] - got[0], want - base, atol=1e-6, rtol=0)
            entry = np.asarray(pose_log_conditional(t, cands, path, walls, entry_data))
            entry_gap = max(entry_gap, np.abs((entry[1:] - entry[0]) - (got[1:] - got[0])).max())
            if params.cut:
                stops = y[t] + params.cut_past_reading + params.grid.resolution
                for c in cands:
                    beams = c[2] + angles[t]
                    whole = march_first_chord(walls, c[:2], beams, params.grid, params.max_range)
                    stopped = march_first_chord(walls, c[:2], beams, params.grid, params.max_range, stops)
                    skipped += int(np.sum(np.asarray(whole)[:, 0] != np.asarray(stopped)[:, 0]))
        assert geometry == "entry" or entry_gap > 0.1
    return skipped


@pytest.mark.parametrize("seed", range(2))
def test_tempered_pose_conditional(seed):
    """With eta = 0.4: differences equal motion (path_logpdf) + eta * sensor part (log_joint_scans at the path,
    whose prior term is the same for every candidate), float64 to 1e-6."""
    with enable_x64():
        eta = 0.4
        params, path, walls, inc, cov, angles, y, step = random_slam_scene(seed)
        data = slam_data(inc, cov, angles, y, params)

        def target(p):
            p = np.asarray(p)
            return (float(motion.path_logpdf(p, path[0], inc, cov))
                    + eta * float(log_joint_scans(walls, y, p[:, :2], params, p[:, 2:3] + angles)))

        rng = np.random.default_rng(seed)
        for t in (1, len(path) - 1):
            cands = path[t] + rng.normal(0, [step, step, 0.3], (4, 3))
            got = np.asarray(pose_log_conditional(t, np.concatenate([path[t:t + 1], cands]), path, walls, data, eta))
            want = np.array([target(_with(path, t, c)) for c in cands])
            np.testing.assert_allclose(got[1:] - got[0], want - target(path), atol=1e-6, rtol=0)


def _with(path, t, pose):
    out = np.array(path, copy=True)
    out[t] = pose
    return out


def test_scan_log_likelihood_is_the_sensor_part_of_assess():
    """At a single pose it equals log_joint_scans of that one scan minus the prior (float64, 1e-9)."""
    with enable_x64():
        params, path, walls, inc, cov, angles, y, _ = random_slam_scene(3)
        got = np.asarray(scan_log_likelihood(walls, path, angles[0], y[0], params))
        p = params.prior_wall_prob
        prior = float(np.sum(np.where(walls > 0, np.log(p), np.log1p(-p))))
        for m, pose in enumerate(path):
            want = float(log_joint_scans(walls, y[:1], pose[None, :2], params, pose[2] + angles[:1])) - prior
            assert got[m] == pytest.approx(want, abs=1e-6)


def test_bad_arguments_are_errors():
    params, path, walls, inc, cov, angles, y, _ = random_slam_scene(0)
    data = slam_data(inc, cov, angles, y, params)
    with pytest.raises(BayesmapError, match="got 0"):
        pose_log_conditional(0, path[:1], path, walls, data)
    with pytest.raises(BayesmapError, match="got 4"):
        pose_log_conditional(4, path[:1], path, walls, data)
    with pytest.raises(BayesmapError, match="likelihood_power"):
        pose_log_conditional(1, path[:1], path, walls, data, likelihood_power=1.5)
    with pytest.raises(BayesmapError, match="readings"):
        slam_data(inc, cov, angles, y[:, :3], params)
    with pytest.raises(BayesmapError, match="candidates"):
        discrete_pose_gibbs(data, np.zeros((3, 2, 3)))
    with pytest.raises(BayesmapError, match="h_theta"):
        lattice_pose_mh(data, 0.1, -1.0)
    with pytest.raises(BayesmapError, match="jitter"):
        lattice_pose_mh(data, 0.1, 0.1, jitter=1.0)


def test_random_walk_cache_gives_the_same_moves_and_stays_the_scans_likelihood():
    """random_walk_pose_mh's init caches each scan's log-likelihood at its pose; a sweep from it scores the current
    pose from the cache. With the same keys, a state without the cache (a joint kernel's, recast each move) must make
    the same moves on a 6-scan random scene, several of them accepted (so the cache's bookkeeping is exercised), and
    after three sweeps the cache must equal a fresh cast at the new poses (float64: equal to 1e-9, rounding of the
    same sums). A cache left at the old pose after an accepted move fails the second check."""
    with enable_x64():
        params, path, walls, inc, cov, angles, y, _ = random_slam_scene(2, num_scans=6)
        data = slam_data(inc, cov, angles, y, params)
        kernel = random_walk_pose_mh(data, (0.02, 0.02, 0.02))
        cached = kernel.init(path, walls)
        plain = cached._replace(scan_log_lik=None)
        step = jax.jit(kernel.step)
        moved = 0
        for key in jax.random.split(jax.random.key(5), 3):
            cached, info = step(key, cached)
            plain, _ = step(key, plain)
            moved += int(np.sum(info.accepted))
        assert moved >= 3, moved
        np.testing.assert_array_equal(np.asarray(cached.poses), np.asarray(plain.poses))
        assert plain.scan_log_lik is None
        fresh = kernel.init(cached.poses, walls).scan_log_lik
        np.testing.assert_allclose(np.asarray(cached.scan_log_lik), np.asarray(fresh), rtol=1e-9)


@pytest.mark.parametrize("geometry", ["entry", "chord"])
def test_scans_log_likelihood_equals_one_scan_at_a_time(geometry):
    """All scans' beams cast at once (march_ray_chords, 7 lanes for 6 x 12 beams: lanes take new beams many times)
    equal scan_log_likelihood of each scan at its pose, float64 to 1e-12, with beams cut past their readings and
    without, on the 6-scan scene of seed 3 with a third of the readings short."""
    with enable_x64():
        params, path, walls, inc, cov, angles, y, _ = random_slam_scene(3, "beam", num_scans=6, geometry=geometry)
        y = np.where(np.random.default_rng(3).random(y.shape) < 0.3, 0.3 * y, y)
        for cut in (math.inf, 0.6 * params.grid.resolution):
            p = replace_params(params, cut_past_reading=cut)
            want = np.array([float(scan_log_likelihood(walls, path[m:m + 1], angles[m], y[m], p)[0])
                             for m in range(len(path))])
            got = np.asarray(scans_log_likelihood(walls, path, angles, y, p))
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def check_sweeps_against_replay(kernel, path, walls, key, sweeps: int, replay):
    """``sweeps`` sweeps of ``kernel`` from ``path``, with the state's cached scan log-likelihoods and without: after
    each, ``replay(sweep key, info, reference path, counts)`` moves the reference path move by move (counting the
    rejected and accepted moves in ``counts``) and the sweep's poses must equal it to 1e-12; at least three moves of
    each kind."""
    step = jax.jit(kernel.step)
    for cached in (True, False):
        state = kernel.init(path, walls)
        if not cached:
            state = state._replace(scan_log_lik=None)
        ref = np.array(path, dtype=np.float64)
        counts = [0, 0]
        for k in jax.random.split(key, sweeps):
            state, info = step(k, state)
            ref = replay(k, info, ref, counts)
            np.testing.assert_allclose(np.asarray(state.poses), ref, rtol=0, atol=1e-12)
        assert min(counts) >= 3, counts


def test_segment_sweep_is_segment_moves_first_third_then_second_fourth():
    """A sweep of segment_pose_mh (length 3, 11 scans) moves the first, third, ... segments at once, then the
    second, fourth, ...: the same poses and acceptances as the segment moves one after another in that order, each
    accepted by the public segment_log_ratio (the model's log joint difference, tested against assess) with segment
    ``k``'s key the k-th of the sweep's splits, split again into the move's and the acceptance's, and the offset drawn
    from the sweep key's first split (float64; poses equal to 1e-12). Eight sweeps with and without the cache, moves
    accepted and rejected. The odometry is the path itself with a tight motion model (0.02 m and rad), so that a
    segment's acceptance turns on whether its neighbour moved: the same replay in the order 0, 1, 2, ..., or with
    every segment scored against the sweep's starting path (neighbours moved at once), fails."""
    with enable_x64():
        params, path, walls, _, _, angles, y, _ = random_slam_scene(1, num_scans=11)
        inc, cov = motion.odometry_controls(path, motion.make_motion_params((0, 0, 0, 0), 0.02, 0.02))
        data = slam_data(inc, cov, angles, y, params)
        length, scale, s = 3, np.array([0.02, 0.02, 0.02]), len(path)

        def replay(key, info, ref, counts):
            k_offset, k_moves = jax.random.split(key)
            offset = int(jax.random.randint(k_offset, (), 0, length))
            count = (s - 2) // length + 2
            keys = jax.random.split(k_moves, count)
            for k in [*range(0, count, 2), *range(1, count, 2)]:
                first = 1 + offset + (k - 1) * length
                a, b = max(first, 1), min(first + length - 1, s - 1)
                if a > b:
                    continue
                k_delta, k_acc = jax.random.split(keys[k])
                delta = scale * np.asarray(jax.random.normal(k_delta, (3,), jnp.float64))
                ratio = float(segment_log_ratio(a, b, delta, ref, walls, data))
                accept = np.log(float(jax.random.uniform(k_acc, (), jnp.float64))) < ratio
                assert np.all(np.asarray(info.accepted[a - 1:b]) == accept), (k, a, b)
                if accept:
                    ref = np.asarray(moved_segment(ref, a, b, jnp.asarray(delta)))
                counts[int(accept)] += 1
            return ref

        check_sweeps_against_replay(segment_pose_mh(data, length, (0.02, 0.02)), path, walls, jax.random.key(12), 8,
                                    replay)


def test_random_walk_sweep_is_single_pose_moves_odd_then_even():
    """A sweep of random_walk_pose_mh moves the odd poses at once, then the even ones: the same poses, acceptances
    and log conditionals as single-pose Metropolis moves in the order 1, 3, 5, 2, 4 (7 scans), each from
    pose_log_conditional with pose t's key the (t - 1)-th of the sweep key's 6 splits, split again into the
    proposal's and the acceptance's (float64; poses equal to 1e-12, every acceptance the same). Three sweeps with
    and without the cache, several moves accepted and several rejected. Moving the even poses before the odd ones'
    moves are applied (a block that reads stale neighbours) breaks the equality."""
    with enable_x64():
        params, path, walls, inc, cov, angles, y, _ = random_slam_scene(2, num_scans=7)
        data = slam_data(inc, cov, angles, y, params)
        scale = np.array([0.02, 0.02, 0.02])

        def replay(key, info, ref, counts):
            keys = jax.random.split(key, len(path) - 1)
            for t in (1, 3, 5, 2, 4, 6):
                k_prop, k_acc = jax.random.split(keys[t - 1])
                proposal = ref[t] + scale * np.asarray(jax.random.normal(k_prop, (3,), jnp.float64))
                logc = np.asarray(pose_log_conditional(t, np.stack([ref[t], proposal]), ref, walls, data))
                accept = np.log(float(jax.random.uniform(k_acc, (), jnp.float64))) < logc[1] - logc[0]
                assert bool(info.accepted[t - 1]) == accept, t
                assert float(info.log_conditional[t - 1]) == pytest.approx(logc[int(accept)], abs=1e-9)
                ref[t] = proposal if accept else ref[t]
                counts[int(accept)] += 1
            return ref

        check_sweeps_against_replay(random_walk_pose_mh(data, scale), path, walls, jax.random.key(11), 3, replay)
