"""SLAM on a real log: the path and the map of hundreds of scans of a real building.

The target is the SLAM model's posterior ``p(poses, walls | readings, odometry)``
(:data:`bayesmap.model.slam.slam_model`, the readings' likelihood tempered by the problem's power as for
mapping at known poses). :func:`run_log_slam` finds a start, then runs a blocked Gibbs chain on it:

1. **Front end**: sequential correlative scan matching (:func:`bayesmap.slam.scanmatch.correlative_path`), the
   scans' field scores at the problem's likelihood power against the motion model (:func:`front_end`).
2. **Back end**: loop closure and pose-graph optimization (:func:`bayesmap.slam.posegraph.close_loops`), each
   sequential edge weighted by the posterior covariance of the front end's step.
   2b. **Branches** (:func:`branched_start`, :mod:`bayesmap.slam.branches`): at the few steps where the front
   end's match and the odometry disagree beyond a quantile of the motion model, the front end again with that step
   taken from the odometry, and the loop closure; every closed path weighed by the target with the walls integrated
   out (:func:`bayesmap.slam.evidence.path_evidence`, each a short map chain from the empty map with the joint
   chain's first map key), the heaviest kept.
   Stages 1 and 2 only choose where the chain starts; they do not enter its target.
3. **The grid**: fitted to the beam endpoints at that path, plus :data:`MAP_MARGIN` meters. Where branches were
   weighed, the chain runs on the grid that holds every hypothesis's beams, on which the heaviest one's map was
   drawn: that draw is the joint chain's first map block (the same sweeps from the same map, at the same path, with
   the same key); its maps are then restricted to the start path's grid (the cells beyond it only the other
   hypotheses' beams reach), the grid of the final map and of the maps returned.
4. **The joint chain**, :data:`ROUNDS` rounds of two blocks (Gibbs over blocks; docs/slam.md):

   * the walls given the poses: the ray-cell table is built at the current poses
     (:func:`bayesmap.geometry.raytable.build_ray_table`) and :data:`MAP_SWEEPS` sweeps of the cellwise Gibbs
     sampler run on it (:mod:`bayesmap.inference.cellwise`), continuing from the current walls; a log whose table
     would hold more than :data:`bayesmap.inference.tiled.TILE_PAIRS` pairs is swept a tile of the grid at a time,
     each tile with its own table (:func:`bayesmap.inference.tiled.tiled_map_chain`);
   * the poses given the walls: :data:`POSE_SWEEPS` sweeps, each of random-walk Metropolis over each pose
     (:func:`bayesmap.slam.poses.random_walk_pose_mh`, exact ray casts by grid traversal) and then of rigid moves of
     stretches of :data:`bayesmap.slam.poses.SEGMENT_LENGTH` poses (:func:`bayesmap.slam.poses.segment_pose_mh`).

   Each block's kernel leaves the joint posterior invariant, so the chain does. The first :data:`BURN_IN_ROUNDS`
   rounds are dropped; the pose samples of the others give the mean path and the covariances, and the map sweeps'
   conditional wall probabilities the posterior map.

The table is rebuilt (and its sampler compiled) once per round, not after every pose move: a round's map sweeps
see the poses of the round's start, which is still an exact blocked Gibbs chain, only a slower-mixing one.

5. **The path's uncertainty.** Single-pose moves given the map measure each pose's conditional spread given the map
   and its neighbours (about 1 cm on the three logs), not how far the path as a whole can bend with the map: the
   chain cannot move hundreds of poses together. That spread comes from the pose graph of stage 2, the Laplace
   approximation of the path's posterior with the map marginalized (:func:`bayesmap.slam.posegraph.
   marginal_covariances`), linearized at the chain's mean path, with each sequential edge's covariance the
   posterior covariance of the front end's step (:func:`bayesmap.slam.scanmatch.step_posterior`: the target's
   tempered scan likelihood against the local map, times the motion model, integrated over a lattice around the
   match; Olson 2009), its scan's part tied to the scans of the local map it was matched against
   (:class:`bayesmap.slam.posegraph.LocalMaps`, :func:`bayesmap.slam.scanmatch.local_map_shares`), and each
   loop edge's covariance its match's posterior (:func:`bayesmap.slam.posegraph.loop_posteriors`, where the
   optimization keeps :data:`bayesmap.slam.posegraph.LOOP_STD`). No factor is fitted on truth.
   The reported covariance of a pose is the chain's plus the graph's; each pose sample is a chain sample plus a
   draw of the graph's correlated deviation of the whole path (:func:`bayesmap.slam.posegraph.sample_deviations`),
   in antithetic pairs so that the samples' mean is the chain's mean path (docs/slam.md). Where the loop closure's
   other hypotheses about which loop edges are true (:func:`bayesmap.slam.posegraph.loop_hypotheses`) weigh enough
   to get samples, those samples come from their own graphs: a mixture (:func:`graph_uncertainty`).
6. **The final map** (with ``problem.final_map_params``, which :func:`bayesmap.slam.problem.log_slam_problem` sets): the
   walls given the readings at the mean path, in the map model of a log at known poses
   (:func:`bayesmap.slam.problem.log_map_params`: the structured prior, wall cells a beam can pass, a likelihood power
   that follows the readings' density at the path, :func:`final_map_power`; cross-validated across logs), with the
   model's 0.05 m sensor noise widened to :data:`FINAL_MAP_NOISE` (a reading at the mean path errs by the sensor's
   noise and the path's error together), :data:`FINAL_MAP_SWEEPS` cellwise sweeps from the chain's last map. This is
   what a SLAM system's map is, occupancy mapping at the estimated path, in bayesmap's best map model of known poses;
   the joint chain's own map (the SLAM model's, whose walls stop every beam as its pose moves need) stays in
   ``chain_posterior``. Scored at the true poses on held-out beams it ranks the cells better than the chain's
   ([validation](../validation/slam.md)).
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.devices import on_sweep_devices
from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import scan_endpoints
from bayesmap.inference.cellwise import SweepShapes
from bayesmap.inference.chains import compile_recorded_chain, run_recorded_chains
from bayesmap.inference.tiled import TILE_PAIRS, TiledChain, check_tile_pairs, tiled_map_chain
from bayesmap.memory import drop_compiled_programs
from bayesmap.model.generative import replace_params
from bayesmap.model.motion import wrap_angle
from bayesmap.progress import ProgressCallback, report
from bayesmap.scenes import endpoints_per_cell, log_likelihood_power
from bayesmap.slam.branches import (
    BRANCH_GATE,
    BRANCHES,
    EVIDENCE_SWEEPS,
    PathHypotheses,
    branch_points,
    hypothesis_weights,
    rejoin_scan,
    spliced,
    step_disagreement,
    steps_apart,
)
from bayesmap.slam.evidence import check_evidence_arguments, draw_evidence, drawn_map
from bayesmap.slam.joint import SlamResult, check_counts, pose_summary
from bayesmap.slam.keyframes import keyframe_problem, owners, place_scans, placed_uncertainty
from bayesmap.slam.particles import particle_path
from bayesmap.slam.posegraph import (
    Edges,
    LocalMaps,
    LoopClosure,
    LoopMatches,
    close_loops,
    concat_edges,
    loop_posteriors,
    marginal_covariances,
    optimize_pose_graph,
    sample_deviations,
    with_covariances,
)
from bayesmap.slam.poses import SEGMENT_LENGTH, composed_pose_kernels, random_walk_pose_mh, segment_pose_mh, slam_data
from bayesmap.slam.scanmatch import (
    FIELD_SEED,
    LOCAL_MAP_DISTANCE,
    MATCH_LEVELS,
    MIN_HIT_FRACTION,
    MOTION_TAIL_WEIGHT,
    MatchedPath,
    ScanData,
    correlative_path,
    local_map_shares,
    path_length,
)

FRONT_END_RESOLUTION = 0.05
"""Cell size of the front end's likelihood fields, meters (finer than the map: the fields resolve sub-cell
shifts)."""

FRONT_END_PARTICLES = 1
"""Hypotheses the front end keeps (:func:`bayesmap.slam.particles.particle_path`); 1: the single-track correlative
front end, the same path as before the particles existed. On a CPU time grows about linearly with it, memory by about
30 MB a particle. Kept at 1 by leave-one-log-out cross-validation of the start path's ATE between 1 and 8 over Intel,
ACES and CSAIL, odometry seeds 0-2, every scan and every other scan (``benchmarks/front_end_cv.py --parameter
particles``; [validation](../validation/defaults.md#front_end_particles))."""


MAP_MARGIN = 2.0
"""Meters around the matched path's endpoints for the final grid (room for the chain's pose moves)."""

ROUNDS = 3
"""Default rounds of the joint chain (each: the walls given the poses, then the poses given the walls): the
configuration every SLAM figure was measured with
([validation](../validation/defaults.md#rounds-and-burn_in_rounds))."""

BURN_IN_ROUNDS = 1
"""Default rounds dropped before the posterior is averaged (with :data:`ROUNDS`, the measured configuration)."""

MAP_SWEEPS = 4
"""Cellwise map sweeps per round."""

POSE_SWEEPS = 8
"""Pose sweeps (every pose once) per round."""

FINAL_MAP_NOISE = 0.15
"""The sensor noise of the final map (stage 6), meters: the map model's 0.05 m widened by the mean path's own
position error, since a beam cast from the mean pose ends where the true pose's beam ends plus that error (the
propagation of a pose's uncertainty into a measurement's noise, *Probabilistic Robotics* sec. 10.2). Chosen by
leave-one-log-out cross-validation of the final map's held-out AUC at the true poses over 0.05, 0.1, 0.15 and
0.2 m and the noise widened by the reported path covariance (every fold chose 0.15 m; the reported covariance,
about twice as wide as the path's errors, blurred the maps) on Intel, ACES and CSAIL, odometry seed 0
([validation](../validation/slam.md#the-final-map-with-the-paths-uncertainty))."""

FINAL_MAP_SWEEPS = 40
"""Cellwise sweeps of the final map (stage 6; the first half burn-in): the sweeps with which the map model of a log
at known poses was cross-validated ([validation](../validation/defaults.md#final_map_sweeps))."""

MAP_SHAPE_HEADROOM = 0.1
"""How much larger than its table needs (a fraction) a joint chain's map block pads its sweep's arrays, so that the
next blocks' tables, at slightly moved poses, fit them and reuse one compiled sweep (each compilation takes 4-5 s
on two cores). A speed knob, not a model setting: padding changes no draw (tested). On the shared logs a width
group's cells vary by up to 8 % from one round to the next (a few percent for the large groups); blocks that do not
fit compile anew ([scale page](../validation/scale.md#where-the-slam-time-went-on-intel-and-what-was-cut))."""

def scan_data(problem) -> ScanData:
    """The :class:`~bayesmap.slam.scanmatch.ScanData` of a :class:`bayesmap.slam.problem.SlamProblem` (odometry
    controls under the problem's motion model; max-range beams marked as not returned). The readings are what the
    sensor read: the model's readings plus the problem's ``range_offset``, so that scan matching aligns the scans'
    true endpoints (the offset belongs to the map's cell geometry; subtracted, it shrinks every scan towards its pose
    and biases each match along the direction of travel: 0.6 % of the distance on ACES)."""
    increments, covs = problem.motion_steps()
    mask = problem.max_range_mask if problem.max_range_mask is not None else np.zeros(problem.readings.shape, bool)
    returned = ~np.asarray(mask, bool)
    readings = np.where(returned, problem.readings + problem.range_offset, 0.0)
    return ScanData(np.asarray(problem.sensor_angles), readings, returned, np.asarray(increments),
                    np.asarray(covs))


def _returned_endpoints(data: ScanData, path) -> np.ndarray:
    """``(N, 2)`` float64 world endpoints (meters) of the returned beams of ``data`` (:func:`scan_data`: the readings
    as measured) at ``path`` ``(S, 3)``."""
    return np.asarray(scan_endpoints(jnp.asarray(path), data.sensor_angles, data.readings))[data.returned]


def fitted_grid(data: ScanData, path, resolution: float, margin: float = MAP_MARGIN) -> Grid:
    """The grid covering the returned beams' endpoints (:func:`scan_data`) and the sensor positions at ``path``
    ``(S, 3)``, or at every path of a stack ``(H, S, 3)``, plus ``margin`` meters."""
    paths = np.reshape(path, (-1, *np.shape(path)[-2:]))
    points = [np.vstack([_returned_endpoints(data, p), p[:, :2]]) for p in paths]
    return Grid.covering(np.vstack(points), resolution=resolution, margin=margin)


def front_end(problem, data: ScanData, min_hit_fraction: float = MIN_HIT_FRACTION,
              window: float = LOCAL_MAP_DISTANCE, particles: int = FRONT_END_PARTICLES, seed: int = 0,
              progress: ProgressCallback | None = None, levels=MATCH_LEVELS,
              motion_tail: float = MOTION_TAIL_WEIGHT, field_seed: bool = FIELD_SEED,
              odometry_steps=None, prefix: MatchedPath | None = None, until=None) -> MatchedPath:
    """The front end's path ``(S, 3)`` float64 (x m, y m, theta rad) and its steps' posterior covariances
    (:class:`bayesmap.slam.scanmatch.MatchedPath`): correlative scan matching from the first
    odometry pose on fields of :data:`FRONT_END_RESOLUTION` meters that follow the robot
    (:data:`bayesmap.slam.scanmatch.MATCH_GRID_HALF_WIDTH`), each scan's field score raised to the problem's
    likelihood power against the motion model, as the target tempers the readings (docs/slam.md: at power 1 the
    scans' correlated beams outweigh the odometry along corridors, where the front end slipped; chosen by
    leave-one-log-out cross-validation, ``benchmarks/front_end_cv.py``); a scan whose match puts fewer than
    ``min_hit_fraction`` of its endpoints on the local map takes the odometry's prediction
    (:data:`bayesmap.slam.scanmatch.MIN_HIT_FRACTION`, chosen the same way). The local map holds the scans of
    the last ``window`` meters of travel (:data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`). With ``particles``
    above 1, that many hypotheses (:func:`bayesmap.slam.particles.particle_path`, random seed ``seed``), the
    heaviest particle's path returned and the distinct heavy paths counted (:data:`FRONT_END_PARTICLES`).
    ``levels`` is the coarse-to-fine search (:data:`bayesmap.slam.scanmatch.MATCH_LEVELS`). The search and the
    steps' posteriors score the motion model with a broad component of weight ``motion_tail``, the covariance of a
    step that backed up under the problem's motion noise (:data:`bayesmap.slam.scanmatch.MOTION_TAIL_WEIGHT`;
    0: the motion model alone); the target's motion density is the model's. ``field_seed``: the search also
    descends from the scan's best fit alone at its first level (:data:`bayesmap.slam.scanmatch.FIELD_SEED`).
    ``odometry_steps``: scans that take the odometry's step, ``prefix``: a path whose poses before the first of
    them are kept, and ``until``: where to stop (:func:`bayesmap.slam.scanmatch.correlative_path`; the single track
    only). ``progress`` gets ``Progress("front end", done, S - 1, "scan")`` as the scans are matched.

    Raises:
        BayesmapError: as :func:`bayesmap.slam.scanmatch.correlative_path` and
            :func:`bayesmap.slam.particles.particle_path`."""
    odometry = np.asarray(problem.odometry, np.float64)
    options = dict(likelihood_power=problem.likelihood_power, min_hit_fraction=min_hit_fraction, window=window,
                   progress=progress, levels=levels, motion_tail=motion_tail, motion=problem.motion,
                   field_seed=field_seed)
    if isinstance(particles, (int, np.integer)) and not isinstance(particles, bool) and particles == 1:
        return correlative_path(odometry[0], data, FRONT_END_RESOLUTION, odometry_steps=odometry_steps,
                                prefix=prefix, until=until, **options)
    if odometry_steps is not None or prefix is not None or until is not None:
        raise BayesmapError("odometry_steps, prefix and until are for the single-track front end (particles 1)")
    return particle_path(odometry[0], data, FRONT_END_RESOLUTION, particles, seed=seed, **options).matched


class StartMap(NamedTuple):
    """The map drawn at the start path the branches chose (:func:`branched_start`): the grid that holds every
    hypothesis's beams, and the chosen hypothesis's draw for its evidence
    (:func:`bayesmap.slam.evidence.drawn_map`, :data:`bayesmap.slam.branches.EVIDENCE_SWEEPS` sweeps from an empty
    map), which is the joint chain's first map block at that path when drawn with the chain's first key."""

    grid: Grid
    draw: TiledChain


def branched_start(problem, scans: ScanData, front: MatchedPath, closed: LoopClosure, key,
                   branches: int = BRANCHES, tile_pairs: int = TILE_PAIRS, progress: ProgressCallback | None = None,
                   gate: float = BRANCH_GATE, matches: LoopMatches | None = None,
                   rejoin_travel: float = LOCAL_MAP_DISTANCE, on_grid: Callable | None = None,
                   ) -> tuple[MatchedPath, LoopClosure, PathHypotheses | None, StartMap | None]:
    """Stage 2b of the module docstring (:mod:`bayesmap.slam.branches`): the front end's path ``front`` and its
    loop closure ``closed``, and at most ``branches`` branches (the front end again from each branch point, a step
    whose match disagrees with the odometry beyond ``gate`` (:func:`bayesmap.slam.branches.branch_points`), with its
    step taken from the odometry, resumed from ``front``, until it rejoins ``front``
    (:func:`bayesmap.slam.branches.rejoin_scan` at ``gate`` over ``rejoin_travel`` meters, the front end's local
    map's span :data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`), ``front``'s later steps after that
    (:func:`bayesmap.slam.branches.spliced`); the loop closure), weighed by their evidence
    (:func:`bayesmap.slam.evidence.path_evidence`, :data:`bayesmap.slam.branches.EVIDENCE_SWEEPS` sweeps, random
    key ``key`` for every hypothesis, on one grid covering every hypothesis's beams, in tiles of at most
    ``tile_pairs`` pairs). ``progress`` gets ``Progress("branches", done, H, "path")`` as each hypothesis is weighed.
    ``matches``: the loop matches ``closed`` made (:class:`bayesmap.slam.posegraph.LoopMatches`, filled by
    ``close_loops(..., matches=)``): a branch's loop closure takes those whose inputs it shares (its first round's
    among the scans before its branch point) instead of searching again, the same result; None: none kept. The
    compiled programs of the front end and the loop closure are dropped before the evidence
    (:func:`bayesmap.memory.drop_compiled_programs`), whose map sweep the joint chain then shares. ``on_grid``:
    called with the chain's model on the grid of every hypothesis's beams (:class:`StartMap`'s) once it is known,
    before the draws (:func:`run_log_slam` then compiles the chain's pose block on another thread).

    Returns:
        ``(front end, loop closure, hypotheses, start map)`` of the heaviest hypothesis, ``start map`` its
        :class:`StartMap`; ``hypotheses`` and ``start map`` None where no step's match disagrees with the odometry
        beyond ``gate`` (:data:`bayesmap.slam.branches.BRANCH_GATE`; then ``front`` and ``closed`` themselves, and
        nothing is weighed).
    """
    distance = step_disagreement(front.path, scans.increments, scans.covs)
    points = branch_points(distance, gate, branches)
    if not len(points):
        return front, closed, None, None
    total = len(points) + 1
    report(progress, "branches", 0, total, "path")
    matches = LoopMatches() if matches is None else matches
    candidates, rejoined, travelled = [(front, closed)], [0], path_length(scans.increments)
    for t in points:
        def until(path, step_cov, t=int(t)):  # where the branch's steps have become the single track's
            return rejoin_scan(steps_apart(front.path, front.step_cov, path, step_cov), travelled, t,
                               rejoin_travel, gate)

        other = front_end(problem, scans, odometry_steps=[int(t)], prefix=front, until=until)
        rejoined.append(len(other.path) - 1 if len(other.path) < len(front.path) else -1)
        other = spliced(other, front)
        candidates.append((other, close_loops(other.path, scans, step_cov=other.step_cov, matches=matches)))
    params = with_grid(problem.params, fitted_grid(scans, np.stack([c.path for _, c in candidates]),
                                                   problem.params.grid.resolution))
    check_evidence_arguments(params, EVIDENCE_SWEEPS)
    drop_compiled_programs()  # (the branches' front ends and loop closures are done)
    if on_grid is not None:
        on_grid(params)
    # where the run reports progress, its chain's map blocks run one sweep per compiled call: so do the draws
    # here, unreported, and the chain shares their compiled sweep
    silent = None if progress is None else _unreported
    evidence, shapes, chosen, chosen_draw = [], None, 0, None
    for h, (_, c) in enumerate(candidates):
        with on_sweep_devices():  # where the chain's map blocks run (bayesmap.devices)
            draw = drawn_map(problem, params, c.path, key, EVIDENCE_SWEEPS, tile_pairs, shapes, MAP_SHAPE_HEADROOM,
                             silent)
            evidence.append(draw_evidence(problem, params, c.path, draw))
        shapes = draw.shapes
        if h == 0 or evidence[h] > evidence[chosen]:  # the heaviest, the first of equal ones; only its draw is kept
            chosen, chosen_draw = h, draw
        del draw
        report(progress, "branches", h + 1, total, "path")
    weights = hypothesis_weights(evidence)
    disagreement = np.concatenate([[0.0], distance[points - 1]])
    hypotheses = PathHypotheses(np.concatenate([[0], points]).astype(np.int64), disagreement,
                                np.asarray(evidence, np.float64), weights, chosen, np.asarray(rejoined, np.int64))
    # the sizes the last draw's sweep was compiled for (at least every earlier draw's) go on to the chain's
    return (*candidates[chosen], hypotheses, StartMap(params.grid, chosen_draw._replace(shapes=shapes)))


def _unreported(_progress) -> None:
    """A progress callback that reports nothing."""


def with_grid(params, grid: Grid):
    """``params`` (:class:`bayesmap.model.generative.ModelParams`) on another grid, every other value kept (the max
    range the one ``params`` resolves on its own grid)."""
    return replace_params(params, grid=grid, max_distance=params.max_range)


def _pose_record(state, info):
    """What a pose chain of :func:`run_log_slam` keeps per sweep: the poses and the acceptances."""
    return state.poses, info.accepted


def _map_round(key, problem, params, poses, walls, sweeps: int, power: float | None = None,
               progress: ProgressCallback | None = None, stage: str = "map", tile_pairs: int = TILE_PAIRS,
               shapes: SweepShapes | None = None, headroom: float = 0.0):
    """One map block: the table at ``poses`` and ``sweeps`` cellwise sweeps from ``walls`` (likelihood power
    ``power``, default the problem's), in tiles of at most ``tile_pairs`` pairs
    (:func:`bayesmap.inference.tiled.tiled_map_chain`); the sweep (the whole table's or each tile's) padded to
    ``shapes`` with ``headroom`` (the same draws; :class:`bayesmap.inference.cellwise.CellwiseGibbs`), so that the
    blocks of a joint chain share one compilation. Returns the chain's ``(last walls (nx, ny) float32, wall
    probabilities (sweeps, nx, ny), the sizes its sweep was compiled for (the last tile's))``. ``progress`` gets
    ``Progress(stage, done, sweeps, "sweep")`` from before the table is built and as the sweeps run."""
    theta = poses[:, 2:3] + problem.sensor_angles
    origins = np.repeat(poses[:, :2], problem.sensor_angles.shape[1], axis=0)
    chain = tiled_map_chain(key, params, origins, theta.reshape(-1), problem.readings.reshape(-1), walls, sweeps,
                            problem.likelihood_power if power is None else power, max_pairs=tile_pairs,
                            progress=progress, stage=stage, shapes=shapes, headroom=headroom)
    return chain.walls, chain.wall_probs, chain.shapes


def final_map_power(problem, data: ScanData, path, grid: Grid) -> float:
    """The likelihood power of the final map at ``path`` (``(S, 3)``, x m, y m, theta rad) on ``grid``:
    ``problem.final_map_power``, or where that is None the log default,
    :func:`bayesmap.scenes.log_likelihood_power` of the :func:`bayesmap.scenes.endpoints_per_cell` of the returned
    beams of ``data`` (:func:`scan_data` of ``problem``: the readings as measured) at the path."""
    if problem.final_map_power is not None:
        return float(problem.final_map_power)
    return log_likelihood_power(endpoints_per_cell(_returned_endpoints(data, path), grid))


def hypothesis_counts(num: int, weights) -> np.ndarray:
    """How many of ``num`` samples each hypothesis of ``weights`` ``(H,)`` (summing to 1) gets: the largest-remainder
    apportionment (Hamilton's method) of ``num * weights``, remainders tied in order; ``(H,)`` int64 summing to
    ``num``."""
    weights = np.asarray(weights, np.float64)
    quota = num * weights / weights.sum()
    counts = np.floor(quota).astype(np.int64)
    extra = np.argsort(-(quota - counts), kind="stable")[: num - int(counts.sum())]
    counts[extra] += 1
    return counts


def _antithetic(seed: int, path, edges, num: int, local_maps: LocalMaps | None = None) -> np.ndarray:
    """``num`` graph deviations of ``path`` (:func:`bayesmap.slam.posegraph.sample_deviations`) in antithetic pairs
    (``ceil(num / 2)`` draws and their negatives); zeros for a single one."""
    half = sample_deviations(seed, path, edges, (num + 1) // 2, local_maps)
    return np.concatenate([half, -half])[:num] if num > 1 else np.zeros((num, *np.shape(path)))


class LoopPosteriors:
    """Loop edges with their matches' posterior covariances (:func:`bayesmap.slam.posegraph.loop_posteriors` at
    ``path`` ``(S, 3)``, the scans ``data`` and the likelihood ``power``), each edge's computed once however many
    hypotheses hold it (keyed by its two scans), reported to ``progress`` as there: :func:`graph_uncertainty`'s
    ``loop_posterior``."""

    def __init__(self, path, data: ScanData, power: float, progress: ProgressCallback | None = None):
        self.path, self.data, self.power, self.known = np.asarray(path, np.float64), data, power, {}
        self.progress = progress

    def __call__(self, loops: Edges) -> Edges:
        pairs = list(zip(np.asarray(loops.i).tolist(), np.asarray(loops.j).tolist()))
        new = [k for k, pair in enumerate(pairs) if pair not in self.known]
        if new:
            found = loop_posteriors(self.path, self.data, loops.take(np.asarray(new, np.int64)), self.power,
                                    self.progress)
            self.known.update({pairs[k]: c for k, c in zip(new, found)})
        return with_covariances(loops, np.array([self.known[p] for p in pairs]).reshape(len(pairs), 3, 3))


def graph_uncertainty(seed: int, chain_samples, edges, hypotheses=None, local_maps: LocalMaps | None = None,
                      loop_posterior: Callable | None = None):
    """Stage 5 of the module docstring: the chain's pose samples with the pose graph's uncertainty (the graph's
    Laplace approximation, Lu & Milios 1997; antithetic pairs, Hammersley & Morton 1956; docs/slam.md), and with
    the loop closure's other hypotheses where they weigh enough to get samples.

    Args:
        seed: seed of the graph's draws (``numpy.random.default_rng``; hypothesis ``h`` uses ``seed + h``).
        chain_samples: ``(N, S, 3)`` pose samples of the joint chain (x m, y m, theta rad), ``N >= 1``.
        edges: the pose graph (:func:`bayesmap.slam.posegraph.close_loops`: the ``S - 1`` sequential edges first,
            here with the front end's step covariances, ``close_loops(step_cov=...)``),
            every pose after the first on an edge.
        hypotheses: None, or the loop closure's :class:`bayesmap.slam.posegraph.LoopHypotheses`, the first the
            one ``edges`` holds. Hypothesis ``h`` gets :func:`hypothesis_counts` of the ``N`` samples (the chain's
            samples in order: the first ones stay with the first hypothesis); one with any gets the graph of the
            sequential edges and its loop edges, optimized from the chain's mean path, and its samples are that
            path plus a chain sample's deviation from the chain's mean plus that graph's deviation: a mixture of
            the hypotheses' Laplace approximations, each with the chain's local spread.
        local_maps: None, or what the front end matched each step against
            (:class:`bayesmap.slam.posegraph.LocalMaps`): every hypothesis's graph then ties each step's scan
            information to its local map's scans (:func:`bayesmap.slam.posegraph.marginal_covariances`).
        loop_posterior: None, or a function of a graph's loop edges (:class:`bayesmap.slam.posegraph.Edges`) that
            returns them with the covariances each hypothesis's Laplace approximation gives them instead of their
            deviations (their matches' posteriors, :func:`bayesmap.slam.posegraph.loop_posteriors`); the graph a
            hypothesis's path is optimized on keeps the deviations.

    Returns:
        ``(mean (S, 3), cov (S, 3, 3), samples (N, S, 3), graph_cov (S, 3, 3))`` float64. With one hypothesis
        holding every sample: the chain's mean path (:func:`bayesmap.slam.joint.pose_summary`), the chain's
        covariance plus the graph's (:func:`bayesmap.slam.posegraph.marginal_covariances` at the mean path), each
        chain sample plus a graph deviation (``ceil(N / 2)`` draws and their negatives, so for even ``N`` the
        samples' mean position is the chain's; a single sample gets none), and the graph's covariance. With
        several: the mixture's mean and covariance, each hypothesis weighted by its share of the samples (headings
        averaged as differences from the first's, wrapped), and the first hypothesis's ``graph_cov``.

    Raises:
        BayesmapError: on a graph that leaves a pose without edges or is in pieces
            (:func:`bayesmap.slam.posegraph.marginal_covariances`).
    """
    chain_samples = np.asarray(chain_samples, np.float64)
    mean, chain_cov = pose_summary(chain_samples)
    sequential = edges.take(slice(0, len(mean) - 1))

    def laplace(graph):  # the graph the Laplace approximation reads
        if loop_posterior is None:
            return graph
        return concat_edges(sequential, loop_posterior(graph.take(slice(len(mean) - 1, None))))

    first = laplace(edges)
    graph_cov = marginal_covariances(mean, first, local_maps)
    n = len(chain_samples)
    counts = np.array([n]) if hypotheses is None else hypothesis_counts(n, hypotheses.weights)
    if counts[0] == n:
        return mean, chain_cov + graph_cov, chain_samples + _antithetic(seed, mean, first, n, local_maps), graph_cov
    parts, starts = [], np.concatenate([[0], np.cumsum(counts)])
    for h in np.flatnonzero(counts):
        if h == 0:
            path, graph, cov_h = mean, first, graph_cov
        else:
            graph = concat_edges(sequential, hypotheses.loops.take(hypotheses.sets[h]))
            path = optimize_pose_graph(mean, graph)  # (on the loop edges' deviations)
            graph = laplace(graph)
            cov_h = marginal_covariances(path, graph, local_maps)
        local = chain_samples[starts[h]: starts[h + 1]] - mean
        local[:, :, 2] = wrap_angle(local[:, :, 2])
        samples = path + local + _antithetic(seed + int(h), path, graph, int(counts[h]), local_maps)
        parts.append((counts[h] / n, path, chain_cov + cov_h, samples))
    offsets = [np.concatenate([p[:, :2] - mean[:, :2], wrap_angle(p[:, 2:] - mean[:, 2:])], axis=1)
               for _, p, _, _ in parts]
    shift = sum(f * o for (f, _, _, _), o in zip(parts, offsets))
    mixture_cov = sum(f * (c + np.einsum("si,sj->sij", o - shift, o - shift))
                      for (f, _, c, _), o in zip(parts, offsets))
    return (mean + shift, mixture_cov, np.concatenate([s for _, _, _, s in parts]), graph_cov)


def chain_keys(seed: int, rounds: int) -> jax.Array:
    """``(2 rounds,)`` the joint chain's random keys: round ``r``'s map block ``2 r``, its pose block ``2 r + 1``
    (:func:`run_log_slam`)."""
    return jax.random.split(jax.random.key(seed), 2 * rounds)


@on_sweep_devices()  # the sweeps on the CPU, also where JAX's default device is a GPU (bayesmap.devices)
def _joint_chain(problem, scans: ScanData, params, path, seed: int, counts: tuple[int, int, int, int],
                 progress: ProgressCallback | None, tile_pairs: int = TILE_PAIRS,
                 segment_length: int = SEGMENT_LENGTH, first_map: TiledChain | None = None,
                 compiling: Future | None = None) -> tuple:
    """Stage 4 of the module docstring: the joint chain from ``path`` ``(S, 3)`` and an empty map on ``params``'s
    grid, ``counts`` = ``(rounds, burn_in, map_sweeps, pose_sweeps)``, reporting each round's map and pose sweeps
    (stages ``"round r/R: map"`` and ``"round r/R: poses"``), the map blocks in tiles of at most ``tile_pairs``, each
    pose sweep a random-walk sweep then, with ``segment_length`` > 0, a sweep of segment moves of that many poses.
    ``first_map``: the first round's map block already drawn (``map_sweeps`` sweeps from the empty map at ``path``
    with the chain's first key, :func:`chain_keys`; :class:`StartMap`), reported as done; the compiled programs are
    then kept (the caller dropped those it no longer needs). None: the first block drawn here, after dropping them.
    ``compiling``: the pose block's compilation under way on another thread (:func:`compile_pose_block`), waited
    for before the first pose sweep.

    Returns:
        ``(last walls (nx, ny) float32, pose samples (N, S, 3) float64, wall probabilities (M, nx, ny),
        acceptances (N, S - 1) bool)`` of the rounds after the burn-in (the last walls: of the last round).
    """
    rounds, burn_in, map_sweeps, pose_sweeps = counts
    if first_map is None:
        # the front end's and the loop closure's compiled searches, and what they hold (about 250 MB on Intel), are
        # not needed again before the scans between keyframes are placed; the map blocks' sweep is then compiled
        # once (:data:`MAP_SHAPE_HEADROOM`) and the pose sweeps' once
        drop_compiled_programs()
    data, pose_kernel = _pose_kernel(problem, scans, params, segment_length)
    walls = jnp.zeros(params.grid.shape, jnp.float32)
    poses = jnp.asarray(path, data.increments.dtype)
    keys = chain_keys(seed, rounds)
    samples, probs, accepted, shapes = [], [], [], None
    for r in range(rounds):
        stage = f"round {r + 1}/{rounds}: map"
        if r == 0 and first_map is not None:
            walls, wall_probs, shapes = first_map.walls, first_map.wall_probs, first_map.shapes
            report(progress, stage, map_sweeps, map_sweeps, "sweep")
        else:
            walls, wall_probs, shapes = _map_round(keys[2 * r], problem, params, np.asarray(poses, np.float64), walls,
                                                   map_sweeps, progress=progress, stage=stage, tile_pairs=tile_pairs,
                                                   shapes=shapes, headroom=MAP_SHAPE_HEADROOM)
        if compiling is not None:  # the pose block compiled on another thread (run_log_slam): wait for it
            compiling.result()
            compiling = None
        pose_samples, acc = run_recorded_chains(keys[2 * r + 1], pose_kernel.init(poses, walls),
                                                pose_kernel, pose_sweeps, _pose_record, progress=progress,
                                                stage=f"round {r + 1}/{rounds}: poses")
        poses = pose_samples[-1]
        if r >= burn_in:
            samples.append(np.asarray(pose_samples, np.float64))
            probs.append(wall_probs)
            accepted.append(np.asarray(acc))
    return walls, np.concatenate(samples), np.concatenate(probs), np.concatenate(accepted)


def _pose_kernel(problem, scans: ScanData, params, segment_length: int):
    """``(data, kernel)``: the joint chain's pose block on ``params``' grid (module docstring, stage 4)."""
    data = slam_data(scans.increments, scans.covs, problem.sensor_angles, problem.readings, params)
    kernel = random_walk_pose_mh(data, likelihood_power=problem.likelihood_power)
    if segment_length:
        kernel = composed_pose_kernels(kernel, segment_pose_mh(data, segment_length,
                                                               likelihood_power=problem.likelihood_power))
    return data, kernel


@on_sweep_devices()  # (where _joint_chain runs its sweeps: the same program)
def compile_pose_block(problem, scans: ScanData, params, num_poses: int, seed: int, counts: tuple[int, int, int, int],
                       reported: bool, segment_length: int = SEGMENT_LENGTH) -> None:
    """Compile the joint chain's pose block ahead of time: the program :func:`_joint_chain` runs for a path of
    ``num_poses`` poses on ``params``' grid with ``counts`` and ``segment_length`` as there, one sweep per call
    with ``reported`` (a progress callback), for :func:`run_log_slam` to run on another thread while the branches'
    maps are drawn (their tables are built on one core: the compilation, 3-4 s on two cores, then takes the other).
    JAX keeps the program; the chain's first pose block does not compile it again. Runs the pose block's ``init``
    once (every scan cast at a path of zeros, on an empty map)."""
    data, kernel = _pose_kernel(problem, scans, params, segment_length)
    state = kernel.init(jnp.zeros((num_poses, 3), data.increments.dtype), jnp.zeros(params.grid.shape, jnp.float32))
    compile_recorded_chain(chain_keys(seed, counts[0])[1], state, kernel, counts[3], _pose_record, reported)


def _final_map(problem, scans: ScanData, grid: Grid, mean, walls, key, sweeps: int,
               progress: ProgressCallback | None, tile_pairs: int = TILE_PAIRS) -> tuple[np.ndarray, float, float]:
    """Stage 6 of the module docstring: ``sweeps`` cellwise sweeps (the first half burn-in) at the mean path
    ``mean`` ``(S, 3)`` from the chain's last ``walls``, in the map model of ``problem.final_map_params`` with the
    noise :data:`FINAL_MAP_NOISE`, reported as stage ``"final map"`` per sweep, in tiles of at most ``tile_pairs``
    pairs.

    Returns:
        ``(posterior (nx, ny) float64, likelihood power, sensor noise m)``.
    """
    power = final_map_power(problem, scans, mean, grid)
    noise = FINAL_MAP_NOISE
    params = replace_params(with_grid(problem.final_map_params, grid), sensor_noise=noise)
    # the final map's model compiles its own sweep: drop the joint chain's compiled sweeps first, and what they hold
    # (on 300 scans of Intel the final map's peak 1,286 -> 929 MB)
    drop_compiled_programs()
    with on_sweep_devices():  # (bayesmap.devices)
        _, probs, _ = _map_round(key, problem, params, mean, walls, sweeps, power, progress, "final map", tile_pairs)
    return probs[sweeps // 2:].astype(np.float64).mean(axis=0), power, noise


def _check_final_map_sweeps(final_map_sweeps) -> None:
    if (isinstance(final_map_sweeps, bool) or not isinstance(final_map_sweeps, (int, np.integer))
            or final_map_sweeps < 0 or final_map_sweeps == 1):
        raise BayesmapError(f"final_map_sweeps must be 0 or an integer >= 2, got {final_map_sweeps!r}")


def run_log_slam(problem, rounds: int = ROUNDS, burn_in: int = BURN_IN_ROUNDS, seed: int = 0,
                 progress: ProgressCallback | None = None, map_sweeps: int = MAP_SWEEPS, pose_sweeps: int = POSE_SWEEPS,
                 final_map_sweeps: int = FINAL_MAP_SWEEPS,
                 tile_pairs: int = TILE_PAIRS, particles: int = FRONT_END_PARTICLES,
                 segment_length: int = SEGMENT_LENGTH, branches: int = BRANCHES) -> SlamResult:
    """Infer the path and the map of a real log (:func:`bayesmap.slam.problem.log_slam_problem`) with the pipeline
    of the module docstring.

    Args:
        problem: a :class:`bayesmap.slam.problem.SlamProblem` from a log.
        rounds: rounds of the joint chain, >= 1.
        burn_in: rounds dropped, ``0 <= burn_in < rounds``.
        seed: the random seed (``jax.random.key(seed)``).
        progress: a :data:`bayesmap.progress.ProgressCallback`, called stage after stage (each from ``done`` 0 up
            to its ``total``): ``"front end"`` per block of scans matched, ``"loop closure r/3"`` per loop
            candidate of each round of :func:`bayesmap.slam.posegraph.close_loops` that has any (unit ``"scan"``),
            ``"branches"`` per hypothesis weighed where there are branch points (:func:`branched_start`), then per
            sweep ``"round r/R: map"`` and ``"round r/R: poses"`` for each round of the joint chain, ``"path
            uncertainty"`` per loop edge whose match's posterior is computed (:class:`LoopPosteriors`; where there
            are loop edges) and ``"final map"``.
            The chains then run one sweep per compiled call, with the same keys: the result is the same, bit for
            bit. None: no reports.
        map_sweeps: cellwise map sweeps per round, >= 1.
        pose_sweeps: pose sweeps per round, >= 1.
        final_map_sweeps: cellwise sweeps of the final map at the mean path (stage 6, :data:`FINAL_MAP_SWEEPS`),
            >= 2, or 0: no final map (``posterior`` is the chain's). Without ``problem.final_map_params`` there is
            no final map.
        tile_pairs: the most (beam, cell) pairs a map block holds at once: a block whose table would hold more is
            swept a tile of the grid at a time (:data:`bayesmap.inference.tiled.TILE_PAIRS`), >= 1. Bounds the map
            blocks' memory; any value samples the same posterior.
        particles: hypotheses the front end keeps (:func:`front_end`, :data:`FRONT_END_PARTICLES`), >= 1.
        segment_length: poses moved together by the chain's segment moves
            (:func:`bayesmap.slam.poses.segment_pose_mh`, :data:`bayesmap.slam.poses.SEGMENT_LENGTH`), an integer
            >= 1, or 0: single-pose moves only. Any value samples the same posterior.
        branches: the most branch points weighed (stage 2b, :func:`branched_start`,
            :data:`bayesmap.slam.branches.BRANCHES`), an integer >= 0 (0: the single track's start path); with the
            particle front end (``particles`` > 1), none.

    Returns:
        A :class:`bayesmap.slam.joint.SlamResult`: ``pose_samples`` ``(N, S, 3)`` with ``N = (rounds - burn_in)
        pose_sweeps`` and ``pose_cov`` with the graph's uncertainty (:func:`graph_uncertainty`), ``posterior`` on
        ``grid``, the grid fitted to the start path (the final map's, or the chain's without one, restricted to it
        where the chain ran on the grid of every start path weighed; the chain's is ``chain_posterior``),
        ``graph_cov`` the graph's covariance.

    Raises:
        BayesmapError: on bad counts, a bad ``final_map_sweeps``, ``tile_pairs``, ``segment_length`` or
            ``branches`` (the message names the value).
    """
    _check_final_map_sweeps(final_map_sweeps)
    check_tile_pairs(tile_pairs)
    final = problem.final_map_params is not None and final_map_sweeps > 0
    rounds, burn_in, _ = check_counts(rounds, burn_in, 1)
    map_sweeps, _, _ = check_counts(map_sweeps, 0, 1)
    pose_sweeps, _, _ = check_counts(pose_sweeps, 0, 1)
    if isinstance(segment_length, bool) or not isinstance(segment_length, (int, np.integer)) or segment_length < 0:
        raise BayesmapError(f"segment_length must be an integer >= 0, got {segment_length!r}")
    if isinstance(branches, bool) or not isinstance(branches, (int, np.integer)) or branches < 0:
        raise BayesmapError(f"branches must be an integer >= 0, got {branches!r}")
    start = time.perf_counter()
    scans = scan_data(problem)
    front = front_end(problem, scans, particles=particles, seed=seed, progress=progress)
    matches = LoopMatches() if branches and particles == 1 else None
    closed = close_loops(front.path, scans, progress=progress, step_cov=front.step_cov, matches=matches)
    branched, start_map, counts = None, None, (rounds, burn_in, map_sweeps, pose_sweeps)
    background = ThreadPoolExecutor(1, thread_name_prefix="compile") if matches is not None else None
    compiling = []

    def on_grid(params):  # the chain's grid is known: compile its pose block while the maps are drawn
        if map_sweeps == EVIDENCE_SWEEPS:  # (else the chain drops the compiled programs before its first block)
            compiling.append(background.submit(compile_pose_block, problem, scans, params, len(front.path), seed,
                                               counts, progress is not None, int(segment_length)))

    try:
        if matches is not None:
            # every hypothesis's evidence is drawn with the chain's first map key: the chosen one's draw is then
            # the chain's first map block at its start path (the same sweeps from the empty map), which it takes
            front, closed, branched, start_map = branched_start(problem, scans, front, closed,
                                                                chain_keys(seed, rounds)[0], branches, tile_pairs,
                                                                progress, matches=matches, on_grid=on_grid)
        path, edges, hypotheses = closed
        grid = fitted_grid(scans, path, problem.params.grid.resolution)  # the start path's: the maps returned
        chain_grid = grid if start_map is None else start_map.grid  # (the grid of every hypothesis's beams)
        first_map = start_map.draw if start_map is not None and map_sweeps == EVIDENCE_SWEEPS else None
        walls, samples, probs, accepted = _joint_chain(problem, scans, with_grid(problem.params, chain_grid), path,
                                                       seed, counts, progress, tile_pairs, int(segment_length),
                                                       first_map, compiling[0] if compiling else None)
    finally:
        if background is not None:
            background.shutdown(wait=True, cancel_futures=True)
    if chain_grid != grid:  # the cells the start path's beams reach; the others only the other hypotheses' do
        cells = chain_grid.window(grid)
        walls, probs = walls[cells], probs[:, cells[0], cells[1]]
    local_maps = LocalMaps(local_map_shares(front.path, scans), np.asarray(scans.covs, np.float64))
    mean, cov, samples, graph_cov = graph_uncertainty(seed, samples, edges, hypotheses, local_maps,
                                                      LoopPosteriors(path, scans, problem.likelihood_power, progress))
    chain_posterior = probs.astype(np.float64).mean(axis=0)
    posterior, final_power, final_noise = chain_posterior, None, None
    if final:
        key = jax.random.fold_in(jax.random.key(seed), 2 * rounds)  # none of the chain's keys
        posterior, final_power, final_noise = _final_map(problem, scans, grid, mean, walls, key, final_map_sweeps,
                                                         progress, tile_pairs)
    return SlamResult(pose_samples=samples, mean_path=mean, pose_cov=cov, posterior=posterior,
                      acceptance_rate=float(accepted.mean()) if accepted.size else 1.0,
                      runtime_s=time.perf_counter() - start, last_walls=np.asarray(walls, np.float32), grid=grid,
                      loop_edges=len(edges.i) - (len(path) - 1), graph_cov=graph_cov,
                      chain_posterior=chain_posterior if final else None, final_map_power=final_power,
                      final_map_noise=final_noise, loop_hypotheses=hypotheses,
                      front_end_hypotheses=front.hypotheses, path_hypotheses=branched)


def run_keyframe_slam(problem, keyframes, progress: ProgressCallback | None = None, **kwargs) -> SlamResult:
    """:func:`run_log_slam` on the scans ``keyframes`` ``(K,)`` of ``problem`` (:func:`bayesmap.slam.keyframes.
    keyframe_problem`), then every other scan placed on the keyframes' map (:func:`bayesmap.slam.keyframes.
    place_scans`, reported as stage ``"place scans"``) with its covariance and samples from its keyframe's
    (:func:`bayesmap.slam.keyframes.placed_uncertainty`). ``kwargs`` are :func:`run_log_slam`'s.

    Returns:
        A :class:`bayesmap.slam.joint.SlamResult` of every scan of ``problem``: ``mean_path`` ``(S, 3)``,
        ``pose_cov`` and ``graph_cov`` ``(S, 3, 3)`` (a scan between keyframes: its keyframe's graph covariance),
        ``pose_samples`` ``(N, S, 3)``; the maps the keyframes'.

    Raises:
        BayesmapError: as :func:`run_log_slam`.
    """
    keyframes = np.asarray(keyframes, np.int64)
    result = run_log_slam(keyframe_problem(problem, keyframes), progress=progress, **kwargs)
    if len(keyframes) == problem.num_scans:
        return result
    start = time.perf_counter()
    others = problem.num_scans - len(keyframes)
    report(progress, "place scans", 0, others, "scan")
    data = scan_data(problem)  # every scan's beams and motion steps (the problem's, once)
    poses = place_scans(result.mean_path, keyframes, data, problem.likelihood_power)
    cov, samples = placed_uncertainty(poses, keyframes, (data.increments, data.covs), result.pose_cov,
                                      result.pose_samples)
    report(progress, "place scans", others, others, "scan")
    graph_cov = None if result.graph_cov is None else result.graph_cov[owners(problem.num_scans, keyframes)]
    return result._replace(mean_path=poses, pose_cov=cov, pose_samples=samples, graph_cov=graph_cov,
                           runtime_s=result.runtime_s + time.perf_counter() - start)
