"""``scanqa characterize``: ``sweep`` fits the noise model to a simulated or measured sweep,
``board`` finds a real scanner's noise from its calibration board's poses, ``repeats``
from repeated captures of one pose (parsing only; :mod:`scanqa.characterize` does the
work)."""

from __future__ import annotations

import argparse
import csv
import io
import json
from pathlib import Path

from scanqa.cli.common import (
    add_actions,
    add_calibration_argument,
    add_config_argument,
    calibration_from_args,
    config_from_args,
    emit,
    flags,
    number,
)
from scanqa.errors import InputError

_FMT = argparse.RawDescriptionHelpFormatter
_EPILOG = """examples:
  scanqa characterize board pose1/ pose2/ pose3/ --calibration calibration.xml \\
      --config scanner.toml --board 9x13 --out board_noise
  scanqa annotate scan/ --calibration calibration.xml --config scanner.toml \\
      --model board_noise/summary.json --out cloud.ply

Each POSE is a pattern folder (frames + patterns.toml) or a decoded phase.npz of the
chessboard at one pose, with the fringes across it; a pose is named by its folder
(pose1/phase.npz is pose1). --board gives the inner corners as ROWSxCOLS, as calibrate
does. The calibration's baseline must agree with the config's projector position_mm.
Writes summary.json (the noise law
that --model takes, each pose predicted by the others, the smooth part and the
phase-locked ripple per pose) and cells.csv."""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``scanqa characterize`` and its three sources of noise."""
    group = sub.add_parser(
        "characterize", formatter_class=_FMT,
        help="the scanner's noise, measured and fitted: from a sweep, board poses or repeats",
        description="Measure the scanner's noise and fit the model to it: from a sweep of a "
                    "flat (sweep), from the calibration board's poses (board) or from "
                    "repeated captures of one pose (repeats).",
        epilog="examples:\n  scanqa characterize sweep cam --out cam/characterize\n"
               "  scanqa characterize board pose1/ pose2/ --calibration calibration.xml "
               "--config scanner.toml --out board_noise")
    actions = add_actions(group)
    p = actions.add_parser(
        "sweep", formatter_class=_FMT,
        help="fit the noise model to a simulated or measured sweep and say what the data "
             "identify",
        description="Decode a camera, projector or calibration sweep, fit a low-order "
                    "surface to the flat's x_p map per position, compare the residual std "
                    "and the attenuation with the model (Figs. 3/4), and fit every variant "
                    "of the model (the paper's readings and the two-source model). Each "
                    "parameter is reported as fitted, bounded or not identifiable with its "
                    "95 % profile-likelihood interval; the variant that predicts held-out "
                    "positions best is selected and compared with a constant. Several "
                    "sweeps are fitted together.",
        epilog="The scanner config defaults to the one recorded in the sweep's manifest; a "
               "--config given must have the same camera and projector.\n\n"
               "examples:\n  scanqa characterize sweep cam --out cam/characterize\n"
               "  scanqa characterize sweep cam proj --config calib/paper_scanner.toml "
               "--out both\n"
               "  scanqa characterize sweep sweep/sweep.toml   # a rigid scanner's "
               "calibration sweep")
    p.add_argument("sweep", metavar="SWEEP", nargs="+",
                   help="folder(s) written by scanqa simulate camera-sweep/projector-sweep, "
                        "or a calibration sweep's sweep.toml (both devices defocus)")
    add_config_argument(p, required=False)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="folder for summary.json and plots (default: SWEEP_DIR/characterize)")
    p.add_argument("--min-attenuation", type=number(gt=0), default=0.49,
                   help="fit where the moving devices' model attenuation is at least this "
                        "[-] (default 0.49)")
    p.set_defaults(func=run_sweep)

    p = actions.add_parser("board", formatter_class=_FMT,
                           help="a real scanner's per-point noise from its board poses "
                                "(no stage)",
                           epilog=_EPILOG)
    p.add_argument("poses", nargs="+", metavar="POSE", help="board poses (>= 2)")
    add_calibration_argument(p)
    add_config_argument(p)
    p.add_argument("--board", default="9x13", metavar="ROWSxCOLS",
                   help="inner corners (saddle points) of the chessboard, rows x columns as "
                        "for calibrate (default 9x13)")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run_board)
    r = actions.add_parser("repeats", formatter_class=_FMT,
                           help="a scanner's per-pixel noise law from repeated captures of "
                                "one pose",
                           epilog="example:\n  scanqa characterize repeats rep0/ rep1/ rep2/ --out "
                              "noise\n\nEach SCAN is a pattern folder or phase.npz of the same "
                              "static scene (each a separate capture; nothing moved between "
                              "them: repeats that differ beyond their noise are refused). "
                              "Writes summary.json (the law --model takes, fitted "
                              "to the even image rows and checked on the odd ones).")
    r.add_argument("scans", nargs="+", metavar="SCAN", help="repeated captures (>= 2)")
    r.add_argument("--out", required=True, help="output folder")
    r.set_defaults(func=run_repeats)


def _board(text: str) -> tuple[int, int]:
    """``ROWSxCOLS`` -> (rows, cols)."""
    try:
        rows, cols = (int(v) for v in text.lower().split("x"))
    except ValueError:
        cols = rows = 0
    if cols < 2 or rows < 2:
        raise InputError(f"--board takes inner corners as ROWSxCOLS (e.g. 9x13), got {text!r}")
    return rows, cols


def board_notice(rows: int, cols: int) -> str:
    """A one-line notice when ``--board ROWSxCOLS`` looks like the old COLSxROWS order
    (more rows than columns, as the old default 13x9 for a board of 9 rows), else ""."""
    if rows <= cols:
        return ""
    return (f"note: --board {rows}x{cols} is read as ROWSxCOLS ({rows} rows x {cols} columns "
            "of inner corners), as calibrate reads it; characterize board read COLSxROWS "
            "before. The board is found in either orientation, so it fits the same board as "
            f"{cols}x{rows}")


def run_sweep(args: argparse.Namespace) -> int:
    from scanqa.characterization.sweep import characterize_sweeps, sweep_config, sweep_folder
    from scanqa.report.characterization import characterization_lines, write_characterization

    with flags({"leave the config out": "leave --config out",
                "give the config the sweep was made with":
                    "give the config the sweep was made with (--config)"}):
        config = config_from_args(args) if args.config else sweep_config(args.sweep[0])
        result = characterize_sweeps(args.sweep, config, min_attenuation=args.min_attenuation)
    default = sweep_folder(args.sweep[0]) / "characterize"
    out = write_characterization(result, args.out or default, config)
    summary = result.summary()
    emit(summary["verdict"])
    for line in characterization_lines(summary):
        emit(f"  {line}")
    emit(f"wrote {out}")
    return 0


def run_board(args: argparse.Namespace) -> int:
    from scanqa.characterization.board import characterize_board, digest
    from scanqa.characterization.checks import check_scale, pose_keys
    from scanqa.decoding.decoder import decode
    from scanqa.io.atomic import staged_dir, write_text
    from scanqa.io.opencv import require_opencv
    from scanqa.progress import Progress, step_messages

    require_opencv("characterize board (its corner detector)")
    rows, cols = _board(args.board)
    inner = (cols, rows)  # per row, per column
    notice = board_notice(rows, cols)
    if notice:
        emit(notice)
    config = config_from_args(args)
    keys = pose_keys(list(args.poses))
    if len(keys) < 2:
        raise InputError(f"a board characterisation needs >= 2 poses (one held out at a "
                         f"time), got {len(keys)}")
    poses = {name: decode(p) for name, p in keys.items()}
    calibration = calibration_from_args(args, config, next(iter(poses.values())))
    with flags({"wrong square size": "wrong --square-mm"}):
        check_scale(calibration, config, args.calibration)
    with flags({"check the board given": "check --board"}), \
            Progress("characterize board", total=len(poses), unit="pose") as bar:
        result = characterize_board(poses, calibration, inner, progress=step_messages(bar))
    files = [f for pm in poses.values() for f in _files(pm)]
    result["noise_law"]["data_sha256"] = digest(files) if files else ""
    law = result["noise_law"]
    emit(f"noise law: a = {law['read_var_dn2']:.4g} DN^2, b = {law['shot_dn']:.4g} DN; "
         f"systematic {law['systematic_um']:.1f} um")
    rows = result["held_out"]
    for r in rows:
        emit(f"  {r['pose']} {r['colour']}: measured {r['measured_random_um']:.1f} um, "
             f"predicted (held out) {r['predicted_um']:.1f} um, ratio {r['ratio_random']:.3f}")
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    with staged_dir(args.out) as out:
        write_text(out / "summary.json", json.dumps(result, indent=1))
        write_text(out / "cells.csv", text.getvalue())
    emit(f"wrote {Path(args.out) / 'summary.json'} (use it with --model)")
    return 0


def run_repeats(args: argparse.Namespace) -> int:
    from scanqa.characterization.board import characterize_repeats, digest
    from scanqa.characterization.checks import check_repeats, frame_levels
    from scanqa.decoding.decoder import decode
    from scanqa.io.atomic import staged_dir, write_text

    if len(args.scans) < 2:
        raise InputError(f"repeats need >= 2 captures of one pose, got {len(args.scans)}")
    check_repeats([], list(args.scans))  # the same folder twice, before decoding
    scans = [decode(s) for s in args.scans]
    shapes = {s.xp.shape for s in scans}
    if len(shapes) > 1:
        raise InputError(f"the repeats differ in size ({sorted(shapes)}): they must be "
                         "captures of one pose by one camera")
    files = [_files(pm) for pm in scans]
    frames = [list(zip(f, frame_levels(f), strict=True)) for f in files] \
        if all(files) and all(Path(f).is_file() for fs in files for f in fs) else None
    check_repeats(scans, list(args.scans), frames)
    result = characterize_repeats(scans)
    files = [f for pm in scans for f in _files(pm)]
    result["noise_law"]["data_sha256"] = digest(files) if files else ""
    result["noise_law"]["sources"] = list(args.scans)
    law, held = result["noise_law"], result["held_out"]
    emit(f"noise law: a = {law['read_var_dn2']:.4g} DN^2, b = {law['shot_dn']:.4g} DN; "
         f"held-out rows: measured/predicted median {held['median_ratio']:.3f}")
    with staged_dir(args.out) as out:
        write_text(out / "summary.json", json.dumps(result, indent=1))
    emit(f"wrote {Path(args.out) / 'summary.json'} (use it with --model)")
    return 0


def _files(phase_map) -> list[str]:
    """The image files a decoded scan came from (its provenance)."""
    prov = phase_map.provenance
    base = Path(prov.get("patterns_file", ".")).parent
    sets = prov.get("patterns", {}).get("set", [])
    return [str(base / f) for s in sets for f in s.get("files", [])]
