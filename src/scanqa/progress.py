"""Progress of long loops and the ``scanqa`` logger: one style everywhere.

Library code logs through ``logging.getLogger(__name__)`` (a child of the ``"scanqa"``
logger) and never prints. A long loop wraps itself in :class:`Progress`, which shows

* a tqdm bar on stderr when stderr is a terminal,
* one INFO log line per finished step otherwise (log files stay readable: no ``\\r``),
* nothing when the ``scanqa`` logger is not enabled for INFO (``scanqa -q``, or a
  Python program that did not configure logging).

:func:`configure_logging` is what the command line calls for ``-v`` (DEBUG), the default
(INFO) and ``-q`` (WARNING and errors only). Log records go through ``tqdm.write``, so a
message never lands in the middle of a bar, and a bar is closed (its line ended) before
an error reaches the caller.
"""

from __future__ import annotations

import logging
import math
import os
import sys
from collections.abc import Callable
from types import TracebackType

from tqdm import tqdm

#: Name of the package logger; every module logs to a child of it.
LOGGER = "scanqa"
#: Levels of ``-q``, the default and ``-v``.
QUIET, NORMAL, VERBOSE = -1, 0, 1
_LEVELS = {QUIET: logging.WARNING, NORMAL: logging.INFO, VERBOSE: logging.DEBUG}

log = logging.getLogger(LOGGER)


class _TqdmHandler(logging.StreamHandler):
    """Writes records to stderr through ``tqdm.write`` (bars are cleared and redrawn)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # logging's own contract: a handler never raises
            self.handleError(record)


class _Formatter(logging.Formatter):
    """INFO as the bare message; DEBUG with the module; warnings flagged as such."""

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"scanqa: warning: {msg}"
        if record.levelno <= logging.DEBUG:
            return f"debug {record.name}: {msg}"
        return msg


def configure_logging(verbosity: int = NORMAL) -> None:
    """Send the ``scanqa`` logger to stderr at the level of ``verbosity``.

    Parameters
    ----------
    verbosity : int
        :data:`QUIET` (-1: warnings and errors), :data:`NORMAL` (0: progress and
        notes) or :data:`VERBOSE` (1: debug details) [-].
    """
    level = _LEVELS[max(QUIET, min(VERBOSE, int(verbosity)))]
    for handler in [h for h in log.handlers if isinstance(h, _TqdmHandler)]:
        log.removeHandler(handler)
    handler = _TqdmHandler()
    handler.setFormatter(_Formatter())
    log.addHandler(handler)
    log.setLevel(level)
    log.propagate = False


class Progress:
    """Progress of a loop of ``total`` steps (module notes for where it shows).

    Parameters
    ----------
    desc : str
        What runs, e.g. ``"calibrate"``; starts every line.
    total : int, optional
        Number of steps [-]; None when unknown.
    unit : str
        Name of one step, e.g. ``"scan"``.
    logger : logging.Logger, optional
        Where log-mode lines go (default the ``scanqa`` logger).
    enabled : bool
        False shows nothing (a caller's own switch).

    Examples
    --------
    >>> with Progress("demo", total=2, unit="stage") as bar:
    ...     for name in ("load", "fit"):
    ...         bar.update(1, note=name)
    """

    def __init__(self, desc: str, total: int | None = None, unit: str = "step",
                 logger: logging.Logger | None = None, enabled: bool = True) -> None:
        self.desc, self.total, self.unit = desc, total, unit
        self.logger = logger or log
        self.done = 0.0
        self._bar = None
        self._shown = enabled and self.logger.isEnabledFor(logging.INFO)
        if self._shown and _is_terminal():
            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr,
                             dynamic_ncols=True, leave=None)  # an inner bar is erased when done

    def update(self, n: float = 1, note: str = "") -> None:
        """Count ``n`` more steps (fractions allowed) [-]; ``note`` names what finished."""
        before, self.done = self.done, self.done + n
        if not self._shown:
            return
        if self._bar is not None:
            if note:
                self._bar.set_postfix_str(note, refresh=False)
            self._bar.update(n)
        elif math.floor(self.done + 1e-9) > math.floor(before + 1e-9):
            count = f"{math.floor(self.done + 1e-9)}" + (f"/{self.total}" if self.total else "")
            self.logger.info(f"{self.desc}: {self.unit} {count}" + (f" ({note})" if note else ""))

    def close(self) -> None:
        """End the bar's line (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type | None, err: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def step_messages(bar: Progress) -> Callable[[str], None]:
    """A ``progress(message)`` callback, as the library's per-step loops take (board
    poses, ...), that advances ``bar`` one step with the message as its note: a bar in
    a terminal, one log line per step in logs, instead of a line per step everywhere.

    Examples
    --------
    >>> with Progress("calibrate", total=2, unit="pose") as bar:
    ...     tell = step_messages(bar)
    ...     tell("pose 1: 117 corners")
    ...     tell("pose 2: 117 corners")
    """
    return lambda message: bar.update(1, note=message)


def _is_terminal() -> bool:
    """stderr is a terminal with a width (a pseudo-terminal of zero columns, as some
    runners give, would show no bar at all: it gets log lines)."""
    try:
        return sys.stderr.isatty() and os.get_terminal_size(sys.stderr.fileno()).columns > 0
    except (AttributeError, ValueError, OSError):  # a replaced or closed stderr
        return False
