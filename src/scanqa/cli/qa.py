"""``scanqa qa``: gauge-block QA of an annotated cloud (or a scan + calibration)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from scanqa.annotation import annotate
from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    calibration_from_args,
    config_from_args,
    emit,
    number,
)
from scanqa.cloud import AnnotatedCloud, read_cloud
from scanqa.config import ScannerConfig
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io.atomic import staged_dir
from scanqa.qa.blocks import run_qa
from scanqa.qa.detect import detect_blocks
from scanqa.qa.layout import load_layout
from scanqa.report import qa as qa_report


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "qa", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="gauge-block QA: plane fits, measured vs predicted std, steps with U",
        epilog="examples:\n  scanqa qa cloud.ply --layout calib/gauge_blocks_paper.toml "
               "--out qa/\n  scanqa qa scan/phase.npz --calibration table.npz --config "
               "calib/paper_scanner.toml --layout calib/gauge_blocks_paper.toml --out qa/\n\n"
               "writes report.html, blocks.csv, steps.csv, summary.json, cloud_qa.ply")
    p.add_argument("cloud", metavar="CLOUD",
                   help="annotated cloud (.ply/.las/.csv) or, with --calibration, a scan")
    p.add_argument("--layout", help="block layout TOML (nominal heights and regions)")
    p.add_argument("--auto", action="store_true",
                   help="find the blocks by plane segmentation; match nominal heights from "
                        "--layout (regions ignored) or --heights")
    p.add_argument("--heights", default=None,
                   help="with --auto and no --layout: id=height_mm pairs, e.g. 1=50.8,2=25.4")
    add_calibration_argument(p, required=False, when=", when CLOUD is a scan")
    add_config_argument(p, required=False)
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--margin", type=number(ge=0, unit="mm"), default=1.0,
                   help="edge margin [mm] (default 1)")
    p.add_argument("--outliers", type=number(gt=0), default=None, metavar="K",
                   help="reject points beyond K robust std of the first plane fit "
                        "(default: no rejection)")
    p.add_argument("--tolerance", type=number(ge=0, unit="um"), default=20.0,
                   help="tolerance on each height difference [um] (default 20)")
    p.add_argument("--k", type=number(gt=0), default=2.0, help="coverage factor (default 2)")
    p.add_argument("--tile", type=number(gt=0, unit="mm"), default=2.0, metavar="MM",
                   help="tile size [mm] over which the noise correlation of each block is "
                        "measured; at least twice the noise's correlation length (default 2)")
    p.set_defaults(func=run)


def _load(args: argparse.Namespace) -> tuple[AnnotatedCloud, ScannerConfig | None]:
    if args.calibration:
        if not args.config:
            raise InputError("--calibration needs --config (the config the table was built "
                             "with, or that describes the calibrated scanner)")
        config = config_from_args(args)
        scan = decode(args.cloud)
        cloud = annotate(scan, calibration_from_args(args, config, scan), config,
                         keep_invalid=True, source=args.cloud)
        return cloud, config
    config = config_from_args(args) if args.config else None
    return read_cloud(args.cloud), config


def _heights(args: argparse.Namespace) -> dict[int, float]:
    if args.layout:
        return {b.block_id: b.nominal_height_mm for b in load_layout(args.layout).blocks}
    if not args.heights:
        raise InputError("--auto needs nominal heights: give --layout or --heights")
    try:
        pairs = [item.split("=") for item in args.heights.split(",")]
        heights = {int(k): float(v) for k, v in pairs}
    except ValueError:
        heights = {}
    if len(heights) != len(pairs) or not all(math.isfinite(h) and h > 0
                                              for h in heights.values()):
        raise InputError(f"--heights must look like 1=50.8,2=25.4 (distinct ids, heights "
                         f"> 0 mm), got {args.heights!r}")
    return heights


def run(args: argparse.Namespace) -> int:
    if not args.layout and not args.auto:
        raise InputError("give --layout FILE, or --auto to find the blocks")
    with staged_dir(args.out) as stage:  # every output, or none
        cloud, config = _load(args)
        layout = (detect_blocks(cloud.xyz, _heights(args)) if args.auto
                  else load_layout(args.layout))
        result = run_qa(cloud, layout, config=config, margin_mm=args.margin,
                        outlier_k=args.outliers, tolerance_um=args.tolerance, k=args.k,
                        tile_mm=args.tile)
        info = qa_report.write_outputs(result, stage)
    for b in result.blocks:
        emit(f"block {b.block_id}: {b.n_points} points, measured {b.measured_std_um:.1f} um, "
             f"predicted {b.predicted_std_um:.1f} um, {b.status}")
    for s in result.steps:
        emit(f"step {s.block_a}-{s.block_b}: error {s.error_um:+.1f} um, U {s.expanded_um:.1f}"
             f" um, {s.decision}")
    for note in result.notes:
        emit(f"note: {note}")
    frac = info["fraction_within_U"]
    emit(f"report: {Path(args.out) / 'report.html'}" + (
        f" ({100 * frac:.0f} % of steps inside the volume within U)" if frac is not None
        else ""))
    return 0
