"""Reading a user's file whole, with one clear error for everything that can go wrong."""

from __future__ import annotations

import os

from bayesmap.errors import BayesmapError


def read_bytes(path, what: str) -> tuple[str, bytes]:
    """``(name, contents)`` of the file at ``path`` (a string or path-like), read whole.

    Args:
        path: the file.
        what: how to name the file in errors ("CARMEN log", "map file", ...).

    Raises:
        BayesmapError: naming ``what`` and the path, if the path is not a string or path, the file does not exist,
            is a directory, cannot be read (permissions), or reading fails.
    """
    try:
        name = os.fspath(path)
    except TypeError:
        raise BayesmapError(f"{what} path must be a string or path, got {path!r}") from None
    if isinstance(name, bytes):
        name = os.fsdecode(name)
    try:
        with open(name, "rb") as fh:
            return name, fh.read()
    except FileNotFoundError:
        raise BayesmapError(f"{what} {name!r} does not exist") from None
    except IsADirectoryError:
        raise BayesmapError(f"{what} {name!r} is a directory, not a file") from None
    except PermissionError:
        raise BayesmapError(f"{what} {name!r} cannot be read: permission denied") from None
    except OSError as exc:
        raise BayesmapError(f"{what} {name!r} cannot be read: {exc.strerror or exc}") from None
