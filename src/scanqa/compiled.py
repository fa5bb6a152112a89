"""numba where it is installed, plain Python where it is not.

numba compiles scanqa's per-sample loops (the simulator's ray kernels, the annotate
loop); it is an optional speed-up, so every compiled function imports its decorator from
here. Without numba, :func:`njit` returns the function unchanged and :data:`HAVE_NUMBA`
is False: callers with a vectorised numpy path take it instead of a Python loop.

``SCANQA_NO_NUMBA=1`` in the environment makes scanqa run as if numba were not
installed (the paths of a lean install), so that the tests can compare both paths on
one machine; numba is then not even imported.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import sys
from collections.abc import Callable
from typing import Any

#: The environment variable that, set to a non-empty value other than ``0``, makes
#: scanqa take its numpy paths even where numba is installed.
NO_NUMBA_ENV = "SCANQA_NO_NUMBA"
#: pip's name for numba in scanqa's extras (``pip install 'scanqa[fast]'``).
INSTALL_HINT = "pip install 'scanqa[fast]'"

#: True when numba is installed (and not switched off by :data:`NO_NUMBA_ENV`): then
#: :func:`njit` compiles. numba itself is imported only when a function is compiled, so
#: a command that compiles nothing (``scanqa design dof``) does not load it.
HAVE_NUMBA = (os.environ.get(NO_NUMBA_ENV, "0") in ("", "0")
              and importlib.util.find_spec("numba") is not None)
#: :func:`jitable` functions declared before numba was loaded, registered with it at the
#: first :func:`njit`.
_PENDING: list[Callable[..., Any]] = []


def _register_pending() -> None:
    from numba.extending import register_jitable
    while _PENDING:
        register_jitable(_PENDING.pop())


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
    if HAVE_NUMBA:
        from numba import njit as numba_njit
        _register_pending()
        return numba_njit(*args, **kwargs)
    if len(args) == 1 and callable(args[0]) and not kwargs:
        return args[0]

    def identity(func: Callable[..., Any]) -> Callable[..., Any]:
        return func
    return identity


def jitable(func: Callable[..., Any]) -> Callable[..., Any]:
    """``func``, callable from compiled code too (numba's ``register_jitable``): Python
    callers run it as written, on floats or numpy arrays (:mod:`scanqa.model.equations`)."""
    if HAVE_NUMBA:
        _PENDING.append(func)
        if "numba" in sys.modules:
            _register_pending()
    return func


_NOTED: set[str] = set()


def note_numpy_path(logger: logging.Logger, what: str) -> None:
    """Say once per process, at INFO, that ``what`` runs on numpy for want of numba.

    Parameters
    ----------
    logger : logging.Logger
        The caller's logger (a child of ``scanqa``: shown by the command line, silent in
        a program that did not configure logging).
    what : str
        What is slower, e.g. ``"the simulator (about 1.3 x the CPU)"``.
    """
    if HAVE_NUMBA or what in _NOTED:
        return
    _NOTED.add(what)
    logger.info(f"note: numba is not installed, so {what} runs on numpy; "
                f"{INSTALL_HINT} compiles it")
