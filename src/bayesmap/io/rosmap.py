"""Read and write ROS ``map_server`` occupancy-grid maps: a YAML file and a PGM image.

Format (http://wiki.ros.org/map_server, "Map format"): the YAML file holds

* ``image``: the image file, relative to the YAML file's folder (or absolute),
* ``resolution``: meters per pixel (= per cell),
* ``origin``: ``[x, y, yaw]``, the world pose (meters, radians) of the lower-left corner of the lower-left pixel,
* ``negate``: 0 or 1, whether white means occupied,
* ``occupied_thresh``, ``free_thresh``: probabilities in ``[0, 1]``,
* ``mode`` (optional, default ``trinary``): ``trinary``, ``scale`` or ``raw``.

Only PGM images are read: binary ``P5`` and plain (ASCII) ``P2``, 8-bit (maxval <= 255) or 16-bit (maxval up to
65535). map_server's rule for a pixel value ``v`` (scaled to 0-255 as ``v * 255 / maxval``; ``255 - v`` first if
``negate``) is: probability of occupied ``p = (255 - v) / 255``; ``p > occupied_thresh`` is occupied,
``p < free_thresh`` free, anything in between unknown in ``trinary`` mode and a graded value in ``scale`` mode.
In ``raw`` mode the value itself is the occupancy in percent (0-100), anything above 100 is unknown.

Orientation: image row 0 is the top of the map (largest y), column 0 the left (smallest x). Pixel (row ``r``,
column ``c``) of an image with ``nrows`` rows is cell ``(i, j) = (c, nrows - 1 - r)`` of a :class:`Grid` of shape
``(ncols, nrows)`` whose origin is the YAML ``origin`` ``(x, y)``: ROS's origin and ``Grid.origin`` are the same
point (the outer corner of cell ``(0, 0)``). Maps with a nonzero ``yaw`` are rejected (a rotated grid has no
:class:`Grid`).

The YAML file is parsed with PyYAML (``yaml.safe_load``), imported when a YAML file is read.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.files import read_bytes, write_atomic

#: map_server's defaults (also what ``write_rosmap`` writes): 205 (unknown grey) reads as p = 0.196..., which is
#: above ``FREE_THRESH`` and below ``OCCUPIED_THRESH``.
FREE_THRESH = 0.196
OCCUPIED_THRESH = 0.65
#: The pixel value map_server's ``map_saver`` writes for unknown cells.
UNKNOWN_PIXEL = 205
MODES = ("trinary", "scale", "raw")

_WHITESPACE = b" \t\r\n\v\f"
_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")


# ---------------------------------------------------------------------------------------------------------------
# PGM
# ---------------------------------------------------------------------------------------------------------------


def _header_tokens(data: bytes, name: str, start: int, count: int) -> tuple[list[bytes], int]:
    """``count`` whitespace-separated tokens from ``data[start:]``, skipping ``#`` comments (to the end of the
    line). Returns the tokens and the position just after the last one."""
    pos, n = start, len(data)
    tokens = []
    while len(tokens) < count:
        while pos < n:
            if data[pos] in _WHITESPACE:
                pos += 1
            elif data[pos] == ord("#"):
                while pos < n and data[pos] not in b"\r\n":
                    pos += 1
            else:
                break
        if pos >= n:
            raise BayesmapError(f"PGM file {name!r} is truncated: the header ends before width, height and maxval")
        begin = pos
        while pos < n and data[pos] not in _WHITESPACE and data[pos] != ord("#"):
            pos += 1
        tokens.append(data[begin:pos])
    return tokens, pos


def _header_int(token: bytes, name: str, what: str, lo: int, hi: int) -> int:
    text = token.decode("latin-1")
    if not text.isdigit() or not lo <= int(text) <= hi:
        raise BayesmapError(f"PGM file {name!r}: {what} {text!r} is not an integer in [{lo}, {hi}]")
    return int(text)


def _parse_pgm(data: bytes, name: str) -> tuple[np.ndarray, int]:
    """Decode a P5 or P2 PGM; returns the ``(rows, cols)`` image as stored and its maxval."""
    magic = data[:2]
    if magic not in (b"P5", b"P2"):
        shown = data[:2].decode("latin-1") if data[:2].isascii() else repr(data[:2])
        raise BayesmapError(
            f"{name!r} is not a PGM image: it starts with {shown!r}, expected 'P5' (binary) or 'P2' (plain) "
            "(colour PPM 'P6'/'P3', PNG and other formats are not supported)"
        )
    if len(data) > 2 and data[2] not in _WHITESPACE and data[2] != ord("#"):
        raise BayesmapError(f"{name!r} is not a PGM image: the magic number {data[:3]!r} is not followed by whitespace")
    (w, h, m), pos = _header_tokens(data, name, 2, 3)
    width = _header_int(w, name, "width", 1, 2**31 - 1)
    height = _header_int(h, name, "height", 1, 2**31 - 1)
    maxval = _header_int(m, name, "maxval", 1, 65535)
    count = width * height
    dtype = np.uint8 if maxval <= 255 else np.uint16
    if magic == b"P5":
        if pos >= len(data) or data[pos] not in _WHITESPACE:
            raise BayesmapError(
                f"PGM file {name!r}: expected one whitespace character after maxval {maxval}, before the pixel data"
            )
        raster = data[pos + 1 :]
        nbytes = count * (1 if maxval <= 255 else 2)
        if len(raster) < nbytes:
            raise BayesmapError(
                f"PGM file {name!r} is truncated: {width} x {height} pixels need {nbytes} bytes of pixel data, "
                f"the file has {len(raster)}"
            )
        image = np.frombuffer(raster, dtype=np.uint8 if maxval <= 255 else ">u2", count=count).astype(dtype)
    else:
        body = re.sub(rb"#[^\r\n]*", b" ", data[pos:]).split()
        if len(body) < count:
            raise BayesmapError(
                f"PGM file {name!r} is truncated: {width} x {height} pixels need {count} values, "
                f"the file has {len(body)}"
            )
        body = body[:count]
        bad = next((k for k, tok in enumerate(body) if not tok.isdigit()), None)
        if bad is not None:
            raise BayesmapError(
                f"PGM file {name!r}: pixel {bad} value {body[bad].decode('latin-1')!r} is not a non-negative integer"
            )
        over = next((k for k, tok in enumerate(body) if int(tok) > maxval), None)
        if over is not None:
            raise BayesmapError(
                f"PGM file {name!r}: pixel {over} has value {int(body[over])} > maxval {maxval}"
            )
        image = np.array([int(tok) for tok in body], dtype=dtype)
    over = np.flatnonzero(image > maxval)
    if len(over):
        raise BayesmapError(f"PGM file {name!r}: pixel {over[0]} has value {int(image[over[0]])} > maxval {maxval}")
    return image.reshape(height, width), maxval


def read_pgm(path) -> np.ndarray:
    """Read a grayscale PGM image (Netpbm format, http://netpbm.sourceforge.net/doc/pgm.html).

    Binary ``P5`` and plain ``P2`` are accepted, with ``#`` comments anywhere in the header; maxval 1-255 gives
    one byte per pixel, 256-65535 two (big-endian). Pixel data after the first image is ignored.

    Args:
        path: the file (``str`` or path-like).

    Returns:
        ``(rows, cols)`` array of the pixel values as stored (not rescaled to the maxval), ``uint8`` if
        maxval <= 255 else ``uint16``. Row 0 is the top of the image.

    Raises:
        BayesmapError: naming the file, if it does not exist or cannot be read; does not start with ``P5``/``P2``;
            has a header that is truncated or has a width, height or maxval that is not a positive integer
            (maxval <= 65535); has fewer pixel bytes or values than ``width * height``; or has a pixel value that
            is not an integer or exceeds the maxval.
    """
    name, data = read_bytes(path, "PGM file")
    return _parse_pgm(data, name)[0]


def encode_pgm(image, maxval: int | None = None) -> bytes:
    """The bytes of a binary (``P5``) PGM file holding ``image``.

    Args:
        image: ``(rows, cols)`` integer array, row 0 = top of the image, values in ``[0, maxval]``.
        maxval: the file's maxval (1-65535); default 255 if all values are <= 255, else 65535. Above 255 pixels
            take two bytes (big-endian).

    Returns:
        The file's bytes: header ``P5``, width, height, maxval, then the pixels row by row.

    Raises:
        BayesmapError: if ``image`` is not a non-empty 2-D integer array, ``maxval`` is not in 1-65535, or a value
            lies outside ``[0, maxval]`` (names the first one).
    """
    arr = np.asarray(image)
    if arr.ndim != 2 or arr.size == 0:
        raise BayesmapError(f"a PGM image must be a non-empty 2-D array (rows, cols), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise BayesmapError(f"a PGM image must have an integer dtype, got {arr.dtype}")
    if maxval is None:
        maxval = 255 if arr.max() <= 255 else 65535
    if isinstance(maxval, (bool, np.bool_)) or not isinstance(maxval, (int, np.integer)) or not 1 <= maxval <= 65535:
        raise BayesmapError(f"PGM maxval must be an integer in [1, 65535], got {maxval!r}")
    bad = np.argwhere((arr < 0) | (arr > maxval))
    if len(bad):
        r, c = bad[0]
        raise BayesmapError(f"PGM pixel (row {r}, col {c}) is {int(arr[r, c])}, outside [0, {maxval}]")
    header = f"P5\n# written by bayesmap\n{arr.shape[1]} {arr.shape[0]}\n{int(maxval)}\n".encode("ascii")
    pixels = arr.astype(np.uint8 if maxval <= 255 else ">u2").tobytes()
    return header + pixels


def write_pgm(path, image, overwrite: bool = False, maxval: int | None = None) -> Path:
    """Write ``image`` as a binary PGM file (see :func:`encode_pgm`), whole or not at all.

    Raises:
        BayesmapError: as :func:`encode_pgm`; if ``path`` exists and ``overwrite`` is False; if the folder cannot be
            written.
    """
    return write_atomic(path, encode_pgm(image, maxval), overwrite=overwrite)


# ---------------------------------------------------------------------------------------------------------------
# The map
# ---------------------------------------------------------------------------------------------------------------


def _check_thresholds(free_thresh, occupied_thresh, where: str) -> tuple[float, float]:
    for key, val in (("free_thresh", free_thresh), ("occupied_thresh", occupied_thresh)):
        if isinstance(val, (bool, np.bool_)) or not isinstance(val, (int, float, np.integer, np.floating)):
            raise BayesmapError(f"{where}{key} must be a number in [0, 1], got {val!r}")
        if not 0.0 <= float(val) <= 1.0:
            raise BayesmapError(f"{where}{key} must be in [0, 1], got {val!r}")
    if not float(free_thresh) < float(occupied_thresh):
        raise BayesmapError(
            f"{where}free_thresh ({free_thresh!r}) must be below occupied_thresh ({occupied_thresh!r})"
        )
    return float(free_thresh), float(occupied_thresh)


@dataclass(frozen=True, eq=False)
class RosMap:
    """An occupancy grid read from a ROS map_server map.

    Attributes:
        occupancy: ``(nx, ny)`` float32 probability that each cell is occupied, in ``[0, 1]``: map_server's
            ``(255 - v) / 255`` of the cell's pixel ``v`` (``v / 255`` with ``negate``; 16-bit pixels scaled to
            0-255 first). In ``raw`` mode ``v / 100``, and NaN for pixels above 100 (unknown).
        grid: the grid geometry: shape ``(ncols, nrows)`` of the image, the map's resolution (meters per cell) and
            origin (meters).
        free_thresh: cells with occupancy below it are free.
        occupied_thresh: cells with occupancy above it are occupied.
        mode: ``"trinary"`` (cells between the thresholds are unknown), ``"scale"`` (they are known, with a graded
            occupancy) or ``"raw"``.
        path: the file the map was read from ("" if built in memory).

    Raises:
        BayesmapError: on construction, if ``occupancy`` is not ``grid.shape``, has values outside ``[0, 1]``
            (NaN is allowed in raw mode only), the thresholds are not ``0 <= free_thresh < occupied_thresh <= 1``
            or the mode is unknown.
    """

    occupancy: np.ndarray
    grid: Grid
    free_thresh: float = FREE_THRESH
    occupied_thresh: float = OCCUPIED_THRESH
    mode: str = "trinary"
    path: str = ""

    def __post_init__(self) -> None:
        occ = np.array(self.occupancy, dtype=np.float32)
        if occ.shape != self.grid.shape:
            raise BayesmapError(f"RosMap occupancy has shape {occ.shape}, but the grid is {self.grid.shape}")
        if self.mode not in MODES:
            raise BayesmapError(f"RosMap mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        values = occ[~np.isnan(occ)] if self.mode == "raw" else occ
        if not np.all((values >= 0) & (values <= 1)):
            extra = " or NaN" if self.mode == "raw" else ""
            raise BayesmapError(f"RosMap occupancy must be probabilities in [0, 1]{extra}")
        free, occupied = _check_thresholds(self.free_thresh, self.occupied_thresh, "RosMap ")
        occ.setflags(write=False)
        object.__setattr__(self, "occupancy", occ)
        object.__setattr__(self, "free_thresh", free)
        object.__setattr__(self, "occupied_thresh", occupied)
        object.__setattr__(self, "path", str(self.path))

    @property
    def walls(self) -> np.ndarray:
        """``(nx, ny)`` bool, cells with occupancy above ``occupied_thresh`` (map_server's occupied, 100)."""
        return self.occupancy.astype(np.float64) > self.occupied_thresh

    @property
    def free(self) -> np.ndarray:
        """``(nx, ny)`` bool, cells with occupancy below ``free_thresh`` (map_server's free, 0)."""
        return self.occupancy.astype(np.float64) < self.free_thresh

    @property
    def known(self) -> np.ndarray:
        """``(nx, ny)`` bool, cells that are not unknown: in trinary mode the occupied and free cells; in scale mode
        all cells; in raw mode the cells whose pixel is at most 100."""
        if self.mode == "trinary":
            return self.walls | self.free
        return ~np.isnan(self.occupancy)


def _yaml_number(value, key: str, name: str) -> float:
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BayesmapError(f"ROS map {name!r}: {key} must be a finite number, got {value!r}")
    return float(value)


def _load_yaml(name: str, data: bytes) -> dict:
    try:
        import yaml
    except ImportError:  # pragma: no cover - PyYAML is installed with the project
        raise ImportError("reading ROS map YAML files needs PyYAML (pip install pyyaml)") from None
    try:
        doc = yaml.safe_load(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise BayesmapError(f"ROS map {name!r} is not a text file (byte {exc.start} is not UTF-8)") from None
    except yaml.YAMLError as exc:
        raise BayesmapError(f"ROS map {name!r} is not valid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(doc, dict):
        raise BayesmapError(f"ROS map {name!r} must be a YAML mapping of keys (image, resolution, origin, ...)")
    missing = [k for k in _REQUIRED_KEYS if k not in doc]
    if missing:
        keys = "key" if len(missing) == 1 else "keys"
        raise BayesmapError(f"ROS map {name!r} is missing the {keys} {', '.join(missing)}")
    return doc


def _occupancy_from_pixels(image: np.ndarray, maxval: int, negate: bool, mode: str) -> np.ndarray:
    v = image.astype(np.float64) * (255.0 / maxval)
    if negate:
        v = 255.0 - v
    if mode == "raw":
        p = np.where(v <= 100.0, v / 100.0, np.nan)
    else:
        p = (255.0 - v) / 255.0
    return p[::-1].T.astype(np.float32)  # row r (top), column c -> cell (c, nrows - 1 - r)


def read_rosmap(path, resolution: float | None = None, origin=None) -> RosMap:
    """Read a ROS map_server map: its YAML file, or a bare PGM image.

    Args:
        path: the map's YAML file, or a PGM image (recognised by its ``P5``/``P2`` magic bytes). The YAML's
            ``image`` is resolved against the YAML file's folder when relative.
        resolution: meters per cell; required for a bare PGM, not allowed with a YAML file (which gives it).
        origin: ``(x, y)`` world meters of the outer corner of cell ``(0, 0)`` for a bare PGM (default
            ``(0, 0)``); not allowed with a YAML file. A bare PGM gets map_server's defaults: ``negate`` 0,
            ``free_thresh`` 0.196, ``occupied_thresh`` 0.65, ``trinary`` mode.

    Returns:
        The :class:`RosMap`: occupancy ``(nx, ny)`` = ``(image width, image height)`` with image row ``r``, column
        ``c`` at cell ``(c, nrows - 1 - r)``.

    Raises:
        BayesmapError: naming the file, if it cannot be read or is not valid YAML / PGM (see :func:`read_pgm`); if
            the YAML lacks a required key (image, resolution, origin, negate, occupied_thresh, free_thresh), has a
            resolution that is not > 0, an origin that is not three numbers, a nonzero yaw (rotated maps are not
            supported), a negate other than 0/1, thresholds not satisfying ``0 <= free_thresh < occupied_thresh
            <= 1`` or an unknown mode; if ``resolution`` is missing for a bare PGM or given with a YAML file.
    """
    name, data = read_bytes(path, "ROS map")
    if re.match(rb"P[0-9]", data[:2]):
        if resolution is None:
            raise BayesmapError(f"reading the bare PGM image {name!r} needs a resolution (meters per pixel)")
        image, maxval = _parse_pgm(data, name)
        try:
            ox, oy = (0.0, 0.0) if origin is None else (float(v) for v in origin)
        except (TypeError, ValueError):
            raise BayesmapError(f"origin must be two numbers (x, y) in meters, got {origin!r}") from None
        grid = Grid(shape=(image.shape[1], image.shape[0]), resolution=resolution, origin=(ox, oy))
        occ = _occupancy_from_pixels(image, maxval, False, "trinary")
        return RosMap(occ, grid, FREE_THRESH, OCCUPIED_THRESH, "trinary", name)

    if resolution is not None or origin is not None:
        raise BayesmapError(
            f"ROS map {name!r} is a YAML file, which gives the resolution and origin: do not pass them"
        )
    doc = _load_yaml(name, data)
    image_name = doc["image"]
    if not isinstance(image_name, str) or not image_name:
        raise BayesmapError(f"ROS map {name!r}: image must be a file name, got {image_name!r}")
    res = _yaml_number(doc["resolution"], "resolution", name)
    if res <= 0:
        raise BayesmapError(f"ROS map {name!r}: resolution must be > 0 (meters per pixel), got {doc['resolution']!r}")
    org = doc["origin"]
    if not isinstance(org, (list, tuple)) or len(org) != 3:
        raise BayesmapError(f"ROS map {name!r}: origin must be [x, y, yaw], got {org!r}")
    ox, oy, yaw = (_yaml_number(v, "origin", name) for v in org)
    if yaw != 0.0:
        raise BayesmapError(
            f"ROS map {name!r}: origin yaw {org[2]!r} is not supported (only unrotated maps, yaw 0)"
        )
    negate = doc["negate"]
    if isinstance(negate, bool):
        negate = int(negate)
    if negate not in (0, 1) or isinstance(negate, float):
        raise BayesmapError(f"ROS map {name!r}: negate must be 0 or 1, got {doc['negate']!r}")
    free = _yaml_number(doc["free_thresh"], "free_thresh", name)
    occupied = _yaml_number(doc["occupied_thresh"], "occupied_thresh", name)
    _check_thresholds(free, occupied, f"ROS map {name!r}: ")
    mode = doc.get("mode", "trinary")
    if mode not in MODES:
        raise BayesmapError(f"ROS map {name!r}: mode must be one of {', '.join(MODES)}, got {mode!r}")

    image_path = Path(image_name)
    if not image_path.is_absolute():
        image_path = Path(name).parent / image_path
    image_file, image_data = read_bytes(image_path, f"image of ROS map {name!r}:")
    image, maxval = _parse_pgm(image_data, image_file)
    grid = Grid(shape=(image.shape[1], image.shape[0]), resolution=res, origin=(ox, oy))
    occ = _occupancy_from_pixels(image, maxval, bool(negate), mode)
    return RosMap(occ, grid, free, occupied, mode, name)


def _yaml_float(x: float) -> str:
    """A float as YAML 1.1 reads it back exactly (PyYAML needs a '.' in the mantissa: ``1.0e-05``, not ``1e-05``)."""
    text = repr(float(x))
    if "e" in text and "." not in text.split("e")[0]:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    return text


def encode_rosmap(stem: str, occupancy, grid: Grid, free_thresh: float = FREE_THRESH,
                  occupied_thresh: float = OCCUPIED_THRESH, unknown=None) -> dict[str, bytes]:
    """The two files of a ROS map_server map as bytes: ``{stem + ".pgm": image, stem + ".yaml": text}`` (see
    :func:`write_rosmap` for the format and the arguments), for callers that write several outputs at once.

    Raises:
        BayesmapError: as :func:`write_rosmap`, except for the file checks.
    """
    if not isinstance(grid, Grid):
        raise BayesmapError(f"grid must be a bayesmap.geometry.grid.Grid, got {grid!r}")
    occ = np.asarray(occupancy, dtype=np.float64)
    if occ.shape != grid.shape:
        raise BayesmapError(f"occupancy has shape {occ.shape}, but the grid is {grid.shape}")
    if unknown is None:
        unk = np.zeros(grid.shape, dtype=bool)
    else:
        unk = np.asarray(unknown)
        if unk.dtype != bool or unk.shape != grid.shape:
            raise BayesmapError(f"unknown must be a bool mask of shape {grid.shape}, got {unk.dtype} {unk.shape}")
    bad = np.argwhere(~unk & ~((occ >= 0) & (occ <= 1)))
    if len(bad):
        i, j = bad[0]
        raise BayesmapError(f"occupancy of cell ({i}, {j}) is {occ[i, j]!r}, not a probability in [0, 1]")
    free, occupied = _check_thresholds(free_thresh, occupied_thresh, "")
    pixels = np.where(unk, UNKNOWN_PIXEL, np.rint(255.0 * (1.0 - np.where(unk, 0.0, occ)))).astype(np.uint8)
    image = pixels.T[::-1]  # cell (i, j) -> row nrows - 1 - j, column i
    ox, oy = grid.origin
    text = (
        f"image: {stem}.pgm\n"
        f"resolution: {_yaml_float(grid.resolution)}\n"
        f"origin: [{_yaml_float(ox)}, {_yaml_float(oy)}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {_yaml_float(occupied)}\n"
        f"free_thresh: {_yaml_float(free)}\n"
        "mode: trinary\n"
    )
    return {stem + ".pgm": encode_pgm(image, maxval=255), stem + ".yaml": text.encode("utf-8")}


def write_rosmap(yaml_path, occupancy, grid: Grid, overwrite: bool = False, free_thresh: float = FREE_THRESH,
                 occupied_thresh: float = OCCUPIED_THRESH, unknown=None) -> Path:
    """Write an occupancy grid as a ROS map_server map: ``<stem>.pgm`` next to ``yaml_path``, and the YAML file.

    The image is an 8-bit binary PGM with pixel ``round(255 * (1 - p))`` for occupancy ``p`` (white free, black
    occupied), ``205`` for unknown cells; the YAML says ``mode: trinary``, ``negate: 0``, ``origin: [x, y, 0.0]``.
    Reading it back with :func:`read_rosmap` gives the occupancy to within ``0.5 / 255`` and the same grid (a cell
    whose pixel lands between the thresholds, such as ``p = 0.5``, then counts as unknown: that is the format).

    Both files are written whole or not at all (temporary file, then rename); if the YAML cannot be written after
    the image was, a newly created image is removed again.

    Args:
        yaml_path: the YAML file to write (suffix ``.yaml`` or ``.yml``).
        occupancy: ``(nx, ny)`` probabilities of occupied, in ``[0, 1]`` (NaN allowed where ``unknown``).
        grid: its geometry (shape ``(nx, ny)``, resolution in meters per cell, origin in meters).
        overwrite: replace existing files; otherwise refuse.
        free_thresh: the free threshold written to the YAML (map_server's default 0.196).
        occupied_thresh: the occupied threshold written to the YAML (map_server's default 0.65).
        unknown: optional ``(nx, ny)`` bool mask of unknown cells (written as pixel 205).

    Returns:
        The YAML file's path.

    Raises:
        BayesmapError: if ``yaml_path`` does not end in ``.yaml``/``.yml``; ``occupancy`` or ``unknown`` does not
            have the grid's shape, ``unknown`` is not boolean, or an occupancy (outside ``unknown``) is not in
            ``[0, 1]``; the thresholds are not ``0 <= free_thresh < occupied_thresh <= 1``; the YAML or image file
            exists and ``overwrite`` is False; or a file cannot be written.
    """
    yaml_path = Path(yaml_path)
    if yaml_path.suffix.lower() not in (".yaml", ".yml"):
        raise BayesmapError(f"ROS map file {str(yaml_path)!r} must end in .yaml or .yml")
    pgm_path = yaml_path.with_suffix(".pgm")
    files = encode_rosmap(yaml_path.stem, occupancy, grid, free_thresh, occupied_thresh, unknown)
    if not overwrite:
        for p in (yaml_path, pgm_path):
            if p.exists():
                raise BayesmapError(f"{str(p)!r} already exists (refusing to overwrite it)")
    # the YAML names the image by its file name: keep the name of the requested YAML's stem
    text = files[yaml_path.stem + ".yaml"].decode()
    image_bytes = files[yaml_path.stem + ".pgm"]
    pgm_existed = pgm_path.exists()
    write_atomic(pgm_path, image_bytes, overwrite=overwrite)
    try:
        write_atomic(yaml_path, text, overwrite=overwrite)
    except BayesmapError:
        if not pgm_existed:
            pgm_path.unlink(missing_ok=True)
        raise
    return yaml_path
