"""numba where it is installed, plain Python where it is not.

numba compiles scanqa's per-sample loops (the simulator's ray kernels, the annotate
loop); it is an optional speed-up, so every compiled function imports its decorator from
here. Without numba, :func:`njit` returns the function unchanged and :data:`HAVE_NUMBA`
is False: callers with a vectorised numpy path take it instead of a Python loop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

try:  # numba is optional: pip install 'scanqa[fast]'
    from numba import njit as _numba_njit
except ImportError:  # pragma: no cover - exercised in the lean-install check
    _numba_njit = None

#: True when numba is importable and :func:`njit` compiles.
HAVE_NUMBA = _numba_njit is not None


def njit(*args: Any, **kwargs: Any) -> Any:
    """numba's ``njit`` when numba is installed, else the identity decorator.

    Parameters
    ----------
    *args, **kwargs
        What ``numba.njit`` takes: the function itself, or its options (``cache``,
        ``nogil``, ...), as ``@njit`` or ``@njit(cache=True)``.

    Returns
    -------
    callable
        The compiled function (a numba dispatcher, with ``.py_func`` the Python one), the
        decorator, or without numba the function itself.
    """
    if _numba_njit is not None:
        return _numba_njit(*args, **kwargs)
    if len(args) == 1 and callable(args[0]) and not kwargs:
        return args[0]

    def identity(func: Callable[..., Any]) -> Callable[..., Any]:
        return func
    return identity


def jitable(func: Callable[..., Any]) -> Callable[..., Any]:
    """``func``, callable from compiled code too (numba's ``register_jitable``): Python
    callers run it as written, on floats or numpy arrays (:mod:`scanqa.model.equations`)."""
    if _numba_njit is None:
        return func
    from numba.extending import register_jitable
    return register_jitable(func)
