"""Shared fixtures: the tutorial scene with the tutorial's readings (key 0); JAX's compiled programs kept within a
module; and the xdist_group marks made to work again under pytest 9.2 (below)."""

import pytest

from helpers import SHARED_DATA


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """``--dist loadgroup`` sends the tests of one ``xdist_group`` to one worker by the ``@group`` suffix xdist adds
    to their node ids; pytest-xdist 3.8 writes it to ``item._nodeid``, which pytest 9.2's structured node ids no
    longer read, so the marks were silently ignored and every worker that ran a test of a group set up the group's
    module fixtures again (pytest-dev/pytest-xdist#1386). Add the suffix to the structured id instead, on xdist
    workers with loadgroup only, and only where xdist's own suffix is missing (a fixed xdist makes this a no-op)."""
    if not getattr(config.option, "loadgroup", False):
        return
    for item in items:
        names = sorted({str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
                        for mark in item.iter_markers("xdist_group")})
        suffix = "@" + "_".join(names)
        if names and not item.nodeid.endswith(suffix) and hasattr(item, "_id"):
            item._id = type(item._id).parse(item.nodeid + suffix)  # parse keeps the string as given


@pytest.fixture(scope="module", autouse=True)
def compiled_programs_kept_within_a_module():
    """JAX's compiled programs kept while one module's tests run (:func:`bayesmap.memory.keep_compiled_programs`:
    a SLAM run or a tiled chain would otherwise drop every program the worker has compiled, and the next test compile
    its own again); after the module, dropped if the worker's resident memory is above :data:`KEPT_PROGRAMS_MB`, to
    bound it (the next modules reuse them otherwise: the same scenes' samplers, the same shapes)."""
    from bayesmap.memory import drop_compiled_programs, keep_compiled_programs

    with keep_compiled_programs():
        yield
    if resident_mb() > KEPT_PROGRAMS_MB:
        drop_compiled_programs()


KEPT_PROGRAMS_MB = 6000
"""A worker's resident memory (MB) above which the compiled programs are dropped after a module: the suite's two
workers then stay within about 2 x 6 GB plus a module's own. The first pass's workers peaked at 5.6 GB, so it drops
nothing (at 3 GB it dropped after 34 of 58 modules; docs/validation/speed.md)."""


def resident_mb() -> float:
    """This process's resident memory, MB (10**6 bytes), from /proc (0 where there is none)."""
    import os

    try:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return 0.0


@pytest.fixture(scope="session")
def tutorial():
    from bayesmap.scenes import tutorial_problem

    return tutorial_problem()


@pytest.fixture(scope="session")
def tutorial_low_prior():
    from bayesmap.scenes import tutorial_problem

    return tutorial_problem(prior_wall_prob=0.05)


@pytest.fixture(scope="session")
def intel_log():
    path = SHARED_DATA / "carmen" / "intel-corrected.log.gz"
    if not path.exists():
        pytest.skip("shared data not present")
    return path


@pytest.fixture(scope="module")
def small_log(tmp_path_factory, intel_log):
    """The first 12 scans of the Intel log, as a plain CARMEN file."""
    import gzip

    path = tmp_path_factory.mktemp("log") / "intel12.log"
    with gzip.open(intel_log, "rt") as handle:
        lines = [line for line in handle if line.startswith("FLASER")][:12]
    path.write_text("".join(lines))
    return path
