"""Fixtures of the figure tests: the tutorial's map, its unit grid and a scan of 100 beams from the map's center."""

from __future__ import annotations

import numpy as np
import pytest

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles, sensor_distances
from bayesmap.io.ascii import tutorial_map
from helpers import POS


@pytest.fixture(scope="module")
def walls():
    return tutorial_map()


@pytest.fixture(scope="module")
def grid(walls):
    return Grid(shape=walls.shape)


@pytest.fixture(scope="module")
def scan(walls):
    a = np.asarray(angles(100), dtype=np.float64)
    r = np.asarray(sensor_distances(walls, POS, angles(100)), dtype=np.float64)
    return a, r
