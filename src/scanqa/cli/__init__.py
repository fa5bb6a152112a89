"""The ``scanqa`` command line: argument parsing only (load, call the library, write).

Each job has its own module here with ``register(subparsers)``; the module list below
is the one place that adds a command, and every command and sub-command gets ``-v``/``-q``
(:func:`scanqa.cli.common.verbosity_parent`). The commands follow the pipeline; the design
tools are ``scanqa design ...`` and the noise characterisations ``scanqa characterize ...``
(their old flat names, :data:`RENAMED`, still run, with a one-line notice). Every error a
user can cause is a :class:`~scanqa.errors.ScanQAError`, printed as ``scanqa: <message>``
with exit code 2 and no traceback; SIGTERM cleans up like Ctrl-C (temporaries and staged
outputs are removed) and exits 143.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

from scanqa._version import __version__
from scanqa.errors import ScanQAError

#: Modules that register commands, in the order ``--help`` lists them (the pipeline's),
#: with the commands each registers (tests/test_cli_startup.py holds the names to what the
#: modules add): ``scanqa design dof`` imports the one module that runs it, not all
#: fourteen, whose libraries (matplotlib, scipy.stats, numba, open3d) take seconds to load.
COMMANDS = {
    "scanqa.cli.init": ("init",),
    "scanqa.cli.simulate": ("simulate",),
    "scanqa.cli.patterns": ("patterns",),
    "scanqa.cli.describe": ("describe",),
    "scanqa.cli.decode": ("decode",),
    "scanqa.cli.sweep_manifest": ("sweep-manifest",),
    "scanqa.cli.calibrate": ("calibrate",),
    "scanqa.cli.characterize": ("characterize",),
    "scanqa.cli.annotate": ("annotate",),
    "scanqa.cli.qa": ("qa",),
    "scanqa.cli.compare": ("compare",),
    "scanqa.cli.design": ("design",),
    "scanqa.cli.batch": ("batch", "campaign"),
    "scanqa.cli.demo": ("demo",),
}
#: Commands renamed in 0.1 (issue 47), with the words they became. They run for one more
#: release, with a one-line notice on stderr; ``scanqa characterize SWEEP...`` (the sweep
#: form, from before ``characterize`` took sub-commands) likewise, see :func:`renamed`.
RENAMED = {
    "dof": ("design", "dof"),
    "curve": ("design", "curve"),
    "volume": ("design", "volume"),
    "flatten": ("design", "flatten"),
    "characterize-board": ("characterize", "board"),
    "characterize-repeats": ("characterize", "repeats"),
}
#: The sub-commands of ``scanqa characterize``: a first word after it that is none of
#: these (nor -h/-v/-q) is the old sweep form's SWEEP or option.
CHARACTERIZE = ("sweep", "board", "repeats")

log = logging.getLogger(__name__)


class Terminated(BaseException):
    """SIGTERM arrived: unwind like Ctrl-C so that every ``finally`` cleans up."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, like every other scanqa error."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"scanqa {self.prog.split(' ', 1)[-1]}: {message}\n"
                     f"(see 'scanqa {self.prog.split(' ', 1)[-1]} --help')\n"
                  if " " in self.prog else f"scanqa: {message}\n")


class _SubParsers(argparse._SubParsersAction):
    """Adds the shared ``-v``/``-q`` options to every subcommand."""

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        from scanqa.cli.common import verbosity_parent

        kwargs["parents"] = [*kwargs.get("parents", ()), verbosity_parent()]
        kwargs.setdefault("conflict_handler", "resolve")  # a subcommand may refine -q
        parser = super().add_parser(name, **kwargs)
        parser.register("action", "parsers", _SubParsers)  # sub-commands get -v/-q too
        return parser


def renamed(words: list[str]) -> list[str]:
    """The words of a command given by its old name (:data:`RENAMED`, or
    ``characterize SWEEP...``) in its new form, after a one-line notice on stderr naming
    the new command; other words as they are."""
    if words and words[0] in RENAMED:
        new = [*RENAMED[words[0]], *words[1:]]
        old, now = words[0], " ".join(RENAMED[words[0]])
    elif words[:1] == ["characterize"] and _old_characterize(words[1:]):
        new = ["characterize", "sweep", *words[1:]]
        old, now = "characterize SWEEP", "characterize sweep SWEEP"
    else:
        return words
    sys.stderr.write(f"scanqa: 'scanqa {old}' is now 'scanqa {now}'; the old form goes in "
                     "the next release\n")
    sys.stderr.flush()
    return new


def _old_characterize(rest: list[str]) -> bool:
    """Whether the words after ``characterize`` are its sweep form of before 0.1: the first
    that is not -v/-q is neither a sub-command nor -h (a SWEEP folder named like a
    sub-command is written ./sweep)."""
    first = next((w for w in rest if w not in ("-v", "--verbose", "-q", "--quiet")), None)
    return first is not None and first not in (*CHARACTERIZE, "-h", "--help")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered, or with only the module
    of ``command`` (a subcommand's name) when it is given."""
    parser = _Parser(prog="scanqa", description=(
        "Calibration-aware uncertainty toolkit for phase-shift 3D scanners."))
    parser.register("action", "parsers", _SubParsers)
    parser.add_argument("--version", action="version", version=f"scanqa {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, commands in COMMANDS.items():
        if command is None or command in commands:
            importlib.import_module(name).register(sub)
    return parser


@contextlib.contextmanager
def _sigterm_raises() -> Iterator[None]:
    """Turn SIGTERM into :class:`Terminated` while a command runs (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Terminated

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _fail(message: str) -> None:
    """One line on stderr, whatever the message holds (a library's text may have line
    breaks: pandas ends some of its errors with two)."""
    message = " ".join(message.split())
    sys.stderr.write(f"scanqa: {message}\n")
    sys.stderr.flush()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``scanqa`` console script; returns the exit code.

    The library is imported here, not when this module is (``import scanqa`` is lazy), so
    that Ctrl-C during start-up is "scanqa: interrupted" and exit 130, not a traceback.
    """
    try:
        return _main(argv)
    except KeyboardInterrupt:
        _fail("interrupted")
        return 130


def _main(argv: Sequence[str] | None) -> int:
    words = renamed(list(sys.argv[1:] if argv is None else argv))
    named = words[0] if words and any(words[0] in c for c in COMMANDS.values()) else None
    if words == ["--version"]:
        named = "--version"  # no subcommand's module is needed to print the version
    parser = build_parser(named)
    args = parser.parse_args(words)
    from scanqa.cli.common import StdoutClosed, silence_stdout
    from scanqa.progress import NORMAL, QUIET, VERBOSE, configure_logging

    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    configure_logging(QUIET if args.quiet else VERBOSE if args.verbose else NORMAL)
    from scanqa.io.guard import command_inputs

    try:
        with _sigterm_raises(), command_inputs():
            from scanqa.cli.common import check_calibration_extra

            check_calibration_extra(args)
            return int(args.func(args) or 0)
    except ScanQAError as err:
        _fail(str(err))
        return 2
    except StdoutClosed:  # 'scanqa design curve | head -1': stop quietly, like any Unix filter
        silence_stdout()
        return 141
    except OSError as err:  # the environment, not the input: say which file and why
        log.debug("OSError", exc_info=True)
        where = f"{err.filename}: " if err.filename else ""
        _fail(f"{where}{err.strerror or err}")
        return 2
    except KeyboardInterrupt:
        _fail("interrupted")
        return 130
    except Terminated:
        _fail("terminated")
        return 143


if __name__ == "__main__":
    sys.exit(main())
