"""Shared fixtures: the paper's scanner config."""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path

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
#: module fixtures are built once, and workers take files in collection order; started
#: first, the long files no longer leave one worker running alone at the end.
HEAVY_FIRST = (  # CPU seconds per file, measured 2026-11-27 (docs/benchmarks.rst)
    "test_closed_loop.py",      # 98.9
    "test_board_real.py",       # 90.5
    "test_board_gray.py",       # ~56 (wall, make test of 2026-11-27, session 41)
    "test_batch.py",            # 84.6 (LocalClusters)
    "test_flattening_real.py",  # 46.4
    "test_failures.py",         # 38.5
    "test_describe_real.py",    # 38.1
    "test_sweep_fit.py",        # 36.9
    "test_api.py",              # ~35 (wall, session 41)
    "test_compare.py",          # 31.0
    "test_demo.py",             # 25.6
    "test_realdata_noise.py",   # 23.7
    "test_characterize.py",     # 21.9
    "test_target.py",           # 18.8
    "test_fuzz.py",             # 17.6
)


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
