"""The tutorial's ASCII maps: one text line per ``i``, one character per ``j`` (``'X'`` wall, ``'.'`` free).

Exactly as the tutorial's ``extract_points_from_grid_string``: character ``j`` of line ``i`` is ``walls[i, j]``
(so the text is the map transposed). Also the built-in tutorial map (``bayesmap/data/tutorial.txt``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.files import read_bytes, write_atomic

WALL_CHAR = "X"
FREE_CHAR = "."


def parse_map(text: str, source: str = "map") -> np.ndarray:
    """Parse the tutorial's ASCII map format.

    Args:
        text: lines of ``'X'`` (wall) and ``'.'`` (free); line ``i``, character ``j`` is ``walls[i, j]``. Leading and
            trailing blank lines and trailing whitespace on a line are ignored.
        source: a name for the text (a file name) used in error messages.

    Returns:
        walls: ``(nx, ny)`` float32 array of 0.0 / 1.0.

    Raises:
        BayesmapError: if the text has no rows, rows of different lengths (names the line), or a character
            other than ``'X'`` and ``'.'`` (names the character, line and column).
    """
    lines = [line.rstrip() for line in text.strip("\n").split("\n")]
    while lines and not lines[-1]:
        lines.pop()
    if not lines or not lines[0]:
        raise BayesmapError(f"{source}: the map is empty (expected rows of 'X' and '.')")
    width = len(lines[0])
    walls = np.zeros((len(lines), width), dtype=np.float32)
    for i, line in enumerate(lines):
        if len(line) != width:
            raise BayesmapError(
                f"{source}: line {i + 1} has {len(line)} characters, but line 1 has {width} "
                "(rows must have equal length)"
            )
        for j, char in enumerate(line):
            if char == WALL_CHAR:
                walls[i, j] = 1.0
            elif char != FREE_CHAR:
                raise BayesmapError(
                    f"{source}: unknown character {char!r} at line {i + 1}, column {j + 1} "
                    "(use 'X' for wall, '.' for free)"
                )
    return walls


def format_map(walls) -> str:
    """The ASCII text of ``walls`` ``(nx, ny)`` (cells > 0.5 are walls), one line per ``i``, ending in a newline."""
    arr = np.asarray(walls)
    if arr.ndim != 2:
        raise BayesmapError(f"walls must be a 2-D array, got shape {arr.shape}")
    return "".join("".join(WALL_CHAR if v > 0.5 else FREE_CHAR for v in row) + "\n" for row in arr)


def load_map(path) -> np.ndarray:
    """Read an ASCII map file; see :func:`parse_map`.

    Raises:
        BayesmapError: if the file is missing, unreadable, not text, or malformed.
    """
    name, data = read_bytes(path, "map file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise BayesmapError(f"map file {name!r} is not a text file") from None
    return parse_map(text, source=name)


def save_map(path, walls, overwrite: bool = False) -> Path:
    """Write ``walls`` ``(nx, ny)`` as an ASCII map file, whole or not at all; see :func:`write_atomic`."""
    return write_atomic(path, format_map(walls), overwrite=overwrite)


def tutorial_map() -> np.ndarray:
    """The tutorial's 21 x 21 map, ``(21, 21)`` float32 of 0.0 / 1.0 (shipped as ``bayesmap/data/tutorial.txt``)."""
    text = resources.files("bayesmap").joinpath("data/tutorial.txt").read_text(encoding="utf-8")
    return parse_map(text, source="tutorial map")
