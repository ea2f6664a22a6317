"""``bayesmap bench`` runs and reports every figure of its table (no timing is asserted: benchmarks only)."""

import json

import pytest

from helpers import run_cli

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

FIELDS = {"reference_s_per_sweep", "fast_s_per_sweep", "ratio", "compile_s", "time_to_accuracy_s"}


def test_bench_prints_table_and_writes_json(tmp_path, monkeypatch, capsys):
    out = tmp_path / "bench.json"
    args = ("bench", "--samplers", "outward,chromatic", "--sweeps", 3, "--reference-sweeps", 1, "--repeats", 1,
            "--chains", 4, "--json", out)
    code, stdout, err = run_cli(monkeypatch, capsys, *args)
    assert code in (0, None), err
    figures = json.loads(out.read_text())
    assert set(figures) == {"outward", "chromatic"}
    for name, row in figures.items():
        assert FIELDS <= set(row)
        assert row["reference"] == {"outward": "reference-outward", "chromatic": "reference-raster"}[name]
        assert row["fast_s_per_sweep"] > 0 and row["reference_s_per_sweep"] > 0
        assert row["ratio"] == row["reference_s_per_sweep"] / row["fast_s_per_sweep"]
        assert row["sweeps_to_accuracy"] is not None and row["time_to_accuracy_s"] > 0
        assert row["num_chains"] == 4 and row["chain_sweeps_per_s"] > 0
    assert "reference-outward" in stdout and "ratio" in stdout
    # the JSON file is not overwritten without --force, and bad values are one-line errors
    code, _, err = run_cli(monkeypatch, capsys, *args)
    assert code == 2 and "already exists" in err
    code, _, err = run_cli(monkeypatch, capsys, "bench", "--samplers", "gibbs")
    assert code == 2 and "unknown benchmark sampler 'gibbs'" in err
    code, _, err = run_cli(monkeypatch, capsys, "bench", "--repeats", 0)
    assert code == 2 and "--repeats must be >= 1" in err
