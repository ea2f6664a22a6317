"""Occupancy grids: shape, resolution, origin, world <-> cell conversion.

Conventions (the tutorial's):

* ``walls[i, j]`` is cell ``(i, j)``; ``i`` runs along x, ``j`` along y.
* A :class:`Grid` has a ``shape`` ``(nx, ny)`` in cells, a ``resolution`` in meters per cell and an ``origin``:
  the world coordinates (meters) of the corner of cell ``(0, 0)`` with the smallest x and y (the ROS
  ``map_server`` convention). Cell ``(i, j)`` is the square
  ``[ox + i*res, ox + (i+1)*res] x [oy + j*res, oy + (j+1)*res]``.
* The default origin ``(-0.5, -0.5)`` with resolution 1 is the tutorial's: cell ``(i, j)`` is the unit square
  centered at ``(i, j)``, so world coordinates and cell indices coincide at cell centers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesmap.errors import BayesmapError


@dataclass(frozen=True)
class Grid:
    """The geometry of an occupancy grid (hashable, so it can be a static argument of ``jax.jit``).

    Attributes:
        shape: ``(nx, ny)``, number of cells along x and along y (positive ints).
        resolution: meters per cell (finite, > 0). 1.0 for the tutorial's unit cells.
        origin: world ``(x, y)`` in meters of the outer corner of cell ``(0, 0)``; ``(-0.5, -0.5)`` (the default)
            puts cell centers at integer coordinates, as in the tutorial.

    Raises:
        BayesmapError: on a non-positive or non-integer shape, a resolution that is not finite and > 0, or an
            origin that is not two finite numbers.
    """

    shape: tuple[int, int]
    resolution: float = 1.0
    origin: tuple[float, float] = (-0.5, -0.5)

    def __post_init__(self):
        shape = tuple(self.shape)
        if len(shape) != 2 or any(int(n) != n or n < 1 for n in shape):
            raise BayesmapError(f"grid shape must be two positive integers, got {self.shape!r}")
        resolution = float(self.resolution)
        if not math.isfinite(resolution) or resolution <= 0:
            raise BayesmapError(f"grid resolution must be a finite number > 0 (meters per cell), "
                                f"got {self.resolution!r}")
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 2 or not all(math.isfinite(v) for v in origin):
            raise BayesmapError(f"grid origin must be two finite numbers (meters), got {self.origin!r}")
        object.__setattr__(self, "shape", (int(shape[0]), int(shape[1])))
        object.__setattr__(self, "resolution", resolution)
        object.__setattr__(self, "origin", origin)

    @property
    def num_cells(self) -> int:
        """Number of cells, ``nx * ny``."""
        return self.shape[0] * self.shape[1]

    @property
    def default_max_distance(self) -> float:
        """The tutorial's cap on distances: twice the larger side of the grid, in meters (42 for 21 x 21 unit cells)."""
        return 2.0 * max(self.shape) * self.resolution

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the grid in world meters (for ``imshow(..., extent=...)`` after a
        transpose)."""
        ox, oy = self.origin
        return (ox, ox + self.shape[0] * self.resolution, oy, oy + self.shape[1] * self.resolution)

    def to_cell_coords(self, xy):
        """World coordinates (meters, shape ``(..., 2)``) to continuous cell coordinates in which the center of cell
        ``(i, j)`` is ``(i, j)`` (the tutorial's frame). Works on numpy and JAX arrays."""
        return (xy - np.asarray(self.origin)) / self.resolution - 0.5

    def cell_centers(self) -> np.ndarray:
        """World coordinates of all cell centers, ``(nx, ny, 2)`` float64, meters."""
        i, j = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        ox, oy = self.origin
        return np.stack([ox + (i + 0.5) * self.resolution, oy + (j + 0.5) * self.resolution], axis=-1)

    def cell_index(self, xy) -> np.ndarray:
        """Integer cell indices ``(..., 2)`` of world points ``(..., 2)`` (meters); points on a shared edge go to the
        cell with the larger index. Points outside the grid give indices outside ``[0, shape)``."""
        return np.floor(self.to_cell_coords(np.asarray(xy, dtype=np.float64)) + 0.5).astype(np.int64)

    def contains(self, xy) -> bool:
        """True if the world point ``xy`` (meters, shape ``(2,)``) lies inside the grid (edges included)."""
        x, y = (float(v) for v in np.asarray(xy, dtype=np.float64).reshape(2))
        xmin, xmax, ymin, ymax = self.extent
        return xmin <= x <= xmax and ymin <= y <= ymax

    def check_inside(self, xy, what: str = "sensor position") -> None:
        """Raise :class:`BayesmapError` naming ``xy`` unless it is a finite point inside the grid."""
        point = np.asarray(xy, dtype=np.float64).reshape(-1)
        if point.shape != (2,) or not np.all(np.isfinite(point)):
            raise BayesmapError(f"{what} must be two finite numbers (x, y), got {xy!r}")
        if not self.contains(point):
            xmin, xmax, ymin, ymax = self.extent
            raise BayesmapError(
                f"{what} ({point[0]:g}, {point[1]:g}) is outside the grid "
                f"[{xmin:g}, {xmax:g}] x [{ymin:g}, {ymax:g}]"
            )

    def window(self, sub: "Grid") -> tuple[slice, slice]:
        """The index ranges ``(along x, along y)`` of this grid's cells that are the cells of ``sub``, a grid of the
        same resolution whose cells are some of this one's (``array[grid.window(sub)]`` is an ``(nx, ny)`` array of
        this grid restricted to ``sub``; two :meth:`covering` grids of one resolution, the one covering the other's
        points, are such a pair).

        Raises:
            BayesmapError: if ``sub``'s resolution differs, its cells are not this grid's (an origin off this grid's
                lattice by more than 1e-6 of a cell), or it reaches outside this grid.
        """
        if sub.resolution != self.resolution:
            raise BayesmapError(f"grid resolution {sub.resolution!r} m is not this grid's {self.resolution!r} m")
        offset = (np.asarray(sub.origin) - np.asarray(self.origin)) / self.resolution
        start = np.round(offset).astype(int)
        if np.any(np.abs(offset - start) > 1e-6) or np.any(start < 0) or np.any(
                start + np.asarray(sub.shape) > np.asarray(self.shape)):
            raise BayesmapError(f"grid {sub.shape} at {sub.origin} is not a window of grid {self.shape} at "
                                f"{self.origin} ({self.resolution:g} m cells)")
        return slice(int(start[0]), int(start[0]) + sub.shape[0]), slice(int(start[1]), int(start[1]) + sub.shape[1])

    @classmethod
    def covering(cls, points, resolution: float, margin: float = 0.0) -> "Grid":
        """The smallest grid with the given resolution whose cells cover all world ``points`` ``(n, 2)`` (meters)
        plus ``margin`` meters on every side; its origin is a multiple of the resolution.

        Raises:
            BayesmapError: if there are no finite points.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        points = points[np.all(np.isfinite(points), axis=1)]
        if len(points) == 0:
            raise BayesmapError("cannot build a grid covering no points")
        lo = np.floor((points.min(axis=0) - margin) / resolution) * resolution
        hi = np.ceil((points.max(axis=0) + margin) / resolution) * resolution
        shape = np.maximum(np.round((hi - lo) / resolution).astype(int), 1)
        return cls(shape=(int(shape[0]), int(shape[1])), resolution=resolution, origin=(float(lo[0]), float(lo[1])))
