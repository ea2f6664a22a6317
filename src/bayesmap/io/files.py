"""Files a user gave or will read: read whole with one clear error for everything that can go wrong,
written whole or not at all.

Only regular files are read: a device such as ``/dev/zero`` never ends and a FIFO blocks until something writes to
it, so both are refused at once, by name (:func:`read_bytes`, :func:`check_regular`).

Writes go through a hidden staging entry beside the target, ``.NAME.bayesmap-PID-XXXXXXXX`` (a folder, or a file
ending in ``.tmp``), renamed into place when complete. A process killed in that instant (SIGKILL, power loss) leaves
the staging entry behind; the next write to the same place removes it (:func:`sweep_stale`).
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import tempfile
import time
from pathlib import Path

from bayesmap.errors import BayesmapError

STALE_AFTER_S = 3600.0
"""Seconds after which a staging entry (see the module docstring) counts as abandoned even though the process id in
its name runs: ids are reused, so a running id does not prove the writer is alive. A staging entry lives only while
bytes already computed are written and renamed: seconds even for the largest outputs (on a 2-core machine, a 200 MB
output folder in 0.7 s, the largest shared log, Freiburg's, converted to a 12 MB bag in under 6 s all told), so an
hour leaves a wide margin for a slow or busy disk."""

_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def _not_regular(mode: int) -> str | None:
    """What a file of ``mode`` is if not a regular file ("a FIFO (named pipe)", ...), else None."""
    if stat.S_ISREG(mode):
        return None
    return next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


def _nonblocking(name, flags):
    """``open``'s opener: never wait on a FIFO with no writer (the file is checked before it is read)."""
    return os.open(name, flags | os.O_NONBLOCK)


def read_bytes(path, what: str) -> tuple[str, bytes]:
    """``(name, contents)`` of the regular file at ``path`` (a string or path-like, or a link to such a file), read
    whole.

    Args:
        path: the file.
        what: how to name the file in errors ("CARMEN log", "map file", ...).

    Raises:
        BayesmapError: naming ``what`` and the path, if the path is not a string or path, the file does not exist,
            is a directory, a device, a FIFO or a socket (refused before anything is read: ``/dev/zero`` would be
            read without end, a FIFO would block), cannot be read (permissions), or reading fails.
    """
    try:
        name = os.fspath(path)
    except TypeError:
        raise BayesmapError(f"{what} path must be a string or path, got {path!r}") from None
    if isinstance(name, bytes):
        name = os.fsdecode(name)
    try:
        with open(name, "rb", opener=_nonblocking) as fh:
            kind = _not_regular(os.fstat(fh.fileno()).st_mode)
            if kind is not None:
                raise BayesmapError(f"{what} {name!r} is {kind}, not a regular file")
            return name, fh.read()
    except FileNotFoundError:
        raise BayesmapError(f"{what} {name!r} does not exist") from None
    except IsADirectoryError:
        raise BayesmapError(f"{what} {name!r} is a directory, not a file") from None
    except PermissionError:
        raise BayesmapError(f"{what} {name!r} cannot be read: permission denied") from None
    except OSError as exc:
        raise BayesmapError(f"{what} {name!r} cannot be read: {exc.strerror or exc}") from None


def check_regular(path, what: str, folder: bool = False) -> Path:
    """Refuse, before a library opens it, a ``path`` that is not a regular file: for a reader that opens files
    itself (a ROS bag's). With ``folder``, a folder is accepted if every entry in it that is not a folder is a
    regular file (a ROS 2 bag: metadata.yaml and its storage files).

    Raises:
        BayesmapError: naming ``what`` and the path (or the entry of the folder), if it does not exist, or is a
            device, a FIFO, a socket, or a folder (without ``folder``).
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise BayesmapError(f"{what} {str(path)!r} does not exist") from None
    except OSError as exc:
        raise BayesmapError(f"{what} {str(path)!r} cannot be read: {exc.strerror or exc}") from None
    if folder and stat.S_ISDIR(mode):
        try:
            entries = sorted(path.iterdir())
        except OSError as exc:
            raise BayesmapError(f"{what} {str(path)!r} cannot be listed: {exc.strerror or exc}") from None
        for entry in entries:
            if not entry.is_dir():
                check_regular(entry, f"{what} {str(path)!r}: file")
        return path
    kind = _not_regular(mode)
    if kind is not None:
        raise BayesmapError(f"{what} {str(path)!r} is {kind}, not a regular file")
    return path


def check_own_folder(folder, required: str, endings: tuple[str, ...], what: str) -> Path:
    """Refuse to replace ``folder`` unless it is empty or holds the file ``required`` and otherwise only files whose
    names end in one of ``endings``: what a writer of ``what`` (such as "a ROS 2 bag") recognises as its own.

    Raises:
        BayesmapError: naming ``folder`` and the entry that is not the writer's (or the missing ``required``).
    """
    folder = Path(folder)
    try:
        entries = sorted(folder.iterdir())
    except OSError as err:
        raise BayesmapError(f"{str(folder)!r} cannot be listed: {err.strerror}") from None
    if entries and not (folder / required).is_file():
        raise BayesmapError(f"{str(folder)!r} is a folder but not {what} (no {required}); bayesmap replaces only "
                            f"{what}: choose another name, or remove the folder yourself")
    for entry in entries:
        if entry.name != required and not (entry.is_file() and entry.name.endswith(tuple(endings))):
            raise BayesmapError(f"{str(folder)!r} is not only {what} (it holds {entry.name!r}); bayesmap replaces "
                                f"only {what}'s own files: choose another name, or move that file away")
    return folder


def _staging_pattern(name: str) -> re.Pattern:
    """The names of staging entries for a target named ``name``: ``.NAME.bayesmap-PID-XXXXXXXX`` (group 1 the
    process id, then ``tempfile``'s eight random characters), ending in ``.tmp`` for a file of :func:`write_atomic`.
    Only this form is matched, never a user's own hidden file (nor the unmarked names of bayesmap 0.1's staging)."""
    return re.compile(rf"\.{re.escape(name)}\.bayesmap-(\d+)-[a-z0-9_]{{8}}(?:\.tmp)?")


def _running(pid: int) -> bool:
    """True if a process ``pid`` runs on this machine (or might: one of another user's)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def sweep_stale(path) -> list[Path]:
    """Remove the staging entries a killed write to ``path`` left beside it (module docstring); returns them.

    An entry is stale when the process id in its name runs no more on this machine, or when it is older than
    :data:`STALE_AFTER_S` (its id reused by another process). A write in progress, by this or another process, is
    left alone. Removal is best effort: an entry that cannot be removed is skipped.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    pattern = _staging_pattern(path.name)
    try:
        candidates = [p for p in parent.iterdir() if pattern.fullmatch(p.name)]
    except OSError:
        return []
    removed = []
    for entry in candidates:
        pid = int(pattern.fullmatch(entry.name).group(1))
        try:
            age = time.time() - entry.lstat().st_mtime
        except OSError:
            continue
        if age <= STALE_AFTER_S and (pid == os.getpid() or _running(pid)):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        except OSError:
            continue
        removed.append(entry)
    return removed


def make_staging(path, folder: bool = False) -> Path:
    """A new, empty staging entry for a write to ``path``: a hidden folder (``folder``) or file beside it, named
    ``.NAME.bayesmap-PID-XXXXXXXX`` (``.tmp`` for a file), after removing stale ones (:func:`sweep_stale`). The
    caller renames it into place or removes it.

    Raises:
        OSError: if the folder of ``path`` cannot be written.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    sweep_stale(path)
    prefix = f".{path.name}.bayesmap-{os.getpid()}-"
    if folder:
        return Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
    fd, name = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=parent)
    os.close(fd)
    return Path(name)


def write_atomic(path, data: bytes | str, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` whole or not at all (a staging file in the same folder, :func:`make_staging`, then
    a rename).

    Raises:
        BayesmapError: if ``path`` exists and ``overwrite`` is False, or the folder cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise BayesmapError(f"{str(path)!r} already exists (refusing to overwrite it)")
    payload = data.encode("utf-8") if isinstance(data, str) else data
    try:
        tmp = make_staging(path)
    except OSError as err:
        raise BayesmapError(f"cannot write {str(path)!r}: {err.strerror}") from None
    try:
        tmp.write_bytes(payload)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise BayesmapError(f"cannot write {str(path)!r}: {err.strerror}") from None
    except BaseException:  # Ctrl+C: nothing written, nothing left behind
        tmp.unlink(missing_ok=True)
        raise
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

    The new folder is written beside ``out`` (a hidden staging folder in the same parent, so on the same file
    system: :func:`make_staging`, which first removes those a killed run left), then swapped in: one atomic
    ``renameat2(RENAME_EXCHANGE)`` where Linux offers it, else two renames (old folder aside, new one in). A run
    killed at any moment leaves ``out`` as it was or complete (with the two-rename fallback, in the instant between
    them, the old folder under a staging name), and at worst a staging folder that the next write removes. Files
    of ``out`` named neither in ``files`` nor in ``owned`` (the names of every output the caller may write, such as
    an old run's diagnostics) are the user's: they are hard-linked into the new folder and stay. A new folder gets
    the permissions of the user's umask (an existing one keeps its mode).

    Raises:
        BayesmapError: naming ``out``, if it exists and is not a folder, holds sub-folders of its own (it cannot be
            swapped as a whole: choose a folder of bayesmap's own), or cannot be written.
    """
    out = Path(out)
    others = check_replaceable_folder(out, tuple(files) + tuple(owned))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = make_staging(out, folder=True)
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
            aside = make_staging(out, folder=True)
            os.rename(out, aside / out.name)
            os.rename(staging, out)
            shutil.rmtree(aside, ignore_errors=True)
    except OSError as err:
        raise BayesmapError(f"cannot write output folder {str(out)!r}: {err.strerror or err}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out
