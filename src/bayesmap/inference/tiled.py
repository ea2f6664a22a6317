"""A whole log's map chain in tiles: memory bounded by the tile being sampled, not by the log's beams.

The cellwise sampler (:mod:`bayesmap.inference.cellwise`) holds every (beam, cell) pair of the log: about 20-40 bytes
each, tables and sweep lanes, so a log twice as long needs twice the memory. :func:`tiled_map_chain` runs the same
chain a tile of the grid at a time when the log's pairs exceed a budget (:data:`TILE_PAIRS`):

1. The grid is cut into rectangles of at most ``max_pairs`` pairs each (:func:`bayesmap.geometry.tiles.split_tiles`
   on the rays per cell, counted a chunk of beams at a time).
2. Tile after tile: the tile grown by a band of ``margin`` meters (:data:`TILE_MARGIN`) is the block; its table is
   built with every other cell held at its current value (:func:`bayesmap.geometry.tiles.tile_table`: the beams that
   cross the block, their pairs in it and their first few wall cells outside it), and ``sweeps`` cellwise sweeps of
   the block's cells run with the rest frozen (``CellwiseGibbs(..., frozen=...)``; with ``focus``, after the first
   :data:`~bayesmap.inference.focus.FOCUS_START` sweeps most of them of the block's cells in doubt only:
   :func:`bayesmap.inference.focus.focused_chain`); the block's last draw is written
   into the map, the tile's cells' conditional probabilities into the record, and the table is dropped before the
   next tile. Where the caller shares compiled sweeps between chains (``shapes`` or a ``headroom``: a SLAM run's
   map blocks and draws), each tile's sweep is padded to the sizes of the one before where they fit (padding
   changes no draw), so that the tiles, and the next chain's, run one compiled sweep; otherwise each tile's sweep is
   sized for its own table, and its compiled program is dropped before the next tile (the padding cost ``infer``'s
   100 sweeps more than the compilations it saved).

Each of a tile's sweeps draws every cell of the tile (or every cell of it in doubt) from its full conditional given
every other cell of the map (the tile's table gives it exactly the conditional of the whole table: tested), so each
leaves the posterior invariant, and the chain as a whole is a blocked Gibbs sampler whose (overlapping) blocks are
the grown tiles, each updated by ``sweeps`` Gibbs sweeps in turn (a composition of kernels that each leave the target
invariant leaves it invariant; Tierney 1994, sec. 2.4). What differs from the whole map's chain is the order of
the updates: a tile is swept ``sweeps`` times before the next is touched (``passes`` > 1: ``sweeps / passes`` times,
the tiles visited ``passes`` times in turn), so its cells are drawn given the other tiles as they were when it was
visited (the tiles before it: their last draws; after it: the chain's starting map). The per-cell record,
``wall_probs[t]``, is each cell's conditional wall probability in the ``t``-th sweep of its own tile; the mean over kept
sweeps is a Rao-Blackwellized estimate of the marginal as in the whole chain, but the records of one sweep index are not
one joint state of the map (only the last map, ``walls``, is). Its effect on the held-out scores (within the whole
table's seed-to-seed spread) and on the SLAM path is measured on the validation
pages (docs/validation/defaults.md, "TILE_MARGIN"; docs/validation/scale.md, "Tiles").

When the log's pairs fit the budget, :func:`tiled_map_chain` is the whole table's chain
(:func:`~bayesmap.inference.chains.run_chain` of :class:`~bayesmap.inference.cellwise.CellwiseGibbs`, or with
``focus`` :func:`~bayesmap.inference.focus.focused_chain` of its kernel), with the same keys and results.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.geometry.tiles import Tile, ray_cells, rays_per_cell, split_tiles, tile_table
from bayesmap.inference.cellwise import CellwiseGibbs, SweepShapes
from bayesmap.inference.chains import run_chain, run_chains_on_devices
from bayesmap.inference.focus import focused_chain
from bayesmap.memory import drop_compiled_programs, release_freed_memory
from bayesmap.model.generative import ModelParams, beam_lengths, ray_limits
from bayesmap.progress import Progress, ProgressCallback, report

TILE_PAIRS = 12_000_000
"""The most (beam, cell) pairs one tile of a map chain holds (:func:`tiled_map_chain`): a map whose beams cross more
cells is swept a tile at a time. A memory knob, not a model setting (any value samples the same posterior): a tile takes
about 35 bytes a pair in the sampler plus the tracing of its beams, so about 0.4 GB at this value; each tile compiles
its own sweep (about 2 s on two cores) unless its caller shares them (module docstring). Chosen as the larger of two
budgets measured on Freiburg 079's SLAM run (its map stages peak at 1.7 GB; at 6 million at 1.4-1.5 GB, taking 45 %
longer), on the validation page (docs/validation/defaults.md#tile_pairs)."""

TILE_MARGIN = 0.5
"""How far, in meters, the cells sampled with a tile reach beyond it on every side (clipped to the grid): a tile is
swept together with this band of its neighbours' cells, and its last draw of both is kept (the blocks of the
blocked Gibbs sampler overlap). Without it a cell on a tile's edge is drawn while the walls just beyond the edge are
frozen at the chain's start (an empty map in a SLAM chain's first round), and takes the wall of a beam that ends
just beyond it. Chosen by leave-one-log-out cross-validation of the held-out NLL over 0, 0.5, 1 and 2 m
(``benchmarks/tile_cv.py``; docs/validation/defaults.md#tile_margin)."""


class TiledChain(NamedTuple):
    """A map chain of :func:`tiled_map_chain`.

    Attributes:
        walls: ``(nx, ny)`` float32, the map after the chain's last update (0/1).
        wall_probs: ``(sweeps, nx, ny)`` float32, each cell's conditional wall probability in each sweep of its tile
            (module docstring).
        samples: ``(sweeps, nx, ny)`` bool, each cell's draw in each sweep of its tile (with one tile, the map after
            each sweep; with several, the records of one sweep are not one joint map: module docstring).
        tiles: the tiles, in the order they were sampled (one tile, the whole grid, when the log fit the budget).
        shapes: the sizes its sweep was compiled for (the last tile's with several;
            :attr:`bayesmap.inference.cellwise.CellwiseKernel.shapes`): pass them to the next chain of a similar
            table to reuse the compilation.
        readings_log_lik: with one tile, the readings' tempered log-likelihood (nats) at ``walls``
            (:meth:`bayesmap.inference.cellwise.CellwiseKernel.readings_log_likelihood`, from the sweep's own
            table); None with several.
    """

    walls: jax.Array
    wall_probs: np.ndarray
    tiles: tuple[Tile, ...]
    samples: np.ndarray
    shapes: SweepShapes | None = None
    readings_log_lik: float | None = None


class _TileProgress:
    """Reports visit ``index`` of ``visits`` (a tile in a pass, ``count`` sweeps) as the chain's ``sweeps``: after
    sweep ``t`` of it, ``(index + t / count) / visits`` of the work is done (the stage keeps one total, as a bar
    and a stage record expect)."""

    def __init__(self, progress: ProgressCallback, stage: str, index: int, count: int, visits: int, sweeps: int):
        self.progress, self.stage, self.index, self.count = progress, stage, index, count
        self.visits, self.sweeps = visits, sweeps

    def __call__(self, p: Progress) -> None:
        done = (self.index * self.count + p.done) * self.sweeps // (self.visits * self.count)
        report(self.progress, self.stage, done, self.sweeps, p.unit)


def _whole_sampler(params: ModelParams, origins, angles, readings, likelihood_power: float, max_pairs: int,
                   shapes: SweepShapes | None = None, headroom: float = 0.0):
    """``(sampler, tile)``: the cellwise sampler of the whole table (its arrays padded to ``shapes`` with
    ``headroom``: :class:`~bayesmap.inference.cellwise.CellwiseGibbs`) and the tile of the whole grid, when the
    table's estimated pairs fit ``max_pairs``; else None."""
    grid = params.grid
    if ray_cells(grid, origins, angles, beam_lengths(readings, params)).sum() > max_pairs:  # (an estimate, within 1 %)
        return None
    limits = ray_limits(readings, params)
    table = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    gibbs = CellwiseGibbs(table, readings, params, likelihood_power, shapes=shapes, headroom=headroom)
    tile = Tile(0, grid.shape[0], 0, grid.shape[1], table.num_pairs)
    del table  # the sampler holds what its sweeps read
    release_freed_memory()  # (the sorting's temporaries: the sweeps' peak does not count them)
    return gibbs, tile


def _map_chain(key, gibbs: CellwiseGibbs, walls, sweeps: int, focus: bool, progress: ProgressCallback | None,
               stage: str):
    """``sweeps`` sweeps of ``gibbs`` from ``walls``: :func:`~bayesmap.inference.focus.focused_chain` of its kernel
    with ``focus``, else :func:`~bayesmap.inference.chains.run_chain`."""
    if focus:
        return focused_chain(key, gibbs.kernel, walls, sweeps, progress, stage)
    return run_chain(key, gibbs.algorithm, walls, sweeps, progress, stage)


def map_chains(keys, params: ModelParams, origins, beam_angles, readings, walls, sweeps: int,
               likelihood_power: float = 1.0, max_pairs: int = TILE_PAIRS,
               progress: ProgressCallback | None = None, stage: str = "sweeps", focus: bool = False
               ) -> list[TiledChain]:
    """``len(keys)`` chains of :func:`tiled_map_chain` from ``walls``, chain ``c`` with ``keys[c]`` (the same records,
    tested): when the whole table fits ``max_pairs``, its sampler is built once and the chains run split over the
    CPU devices JAX sees (:func:`bayesmap.inference.chains.run_chains_on_devices`, :mod:`bayesmap.devices`: each
    runs its share of the chains); beyond it, one tiled chain after another (tiles share beams and a tile's table
    depends on its chain's map, so they stay on one device; ``focus`` as :func:`tiled_map_chain`'s). ``progress``
    gets ``Progress(stage, done, len(keys) * sweeps, "sweep")``, ``done`` the sweeps of every chain so far.

    Raises:
        BayesmapError: as :func:`tiled_map_chain`.
    """
    total = len(keys) * sweeps
    check_tile_pairs(max_pairs)
    _check_sweeps(sweeps)
    report(progress, stage, 0, total)
    angles = np.asarray(beam_angles, np.float64).reshape(-1)
    origins = np.asarray(origins, np.float64).reshape(-1, 2)
    readings = np.asarray(readings).reshape(-1)
    whole = _whole_sampler(params, origins, angles, readings, likelihood_power, max_pairs) if len(keys) > 1 else None
    if whole is not None:
        gibbs, tile = whole
        sampler, shapes = gibbs.algorithm, gibbs.kernel.shapes

        def every_chain(p: Progress) -> None:
            report(progress, stage, p.done * len(keys), total, p.unit)

        state = sampler.init(jnp.asarray(walls, jnp.float32))
        run = run_chains_on_devices(jnp.stack(list(keys)), state, sampler, sweeps,
                                    None if progress is None else every_chain, stage)
        del sampler, gibbs, whole, state
        release_freed_memory()
        return [TiledChain(jnp.asarray(run.samples[c, -1], jnp.float32), run.wall_probs[c], (tile,), run.samples[c],
                           shapes)
                for c in range(len(keys))]
    chains = []
    for c, key in enumerate(keys):
        def one(p: Progress, c=c) -> None:
            report(progress, stage, c * sweeps + p.done, total, p.unit)

        chains.append(tiled_map_chain(key, params, origins, angles, readings, walls, sweeps, likelihood_power,
                                      max_pairs, progress=None if progress is None else one, stage=stage,
                                      focus=focus))
    return chains


def _check_sweeps(sweeps) -> None:
    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or sweeps < 1:
        raise BayesmapError(f"sweeps must be an integer >= 1, got {sweeps!r}")


def check_tile_pairs(max_pairs) -> None:
    """Refuse a tile budget that is not an integer >= 1.

    Raises:
        BayesmapError: naming the value.
    """
    if isinstance(max_pairs, bool) or not isinstance(max_pairs, (int, np.integer)) or max_pairs < 1:
        raise BayesmapError(f"the pairs per tile must be an integer >= 1, got {max_pairs!r}")


def tiled_map_chain(key, params: ModelParams, origins, beam_angles, readings, walls, sweeps: int,
                    likelihood_power: float = 1.0, max_pairs: int = TILE_PAIRS, margin: float = TILE_MARGIN,
                    passes: int = 1, progress: ProgressCallback | None = None, stage: str = "sweeps",
                    shapes: SweepShapes | None = None, headroom: float = 0.0, focus: bool = False) -> TiledChain:
    """``sweeps`` cellwise sweeps of the map given rays at known poses, a tile at a time when the rays' table would
    hold more than ``max_pairs`` pairs (module docstring).

    Args:
        key: a JAX PRNG key (split into one key per tile when there are several).
        params: the model (its grid, max range and cut past the reading).
        origins: ``(R, 2)`` float, each ray's sensor position, world meters.
        beam_angles: ``(R,)`` float, world-frame beam angles, radians.
        readings: ``(R,)`` float, range readings, meters.
        walls: ``(nx, ny)`` the starting map (0/1).
        sweeps: sweeps of each tile, >= 1.
        likelihood_power: ``eta`` in (0, 1] (:class:`~bayesmap.inference.cellwise.CellwiseGibbs`).
        max_pairs: the most pairs a tile holds (:data:`TILE_PAIRS`), >= 1.
        margin: meters of the neighbouring tiles swept with each tile (:data:`TILE_MARGIN`), >= 0.
        passes: how many times the tiles are visited in turn, ``1 <= passes``; the sweeps are shared among the
            passes (pass ``p`` records sweeps ``sweeps * p / passes`` to ``sweeps * (p + 1) / passes``, rounded).
        progress: gets ``Progress(stage, done, sweeps, "sweep")`` before the table is built and as the sweeps
            run (with tiles, ``done`` counts the sweeps of every tile divided by the number of tiles).
        stage: the stage the reports name.
        shapes: the sweep's arrays are padded at least to these where they fit
            (:class:`~bayesmap.inference.cellwise.CellwiseGibbs`; the same draws): the ``shapes`` of a previous
            chain's :class:`TiledChain`, to reuse its compiled sweep; with tiles, the first tile's, and each later
            tile's padded to the sizes of the one before. None: the first tile's (or the whole table's) not padded,
            and, with no ``headroom`` either, each tile sized for itself (module docstring).
        headroom: the padding of a size ``shapes`` does not give or that does not fit it, a fraction >= 0
            (:func:`~bayesmap.inference.cellwise.fitted_shapes`); > 0 also pads the tiles as ``shapes`` does.
        focus: after the first sweeps, sweep mostly the cells in doubt (:func:`bayesmap.inference.focus.
            focused_chain`, the whole table or each tile); False: every sweep visits every cell.

    Returns:
        :class:`TiledChain`.

    Raises:
        BayesmapError: on ``sweeps`` < 1, ``max_pairs`` < 1, ``passes`` < 1, a negative or non-finite ``margin``, and as
            :func:`~bayesmap.geometry.raytable.build_ray_table` and
            :class:`~bayesmap.inference.cellwise.CellwiseGibbs`.
    """
    check_tile_pairs(max_pairs)
    _check_sweeps(sweeps)
    if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 1:
        raise BayesmapError(f"passes must be an integer >= 1, got {passes!r}")
    if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not np.isfinite(margin) or margin < 0:
        raise BayesmapError(f"margin must be a finite number of meters >= 0, got {margin!r}")
    report(progress, stage, 0, sweeps)
    grid = params.grid
    angles = np.asarray(beam_angles, np.float64).reshape(-1)
    origins = np.asarray(origins, np.float64).reshape(-1, 2)
    readings = np.asarray(readings).reshape(-1)
    limits = ray_limits(readings, params)
    whole = _whole_sampler(params, origins, angles, readings, likelihood_power, max_pairs, shapes, headroom)
    if whole is not None:
        gibbs, tile = whole
        shapes = gibbs.kernel.shapes
        chain = _map_chain(key, gibbs, walls, sweeps, focus, progress, stage)
        readings_log_lik = gibbs.kernel.readings_log_likelihood(chain.final_state)
        del gibbs, whole
        release_freed_memory()
        return TiledChain(jnp.asarray(chain.samples[-1], jnp.float32), np.asarray(chain.wall_probs), (tile,),
                          np.asarray(chain.samples), shapes, readings_log_lik)
    counts = rays_per_cell(grid, origins, angles, params.max_range, limits)
    tiles = tuple(split_tiles(counts, max_pairs))
    del counts
    kept = 3 if params.penetrable else 2
    current = np.array(walls, dtype=np.float32)
    probs = np.zeros((sweeps, *grid.shape), dtype=np.float32)
    samples = np.zeros((sweeps, *grid.shape), dtype=bool)
    keys = jax.random.split(key, len(tiles) * passes).reshape(passes, len(tiles))
    grow = int(np.ceil(margin / grid.resolution - 1e-9))
    bounds = np.linspace(0, sweeps, passes + 1).round().astype(int)  # pass p records sweeps bounds[p]:bounds[p+1]
    visits = [(p, k) for p in range(passes) for k in range(len(tiles)) if bounds[p + 1] > bounds[p]]
    shared = shapes is not None or headroom > 0  # the caller's chains share compiled sweeps: so do its tiles
    for visit, (p, k) in enumerate(visits):
        tile, first, count = tiles[k], int(bounds[p]), int(bounds[p + 1] - bounds[p])
        inside = tile.mask(grid.shape)
        block = Tile(max(tile.i0 - grow, 0), min(tile.i1 + grow, grid.shape[0]), max(tile.j0 - grow, 0),
                     min(tile.j1 + grow, grid.shape[1]))
        sampled = block.mask(grid.shape)
        table, rays = tile_table(grid, origins, angles, params.max_range, limits, current, block, kept)
        gibbs = CellwiseGibbs(table, readings[rays], params, likelihood_power, frozen=~sampled,
                              shapes=shapes if shared else None, headroom=headroom)
        del table
        shapes = gibbs.kernel.shapes  # (shared: the next tile's sweep padded to these runs this one's compiled sweep)
        release_freed_memory()
        sub = None if progress is None else _TileProgress(progress, stage, visit, count, len(visits), sweeps)
        chain = _map_chain(keys[p, k], gibbs, current, count, focus, sub, stage)
        last = np.asarray(chain.samples[-1])
        current[sampled] = last[sampled]
        probs[first:first + count, inside] = np.asarray(chain.wall_probs)[:, inside]
        samples[first:first + count, inside] = np.asarray(chain.samples)[:, inside]
        del gibbs, chain
        if not shared:
            drop_compiled_programs()  # the next tile compiles a sweep for its own sizes: drop this one's
        release_freed_memory()
    return TiledChain(jnp.asarray(current), probs, tiles, samples, shapes)
