"""Shared fixtures: the tutorial scene with the tutorial's readings (key 0)."""

import pytest

from helpers import SHARED_DATA


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
