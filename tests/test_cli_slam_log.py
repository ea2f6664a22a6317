"""`bayesmap slam --log/--bag` on a slice of a real log, and `bayesmap evaluate --truth-trajectory`: the outputs,
their shapes and stamps, the bag against the log, hand-computed trajectory scores, and one-line refusals."""

import io
import json
import math

import numpy as np
import pytest
from PIL import Image

from bayesmap import scenes
from bayesmap.geometry.grid import Grid
from bayesmap.io.carmen import read_carmen
from bayesmap.io.rosbag import read_bag
from bayesmap.io.tum import read_tum, tum_stamps, write_tum
from bayesmap.runs.slam import loop_hypotheses_summary, path_hypotheses_summary
from bayesmap.slam.branches import BRANCHES, PathHypotheses
from bayesmap.slam.keyframes import keyframe_problem, owners, select_keyframes
from bayesmap.slam.pipeline import (
    FINAL_MAP_NOISE,
    FINAL_MAP_SWEEPS,
    POSE_SWEEPS,
    final_map_power,
    front_end,
    scan_data,
)
from bayesmap.slam.posegraph import (
    Edges,
    LocalMaps,
    LoopHypotheses,
    marginal_covariances,
    sequential_edges,
    with_covariances,
)
from bayesmap.slam.problem import log_slam_problem
from bayesmap.slam.scanmatch import local_map_shares
from helpers import SHARED_DATA, run_cli, run_main

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

SLICE = ("--scans", "0:25", "--resolution", "0.2", "--sweeps", "2", "--seed", "3")
"""25 scans of ACES at 0.2 m cells, 2 sweeps (the burn-in a third: none; `evaluate` has no --burn-in): a slice whose
timestamps increase strictly (ACES's do), so trajectory.tum carries them. Each sweep's map round compiles its own
cellwise sweep (the ray table changes with the poses), about 10 s, so the runs are kept to two sweeps, the fewest
that have the second round start from the first's map and poses."""


@pytest.fixture(scope="module")
def aces_odom():
    path = SHARED_DATA / "slam" / "aces-odom.log.gz"
    if not path.exists():
        pytest.skip("shared data not present")
    return path


ONE_RUN = pytest.mark.xdist_group("slam_log_run")
"""The tests that read :func:`log_run`'s folder: on one xdist worker (``--dist loadgroup``), so the module-scoped run
happens once, not once per worker."""


@pytest.fixture(scope="module")
def log_run(aces_odom, tmp_path_factory):
    """One ``slam --log`` run on the slice with every optional output (the folder)."""
    out = tmp_path_factory.mktemp("slamlog") / "run"
    code = run_main("slam", "--log", aces_odom, *SLICE, "--rosmap", "--maps", "--report", "--out", out)
    assert code == 0
    return out


@ONE_RUN
def test_slam_log_writes_every_output(log_run, aces_odom):
    names = {"trajectory.tum", "trajectory_samples.npy", "pose_cov.npy", "posterior.npy", "posterior.png",
             "occupancy.png", "summary.json", "report.html", "map.pgm", "map.yaml", "posterior.npz",
             "probability.png", "probability.yaml", "std.png", "std.yaml"}
    assert {p.name for p in log_run.iterdir()} == names
    stamps, poses = read_tum(log_run / "trajectory.tum")
    log = read_carmen(aces_odom)
    assert np.all(np.diff(log.timestamps) > 0)  # so the stamps are the scans' own, not indices
    assert np.array_equal(stamps, tum_stamps(log.timestamps)[:25]) and np.array_equal(stamps, log.timestamps[:25])
    samples = np.load(log_run / "trajectory_samples.npy")
    cov = np.load(log_run / "pose_cov.npy")
    assert samples.shape == (2 * POSE_SWEEPS, 25, 3) and cov.shape == (25, 3, 3)  # both rounds kept
    # the samples' mean is the mean path (the TUM file's 6 decimals): a keyframe's samples are the chain's plus the
    # graph's deviations in antithetic pairs; a scan between keyframes is its keyframe's sample composed with its
    # offset, whose mean turns the offset by E[R(delta)] instead of R(0), off by at most |offset| E[delta^2] / 2
    # (delta the keyframe's heading deviation; |exp(i d) - 1 - i d| <= d^2 / 2, E[delta] = 0)
    slam_problem = log_slam_problem(read_carmen(aces_odom), np.arange(25), resolution=0.2)
    keyframes = select_keyframes(slam_problem.odometry)
    own = keyframes[owners(25, keyframes)]
    delta = samples[:, own, 2] - poses[own, 2]
    delta = (delta + np.pi) % (2 * np.pi) - np.pi
    reach = np.linalg.norm(poses[:, :2] - poses[own, :2], axis=1)
    off = np.linalg.norm(poses[:, :2] - samples[:, :, :2].mean(axis=0), axis=1)
    assert np.all(off <= 2e-5 + reach * np.mean(delta**2, axis=0) / 2), off
    assert np.all(off[own == np.arange(25)] <= 2e-5)
    assert np.allclose(poses[0], log.poses[0], atol=1e-5)  # the first pose anchors the frame: the odometry's
    summary = json.loads((log_run / "summary.json").read_text())
    settings = summary["settings"]
    assert summary["num_scans"] == 25 and settings["sweeps"] == 2 and settings["burn_in"] == 0 and settings["seed"] == 3
    assert settings["geometry"] == "chord" and settings["range_offset_m"] == 0.0  # no offset in any default
    # posterior.npy is the final map at the mean path, in the map model of a log at known poses (log_problem's)
    final, known = settings["final_map"], scenes.log_problem(read_carmen(aces_odom), np.arange(25), resolution=0.2)
    assert final["sweeps"] == FINAL_MAP_SWEEPS and final["geometry"] == "chord"
    for name in ("coupling", "wall_pass_prob"):
        assert final[name] == pytest.approx(float(getattr(known.params, name))) and final[name] > 0, name
    # its noise is the model's widened for the path's error (FINAL_MAP_NOISE); 23 of the 25 scans are keyframes, by
    # distance and turn alone (with the motion model's steps, KEYFRAME_HEADING_SD, scan 17 would be one too: the
    # steps from 16 to 18 compose to a heading standard deviation over it; slam --log does not pass them)
    assert settings["keyframes"] == len(keyframes) == 23 and 17 not in keyframes
    assert "keyframe_heading_sd_rad" not in settings
    assert 17 in select_keyframes(slam_problem.odometry, step_covs=slam_problem.motion_steps()[1])
    assert final["sensor_noise"] == FINAL_MAP_NOISE
    assert final["sensor_noise"] > float(known.params.sensor_noise)
    # its power follows the readings' density at the mean path (trajectory.tum, rounded to 1e-6: a few endpoints
    # may change cells, hence rel 1e-2), not at the odometry, whose endpoints smear over twice the cells here
    wide = Grid((2000, 2000), resolution=0.2, origin=(-200.0, -200.0))
    data = scan_data(slam_problem)
    chain = keyframe_problem(slam_problem, keyframes)  # the final map is drawn from the keyframes' scans
    at_mean = final_map_power(chain, scan_data(chain), poses[keyframes], wide)
    assert final["likelihood_power"] == pytest.approx(at_mean, rel=1e-2)
    assert final_map_power(slam_problem, data, slam_problem.odometry, wide) == pytest.approx(known.likelihood_power)
    assert abs(at_mean - known.likelihood_power) > 0.2 * known.likelihood_power
    assert summary["pose_samples"] == len(samples) and 0 <= summary["acceptance_rate"] <= 1
    assert "graph_cov_scale" not in settings and summary["loop_edges"] == 0
    assert summary["loop_hypotheses"] is None  # no loop edge, nothing to weigh
    assert settings["front_end_particles"] == 1 and summary["front_end_hypotheses"] == 1  # the single track
    # no step's match is beyond the motion model's 99.9 % quantile here, so the front end's path is the only one
    assert settings["branches"] == BRANCHES and summary["path_hypotheses"]["weighed"] == 1
    assert summary["path_hypotheses"]["branch_scans"] == [None]
    assert summary["path_hypotheses"]["above_1_percent"] == 1
    assert settings["motion"] == pytest.approx({"a1": 0.1, "a2": 0.05, "a3": 0.1, "a4": 0.05, "floor_xy": 0.01,
                                                "floor_theta": 0.005})
    # the pose graph's spread is in the covariances, with no factor: 25 scans close no loop (LOOP_GAP), so the graph
    # is the sequential edges over the keyframes, each with its front-end step's posterior covariance, the scan's part
    # tied to the scans of its local map (LocalMaps); linearized at the mean path, it is a keyframe's covariance less
    # the chain's own (positive semidefinite) spread, and a scan between keyframes has its keyframe's and more. Tied
    # to the local maps, the last keyframe's position variance is a sixth of the plain chain's, which adds every
    # step's (the chain's own spread, about a centimeter, is far below the difference).
    front = front_end(chain, scan_data(chain))
    steps = front.step_cov
    sequential = with_covariances(sequential_edges(front.path), steps)
    tied = marginal_covariances(poses[keyframes], sequential,
                                LocalMaps(local_map_shares(front.path, scan_data(chain)), scan_data(chain).covs))
    plain = marginal_covariances(poses[keyframes], sequential)
    k = owners(25, keyframes)
    excess = cov - tied[k]
    assert np.all(np.linalg.eigvalsh(excess[:, :2, :2]) >= -1e-6 * np.trace(tied[k, :2, :2], axis1=1, axis2=2)[:, None])
    assert np.trace(tied[-1, :2, :2]) < np.trace(plain[-1, :2, :2]) / 2  # 0.0072 against 0.044 m^2
    assert np.trace(cov[keyframes[-1], :2, :2]) < np.trace(plain[-1, :2, :2]) / 2  # the run's graph is the tied one
    given_heading = steps[:, :2, :2] - np.einsum("si,sj->sij", steps[:, :2, 2], steps[:, :2, 2]) / steps[:, 2:, 2:]
    accumulated = np.concatenate([[0.0], np.cumsum(np.trace(given_heading, axis1=1, axis2=2))])
    assert accumulated[-1] > 20 * 2 * 0.012**2 / 12  # the steps are wider than the lattice's floor
    posterior = np.load(log_run / "posterior.npy")
    assert list(posterior.shape) == summary["grid"]["shape"] and summary["grid"]["resolution"] == 0.2
    assert posterior.min() >= 0 and posterior.max() <= 1
    maps = np.load(log_run / "posterior.npz")
    assert maps["probability"].shape == posterior.shape and maps["seen"].any() and not maps["seen"].all()
    assert np.allclose(maps["origin"], summary["grid"]["origin"])
    for name in ("posterior.png", "occupancy.png"):
        with Image.open(log_run / name) as png:
            png.verify()
    assert "data:image/png;base64," in (log_run / "report.html").read_text()


@ONE_RUN
def test_slam_log_summary_holds_each_stage(log_run):
    """summary.json's stages: the runs layer's (reading the log, building the problem, the figures, the files)
    around the pipeline's, in the order they ran (no loop closure on 25 scans: no candidate; the 2 scans that are
    not keyframes placed last). The pipeline times
    itself (runtime_s) from inside "build problem" (the scans' data precede its first report) until it returns,
    a few lines before "figures" starts: so its stages add up to runtime_s less part of "build problem", within
    0.2 s (the lines between, and 1 ms of rounding per stage). Each peak is positive and at most the run's."""
    summary = json.loads((log_run / "summary.json").read_text())
    stages = summary["stages"]
    rounds = [f"round {r}/2: {part}" for r in (1, 2) for part in ("map", "poses")]
    assert [s["stage"] for s in stages] == ["read log", "build problem", "front end", *rounds, "final map",
                                            "place scans", "figures", "write outputs"]
    pipeline = sum(s["seconds"] for s in stages[2:-2])
    assert pipeline - 0.2 <= summary["runtime_s"] <= pipeline + stages[1]["seconds"] + 0.2
    assert all(0 < s["peak_rss_mb"] <= summary["peak_rss_mb"] for s in stages)
    assert all(s["seconds"] >= 0 for s in stages)


@ONE_RUN
def test_slam_log_in_tiles_maps_the_same_building(log_run, aces_odom, tmp_path):
    """With --tile-pairs below the slice's pairs (about 141,000 at the start path: two tiles), every map block is
    swept in tiles: the run records its budget, each block is one stage however many tiles it has, and its map is
    the untiled run's building: the two final maps' probabilities correlate above 0.9 over the cells either run's
    beams crossed (0.97 measured: they differ by their chains' draws and the path of one round fewer; a tile left
    at its starting map or without its beams would leave half the building at the prior). One round, to keep the
    run short: each tile compiles its own sweep. (The tiles' band is checked in tests/inference/test_tiled.py,
    where it matters; here the final map starts from the chain's walls and the band changes little.)"""
    out = tmp_path / "tiled"
    code = run_main("slam", "--log", aces_odom, "--scans", "0:25", "--resolution", "0.2", "--sweeps", "1",
                    "--seed", "3", "--tile-pairs", "100000", "--maps", "--out", out)
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["tile_pairs"] == 100000
    assert [s["stage"] for s in summary["stages"]] == ["read log", "build problem", "front end", "round 1/1: map",
                                                      "round 1/1: poses", "final map", "place scans", "figures",
                                                      "write outputs"]
    tiled, whole = (np.load(folder / "posterior.npz") for folder in (out, log_run))
    assert tiled["probability"].shape == whole["probability"].shape
    seen = tiled["seen"] | whole["seen"]
    assert np.corrcoef(tiled["probability"][seen], whole["probability"][seen])[0, 1] > 0.9


@ONE_RUN
def test_slam_bag_gives_the_logs_trajectory(log_run, aces_odom, tmp_path, monkeypatch, capsys):
    """The slice written as a ROS 1 bag by `bayesmap convert` maps to the log's path (same seed): the bag keeps
    ranges and poses exactly and beam angles to 2e-7 rad (float32)."""
    bag = tmp_path / "slice.bag"
    code, _, err = run_cli(monkeypatch, capsys, "convert", aces_odom, bag, "--scans", "0:25")
    assert code == 0, err
    code, _, err = run_cli(monkeypatch, capsys, "slam", "--bag", bag, *SLICE, "--out", tmp_path / "bagrun")
    assert code == 0, err
    stamps, poses = read_tum(tmp_path / "bagrun" / "trajectory.tum")
    log_stamps, log_poses = read_tum(log_run / "trajectory.tum")
    assert np.allclose(stamps, read_bag(bag).timestamps, rtol=0, atol=1e-6)
    assert np.allclose(stamps, log_stamps, rtol=0, atol=1e-6)
    assert np.abs(poses[:, :2] - log_poses[:, :2]).max() < 1e-3  # meters
    assert np.abs(np.angle(np.exp(1j * (poses[:, 2] - log_poses[:, 2])))).max() < 1e-3  # radians


@ONE_RUN
def test_evaluate_runs_slam_on_the_log(log_run, aces_odom, tmp_path, monkeypatch, capsys):
    """Without --run, evaluate runs SLAM on the log's slice itself: the same path as `slam --log` with the same
    options and seed (so the same scores as --run on that folder); the truth has one pose per scan of the whole log,
    so the slice's poses are its rows 0..24; the odometry's scores are those of the log's poses."""
    from bayesmap.evaluation.trajectory import score_trajectory

    truth = SHARED_DATA / "slam" / "aces-odom.truth.tum"
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", aces_odom, "--truth-trajectory", truth,
                             *SLICE, "--json", tmp_path / "new.json")
    assert code == 0, err
    code, _, err = run_cli(monkeypatch, capsys, "evaluate", "--log", aces_odom, "--truth-trajectory", truth,
                           "--run", log_run, "--json", tmp_path / "run.json")
    assert code == 0, err
    new, old = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("new", "run"))
    assert new["setup"]["paired_by"] == "order" and new["setup"]["scans"] == 25
    # the JSON's stages: a new run's pipeline (no final map: the path is scored) between reading and scoring
    assert [s["stage"] for s in old["stages"]] == ["read truth", "read log", "score"]
    names = [s["stage"] for s in new["stages"]]
    assert names[:4] == ["read truth", "read log", "build problem", "front end"] and names[-1] == "score"
    assert "round 2/2: poses" in names and "final map" not in names and new["peak_rss_mb"] > 0
    # 1e-5 m: the run folder's trajectory.tum keeps 6 decimals
    assert new["bayesmap"]["ate_rmse_m"] == pytest.approx(old["bayesmap"]["ate_rmse_m"], abs=1e-5)
    _, true_poses = read_tum(truth)
    expected = score_trajectory(read_carmen(aces_odom).poses[:25], true_poses[:25])
    assert new["odometry"]["coverage"] is None and old["odometry"] == new["odometry"]
    assert {k: v for k, v in new["odometry"].items() if v is not None} == pytest.approx(
        {k: v for k, v in expected.items() if v is not None}, rel=1e-12)


def _square_case(tmp_path):
    """A 4-scan log, its true path (a 2 m square, heading along it), a run folder whose path is the square scaled
    by 1.5 about its center, then turned by 0.7 rad and shifted (a rigid motion the ATE's alignment undoes), and
    odometry (the log's poses) the square scaled by 2.

    By hand: the best rigid alignment of a square scaled by s about its center is the identity (symmetry), each
    corner then off by |s - 1| sqrt(2) m, so ATE = 0.5 sqrt(2) m (run) and sqrt(2) m (odometry); each 2 m side
    is 2 s m long, so RPE over one scan is |2 s - 2| = 1 m (run) and 2 m (odometry), with no rotation error; the
    95 % ellipse of radius sqrt(-2 ln 0.05) sd (2.45 sd) holds a 0.71 m error for sd 0.5 m, not for sd 0.1 m."""
    center = np.array([1.0, 1.0])
    corners = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    heading = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2])
    truth = np.column_stack([corners, heading])
    phi, shift = 0.7, np.array([3.0, -1.0])
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    run_xy = (1.5 * (corners - center)) @ rot.T + center + shift
    run_path = np.column_stack([run_xy, heading + phi])
    odometry = np.column_stack([2.0 * (corners - center) + center, heading])
    stamps = np.array([100.0, 100.5, 101.0, 101.5])
    lines = [f"FLASER 3 1.0 1.5 2.0 {x!r} {y!r} {t!r} {x!r} {y!r} {t!r} {s!r} host {s!r}\n"
             for (x, y, t), s in zip(odometry, stamps)]
    (tmp_path / "square.log").write_text("".join(lines))
    write_tum(tmp_path / "truth.tum", stamps, truth)
    run = tmp_path / "run"
    run.mkdir()
    write_tum(run / "trajectory.tum", stamps, run_path)
    sd = np.array([0.5, 0.5, 0.1, 0.1])
    buf = io.BytesIO()
    np.save(buf, np.eye(3)[None] * (sd**2)[:, None, None])
    (run / "pose_cov.npy").write_bytes(buf.getvalue())
    return stamps, truth


def test_evaluate_run_scores_by_hand(tmp_path, monkeypatch, capsys):
    _square_case(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "truth.tum", "--run", tmp_path / "run", "--json", tmp_path / "s.json")
    assert code == 0, err
    assert "bayesmap" in out and "odometry" in out and "paired by order" in out
    scores = json.loads((tmp_path / "s.json").read_text())
    run, odo = scores["bayesmap"], scores["odometry"]
    # 1e-6: the TUM file's 6 decimals of position (5e-7 m each)
    assert run["ate_rmse_m"] == pytest.approx(0.5 * math.sqrt(2), abs=1e-6)
    assert run["rpe1_trans_rmse_m"] == pytest.approx(1.0, abs=1e-6) and run["rpe1_rot_rmse_deg"] < 1e-5
    assert run["coverage"] == 0.5 and run["poses"] == 4 and "rpe10_trans_rmse_m" not in run
    # the best similarity undoes the scaling: the truth is 1 / 1.5 of the run's size and 1 / 2 of the odometry's
    assert run["scale_pct"] == pytest.approx(100 * (1 / 1.5 - 1), abs=1e-4)
    assert odo["scale_pct"] == pytest.approx(-50.0, abs=1e-9)
    assert odo["ate_rmse_m"] == pytest.approx(math.sqrt(2), abs=1e-9)
    assert odo["rpe1_trans_rmse_m"] == pytest.approx(2.0, abs=1e-9) and odo["coverage"] is None


def test_evaluate_ranks_the_truth_among_the_run_samples(tmp_path, monkeypatch, capsys):
    """A run folder with trajectory_samples.npy: its samples are scored as the truth is. By hand (the square case):
    one sample on the run's path covers 4 of 4, one the truth carried rigidly covers 2 of 4 as the truth does, so
    the truth ties one and is below the other: rank (0 + 0.5) / 2. A samples file of the wrong shape is refused by
    name, exit code 2."""
    _square_case(tmp_path)
    _, path = read_tum(tmp_path / "run" / "trajectory.tum")
    _, truth = read_tum(tmp_path / "truth.tum")
    buf = io.BytesIO()
    np.save(buf, np.stack([path, moved_onto(truth, path)]))
    (tmp_path / "run" / "trajectory_samples.npy").write_bytes(buf.getvalue())
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "truth.tum", "--run", tmp_path / "run", "--json", tmp_path / "s.json")
    assert code == 0, err
    run = json.loads((tmp_path / "s.json").read_text())["bayesmap"]
    assert run["coverage"] == 0.5 and run["samples"] == 2 and run["coverage_rank"] == 0.25
    assert run["samples_coverage_min"] == 0.5 and run["samples_coverage_max"] == 1.0
    assert "the 2 posterior samples" in out and "ranks 0.25" in out
    buf = io.BytesIO()
    np.save(buf, np.zeros((2, 3, 3)))
    (tmp_path / "run" / "trajectory_samples.npy").write_bytes(buf.getvalue())
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "truth.tum", "--run", tmp_path / "run")
    assert code == 2 and "trajectory_samples.npy" in err and "(2, 3, 3)" in err and len(err.strip().splitlines()) == 1


def moved_onto(poses, onto):
    """``poses`` ``(S, 3)`` carried by the rigid motion that best aligns them onto ``onto`` (positions; headings
    turned by its angle)."""
    from bayesmap.evaluation.trajectory import align_rigid_2d

    rot, t = align_rigid_2d(poses[:, :2], onto[:, :2])
    return np.column_stack([poses[:, :2] @ rot.T + t, poses[:, 2] + math.atan2(rot[1, 0], rot[0, 0])])


def test_evaluate_pairs_a_longer_truth_by_timestamp(tmp_path, monkeypatch, capsys):
    """A truth with poses between the scans (6 poses, 4 scans, a 5-scan log) pairs by stamp: the same scores."""
    stamps, truth = _square_case(tmp_path)
    extra = np.array([100.25, 101.25])
    all_stamps = np.sort(np.concatenate([stamps, extra]))
    poses = np.zeros((6, 3))
    poses[np.searchsorted(all_stamps, stamps)] = truth
    poses[np.searchsorted(all_stamps, extra)] = [[9.0, 9.0, 0.0], [-9.0, 4.0, 1.0]]  # off the path: must not pair
    write_tum(tmp_path / "long.tum", all_stamps, poses)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "long.tum", "--run", tmp_path / "run", "--json", tmp_path / "s.json")
    assert code == 0, err
    assert "paired by timestamp" in out
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["bayesmap"]["ate_rmse_m"] == pytest.approx(0.5 * math.sqrt(2), abs=1e-6)
    assert scores["odometry"]["ate_rmse_m"] == pytest.approx(math.sqrt(2), abs=1e-9)


@pytest.mark.parametrize("make_args, match", [
    (lambda t: ["slam", "--log", t / "square.log", "--bag", t / "x.bag"], "either --log or --bag"),
    (lambda t: ["slam", "--log", t / "missing.log"], "missing.log"),
    (lambda t: ["slam", "--log", t / "square.log", "--num-poses", "5"], "--num-poses"),
    (lambda t: ["slam", "--scans", "0:5"], "--scans"),
    (lambda t: ["slam", "--tile-pairs", "1000"], "--tile-pairs"),
    (lambda t: ["slam", "--log", t / "square.log", "--tile-pairs", "0"], "--tile-pairs must be an integer >= 1, got 0"),
    (lambda t: ["slam", "--particles", "8"], "--particles"),
    (lambda t: ["slam", "--log", t / "square.log", "--particles", "0"], "--particles must be at least 1, got 0"),
    (lambda t: ["slam", "--branches", "2"], "--branches"),
    (lambda t: ["slam", "--log", t / "square.log", "--branches", "-1"], "--branches must be at least 0, got -1"),
    (lambda t: ["slam", "--motion-alphas", "0.1,0.05,0.1,0.05"], "--motion-alphas"),
    (lambda t: ["slam", "--log", t / "square.log", "--motion-alphas", "0.1,0.05"],
     "--motion-alphas must be four numbers A1,A2,A3,A4, got 2 in '0.1,0.05'"),
    (lambda t: ["slam", "--log", t / "square.log", "--motion-alphas", "0.1,x,0.1,0.05"], "got '0.1,x,0.1,0.05'"),
    (lambda t: ["slam", "--log", t / "square.log", "--motion-alphas", "0.1,-1,0.1,0.05"],
     "a2 must be a finite number >= 0, got -1.0"),
    (lambda t: ["slam", "--log", t / "square.log", "--sweeps", "4", "--burn-in", "4"], "--burn-in"),
    (lambda t: ["evaluate", "--truth-trajectory", t / "truth.tum"], "needs --log"),
    (lambda t: ["evaluate", "--log", t / "square.log", "--truth-trajectory", t / "missing.tum"], "missing.tum"),
    (lambda t: ["evaluate", "--log", t / "square.log", "--truth-trajectory", t / "short.tum", "--run", t / "run"],
     "3 poses, not one per scan of the run (4)"),
    (lambda t: ["evaluate", "--log", t / "square.log", "--truth-trajectory", t / "truth.tum", "--run", t / "nope"],
     "not a folder"),
    (lambda t: ["evaluate", "--log", t / "square.log", "--truth-trajectory", t / "truth.tum", "--run", t / "bad"],
     "pose_cov.npy"),
    (lambda t: ["evaluate", "--log", t / "square.log", "--run", t / "run"], "--truth-trajectory"),
])
def test_slam_and_evaluate_errors_are_one_line_exit_2(tmp_path, monkeypatch, capsys, make_args, match):
    stamps, truth = _square_case(tmp_path)
    write_tum(tmp_path / "short.tum", stamps[:3] + 0.2, truth[:3])  # 3 poses at stamps no scan has
    (tmp_path / "bad").mkdir()
    write_tum(tmp_path / "bad" / "trajectory.tum", stamps, truth)  # and no pose_cov.npy
    args = make_args(tmp_path)
    code, _, err = run_cli(monkeypatch, capsys, *args, *(["--out", tmp_path / "o"] if args[0] == "slam" else []))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], err
    assert not (tmp_path / "o").exists()


def test_slam_motion_alphas_set_the_motion_model(tmp_path, monkeypatch):
    """``slam --log --motion-alphas A1,A2,A3,A4`` builds the problem with that motion noise, the floors at their
    defaults (without the option: MotionParams' defaults)."""
    from bayesmap.runs import slam as slam_run

    _square_case(tmp_path)
    seen = []

    def stop(problem, keyframes, **kwargs):
        seen.append(problem.motion)
        raise RuntimeError("stop")

    monkeypatch.setattr(slam_run, "run_keyframe_slam", stop)
    for alphas, expected in ((None, (0.1, 0.05, 0.1, 0.05)), ("0.05,0.02,0.2,0.01", (0.05, 0.02, 0.2, 0.01))):
        with pytest.raises(RuntimeError, match="stop"):
            slam_run.slam(slam_run.SlamRequest(log=tmp_path / "square.log", motion_alphas=alphas, out=tmp_path / "o"))
        motion = seen[-1]
        assert (motion.a1, motion.a2, motion.a3, motion.a4) == pytest.approx(expected)
        assert (motion.floor_xy, motion.floor_theta) == (0.01, 0.005)


def test_summary_json_counts_the_loop_hypotheses_over_one_percent():
    """summary.json's ``loop_hypotheses``: of three weighed hypotheses (0.98, 0.015, 0.005) two weigh over 1 %; the
    weights and edge counts as they are, most probable first, and the path samples each drew of 100, plain JSON; no
    hypotheses (no loop edge): null."""
    loops = Edges(np.arange(4), np.arange(40, 44), np.zeros((4, 3)), np.full((4, 3), 0.1))
    hypotheses = LoopHypotheses([np.array([0, 1, 2]), np.array([3]), np.zeros(0, np.int64)],
                                np.array([0.98, 0.015, 0.005]), 2, loops)
    summary = json.loads(json.dumps(loop_hypotheses_summary(hypotheses, 100)))
    assert summary == {"above_1_percent": 2, "weighed": 3, "consistent_sets": 2, "weights": [0.98, 0.015, 0.005],
                       "loop_edges": [3, 1, 0], "samples": [98, 2, 0]}  # 1.5 and 0.5: the larger remainder first
    assert loop_hypotheses_summary(None, 100) is None


def test_path_hypotheses_summary_names_the_logs_scans():
    """A branch's step is a keyframe's index in the run; summary.json names the log's scan (``scans[t]``), the
    evidence less the front end's, and counts the hypotheses weighing at least 1 %."""
    hypotheses = PathHypotheses(np.array([0, 3, 7]), np.array([0.0, 40.25, 17.5]), np.array([-100.0, -95.0, -90.0]),
                                np.array([0.004, 0.2, 0.796]), 2, np.array([0, 5, -1]))
    summary = path_hypotheses_summary(hypotheses, np.array([0, 2, 4, 10, 12, 14, 16, 21]))
    assert summary == {"above_1_percent": 2, "weighed": 3, "branch_scans": [None, 10, 21],
                       "rejoin_scans": [None, 14, None], "disagreement": [0.0, 40.25, 17.5],
                       "evidence_nats": [0.0, 5.0, 10.0], "weights": [0.004, 0.2, 0.796], "chosen": 2}


def test_summary_lines_name_the_start_paths_weighed(tmp_path):
    """Where branch points were weighed, ``bayesmap slam`` says how many paths and which one the chain started from;
    with none, no such line."""
    from types import SimpleNamespace

    from bayesmap.runs.slam import summary_lines

    def lines(hypotheses):
        summary = {"settings": {"sweeps": 3, "burn_in": 1}, "grid": {"shape": [4, 5], "resolution": 0.1},
                   "path_hypotheses": hypotheses}
        run = SimpleNamespace(problem=SimpleNamespace(source="x.log", readings=np.zeros((2, 3)), num_scans=2),
                              result=SimpleNamespace(acceptance_rate=0.5, runtime_s=1.0,
                                                     pose_cov=np.stack([np.eye(3), np.eye(3)])),
                              summary=summary)
        return [line for line in summary_lines(run, tmp_path, ["a"]) if line.startswith("start:")]

    weighed = path_hypotheses_summary(PathHypotheses(np.array([0, 3, 7]), np.array([0.0, 40.0, 20.0]),
                                                     np.array([0.0, 5.0, -90.0]), np.array([0.0, 1.0, 0.0]), 1,
                                                     np.array([0, 4, -1])),
                                      np.array([0, 2, 4, 10, 12, 14, 16, 21]))
    assert lines(weighed) == ["start:    3 paths weighed (the odometry's step at scans 10, 21); the one through "
                              "scan 10 kept"]
    alone = path_hypotheses_summary(PathHypotheses(np.array([0, 3]), np.array([0.0, 40.0]), np.array([0.0, -9.0]),
                                                   np.array([1.0, 0.0]), 0, np.array([0, -1])), np.arange(8))
    assert lines(alone) == ["start:    2 paths weighed (the odometry's step at scan 3); the front end's own kept"]
    assert lines(path_hypotheses_summary(None, np.arange(8))) == []

