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
	@# --no-compile: no bytecode for the whole lock at install time (Python writes it for the modules it imports, when
	@# it imports them): the install took 72 s instead of 116 s on the 2-core machine
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-compile -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-compile --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/bayesmap demo --force

# the docs build (strict: any warning fails it) and the lint check first, then the suite in two passes: the modules
# marked compute_bound (pyproject.toml) compiled at XLA's default optimization, the others with XLA's CPU backend at
# optimization level 0, which compiles about 40% faster and runs compiled loops up to 10x slower (most tests spend
# three quarters of their time compiling; docs/validation/speed.md, "The test suite's compilation"). The first
# pass hands out whole modules (--dist loadfile), so a module's tests share the programs they compile on one worker.
test: $(STAMP) docs lint
	XLA_FLAGS="--xla_backend_optimization_level=0 $$XLA_FLAGS" $(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not compute_bound"
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup -m compute_bound

# API documentation from the docstrings (mkdocs.yml), offline, into site/
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# ruff ([tool.ruff] in pyproject.toml); imports of another module's private names inside bayesmap, which ruff's
# PLC2701 does not see, are checked by tests/test_package_layout.py
lint: $(STAMP)
	$(BIN)/ruff check src tests notebooks benchmarks

# the tutorial notebook, executed, as one HTML file with its outputs
notebook: $(STAMP)
	cd notebooks && ../$(BIN)/jupytext --to ipynb --execute --output mapping_tutorial.ipynb mapping_tutorial.py
	$(BIN)/jupyter nbconvert --to html notebooks/mapping_tutorial.ipynb
	rm -f notebooks/mapping_tutorial.ipynb
	@echo "wrote notebooks/mapping_tutorial.html"

clean:
	rm -rf $(VENV) site bayesmap-out .pytest_cache notebooks/mapping_tutorial.html notebooks/mapping_tutorial.ipynb
