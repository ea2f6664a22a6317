"""A log's ray-cell table read a piece of whole scans at a time (``Problem.table_chunks``): the pieces are the whole
table's rows, and what is summed over them (log-odds mapping, the log joint, the seen cells) equals the whole
table's result, so ``infer`` never needs the whole table."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import bayesmap.problem as problem_module
from bayesmap.inference.driver import run_logodds
from bayesmap.io.carmen import read_carmen
from bayesmap.io.maps_out import seen_cells
from bayesmap.runs.infer import infer_seen
from bayesmap.scenes import log_problem

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

SLOTS = 3_000  # pairs per piece: the 12 scans' table (about 20,000 pairs at 0.2 m) comes in several pieces


@pytest.fixture(scope="module")
def pieces_problem(small_log):
    return log_problem(read_carmen(small_log), resolution=0.2, wall_pass_prob=0.3)


def test_the_pieces_are_the_whole_tables_rows_in_whole_scans(pieces_problem):
    pieces = list(without_table(pieces_problem).table_chunks(SLOTS))
    whole = pieces_problem.table  # (built and kept by this call)
    assert len(pieces) >= 3
    k = pieces_problem.observations.num_beams
    starts = [rays.start for rays, _ in pieces]
    assert starts[0] == 0 and all(start % k == 0 for start in starts)
    assert [rays.stop for rays, _ in pieces] == starts[1:] + [whole.num_rays]
    np.testing.assert_array_equal(np.concatenate([t.pair_cells for _, t in pieces]), whole.pair_cells)
    np.testing.assert_array_equal(np.concatenate([t.pair_dists for _, t in pieces]), whole.pair_dists)
    offsets = [0]
    for _, t in pieces:
        offsets.extend(offsets[-1] + t.offsets[1:])
    np.testing.assert_array_equal(offsets, whole.offsets)
    # a problem whose table is held reads it in one piece
    assert list(pieces_problem.table_chunks(SLOTS)) == [(slice(0, whole.num_rays), whole)]


def without_table(problem):
    """The same problem (the same world-frame angles) with its table not built."""
    return dataclasses.replace(problem)


def test_sums_over_the_pieces_equal_the_whole_tables(pieces_problem, monkeypatch):
    """Log-odds mapping (per-scan updates with clamping, scans in order: exactly the same map), the log joint of one
    map and of several in one pass (the same to float32 rounding of the per-piece sums: 1e-6 relative) and the seen
    cells, a piece at a time and with the whole table."""
    whole = pieces_problem
    whole.table  # noqa: B018 (held: one piece)
    monkeypatch.setattr(problem_module, "TABLE_PIECE_PAIRS", SLOTS)
    streamed = without_table(whole)
    assert len(list(streamed.table_chunks())) >= 3
    np.testing.assert_array_equal(run_logodds(streamed).posterior, run_logodds(whole).posterior)
    assert run_logodds(streamed).summary["ray_cell_pairs"] == whole.table.num_pairs
    rng = np.random.default_rng(0)
    maps = np.stack([rng.random(whole.grid.shape) < density for density in (0.05, 0.3, 0.6)])
    want = [whole.table_log_joint(walls) for walls in maps]
    assert streamed.table_log_joint(maps[1]) == pytest.approx(want[1], rel=1e-6)
    np.testing.assert_allclose(streamed.table_log_joints(maps), want, rtol=1e-6)  # (all maps, one pass)
    assert len(set(np.round(want))) == 3
    np.testing.assert_array_equal(infer_seen(streamed), seen_cells(whole.table, whole.ray_readings))
    assert "table" not in streamed.__dict__  # nothing above built the whole table
