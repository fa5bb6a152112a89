"""Argument helpers shared by the subcommands (parsing only)."""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path

from scanqa.calibration.base import Calibration, load_calibration
from scanqa.config import ScannerConfig, load_config
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io.atomic import check_out_dir


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
        from scanqa.characterization import apply_fitted_model

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


def calibration_from_args(args: argparse.Namespace, config: ScannerConfig, scan: PhaseMap
                          ) -> Calibration:
    """Load ``--calibration`` for ``scan`` (its fringe orientation) and ``config`` (the sizes
    an OpenCV file may lack)."""
    depth = args.depth_range_mm or [0.0, math.inf]
    if len(depth) != 2:
        raise InputError(f"--depth-range-mm takes NEAR,FAR [mm], got {depth}")
    return load_calibration(args.calibration, config, scan.orientation, tuple(depth))


def float_list(text: str) -> list[float]:
    """argparse type: '0.25,0.49' -> [0.25, 0.49]."""
    try:
        values = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one number")
    return values


def add_output_arguments(parser: argparse.ArgumentParser, plot: bool = True) -> None:
    """``--json``, ``--csv`` and (optionally) ``--plot FILE.png``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--json", action="store_true", help="print rows as JSON")
    group.add_argument("--csv", action="store_true", help="print rows as CSV")
    if plot:
        parser.add_argument("--plot", metavar="FILE.png", default=None,
                            help="also write a PNG plot to this file")


def _clean(value: object) -> object:
    """JSON-safe value: NaN and inf become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def format_rows(rows: Sequence[dict], as_json: bool, as_csv: bool) -> str:
    """Rows as JSON, CSV or an aligned text table."""
    if as_json:
        return json.dumps([{k: _clean(v) for k, v in r.items()} for r in rows], indent=1)
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
