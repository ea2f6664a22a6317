"""Files a user gave or will read: read whole with one clear error for everything that can go wrong,
written whole or not at all."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

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


def write_atomic(path, data: bytes | str, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` whole or not at all (a temporary file in the same folder, then a rename).

    Raises:
        BayesmapError: if ``path`` exists and ``overwrite`` is False, or the folder cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise BayesmapError(f"{str(path)!r} already exists (refusing to overwrite it)")
    payload = data.encode("utf-8") if isinstance(data, str) else data
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent if str(path.parent) else ".", prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:
        raise BayesmapError(f"cannot write {str(path)!r}: {err.strerror}") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise BayesmapError(f"cannot write {str(path)!r}: {err.strerror}") from None
    return path
