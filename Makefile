# scanqa: two commands do everything on a fresh Debian machine (as root).
#   make demo   - set up .venv, install what is missing, run the demo
#   make test   - same set-up, then the whole test suite and the docs build
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test docs bench lint fuzz setup syslibs syslibs-test clean

setup: $(STAMP)

syslibs:
	@sh tools/install_syslibs.sh

syslibs-test:
	@sh tools/install_syslibs.sh test

$(STAMP): pyproject.toml | syslibs
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install --quiet --upgrade pip
	@$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: syslibs $(STAMP)
	@$(BIN)/scanqa demo $(DEMO_ARGS)

# SCANQA_REQUIRE_CLIENTS=1: the round-trip tests through CloudCompare fail, not skip,
# when the client is missing (make test installs it).
test: syslibs-test $(STAMP)
	@SCANQA_REQUIRE_CLIENTS=1 $(BIN)/python -m pytest -q $(PYTEST_ARGS)
	@$(MAKE) --no-print-directory docs

# The documentation site (docs/): warnings are errors, so a broken reference, a malformed
# docstring or a module missing from docs/api.rst fails the build.
docs: $(STAMP)
	@$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs: docs/_build/html/index.html"

lint: $(STAMP)
	@$(BIN)/ruff check src tests benchmarks

bench: $(STAMP)
	@$(BIN)/python benchmarks/run_all.py

# Nightly-size fuzz run: 400 seeded mutations of each of the six input formats through
# the command line (2400 cases, ~30 min); FUZZ_ARGS="CASES SEED" changes size and seed.
fuzz: $(STAMP)
	@$(BIN)/python -m tests.fuzz $(or $(FUZZ_ARGS),400 0)

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache docs/_build docs/api
