"""Files a user gave or will read: read whole with one clear error for everything that can go wrong,
written whole or not at all."""

from __future__ import annotations

import os
import shutil
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


_RENAME_EXCHANGE = 2  # linux/fs.h: renameat2 flag, swap the two names atomically
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names ``a`` and ``b`` in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``); False where the
    system or file system cannot."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    return renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_replaceable_folder(out, names=()) -> list[Path]:
    """Check that :func:`replace_folder` can replace ``out``; returns the entries of ``out`` not named in ``names``
    (the user's own files, ``[]`` if ``out`` does not exist).

    Raises:
        BayesmapError: naming ``out``, if it exists and is not a folder, or holds a sub-folder (a folder with
            folders of its own, such as a project's root, is not swapped as a whole).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BayesmapError(f"output folder {str(out)!r} exists and is not a folder")
    if not out.is_dir():
        return []
    try:
        others = sorted(p for p in out.iterdir() if p.name not in names)
    except OSError as err:
        raise BayesmapError(f"output folder {str(out)!r} cannot be listed: {err.strerror}") from None
    subfolders = [p.name for p in others if p.is_dir() and not p.is_symlink()]
    if subfolders:
        raise BayesmapError(f"output folder {str(out)!r} holds a folder of its own ({subfolders[0]!r}); bayesmap "
                            "replaces its output folder as a whole: choose an --out folder for bayesmap alone")
    return others


def replace_folder(out, files: dict[str, bytes], owned=()) -> Path:
    """Make the folder ``out`` hold ``files`` (``{name: contents}``) as a whole, never a mix of old and new outputs.

    The new folder is written beside ``out`` (a hidden ``.NAME.XXXX`` folder in the same parent, so on the same file
    system), then swapped in: one atomic ``renameat2(RENAME_EXCHANGE)`` where Linux offers it, else two renames (old
    folder aside, new one in). A run killed at any moment leaves ``out`` as it was or complete (with the two-rename
    fallback, in the instant between them, the old folder under ``.NAME.XXXX``). Files of ``out`` named neither in
    ``files`` nor in ``owned`` (the names of every output the caller may write, such as an old run's diagnostics)
    are the user's: they are hard-linked into the new folder and stay. A new folder gets the permissions of the
    user's umask (an existing one keeps its mode).

    Raises:
        BayesmapError: naming ``out``, if it exists and is not a folder, holds sub-folders of its own (it cannot be
            swapped as a whole: choose a folder of bayesmap's own), or cannot be written.
    """
    out = Path(out)
    others = check_replaceable_folder(out, tuple(files) + tuple(owned))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    except OSError as err:
        raise BayesmapError(f"cannot write output folder {str(out)!r}: {err.strerror}") from None
    try:
        os.chmod(staging, out.stat().st_mode & 0o7777 if out.is_dir() else 0o777 & ~_umask())
        for name, data in files.items():
            (staging / name).write_bytes(data)
        for path in others:
            try:
                os.link(path, staging / path.name, follow_symlinks=False)
            except OSError:
                shutil.copy2(path, staging / path.name, follow_symlinks=False)
        if not out.exists():
            os.rename(staging, out)
            return out
        if not _exchange(staging, out):
            aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.rename(out, aside / out.name)
            os.rename(staging, out)
            shutil.rmtree(aside, ignore_errors=True)
    except OSError as err:
        raise BayesmapError(f"cannot write output folder {str(out)!r}: {err.strerror or err}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out
