# scanqa: two commands do everything on a fresh Debian machine (as root).
#   make demo   - set up .venv, install what is missing, run the demo
#   make test   - same set-up, then the whole test suite and the docs build
#   make mutate - mutation testing of optics, the QA core and the table lookup
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO_STAMP := $(VENV)/.installed-demo
WHEEL_VENV := build/wheel-venv
# make test runs the suite on one process per core (at most 4: each may hold a simulated
# scan in memory); whole test files stay on one worker, so their fixtures are built once,
# and the heaviest files are collected first (tests/conftest.py, HEAVY_FIRST) so that no
# worker finishes a long file alone at the end.
JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)

.PHONY: demo test docs bench lint fuzz mutate setup syslibs syslibs-test clean wheel-check \
	fringes-ref

setup: $(STAMP)

syslibs:
	@sh tools/install_syslibs.sh

syslibs-test:
	@sh tools/install_syslibs.sh test

$(STAMP): pyproject.toml | syslibs
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install --quiet --upgrade pip
	@$(BIN)/python -m pip install --quiet --no-compile -e '.[test]'
	@$(MAKE) --no-print-directory fringes-ref
	@$(BIN)/python tools/warm_numba.py
	@touch $(STAMP)

# The reference decoder of tests/test_fringes_agreement.py without its dependencies: it
# asks for opencv-contrib-python, and a second cv2 wheel beside scanqa[calib]'s
# opencv-python-headless breaks both (its other dependencies are in [test]). The tests
# that write OpenCV's own Gray code (cv2.structured_light.GrayCodePattern, a contrib
# module scanqa itself never uses) need the contrib build: the test venv swaps the
# headless wheel for opencv-contrib-python-headless of the same version, a superset of
# it (the same main modules, no Qt), so one cv2 is kept.
fringes-ref:
	@if $(BIN)/python -m pip show -q opencv-contrib-python 2>/dev/null; then \
		$(BIN)/python -m pip uninstall --quiet -y opencv-contrib-python; fi
	@if ! $(BIN)/python -c "import cv2; cv2.structured_light.GrayCodePattern" 2>/dev/null; then \
		v=$$($(BIN)/python -m pip show opencv-python-headless 2>/dev/null | sed -n 's/^Version: //p'); \
		$(BIN)/python -m pip uninstall --quiet -y opencv-python-headless opencv-contrib-python-headless; \
		$(BIN)/python -m pip install --quiet --no-deps "opencv-contrib-python-headless$${v:+==$$v}"; fi
	@$(BIN)/python -m pip install --quiet --no-deps 'fringes==2.1.0'

# make demo installs the package alone (no test, docs or cluster tools)
# --no-compile (here, for the test venv and the wheel's venv): pip byte-compiles every
# installed module, ~1 GB of packages of which a run imports a small part; Python
# compiles what it imports on first use instead. Measured on a fresh venv, idle machine:
# the install 49 -> 23 s, the first demo 22 -> 27 s (docs/install.rst).
$(DEMO_STAMP): pyproject.toml | syslibs
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install --quiet --upgrade pip
	@$(BIN)/python -m pip install --quiet --no-compile -e .
	@touch $(DEMO_STAMP)

demo: syslibs $(DEMO_STAMP)
	@$(BIN)/scanqa demo $(DEMO_ARGS)

# SCANQA_REQUIRE_CLIENTS=1: the round-trip tests through CloudCompare fail, not skip,
# when the client is missing (make test installs it).
test: syslibs-test $(STAMP)
	@SCANQA_REQUIRE_CLIENTS=1 $(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile $(PYTEST_ARGS)
	@$(MAKE) --no-print-directory -j2 docs wheel-check

# The package as a lab installs it: sdist and wheel built, the wheel installed without
# extras into a venv of its own, and the README's Python examples run with that venv's
# Python in a scratch folder (on the wheel's sample data, scanqa.sample_data_path()),
# then `scanqa demo --help`. The whole demo runs in the suite (tests/test_demo.py) and
# from a wheel when docs/install.rst was measured; here it would repeat ~20 s of CPU.
# No extras, so no numba and no OpenCV: the examples take the numpy paths
# (scanqa.compiled, scanqa.calibration.pinhole), and the check fails if numba or cv2 is
# there all the same. The venv is made anew, with the
# dependencies the wheel asks for, only when pyproject.toml changes; scanqa itself is
# reinstalled always.
WHEEL_STAMP := $(WHEEL_VENV)/.deps
$(WHEEL_STAMP): pyproject.toml
	@rm -rf $(WHEEL_VENV) && mkdir -p build && $(PYTHON) -m venv $(WHEEL_VENV)
	@touch $(WHEEL_STAMP).new

wheel-check: $(STAMP) $(WHEEL_STAMP)
	@rm -rf build/dist build/wheel-readme && mkdir -p build/wheel-readme
	@$(BIN)/python -m build --sdist --wheel --outdir build/dist . > build/build.log 2>&1 \
		|| (tail -20 build/build.log; exit 1)
	@if [ -e $(WHEEL_STAMP).new ]; then \
		$(WHEEL_VENV)/bin/python -m pip install --quiet --no-compile build/dist/scanqa-*.whl && \
		mv $(WHEEL_STAMP).new $(WHEEL_STAMP); \
	else $(WHEEL_VENV)/bin/python -m pip install --quiet --force-reinstall --no-deps \
		build/dist/scanqa-*.whl; fi
	@cd build/wheel-readme && env -u PYTHONPATH ../../$(WHEEL_VENV)/bin/python \
		../../tools/readme_examples.py ../../README.md > ../wheel-readme.log 2>&1 \
		|| (tail -20 ../wheel-readme.log; exit 1)
	@if $(WHEEL_VENV)/bin/python -c "import numba" 2>/dev/null; then \
		echo "wheel-check: numba is installed without the fast extra"; exit 1; fi
	@if $(WHEEL_VENV)/bin/python -c "import cv2" 2>/dev/null; then \
		echo "wheel-check: OpenCV (cv2) is installed without the calib extra"; exit 1; fi
	@$(WHEEL_VENV)/bin/scanqa demo --help > /dev/null
	@echo "wheel: $$(ls build/dist | tr "\n" " ")built; installed without extras (no numba, no OpenCV); $$(cat build/wheel-readme.log)"

# The documentation site (docs/): warnings are errors, so a broken reference, a malformed
# docstring or a module missing from docs/api.rst fails the build.
# Incremental: Sphinx rereads only pages whose source or documented module changed (autodoc
# records the .py files a page depends on; autosummary rewrites a generated page only when
# its text changes). Generated pages of modules no longer in docs/api.rst are removed; a
# failed build drops Sphinx's saved state, so the next build reads every page again and a
# warning cannot pass unseen.
docs: $(STAMP)
	@for f in docs/api/scanqa.*.rst; do [ -e "$$f" ] || continue; \
		grep -q "^   $$(basename $$f .rst)$$" docs/api.rst || rm -f "$$f"; done
	@$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html \
		|| (rm -rf docs/_build; exit 1)
	@echo "docs: docs/_build/html/index.html"

lint: $(STAMP)
	@$(BIN)/ruff check src tests benchmarks docs/studies

# Mutation testing (docs/mutation.rst, config in pyproject.toml [tool.mutmut]): every mutant
# of optics.py, the QA core (qa/blocks, results, correlation, planes, vdi2634, verdict,
# budget) and calibration/lookup.py runs the fast tests
# that call it; then the kill rate per module (fails below 85 %) and every survivor.
# About 25 min on 2 cores; MUTATE_JOBS sets the parallel workers. Results in mutants/.
MUTATE_JOBS ?= 2
mutate: $(STAMP)
	@$(BIN)/python -c "import mutmut" 2>/dev/null || $(BIN)/python -m pip install --quiet -e '.[test,mutate]'
	@rm -rf mutants && mkdir mutants
	@echo "mutmut: running (log in mutants/run.log)"
	@$(BIN)/mutmut run --max-children $(MUTATE_JOBS) > mutants/run.log 2>&1 || (tail -c 2000 mutants/run.log; exit 1)
	@$(BIN)/python tools/mutation_report.py

bench: $(STAMP)
	@$(BIN)/python benchmarks/run_all.py

# Nightly-size fuzz run: 560 seeded mutations of each of the nine input formats through
# the command line (5040 cases: TOML with grammar-aware nesting, PLY, CSV, npz containers
# with forged headers, flags and bombs, PNG headers, image stacks), then 560 of each of
# the physical-value kinds (config and sigma_xp off by orders of magnitude, impossible
# per-point values, other units, zeroed/swapped/foreign frames, repeats of another scene);
# fails on a traceback, a broken promise, a case over 30 s, an invalid input accepted, a
# result its oracle calls wrong, or a peak memory over 1 GB. FUZZ_ARGS="CASES SEED
# [FORMAT,...]" changes size, seed and formats (physical-config, physical-frames, ...).
# Then 1000 seeded requests against the design page's server (tests/fuzz_http.py;
# FUZZ_HTTP_ARGS="CASES SEED"): no 500, no traceback, no hang, every refusal refused.
fuzz: $(STAMP)
	@$(BIN)/python -m tests.fuzz $(or $(FUZZ_ARGS),560 0)
	@$(BIN)/python -m tests.fuzz_http $(or $(FUZZ_HTTP_ARGS),1000 0)

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache docs/_build docs/api mutants
