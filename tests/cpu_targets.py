"""Compiled (numba) against numpy on more than one CPU: tolerances and the generic target.

A numba loop and the numpy expressions it replaces may round differently on another CPU:
numpy picks SIMD kernels for its reductions, ``einsum`` and transcendental functions at
run time (AVX2, AVX-512, NEON), BLAS picks a kernel per CPU, and LLVM uses fused
multiply-adds only where the CPU has them. A test that compares the two paths therefore
(a) allows the rounding that the operations can give, :func:`op_bound`, and compares
exactly only what is provably the same on every IEEE-754 machine (integers, sort orders,
booleans away from a threshold, the same basic operations in the same order without
contraction), and (b) runs twice: on this CPU, and in a child pytest with numba
compiling for the ``generic`` x86-64/aarch64 target (no FMA, no AVX), where a
CPU-specific difference shows up on this machine too (:func:`run_under_generic_cpu`).

Tests of that kind carry ``@pytest.mark.compiled_vs_numpy``; tests/test_generic_cpu.py
reruns all of them there, in one child process.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Set in the child pytest of :func:`run_under_generic_cpu`.
GENERIC_ENV = "SCANQA_TEST_CPU_TARGET"


def op_bound(n_ops: int, magnitude, dtype=np.float64, ulps: float = 2.0):
    """Largest difference two CPUs may give a result of ``n_ops`` operations [units of
    ``magnitude``].

    Each correctly rounded operation errs by at most half an ulp of its result, a libm or
    SIMD transcendental (log, exp) by at most 2 ulp; summing in another order or with a
    fused multiply-add moves a partial sum by at most one rounding of the largest operand.
    So ``ulps`` (2) units of ``eps * magnitude`` per operation, where ``magnitude`` is
    the size of the largest operand (the terms of a sum, not the sum, so cancellation is
    covered), bounds the difference between any two evaluation orders.
    """
    return ulps * n_ops * np.finfo(dtype).eps * np.asarray(magnitude, float)


def generic_child() -> bool:
    """True inside the child pytest that runs on numba's generic CPU target."""
    return os.environ.get(GENERIC_ENV) == "generic"


def marked_files() -> list[Path]:
    """The test files that hold ``compiled_vs_numpy`` tests (by the marker's text)."""
    return sorted(p for p in (ROOT / "tests").glob("test_*.py")
                  if "mark.compiled_vs_numpy" in p.read_text(encoding="utf-8"))


def run_under_generic_cpu(*test_files: str | Path) -> None:
    """Rerun the ``compiled_vs_numpy`` tests of ``test_files`` in one child pytest with
    numba compiling for the generic CPU (``NUMBA_CPU_NAME=generic``,
    ``NUMBA_CPU_FEATURES`` unset); fail with the child's report when any of them fails.
    Inside that child, check the target instead.

    numba caches a compiled function per CPU name (``make setup`` compiles them ahead,
    tools/warm_numba.py), so the child pays its start-up (~4 s of CPU) and the
    comparisons themselves.
    """
    if generic_child():
        import numba

        assert numba.config.CPU_NAME == "generic", numba.config.CPU_NAME
        return
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CPU_FEATURES", "PYTEST_ADDOPTS", "PYTEST_XDIST_WORKER",
                        "SCANQA_TEST_CPU_LOG")}  # the parent counts the child's CPU
    env.update(NUMBA_CPU_NAME="generic", **{GENERIC_ENV: "generic"})
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT / "src"), env.get("PYTHONPATH"))
                                        if p)
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
         "-p", "no:xdist", "-m", "compiled_vs_numpy", "--rootdir", str(ROOT),
         *(str(Path(f).resolve()) for f in test_files)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, (
        f"on numba's generic CPU target:\n{proc.stdout[-6000:]}\n{proc.stderr[-2000:]}")
