"""The public API of ``import bayesmap``: every listed name resolves to the object of its module, lazily."""

import importlib
import subprocess
import sys

import pytest

import bayesmap


@pytest.mark.parametrize("name", bayesmap.__all__)
def test_every_public_name_is_the_object_of_its_module(name):
    assert getattr(bayesmap, name) is getattr(importlib.import_module(bayesmap.API[name]), name)
    assert name in dir(bayesmap)


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'plot_everything'"):
        bayesmap.plot_everything  # noqa: B018


def test_import_bayesmap_loads_no_heavy_dependency():
    code = "import sys, bayesmap; print(sorted(m for m in ('jax', 'genjax', 'matplotlib') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_quick_path_of_a_notebook_runs():
    """The module docstring's example: tutorial map -> scene -> inference -> figure."""
    problem = bayesmap.tutorial_problem(bayesmap.tutorial_map())
    result = bayesmap.run_inference(problem, "block", sweeps=20)
    assert result.posterior.shape == problem.grid.shape == (21, 21)
    assert problem.wrong_visible_cells(result.posterior) <= 10
