"""``scanqa calibrate``: build a weighted calibration table from a plane sweep, or (with
``--board``) a camera-projector calibration from chessboard poses."""

from __future__ import annotations

import argparse
import json
import logging

import numpy as np

from scanqa.calibration.board import CORNER_METHODS, Board
from scanqa.calibration.board_fit import MODELS, calibrate_poses, check_baseline
from scanqa.calibration.build import WEIGHT_MODES
from scanqa.calibration.sweep import calibrate
from scanqa.calibration.table import save_table
from scanqa.cli.common import (
    add_config_argument,
    add_model_argument,
    config_from_args,
    emit,
    number,
)
from scanqa.decoding.parsing import load_patterns
from scanqa.errors import InputError
from scanqa.io.atomic import check_out_dir, staged_dir, write_text
from scanqa.io.covariance import write_covariance
from scanqa.io.opencv import (
    is_opencv_file,
    read_opencv_calibration,
    require_opencv,
    write_opencv_calibration,
)
from scanqa.io.sweep import load_sweep
from scanqa.progress import Progress, step_messages
from scanqa.report import board as report_board
from scanqa.report import calibration as report_calibration

log = logging.getLogger(__name__)  # progress: -q silences it


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="build a weighted nonparametric calibration table from a plane sweep",
        epilog="examples:\n  scanqa calibrate sample_data/calibration_sweep/sweep.toml "
               "--config sample_data/sample_scanner.toml#sample --out table.npz\n"
               "  scanqa calibrate --square-mm 10 --patterns columns.toml "
               "rows.toml calseq1 calseq3 calseq4 --out calibration.xml\n\n"
               "writes the table (or calibration) and, beside it, <stem>_report.html and "
               "<stem>_report.json")
    p.add_argument("sweep", metavar="SWEEP", nargs="+",
                   help="sweep manifest (sweep.toml) or its folder; with --board: the "
                        "folders of the board poses")
    add_config_argument(p, required=False)
    add_model_argument(p)
    p.add_argument("--out", required=True, metavar="TABLE.npz",
                   help="table file to write (with --square-mm: the OpenCV calibration, "
                        ".xml)")
    p.add_argument("--weights", choices=WEIGHT_MODES, default="model",
                   help="sample weights: optics model (default), decoder sigma_xp, or none")
    p.add_argument("--cell", type=number(int, ge=1, unit="px"), default=None, metavar="PX",
                   help="node spacing in u and v [camera px] (default: ~0.45 mm on the "
                        "object, at least 4 px)")
    p.add_argument("--min-modulation", type=number(ge=0, unit="DN"), default=0.0, metavar="DN",
                   help="reject samples with modulation below this [DN] (default: decoder "
                        "mask only)")
    p.add_argument("--no-markers", action="store_true",
                   help="ignore the sweep's marker frames: lateral X, Y from 'lateral' maps "
                        "or the config's pinhole (for comparison)")
    board = p.add_argument_group("board calibration (docs/calibration.rst, 'From a board')")
    board.add_argument("--board", metavar="ROWSxCOLS", type=_board_size, default=None,
                       help="inner corners (saddle points) the chessboard must have, e.g. "
                            "9x13 (optional: the grid is found in the frames; this checks it)")
    board.add_argument("--square-mm", type=number(gt=0, unit="mm"), default=None,
                       metavar="MM", help="side of a board square [mm]: calibrate camera "
                                          "and projector from board poses")
    board.add_argument("--patterns", nargs=2, metavar=("COLUMNS.toml", "ROWS.toml"),
                       help="patterns.toml of the column (vertical) and row (horizontal) "
                            "fringes; their file names are read in each pose folder")
    board.add_argument("--corners", choices=CORNER_METHODS, default="model",
                       help="the camera's corner detector: 'model' (default: a blurred "
                            "corner fitted in the mean of every frame) or 'opencv' "
                            "(findChessboardCornersSB's own sub-pixel corners)")
    board.add_argument("--lens-model", choices=MODELS, default="k1",
                       help="k1 (default: square pixels, radial k1, camera principal point "
                            "at the centre), k1k2, or full (k1 k2 p1 p2 k3)")
    board.add_argument("--hold-out", action="store_true",
                       help="also calibrate without each pose in turn and measure on it")
    board.add_argument("--reference", metavar="CALIBRATION.xml", default=None,
                       help="an OpenCV calibration of the same scanner to compare with")
    p.set_defaults(func=run)


def _board_size(text: str) -> tuple[int, int]:
    """argparse type: ROWSxCOLS inner corners."""
    try:
        rows, cols = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected ROWSxCOLS inner corners such as 9x13, got {text!r}") from None
    return rows, cols


def run(args: argparse.Namespace) -> int:
    if args.board is not None or args.square_mm is not None or args.patterns is not None:
        return run_board(args)
    if len(args.sweep) != 1 or args.config is None:
        raise InputError("a table is built from one sweep (SWEEP) and --config; board "
                         "poses need --square-mm and --patterns")
    args.sweep = args.sweep[0]
    config = config_from_args(args)
    out = check_out_dir(args.out)
    sweep = load_sweep(args.sweep)
    if sweep.has_markers and not args.no_markers:
        require_opencv("the printed target of a sweep's marker frames (--no-markers: "
                       "without them)")
    stem = out.with_suffix("").name
    with staged_dir(out.parent) as stage:  # the table and its reports, together or none
        table, report = calibrate(sweep, config, weights=args.weights, cell_px=args.cell,
                                  min_modulation=args.min_modulation,
                                  use_markers=not args.no_markers)
        save_table(stage / out.name, table)
        info = report_calibration.summary(table, report)
        write_text(stage / f"{stem}_report.json", json.dumps(info, indent=1))
        write_text(stage / f"{stem}_report.html", report_calibration.render(table, report))
    rej = ", ".join(f"{k} {v}" for k, v in report.rejected.items() if v) or "none"
    report_html = out.with_name(f"{stem}_report.html")
    median = info["table_sigma_um_median"]
    emit(f"table {out}: {sweep.observation_count()} scans at {len(sweep.positions)} positions, "
         f"{report.used_samples} samples used, rejected: {rej}; table sigma median "
         + (f"{median:.3g} um" if median is not None else "unknown")
         + f"; report {report_html}")
    err = info.get("target_geometry", {}).get("marker_error")
    if err and err["exceeds_bound"]:
        log.warning("the marker fit implies %.2f um of table error in %d %% of "
                    "sweeps, past the bound of %.2f um: capture %s marker frames per "
                    "position (see the report)", err["fit_error_quantile_um"],
                    round(100 * err["quantile"]), err["bound_um"],
                    err["frames_needed"] or "more")
    return 0


def run_board(args: argparse.Namespace) -> int:
    """Board poses: decode them, calibrate, write the file and its reports."""
    require_opencv("calibrate --board (its corner detector and OpenCV's solvers)")
    if args.square_mm is None or args.patterns is None:
        raise InputError("a board calibration needs --square-mm and --patterns "
                         "COLUMNS.toml ROWS.toml")
    out = check_out_dir(args.out)
    if not is_opencv_file(out):
        raise InputError(f"--out {out}: a board calibration is an OpenCV file (.xml, .yml, "
                         ".yaml or .json)")
    board = (args.square_mm if args.board is None
             else Board(args.board[0], args.board[1], args.square_mm))
    Board(2, 2, args.square_mm)  # the square size's range, before any pose is decoded
    reference = read_opencv_calibration(args.reference) if args.reference else None
    try:
        with Progress("calibrate", total=len(args.sweep), unit="pose") as bar:
            result = calibrate_poses(args.sweep, *(load_patterns(p) for p in args.patterns),
                                     board, args.lens_model, args.hold_out, reference,
                                     progress=step_messages(bar), corner_method=args.corners)
    except InputError as err:   # the library speaks of the board given; the CLI of --board
        raise InputError(str(err).replace("the board given", "--board").replace(
            "the board's corner count", "--board").replace(
            "give the board's ROWSxCOLS", "give --board ROWSxCOLS")) from None
    if args.config is not None:  # a wrong square size scales the baseline
        check_baseline(result.data, np.asarray(config_from_args(args).projector.position_mm,
                                               float), args.square_mm)
    stem = out.with_suffix("").name
    with staged_dir(out.parent) as stage:
        write_opencv_calibration(stage / out.name, result.data)
        if result.data.covariance is not None:  # the same term, for copies of the matrices
            write_covariance(stage / f"{stem}_covariance.json", result.data.covariance)
        write_text(stage / f"{stem}_report.json", json.dumps(report_board.summary(result),
                                                            indent=1))
        write_text(stage / f"{stem}_report.html", report_board.render(result))
    err = result.data.errors
    emit(f"calibration {out}: {len(result.poses)} poses, RMS camera {err['cam_error']:.3f} "
         f"px, projector {err['proj_error']:.3f} px, stereo {err['stereo_error']:.3f} px; "
         f"flagged: {', '.join(result.flagged) or 'none'}; report "
         f"{out.with_name(f'{stem}_report.html')}")
    return 0
