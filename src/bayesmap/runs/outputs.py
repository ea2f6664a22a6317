"""The outputs of a run: the files bayesmap owns in an output folder, the checks made before any work (the folder,
``--out-bag``, ``--json``), and the writes, whole or not at all.

An output folder is replaced as a whole (:func:`bayesmap.io.files.replace_folder`): the new run's files, plus the
files of the folder that bayesmap did not write (a user's own), never a mix of two runs' outputs.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.files import check_replaceable_folder, make_staging, replace_folder, write_atomic
from bayesmap.io.maps_out import NPZ_FILE, encode_png16, encode_posterior_npz, posterior_std
from bayesmap.io.rosbag import check_bag_path

OUTPUT_FILES = ("posterior.npy", "readings.npy", "posterior.png", "summary.json")
"""What every ``infer`` and ``demo`` run writes."""
DIAGNOSTICS_FILE = "diagnostics.npz"
"""Split R-hat and effective sample size per cell, written with ``--chains`` >= 2."""
REPORT_FILE = "report.html"
"""Written by ``demo``, and by ``infer`` / ``slam`` with ``--report``."""
ROSMAP_STEM = "map"
"""``--rosmap`` writes map.pgm and map.yaml (ROS map_server)."""
ROSMAP_FILES = (ROSMAP_STEM + ".pgm", ROSMAP_STEM + ".yaml")
"""The files of ``--rosmap``: the image and its map_server YAML."""
MAPS_FILES = (NPZ_FILE, "probability.png", "probability.yaml", "std.png", "std.yaml")
"""Written with ``--maps``."""
ALL_OUTPUT_FILES = OUTPUT_FILES + (DIAGNOSTICS_FILE, REPORT_FILE) + ROSMAP_FILES + MAPS_FILES
"""Every file an ``infer`` run may write into its output folder (an old run's that the new one does not write are
removed)."""
OCCUPANCY_FILE = "occupancy.png"
"""``slam --log / --bag``'s figure of the map alone (the posterior map without paths)."""
SLAM_OUTPUT_FILES = ("trajectory.tum", "trajectory_samples.npy", "pose_cov.npy", OCCUPANCY_FILE)
"""What ``bayesmap slam`` writes besides posterior.npy, posterior.png, summary.json and the optional outputs."""
SLAM_OWNED_FILES = ALL_OUTPUT_FILES + SLAM_OUTPUT_FILES
"""Every file a ``bayesmap slam`` run may write into its output folder."""


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists."""
    parent = path
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    return parent


def _probe_write(target: Path, folder: bool, what: str) -> None:
    """Create and remove a staging entry beside ``target`` (:func:`bayesmap.io.files.make_staging`), where the write
    will make one: permissions alone do not tell (a read-only file system, /proc, a full disk; root passes every
    permission check).

    Raises:
        BayesmapError: naming ``what`` and the reason, if it cannot be created.
    """
    try:
        probe = make_staging(target, folder=folder)
    except OSError as err:
        raise BayesmapError(f"{what} cannot be written: {err.strerror or err}") from None
    if folder:
        probe.rmdir()
    else:
        probe.unlink()


def check_output_dir(out: Path, force: bool, owned=ALL_OUTPUT_FILES) -> None:
    """Check, before any work, that the output folder ``out`` can be written: a folder (or nothing yet) that holds
    none of the ``owned`` files unless ``force``, no sub-folder of its own, and a place where a staging folder can
    be made (tried).

    Raises:
        BayesmapError: naming the folder or the file that would be replaced.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BayesmapError(f"output folder {str(out)!r} exists and is not a folder")
    if out.is_dir() and not force:
        clash = [name for name in owned if (out / name).exists()]
        if clash:
            raise BayesmapError(f"{str(out / clash[0])!r} already exists; pass --force to replace bayesmap's outputs "
                                f"in {str(out)!r}")
    check_replaceable_folder(out, owned)
    parent = _nearest_existing(out if out.is_dir() else out.parent)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"output folder {str(out)!r} cannot be written (no write permission on {str(parent)!r})")
    if out.parent.is_dir():
        _probe_write(out, True, f"output folder {str(out)!r}")


def check_out_bag(path: Path, force: bool) -> None:
    """Check, before any work, an ``--out-bag``: without ``force`` it must not exist; a ``.bag`` name is a ROS 1
    file, any other a ROS 2 folder, which is replaced only if it holds a bag and nothing else
    (:func:`bayesmap.io.rosbag.check_bag_path`); its folder must exist and be writable.

    Raises:
        BayesmapError: naming the path.
    """
    path = Path(path)
    if path.exists() and not force:
        raise BayesmapError(f"{str(path)!r} already exists; pass --force to replace it")
    if path.exists() and (path.suffix == ".bag") != path.is_file():
        raise BayesmapError(f"--out-bag {str(path)!r}: a '.bag' name is a ROS 1 bag file, any other a ROS 2 bag "
                            "folder")
    parent = path.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"--out-bag {str(path)!r} cannot be written (no folder {str(parent)!r} to write in)")
    check_bag_path(path, ros2=path.suffix != ".bag", overwrite=force)


def check_output_file(path: Path, force: bool, option: str = "--json") -> None:
    """Check, before any work, a file ``option`` will write: not a folder, not an existing file without ``force``,
    and in an existing folder where a staging file can be made (tried).

    Raises:
        BayesmapError: naming ``option`` and the path.
    """
    path = Path(path)
    if path.is_dir():
        raise BayesmapError(f"{option} {str(path)!r} is a folder; give a file name")
    if path.exists() and not force:
        raise BayesmapError(f"{str(path)!r} already exists; pass --force to replace it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise BayesmapError(f"{option} {str(path)!r} cannot be written: there is no folder {str(parent)!r}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"{option} {str(path)!r} cannot be written (no write permission on {str(parent)!r})")
    _probe_write(path, False, f"{option} {str(path)!r}")


def write_json(path: Path, data: dict) -> Path:
    """Write ``data`` as indented JSON to ``path``, whole or not at all (replacing a file there)."""
    return write_atomic(path, json_bytes(data), overwrite=True)


def write_outputs(out: Path, files: dict[str, bytes], owned=ALL_OUTPUT_FILES) -> list[str]:
    """Replace the output folder ``out`` as a whole by one holding ``files`` (plus the user's own files already
    there, those not in ``owned``): see :func:`bayesmap.io.files.replace_folder`. Returns the names written.

    Raises:
        BayesmapError: naming the folder, if it cannot be written.
    """
    replace_folder(out, files, owned=owned)
    return list(files)


def json_bytes(data: dict) -> bytes:
    """``data`` as the bytes of an indented JSON file (summary.json's form)."""
    return (json.dumps(data, indent=2) + "\n").encode()


def npy_bytes(array) -> bytes:
    """``array`` as the bytes of a ``.npy`` file."""
    buf = io.BytesIO()
    np.save(buf, np.asarray(array))
    return buf.getvalue()


def map_files(posterior, grid, seen) -> dict[str, bytes]:
    """``--maps``: posterior.npz, and probability and std as 16-bit PNGs with their YAML (:mod:`bayesmap.io.maps_out`);
    ``seen`` ``(nx, ny)`` bool, the cells some beam crossed."""
    probability = np.clip(np.asarray(posterior, dtype=np.float64), 0.0, 1.0)
    files = {NPZ_FILE: encode_posterior_npz(probability, grid, seen)}
    files.update(encode_png16("probability", probability, grid, "probability"))
    files.update(encode_png16("std", posterior_std(probability), grid, "std"))
    return files
