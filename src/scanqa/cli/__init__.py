"""The ``scanqa`` command line: argument parsing only (load, call the library, write).

Each job has its own module here with ``register(subparsers)``; the module list below
is the one place that adds a subcommand. Every error a user can cause is a
:class:`~scanqa.errors.ScanQAError`, printed as ``scanqa: <message>`` with exit code 2
and no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from scanqa._version import __version__
from scanqa.errors import ScanQAError

#: Modules that register subcommands, in the order ``--help`` lists them.
COMMAND_MODULES = (
    "scanqa.cli.init",
    "scanqa.cli.design",
    "scanqa.cli.sweep_manifest",
    "scanqa.cli.calibrate",
    "scanqa.cli.annotate",
    "scanqa.cli.qa",
    "scanqa.cli.demo",
    "scanqa.cli.patterns",
    "scanqa.cli.decode",
    "scanqa.cli.simulate",
)


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, like every other scanqa error."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"scanqa {self.prog.split(' ', 1)[-1]}: {message}\n"
                     f"(see 'scanqa {self.prog.split(' ', 1)[-1]} --help')\n"
                  if " " in self.prog else f"scanqa: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = _Parser(prog="scanqa", description=(
        "Calibration-aware uncertainty toolkit for phase-shift 3D scanners."))
    parser.add_argument("--version", action="version", version=f"scanqa {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``scanqa`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ScanQAError as err:
        print(f"scanqa: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("scanqa: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
