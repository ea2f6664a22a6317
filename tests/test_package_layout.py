"""The package's layering rules, checked on the source: no module imports another module's private names."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def private_imports(text: str) -> list[str]:
    """``module name`` of every ``from bayesmap... import _name`` in a Python source text."""
    found = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "bayesmap":
            found += [f"{node.module} {a.name}" for a in node.names if a.name.startswith("_")
                      and not a.name.startswith("__")]
    return found


def test_the_check_finds_private_imports():
    assert private_imports("from bayesmap.inference.fast import _table, public\nimport os\n") == [
        "bayesmap.inference.fast _table"]
    assert private_imports("from bayesmap import __version__\nfrom numpy import _private\n") == []


def test_no_module_imports_another_modules_private_names():
    files = [p for d in ("src", "tests", "notebooks") for p in (ROOT / d).rglob("*.py")]
    assert len(files) > 50
    found = [f"{p.relative_to(ROOT)}: {hit}" for p in files for hit in private_imports(p.read_text())]
    assert found == []


def test_no_test_imports_a_conftest():
    """Shared test code lives in tests/helpers.py: ``from conftest import`` finds whichever conftest.py was imported
    last (tests/viz has its own), so it breaks depending on which tests are collected together."""
    found = []
    for path in (ROOT / "tests").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module == "conftest":
                found.append(str(path.relative_to(ROOT)))
            if isinstance(node, ast.Import) and any(a.name == "conftest" for a in node.names):
                found.append(str(path.relative_to(ROOT)))
    assert found == []
