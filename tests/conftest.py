"""Shared fixtures: the paper's scanner config."""

from __future__ import annotations

import os
import resource
import sys
import time
import warnings
from pathlib import Path

# One OpenBLAS thread per test process, set before numpy loads OpenBLAS (the xdist
# workers and the CLI's subprocesses inherit it): on 2 cores shared by two workers its
# threads only compete, and they make numpy's tall-skinny products, (n, 3) @ (3, 3) with
# n ~ 1e6, ~30x slower in CPU (docs/benchmarks.rst, "The test suite").
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
if "numpy" in sys.modules:  # loaded by a plugin before this file: too late for the variable
    warnings.warn("numpy was imported before tests/conftest.py: OpenBLAS keeps its "
                  "threads (set OPENBLAS_NUM_THREADS=1)", stacklevel=1)

import pytest

from scanqa.model.config import ScannerConfig, load_config

ROOT = Path(__file__).resolve().parents[1]
PAPER_CONFIG = ROOT / "calib" / "paper_scanner.toml"


@pytest.fixture(scope="session")
def paper_config() -> ScannerConfig:
    """calib/paper_scanner.toml at f/8 (the set-up of Tables 1 and 2)."""
    return load_config(PAPER_CONFIG)


def paper_config_text() -> str:
    """calib/paper_scanner.toml's text for a copy written elsewhere: the characterisation
    file its characterised_by names given by absolute path (a copy's folder lacks it)."""
    evidence = ROOT / "calib" / "paper_scanner_fig3.json"
    return PAPER_CONFIG.read_text().replace('characterised_by = "paper_scanner_fig3.json',
                                            f'characterised_by = "{evidence}')


# ------------------------------------------------------------ heavy test files first
#: The files with the most CPU per file (docs/benchmarks.rst, "The test suite"), largest
#: first. make test runs ``-n 2 --dist loadfile``: a file stays on one worker, so its
#: module fixtures are built once, and workers take files in collection order (xdist's
#: reordering is turned off below); started first, the long files no longer leave one
#: worker running alone at the end.
HEAVY_FIRST = (  # CPU seconds per file: one -n 2 run, session 44 (docs/benchmarks.rst)
    "test_closed_loop.py",              # 72.8 (computes the sample table: shared_runs)
    "test_board_real.py",               # 45.3 (the board calibration test_api reads)
    "test_batch.py",                    # 43.0 (LocalClusters)
    "test_board_gray.py",               # 35.2
    "test_flattening_real.py",          # 28.2
    "test_failures.py",                 # 24.7
    "test_sweep_fit.py",                # 23.0
    "test_describe_real.py",            # 20.8
    "test_readme.py",                   # 17.8
    "test_target.py",                   # 16.2
    "test_generic_cpu.py",              # 14.8 (one child pytest)
    "test_characterize.py",             # 14.3
    "test_compare.py",                  # 11.1
    "test_fuzz.py",                     # 10.2
    "test_describe_corpus.py",          # 10.0
    "test_realdata_noise.py",           # 9.5
    "test_demo.py",                     # 9.2
    "test_misdescribed_real.py",        # 8.9
    "test_align.py",                    # 8.5
    "test_describe_kamino.py",          # 7.9
    "test_decoding_checks.py",          # 7.6
)


def pytest_configure(config):
    # pytest-xdist >= 3.6 reorders the files by their number of tests, largest first,
    # unless told not to: HEAVY_FIRST (few tests, most CPU) would then start last and leave
    # one worker running them alone at the end.
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable sort


# ----------------------------------------------------------- CPU time per test (opt-in)
# SCANQA_TEST_CPU_LOG=FILE appends "seconds<TAB>nodeid" per test: the CPU time of this
# process (all its threads) and of the child processes it waited for, setup to teardown.
# Unlike --durations it does not grow when other jobs load the machine; docs/benchmarks.rst
# ("The test suite") sums it per file (tools/test_cpu_times.py).
_CPU_LOG = os.environ.get("SCANQA_TEST_CPU_LOG")


def _cpu_now() -> float:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    start = _cpu_now() if _CPU_LOG else 0.0
    yield
    if _CPU_LOG:
        with open(_CPU_LOG, "a", encoding="utf-8") as fh:
            fh.write(f"{_cpu_now() - start:.3f}\t{item.nodeid}\n")
