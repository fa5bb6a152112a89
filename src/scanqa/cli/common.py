"""Argument helpers shared by the subcommands (parsing only)."""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from scanqa.calibration.base import Calibration, load_calibration
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError, OutputError, ScanQAError
from scanqa.io.atomic import check_out_dir
from scanqa.io.opencv import is_opencv_file, require_opencv
from scanqa.model.config import ScannerConfig, load_config
from scanqa.numeric import json_ready


def verbosity_parent() -> argparse.ArgumentParser:
    """The ``-v``/``-q`` options every subcommand takes (added by :mod:`scanqa.cli`)."""
    parent = argparse.ArgumentParser(add_help=False)
    group = parent.add_argument_group("messages")
    group.add_argument("-v", "--verbose", action="store_true",
                       help="also print debug details on stderr")
    group.add_argument("-q", "--quiet", action="store_true",
                       help="no progress and notes on stderr, only warnings and errors")
    return parent


def add_actions(parser: argparse.ArgumentParser) -> argparse._SubParsersAction:
    """The sub-commands of a command (``scanqa design dof``); the command given alone
    prints its help and exits 2."""
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    return parser.add_subparsers(dest="action", metavar="ACTION", parser_class=type(parser))


@contextlib.contextmanager
def flags(names: dict[str, str]):
    """Re-raise a library error in this command's words: the library names its parameter
    (or the thing given), the CLI the flag that sets it.

    Parameters
    ----------
    names : dict
        Text of the library's message -> the text that replaces it (naming the flag).

    Examples
    --------
    >>> with flags({"give width_px": "give --projector-width"}):  # doctest: +SKIP
    ...     describe_frames(frames, names)
    """
    try:
        yield
    except ScanQAError as err:
        text = str(err)
        for old, new in names.items():
            text = text.replace(old, new)
        if text == str(err):
            raise
        raise type(err)(text) from None


class StdoutClosed(Exception):
    """The reader of stdout went away (``scanqa design curve | head -1``)."""


def silence_stdout() -> None:
    """Point the process's stdout at /dev/null, so that the interpreter's last flush of
    output nobody can take does not fail again at exit."""
    if sys.stdout is not sys.__stdout__ or sys.stdout is None:
        return
    with contextlib.suppress(OSError, ValueError):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)


def emit(text: str = "") -> None:
    """Print one result line (or block) on stdout, flushed.

    Raises
    ------
    StdoutClosed
        When the reader of a pipe went away.
    OutputError
        When stdout cannot be written (a full disk, /dev/full).
    """
    try:
        sys.stdout.write(text + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        silence_stdout()
        raise StdoutClosed from None
    except OSError as err:
        silence_stdout()
        raise OutputError(f"cannot write to standard output: {err.strerror or err}") from None


def warn(text: str) -> None:
    """Print ``scanqa: warning: <text>`` on stderr (the result lines stay on stdout)."""
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.write(f"scanqa: warning: {text}\n")
        sys.stderr.flush()


def warn_sigma(clouds) -> None:
    """Warn once per distinct message about clouds whose sigmas are not characterised
    (:attr:`scanqa.io.annotated_cloud.AnnotatedCloud.sigma_warning`)."""
    for text in dict.fromkeys(c.sigma_warning for c in clouds if c.sigma_warning):
        warn(text)


def number(kind: type = float, *, gt: float | None = None, ge: float | None = None,
           unit: str = "") -> Callable[[str], float]:
    """argparse type: a finite number (``kind`` float or int) with an optional bound."""
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") from None
        bound = (f"> {gt:g}" if gt is not None else f">= {ge:g}" if ge is not None else "")
        ok = math.isfinite(value) and (gt is None or value > gt) and (ge is None or value >= ge)
        if not ok:
            what = f"a finite number {bound}".rstrip() + (f" {unit}" if unit and bound else "")
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value
    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def add_config_argument(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--config FILE`` and ``--profile NAME``."""
    parser.add_argument("--config", required=required, metavar="FILE",
                        help="scanner config TOML (e.g. calib/paper_scanner.toml); "
                             "FILE#PROFILE selects a profile")
    parser.add_argument("--profile", metavar="NAME", default=None,
                        help="apply the [profiles.NAME] table of the config (e.g. f11)")


def add_model_argument(parser: argparse.ArgumentParser) -> None:
    """``--model SUMMARY.json``: the model variant a characterisation supported."""
    parser.add_argument("--model", metavar="SUMMARY.json", default=None,
                        help="use the sigma_p, gamma and reading fitted by 'scanqa "
                             "characterize' (its summary.json) instead of the config's")


def config_from_args(args: argparse.Namespace) -> ScannerConfig:
    """Load the config named by ``--config``/``--profile`` (and ``--model`` if given)."""
    config = load_config(args.config, profile=args.profile)
    if getattr(args, "model", None):
        from scanqa.characterization.sweep import apply_fitted_model

        config = apply_fitted_model(config, args.model)
    return config


def add_calibration_argument(parser: argparse.ArgumentParser, required: bool = True,
                             when: str = "") -> None:
    """``--calibration FILE`` (old spelling ``--table``) and ``--depth-range-mm NEAR,FAR``."""
    parser.add_argument("--calibration", "--table", dest="calibration", required=required,
                        metavar="FILE",
                        help="calibration" + when + ": a table from 'scanqa calibrate' (.npz) "
                             "or an OpenCV camera-projector calibration (.xml, .yml, .yaml, "
                             ".json with Kc, kc, Kp, kp, Rp, Tp); --table is the old spelling")
    parser.add_argument("--depth-range-mm", type=float_list, default=None, metavar="NEAR,FAR",
                        help="with an OpenCV calibration: the Z range [mm] counted as in "
                             "volume (default: everything in front of both devices)")
    term = parser.add_mutually_exclusive_group()
    term.add_argument("--calibration-covariance", metavar="FILE", default=None,
                      help="with an OpenCV calibration: its parameters' covariance "
                           "(.json or .npz, docs/formats.rst; 'calibrate --board' writes "
                           "one beside its result), the calibration term of every point")
    term.add_argument("--calibration-sigma-um", type=number(ge=0, unit="um"), default=None,
                      metavar="UM", help="with an OpenCV calibration without covariance: a "
                      "stated std of every point from the calibration's own error [um]")


def check_calibration_extra(args: argparse.Namespace) -> None:
    """Refuse, before any work, a ``--calibration`` OpenCV file when OpenCV is absent
    (every command's arguments pass here first; :func:`scanqa.io.opencv.require_opencv`)."""
    value = getattr(args, "calibration", None)
    if isinstance(value, str | os.PathLike) and is_opencv_file(value):
        require_opencv(f"--calibration {Path(value).suffix} (an OpenCV calibration file)")


def calibration_from_args(args: argparse.Namespace, config: ScannerConfig, scan: PhaseMap
                          ) -> Calibration:
    """Load ``--calibration`` for ``scan`` (its fringe orientation) and ``config`` (the sizes
    an OpenCV file may lack)."""
    depth = args.depth_range_mm or [0.0, math.inf]
    if len(depth) != 2:
        raise InputError(f"--depth-range-mm takes NEAR,FAR [mm], got {depth}")
    return load_calibration(args.calibration, config, scan.orientation, tuple(depth),
                            **calibration_term_args(args))


def calibration_term_args(args: argparse.Namespace) -> dict:
    """``--calibration-covariance`` / ``--calibration-sigma-um`` as the ``covariance`` and
    ``sigma_um`` of :func:`~scanqa.calibration.base.load_calibration`."""
    return {"covariance": getattr(args, "calibration_covariance", None),
            "sigma_um": getattr(args, "calibration_sigma_um", None)}


def float_list(text: str) -> list[float]:
    """argparse type: '0.25,0.49' -> [0.25, 0.49]."""
    try:
        values = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one number")
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def add_output_arguments(parser: argparse.ArgumentParser, plot: bool = True) -> None:
    """``--json``, ``--csv`` and (optionally) ``--plot FILE.png``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--json", action="store_true", help="print rows as JSON")
    group.add_argument("--csv", action="store_true", help="print rows as CSV")
    if plot:
        parser.add_argument("--plot", metavar="FILE.png", default=None,
                            help="also write a PNG plot to this file")


def format_rows(rows: Sequence[dict], as_json: bool, as_csv: bool) -> str:
    """Rows as JSON, CSV or an aligned text table."""
    if as_json:
        return json.dumps([json_ready(r) for r in rows], indent=1)
    if not rows:
        return ""
    keys = list(rows[0])
    if as_csv:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        return buf.getvalue().rstrip("\n")
    cells = [[_fmt(r[k]) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(cell, widths, strict=True)) for cell in cells]
    return "\n".join(lines)


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def output_path(text: str | None) -> Path | None:
    """Check that an output file's folder exists; None passes through."""
    return None if text is None else check_out_dir(text)
