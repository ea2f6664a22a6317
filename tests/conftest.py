"""Shared fixtures: the tutorial scene with the tutorial's readings (key 0)."""

from pathlib import Path

import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def tutorial():
    from bayesmap.scenes import tutorial_problem

    return tutorial_problem()


@pytest.fixture(scope="session")
def tutorial_low_prior():
    from bayesmap.scenes import tutorial_problem

    return tutorial_problem(prior_wall_prob=0.05)


@pytest.fixture(scope="session")
def intel_log():
    path = SHARED_DATA / "carmen" / "intel-corrected.log.gz"
    if not path.exists():
        pytest.skip("shared data not present")
    return path


@pytest.fixture(scope="module")
def small_log(tmp_path_factory, intel_log):
    """The first 12 scans of the Intel log, as a plain CARMEN file."""
    import gzip

    path = tmp_path_factory.mktemp("log") / "intel12.log"
    with gzip.open(intel_log, "rt") as handle:
        lines = [line for line in handle if line.startswith("FLASER")][:12]
    path.write_text("".join(lines))
    return path


def random_scene(rng, max_side=8, metric=False):
    """A random small grid, position inside it, map and beam angles (numpy)."""
    from bayesmap.geometry.grid import Grid

    shape = (int(rng.integers(3, max_side + 1)), int(rng.integers(3, max_side + 1)))
    if metric:
        grid = Grid(shape, resolution=float(rng.choice([0.1, 0.25, 0.7])), origin=tuple(rng.normal(0, 3, 2)))
    else:
        grid = Grid(shape)
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
    walls = (rng.random(shape) < rng.uniform(0.1, 0.6)).astype(np.float32)
    beam_angles = rng.uniform(-np.pi, 3 * np.pi, int(rng.integers(1, 60)))
    return grid, pos, walls, beam_angles
