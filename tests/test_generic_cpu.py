"""Every compiled-vs-numpy test again, with numba compiling for the generic CPU.

A numba loop and numpy may round differently on another CPU (tests/cpu_targets.py); the
generic target (no FMA, no AVX) shows such a difference on this machine. One child
pytest runs the ``compiled_vs_numpy`` tests of every file that has them.
"""

from __future__ import annotations

import os

import pytest

from .cpu_targets import generic_child, marked_files, run_under_generic_cpu


def test_compiled_vs_numpy_tests_pass_on_the_generic_cpu():
    files = marked_files()
    assert {p.name for p in files} >= {"test_simulator_raykernels.py", "test_annotkernels.py",
                                       "test_simulator_boxcast.py"}
    assert not generic_child()  # never collected by the child (not marked)
    run_under_generic_cpu(*files)


@pytest.mark.compiled_vs_numpy
def test_the_child_compiles_for_the_generic_cpu():
    # run here and in the child (this file holds a marked test): numba's target is the
    # one asked for, so the child's passes are the generic CPU's
    import numba

    want = "generic" if generic_child() else os.environ.get("NUMBA_CPU_NAME")
    assert numba.config.CPU_NAME == want
