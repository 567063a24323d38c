# The two commands of the README:  `make main`  and  `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: venv main test test-fast lint bench chromium docs

$(BIN)/python:
	$(PY) -m venv $(VENV)

# Installs pbc into a local venv. torch is installed first as the 2.13.0 wheel when it is missing:
# a CPU wheel on the reference machine, the CUDA one on a GPU user's pip.
venv: $(BIN)/python
	@$(BIN)/python -c "import torch" 2>/dev/null || $(BIN)/pip install -q "torch==2.13.0"
	@$(BIN)/pip install -q -e ".[dev,sweeps]"

# The main job on the built-in default data (see README).
main: venv
	$(BIN)/python -m pbc.main

# the browser test (tests/integration/test_view_browser.py) opens `pbc view` in Debian's Chromium; playwright
# downloads no browser of its own
chromium:
	@command -v chromium >/dev/null || (apt-get update -qq && apt-get install -y -qq chromium)

# every tier, in TEST_WORKERS processes (pytest-xdist): whole test files, in collection order (integration before
# unit); tests/conftest.py says how the workers share the session's data and caches
TEST_WORKERS ?= 2
test: venv chromium
	$(BIN)/python -m pytest -x -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# the quick tier: tests/unit (synthetic data, no drape, no subprocess); `test` runs every tier
test-fast: venv
	$(BIN)/python -m pytest -x tests/unit

lint: venv
	$(BIN)/ruff check pbc tests bench

# the documentation site (mkdocs.yml: docs/, the API from the docstrings) into site/, strictly: a broken link,
# anchor, snippet or docstring fails it, as in tests/integration/test_docs_site.py
docs: venv
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

bench: venv
	for b in bench/*.py; do $(BIN)/python $$b || exit 1; done
