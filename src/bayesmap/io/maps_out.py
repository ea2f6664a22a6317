"""The posterior map and its uncertainty in files other tools read: ``.npz`` arrays, 16-bit PNGs with a YAML beside.

``bayesmap infer --maps`` writes them into its output folder (``bayesmap infer --out-bag`` adds a ROS
``nav_msgs/OccupancyGrid``, :mod:`bayesmap.io.rosbag`; ``--rosmap`` the trinary map_server map,
:mod:`bayesmap.io.rosmap`):

``posterior.npz`` (``np.load``)
    ``probability`` ``(nx, ny)`` float32, the posterior wall probability of cell ``(i, j)`` (``i`` along x, ``j``
    along y); ``std`` ``(nx, ny)`` float32, its standard deviation :func:`posterior_std`; ``seen`` ``(nx, ny)`` bool,
    cells some beam crossed (:func:`seen_cells`); ``resolution`` float64 meters per cell; ``origin`` ``(2,)`` float64
    meters, the world ``(x, y)`` of the outer corner of cell (0, 0) (as ROS ``map_server``); ``shape`` ``(2,)``
    int64 ``(nx, ny)``.

``probability.png`` + ``probability.yaml``, ``std.png`` + ``std.yaml``
    16-bit grayscale PNGs laid out as ``map_server`` images (row 0 is the top, the largest y; column ``i`` is x):
    pixel = ``round(value * 65535)``, so value = pixel / 65535 (the YAML's ``value_scale``). The YAML holds
    ``map_server``'s keys (``image``, ``resolution``, ``origin``, ``negate``, ``occupied_thresh``, ``free_thresh``,
    ``mode: scale``; ``negate: 1`` because a bright pixel is a likely wall) plus ``value_scale``, ``value_offset``
    and ``quantity`` (``probability`` or ``std``).

Standard deviation
------------------
A cell is a Bernoulli variable; its posterior standard deviation is ``sqrt(p (1 - p))`` for the posterior wall
probability ``p``. With several chains ``p`` is the pooled mean of all chains' kept sweeps, and ``std`` is
``sqrt(p (1 - p))`` of that pooled ``p``: the spread of the per-chain means is the Monte Carlo error of ``p``, not
the posterior's standard deviation (split R-hat and ESS, in ``diagnostics.npz``, judge that error).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import yaml

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.io.files import read_bytes

__all__ = ["posterior_std", "seen_cells", "seen_cells_along", "encode_posterior_npz", "encode_png16", "read_png16",
           "PNG16_SCALE", "NPZ_FILE"]

PNG16_SCALE = 1.0 / 65535.0
"""A 16-bit pixel's value: ``pixel * PNG16_SCALE`` (probability and std both lie in [0, 1])."""
NPZ_FILE = "posterior.npz"


def _probability(probability) -> np.ndarray:
    p = np.asarray(probability, dtype=np.float64)
    if p.ndim != 2:
        raise BayesmapError(f"a map must be a (nx, ny) array, got shape {p.shape}")
    bad = np.argwhere(~((p >= 0) & (p <= 1)))
    if len(bad):
        i, j = bad[0]
        raise BayesmapError(f"value of cell ({i}, {j}) is {p[i, j]!r}, not in [0, 1]")
    return p


def posterior_std(probability) -> np.ndarray:
    """The posterior standard deviation of each cell's wall indicator: ``sqrt(p (1 - p))`` (module docstring).

    Args:
        probability: ``(nx, ny)`` float, posterior wall probability ``p`` in [0, 1].

    Returns:
        ``(nx, ny)`` float64 in [0, 0.5].

    Raises:
        BayesmapError: on a value outside [0, 1] (naming the cell) or not a 2-D array.
    """
    p = _probability(probability)
    return np.sqrt(p * (1.0 - p))


def seen_cells(table, readings) -> np.ndarray:
    """Cells some beam crossed: a ray's cells whose stopping distance is at most the ray's reading.

    Args:
        table: the :class:`~bayesmap.geometry.raytable.RayTable` of the beams (``Problem.table``).
        readings: ``(R,)`` float, each ray's reading in meters (``Problem.ray_readings``; max-range readings at the
            max range, so such a beam saw its whole length).

    Returns:
        ``(nx, ny)`` bool.
    """
    readings = np.asarray(readings, dtype=np.float64).reshape(-1)
    crossed = np.asarray(table.pair_dists, dtype=np.float64) <= table.per_pair(readings)
    out = np.zeros(table.num_cells, dtype=bool)
    out[np.asarray(table.pair_cells)[crossed]] = True
    return out.reshape(table.grid.shape)


def seen_cells_in_pieces(pieces, readings, shape: tuple[int, int]) -> np.ndarray:
    """:func:`seen_cells` of a ray-cell table given a piece at a time, so that it is never held whole.

    Args:
        pieces: yields ``(rays, table)``: a slice (or index array) of the rays and their ray-cell table
            (:meth:`bayesmap.problem.Problem.table_chunks`).
        readings: ``(R,)`` float, every ray's reading in meters, as for :func:`seen_cells`.
        shape: the grid's ``(nx, ny)``.

    Returns:
        ``(nx, ny)`` bool.
    """
    readings = np.asarray(readings, dtype=np.float64).reshape(-1)
    seen = np.zeros(shape, dtype=bool)
    for rays, table in pieces:
        seen |= seen_cells(table, readings[rays])
    return seen


SEEN_CHUNK_RAYS = 20_000
"""Rays per ray-cell table :func:`seen_cells_along` builds at a time (bounds its memory on a whole log: a no-return
beam of an 80 m laser crosses up to about 1,100 cells of 0.1 m)."""


def seen_cells_along(grid: Grid, poses, sensor_angles, readings, max_range: float) -> np.ndarray:
    """Cells some beam crossed, for scans at ``poses`` (a SLAM run's posterior mean path): :func:`seen_cells` of the
    scans' ray-cell tables, built :data:`SEEN_CHUNK_RAYS` rays at a time.

    Args:
        grid: the map's :class:`~bayesmap.geometry.grid.Grid`.
        poses: ``(S, 3)`` sensor poses (x, y in the grid's units, meters or cells; theta radians).
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians.
        readings: ``(S, K)`` readings in the grid's units (max-range readings at the max range, so such a beam saw
            its whole length).
        max_range: the longest beam, in the grid's units.

    Returns:
        ``(nx, ny)`` bool.

    Raises:
        BayesmapError: if the shapes disagree, or as :func:`bayesmap.geometry.raytable.build_ray_table`.
    """
    poses = np.asarray(poses, dtype=np.float64)
    angles = np.asarray(sensor_angles, dtype=np.float64)
    values = np.asarray(readings, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or angles.ndim != 2 or angles.shape[0] != len(poses) \
            or values.shape != angles.shape:
        raise BayesmapError(f"poses (S, 3), sensor angles (S, K) and readings (S, K) must agree, got {poses.shape}, "
                            f"{angles.shape} and {values.shape}")
    beams = angles.shape[1]
    per = max(1, SEEN_CHUNK_RAYS // max(beams, 1))

    def pieces():
        for start in range(0, len(poses), per):
            part = slice(start, start + per)
            origins = np.repeat(poses[part, :2], beams, axis=0)
            # each ray traced one cell past its reading: the table then holds every pair seen_cells keeps, no more
            limits = np.minimum(values[part].reshape(-1) + grid.resolution, max_range)
            yield slice(start * beams, min(start + per, len(poses)) * beams), build_ray_table(
                grid, origins, (poses[part, 2:3] + angles[part]).reshape(-1), max_range, ray_limits=limits)

    return seen_cells_in_pieces(pieces(), values.reshape(-1), grid.shape)


def encode_posterior_npz(probability, grid: Grid, seen=None) -> bytes:
    """``posterior.npz`` as bytes: ``probability``, ``std``, ``resolution``, ``origin``, ``shape`` and ``seen``.

    Args:
        probability: ``(nx, ny)`` float posterior wall probability in [0, 1], the grid's shape.
        grid: its :class:`~bayesmap.geometry.grid.Grid`.
        seen: ``(nx, ny)`` bool (:func:`seen_cells`), or None (then the file has no ``seen``).

    Raises:
        BayesmapError: on a value outside [0, 1], or a shape other than the grid's.
    """
    p = _probability(probability)
    if p.shape != tuple(grid.shape):
        raise BayesmapError(f"probability has shape {p.shape}, the grid {tuple(grid.shape)}")
    arrays = dict(probability=p.astype(np.float32), std=posterior_std(p).astype(np.float32),
                  resolution=np.float64(grid.resolution), origin=np.asarray(grid.origin, dtype=np.float64),
                  shape=np.asarray(grid.shape, dtype=np.int64))
    if seen is not None:
        seen = np.asarray(seen, dtype=bool)
        if seen.shape != p.shape:
            raise BayesmapError(f"seen has shape {seen.shape}, the probability {p.shape}")
        arrays["seen"] = seen
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def encode_png16(stem: str, values, grid: Grid, quantity: str) -> dict[str, bytes]:
    """A map of values in [0, 1] as a 16-bit grayscale PNG and its YAML: ``{stem + ".png": ..., stem + ".yaml": ...}``.

    Args:
        stem: file name without extension.
        values: ``(nx, ny)`` float in [0, 1], cell ``(i, j)`` with ``i`` along x.
        grid: the map's :class:`~bayesmap.geometry.grid.Grid`.
        quantity: what the values are (``"probability"``, ``"std"``), written into the YAML.

    Raises:
        BayesmapError: on a value outside [0, 1], or a shape other than the grid's.
    """
    from PIL import Image

    v = _probability(values)
    if v.shape != tuple(grid.shape):
        raise BayesmapError(f"{quantity} has shape {v.shape}, the grid {tuple(grid.shape)}")
    pixels = np.rint(v / PNG16_SCALE).astype(np.uint16).T[::-1]  # cell (i, j) -> row ny - 1 - j, column i
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels)).save(buf, format="PNG")
    meta = {"image": f"{stem}.png", "resolution": float(grid.resolution),
            "origin": [float(grid.origin[0]), float(grid.origin[1]), 0.0], "negate": 1, "occupied_thresh": 0.65,
            "free_thresh": 0.25, "mode": "scale", "quantity": quantity, "value_scale": PNG16_SCALE,
            "value_offset": 0.0}
    return {f"{stem}.png": buf.getvalue(), f"{stem}.yaml": yaml.safe_dump(meta, sort_keys=False).encode("utf-8")}


def read_png16(yaml_path) -> tuple[np.ndarray, Grid]:
    """Read back a map written by :func:`encode_png16`: the values per cell and the grid.

    Returns:
        ``(values, grid)``: ``values`` ``(nx, ny)`` float64 = ``pixel * value_scale + value_offset``, cell ``(i, j)``
        with ``i`` along x.

    Raises:
        BayesmapError: naming the file, if the YAML lacks a key or the image is not a 16-bit grayscale PNG.
    """
    from PIL import Image

    name, data = read_bytes(yaml_path, "map YAML")
    try:
        meta = yaml.safe_load(data)
        image_name, resolution = meta["image"], float(meta["resolution"])
        origin = (float(meta["origin"][0]), float(meta["origin"][1]))
        scale, offset = float(meta["value_scale"]), float(meta.get("value_offset", 0.0))
    except (yaml.YAMLError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise BayesmapError(f"{name}: not a bayesmap 16-bit map YAML ({type(exc).__name__}: {exc})") from None
    png_name, png = read_bytes(Path(name).parent / image_name, "16-bit PNG")
    try:
        with Image.open(io.BytesIO(png)) as img:
            if img.mode not in ("I;16", "I;16B", "I"):
                raise BayesmapError(f"{png_name}: a {img.mode} image, not 16-bit grayscale")
            pixels = np.asarray(img).astype(np.float64)
    except OSError as exc:
        raise BayesmapError(f"{png_name}: not a PNG image ({exc})") from None
    values = pixels[::-1].T * scale + offset
    return values, Grid(values.shape, resolution, origin)
