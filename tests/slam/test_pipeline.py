"""run_log_slam's final map (stage 6): drawn after the joint chain without changing it, in the log's map model at
the mean path, and refused counts named; its progress reports, stage by stage, which do not change the result."""

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import read_carmen
from bayesmap.slam.pipeline import FINAL_MAP_NOISE, run_log_slam


@pytest.fixture(scope="module")
def slam_problem(small_log):
    from bayesmap.slam.problem import log_slam_problem

    return log_slam_problem(read_carmen(small_log), resolution=0.2)


RUN = {"rounds": 1, "burn_in": 0, "map_sweeps": 2, "pose_sweeps": 2, "seed": 5}


WITH_FINAL = pytest.mark.xdist_group("slam_pipeline")
"""The tests that use :func:`with_final`: on one xdist worker, so that its run happens once."""


@pytest.fixture(scope="module")
def with_final(slam_problem):
    # 20 sweeps (10 kept): at this slice's power (0.06, 12 scans from nearly one place) 6 sweeps left 3 of the
    # chain's 30 sure walls below 0.5, 20 none (at power 0.1: 1 and none)
    return run_log_slam(slam_problem, final_map_sweeps=20, **RUN)


@WITH_FINAL
def test_final_map_leaves_the_chain_alone_and_differs_from_its_map(slam_problem, with_final):
    """Same seed with and without the final map: the same path samples and the same chain map (the final map's key
    is none of the chain's), and the reported map is another one, in the log's model (walls a beam can pass, the
    structured prior; the model's noise widened to FINAL_MAP_NOISE for the path's error), with the walls of the
    chain's map where the chain is sure of them."""
    without = run_log_slam(slam_problem, final_map_sweeps=0, **RUN)
    assert without.chain_posterior is None and without.final_map_noise is None
    noise = float(slam_problem.final_map_params.sensor_noise)
    assert with_final.final_map_noise == FINAL_MAP_NOISE > noise
    np.testing.assert_array_equal(with_final.pose_samples, without.pose_samples)
    np.testing.assert_array_equal(with_final.chain_posterior, without.posterior)
    final = with_final.posterior
    assert final.shape == without.posterior.shape and final.min() >= 0 and final.max() <= 1
    assert not np.allclose(final, without.posterior, atol=0.05)
    # the same readings at nearly the same poses: the final map ranks the cells the chain holds for sure walls above
    # those it holds for sure free (AUC over every such pair 0.997 here), and keeps the sure free cells free; its
    # noise, 0.15 m on 0.2 m cells from 12 scans, spreads each reading over the cells beside its wall, so 10 of the
    # chain's 33 sure walls end below 0.5 (5 at a noise of 0.08 m)
    sure_wall, sure_free = without.posterior > 0.99, without.posterior < 0.01
    assert sure_wall.sum() > 20 and sure_free.sum() > 100
    walls, free = final[sure_wall], final[sure_free]
    assert np.mean(walls[:, None] > free[None, :]) > 0.98 and np.mean(free < 0.5) > 0.95
    assert np.mean(walls > 0.5) > 0.6


@WITH_FINAL
def test_progress_reports_every_stage_and_leaves_the_result_alone(slam_problem, with_final):
    """With a progress callback: the stages in the pipeline's order (12 scans close no loop: no loop closure stage),
    each reported from 0 up to its total without going back, the final map once per sweep (after a report at its
    start, before its table is built); and the same result, bit for bit, as without one (the chains then run one
    sweep per call over the same keys; the front end one scan per call)."""
    seen = []
    reported = run_log_slam(slam_problem, final_map_sweeps=20, progress=seen.append, **RUN)
    for name in ("pose_samples", "mean_path", "pose_cov", "posterior", "chain_posterior", "last_walls"):
        np.testing.assert_array_equal(getattr(reported, name), getattr(with_final, name), err_msg=name)
    stages = list(dict.fromkeys(p.stage for p in seen))
    assert stages == ["front end", "round 1/1: map", "round 1/1: poses", "final map"]
    assert [p.stage for p in seen] == sorted((p.stage for p in seen), key=stages.index)  # one run of each stage
    totals = {"front end": (11, "scan"), "round 1/1: map": (2, "sweep"), "round 1/1: poses": (2, "sweep"),
              "final map": (20, "sweep")}
    for stage in stages:
        reports = [p for p in seen if p.stage == stage]
        assert {(p.total, p.unit) for p in reports} == {totals[stage]}
        done = [p.done for p in reports]
        assert done[0] == 0 and done[-1] == totals[stage][0] and done == sorted(done)
    final = [p.done for p in seen if p.stage == "final map"]
    assert [d for d in final if d > 0] == list(range(1, 21))


@pytest.mark.parametrize("bad", [1, -2, 2.5, True])
def test_bad_final_map_sweeps_refused_by_name(slam_problem, bad):
    with pytest.raises(BayesmapError, match="final_map_sweeps"):
        run_log_slam(slam_problem, final_map_sweeps=bad, **RUN)


@pytest.mark.parametrize("bad", [-1, 2.5, True, "10"])
def test_bad_segment_length_refused_by_name(slam_problem, bad):
    with pytest.raises(BayesmapError, match="segment_length"):
        run_log_slam(slam_problem, segment_length=bad, **RUN)


def slipped_problem(problem):
    """``problem`` with its odometry slipped 0.4 m sideways into scan 6 (every later odometry pose moved with it)."""
    import dataclasses

    odometry = np.array(problem.odometry, np.float64)
    heading = odometry[5, 2]
    odometry[6:, :2] += 0.4 * np.array([-np.sin(heading), np.cos(heading)])
    return dataclasses.replace(problem, odometry=odometry)


def test_a_step_whose_odometry_slipped_is_weighed_and_the_scans_win(slam_problem):
    """Twelve Intel scans of a robot turning in place, their odometry made to slip 0.4 m sideways into scan 6 (every
    later odometry pose moved with it). The front end's match at scan 6 follows the scans, 3.7 (squared
    Mahalanobis) from the odometry's step where every other step is within 0.3: with a gate of 1 (the default's
    16.27 is for hundreds of steps; a turn's step is wide under the motion model), scan 6 alone is a branch point.
    Its branch takes the odometry's step, keeps every pose before it and puts the later scans 0.4 m off the walls
    they share with the earlier ones. Weighed by the target with the map integrated out, the front end's own path
    wins by over 100 nats (a weight of 1 to float precision), and it is the start returned. Without the slip no
    step is a branch point: nothing is weighed and the start is the front end's."""

    import jax

    from bayesmap.slam.branches import EVIDENCE_SWEEPS
    from bayesmap.slam.evidence import draw_evidence, drawn_map
    from bayesmap.slam.pipeline import MAP_SHAPE_HEADROOM, branched_start, fitted_grid, front_end, scan_data, with_grid
    from bayesmap.slam.posegraph import close_loops, relative

    slipped = slipped_problem(slam_problem)
    for problem, slips in ((slipped, True), (slam_problem, False)):
        scans = scan_data(problem)
        front = front_end(problem, scans)
        closed = close_loops(front.path, scans, step_cov=front.step_cov)
        start_front, start_closed, hypotheses, start_map = branched_start(problem, scans, front, closed,
                                                                          jax.random.key(0), gate=1.0)
        assert start_front is front and start_closed is closed
        if not slips:
            assert hypotheses is None and start_map is None
            continue
        np.testing.assert_array_equal(hypotheses.odometry_steps, [0, 6])
        np.testing.assert_array_equal(hypotheses.rejoined, [0, -1])  # (12 scans from nearly one place: no 10 m)
        assert hypotheses.disagreement[1] > 1.0
        assert hypotheses.chosen == 0 and hypotheses.weights[0] > 1 - 1e-9 and hypotheses.distinct == 1
        assert np.all(hypotheses.evidence[1:] < hypotheses.evidence[0] - 100)
        branch = front_end(problem, scans, odometry_steps=[6], prefix=front).path
        np.testing.assert_array_equal(branch[:6], front.path[:6])
        np.testing.assert_allclose(relative(branch[5], branch[6]), scans.increments[5], atol=1e-5)
        # the start map: the grid of both hypotheses' beams and the chosen one's evidence draw, to the bit
        branch_closed = close_loops(branch, scans, step_cov=front_end(problem, scans, odometry_steps=[6],
                                                                      prefix=front).step_cov)
        assert start_map.grid == fitted_grid(scans, np.stack([closed.path, branch_closed.path]),
                                             problem.params.grid.resolution)
        params = with_grid(problem.params, start_map.grid)
        draw = drawn_map(problem, params, closed.path, jax.random.key(0), EVIDENCE_SWEEPS,
                         headroom=MAP_SHAPE_HEADROOM)
        np.testing.assert_array_equal(start_map.draw.wall_probs, draw.wall_probs)
        np.testing.assert_array_equal(start_map.draw.walls, draw.walls)
        assert hypotheses.evidence[0] == draw_evidence(problem, params, closed.path, draw)


def test_a_branch_that_rejoins_is_the_rerun_up_to_there_and_the_single_tracks_steps_after(slam_problem):
    """With no travel asked of the agreement (the log's 12 scans hardly move), the slipped branch rejoins at the
    first scan after its branch point from which its steps agree with the single track's
    (:func:`bayesmap.slam.branches.rejoin_scan` of the front end run to the end); its path, as its closed path's
    grid and evidence show, is that run up to there and the single track's steps after it, to the bit."""

    import jax

    from bayesmap.slam.branches import EVIDENCE_SWEEPS, rejoin_scan, spliced, steps_apart
    from bayesmap.slam.evidence import draw_evidence, drawn_map
    from bayesmap.slam.pipeline import MAP_SHAPE_HEADROOM, branched_start, fitted_grid, front_end, scan_data, with_grid
    from bayesmap.slam.posegraph import close_loops
    from bayesmap.slam.scanmatch import path_length

    slipped = slipped_problem(slam_problem)
    scans = scan_data(slipped)
    front = front_end(slipped, scans)
    closed = close_loops(front.path, scans, step_cov=front.step_cov)
    whole = front_end(slipped, scans, odometry_steps=[6], prefix=front)
    j = rejoin_scan(steps_apart(front.path, front.step_cov, whole.path, whole.step_cov),
                    path_length(scans.increments), 6, window=0.0)
    assert j is not None and 6 < j < len(front.path) - 1
    *_, hypotheses, start_map = branched_start(slipped, scans, front, closed, jax.random.key(0), gate=1.0,
                                               rejoin_travel=0.0)
    np.testing.assert_array_equal(hypotheses.rejoined, [0, j])
    branch = spliced(type(whole)(whole.path[:j + 1], whole.step_cov[:j]), front)
    assert np.abs(branch.path[j + 1:] - whole.path[j + 1:]).max() > 0  # not the run to the end
    branch_closed = close_loops(branch.path, scans, step_cov=branch.step_cov)
    assert start_map.grid == fitted_grid(scans, np.stack([closed.path, branch_closed.path]),
                                         slipped.params.grid.resolution)
    params = with_grid(slipped.params, start_map.grid)
    first = drawn_map(slipped, params, closed.path, jax.random.key(0), EVIDENCE_SWEEPS, headroom=MAP_SHAPE_HEADROOM)
    draw = drawn_map(slipped, params, branch_closed.path, jax.random.key(0), EVIDENCE_SWEEPS, shapes=first.shapes,
                     headroom=MAP_SHAPE_HEADROOM)
    assert hypotheses.evidence[1] == draw_evidence(slipped, params, branch_closed.path, draw)


def test_the_chain_takes_the_chosen_starts_evidence_draw_as_its_first_map_block(slam_problem, monkeypatch):
    """With a branch point (the slipped odometry of the test above, the gate at 1), ``run_log_slam`` draws every
    hypothesis's evidence with the chain's first map key on the grid of every hypothesis's beams, and its chain
    takes the chosen start's draw as its first map block. A run whose evidence draws 5 sweeps, where the chain's
    4-sweep block must be drawn again, gives the same chain to the bit: the same kernel from the empty map at
    the same path with the same key. Its evidence differs, its choice does not (the scans win by over 100 nats). The
    first run compiles the chain's pose block on another thread while the evidence is drawn, the second does not:
    the same samples, to the bit."""
    import functools

    import bayesmap.slam.pipeline as pipeline

    slipped = slipped_problem(slam_problem)
    monkeypatch.setattr(pipeline, "branched_start", functools.partial(pipeline.branched_start, gate=1.0))
    blocks = []
    map_round = pipeline._map_round
    monkeypatch.setattr(pipeline, "_map_round", lambda *a, **k: blocks.append(k["stage"]) or map_round(*a, **k))
    compiled = []  # the pose block compiled on the other thread while the evidence is drawn (for the same chain)
    compile_pose_block = pipeline.compile_pose_block
    monkeypatch.setattr(pipeline, "compile_pose_block",
                        lambda *a, **k: compiled.append(a[2].grid) or compile_pose_block(*a, **k))
    run = {**RUN, "map_sweeps": pipeline.EVIDENCE_SWEEPS, "final_map_sweeps": 0}  # one round: one map block
    taken = run_log_slam(slipped, **run)
    assert blocks == [] and len(compiled) == 1
    monkeypatch.setattr(pipeline, "EVIDENCE_SWEEPS", pipeline.EVIDENCE_SWEEPS + 1)
    drawn_again = run_log_slam(slipped, **run)
    assert blocks == ["round 1/1: map"] and len(compiled) == 1  # (the chain drops it before its first block)
    for result in (taken, drawn_again):
        np.testing.assert_array_equal(result.path_hypotheses.odometry_steps, [0, 6])
        assert result.path_hypotheses.chosen == 0
    assert not np.array_equal(taken.path_hypotheses.evidence, drawn_again.path_hypotheses.evidence)
    # the chain ran on the grid of both hypotheses' beams; its maps come back on the start path's own grid
    from bayesmap.slam.pipeline import fitted_grid, front_end, scan_data
    from bayesmap.slam.posegraph import close_loops

    scans = scan_data(slipped)
    front = front_end(slipped, scans)
    start = close_loops(front.path, scans, step_cov=front.step_cov).path
    assert taken.grid == drawn_again.grid == fitted_grid(scans, start, slipped.params.grid.resolution)
    assert compiled[0].shape[0] * compiled[0].shape[1] > taken.grid.shape[0] * taken.grid.shape[1]  # the chain's
    assert taken.posterior.shape == taken.last_walls.shape == taken.grid.shape
    np.testing.assert_array_equal(taken.posterior, drawn_again.posterior)  # (no final map: the chain's)
    np.testing.assert_array_equal(taken.pose_samples, drawn_again.pose_samples)
    np.testing.assert_array_equal(taken.last_walls, drawn_again.last_walls)
