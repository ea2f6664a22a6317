# bayesmap: `make demo`, `make docs`, `make lint` and `make test` set up .venv from the pinned versions in
# requirements.lock.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.bayesmap-installed

.PHONY: demo test lint docs notebook install clean

install: $(STAMP)

$(STAMP): pyproject.toml requirements.lock
	@# Debian's chromium for the browser tests (Playwright drives it; never `playwright install`)
	command -v chromium >/dev/null || (apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/bayesmap demo --force

# the docs build (strict: any warning fails it) and the lint check first, then the suite
test: $(STAMP) docs lint
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

# API documentation from the docstrings (mkdocs.yml), offline, into site/
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# ruff ([tool.ruff] in pyproject.toml), then the private-name imports ruff's PLC2701 does not see: those from
# bayesmap inside bayesmap (it skips imports from the importing file's own top-level package)
lint: $(STAMP)
	$(BIN)/ruff check src tests notebooks
	$(BIN)/python -c "$$PRIVATE_IMPORTS"

# the tutorial notebook, executed, as one HTML file with its outputs
notebook: $(STAMP)
	cd notebooks && ../$(BIN)/jupytext --to ipynb --execute --output mapping_tutorial.ipynb mapping_tutorial.py
	$(BIN)/jupyter nbconvert --to html notebooks/mapping_tutorial.ipynb
	rm -f notebooks/mapping_tutorial.ipynb
	@echo "wrote notebooks/mapping_tutorial.html"

clean:
	rm -rf $(VENV) site bayesmap-out .pytest_cache notebooks/mapping_tutorial.html notebooks/mapping_tutorial.ipynb

# `from bayesmap.x import _name` anywhere in src/, tests/ or notebooks/ (one module importing another's private name)
define PRIVATE_IMPORTS
import ast, pathlib, sys
found = []
for path in sorted(p for d in ("src", "tests", "notebooks") for p in pathlib.Path(d).rglob("*.py")):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "bayesmap":
            found += [f"{path}:{node.lineno}: {node.module} {a.name}" for a in node.names
                      if a.name.startswith("_") and not a.name.startswith("__")]
print("\n".join(["private names imported from another module:"] + found) if found else "no private-name imports")
sys.exit(1 if found else 0)
endef
export PRIVATE_IMPORTS
