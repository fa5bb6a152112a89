"""``scanqa qa``: gauge-block QA of an annotated cloud (or a scan + table)."""

from __future__ import annotations

import argparse

from scanqa.annotation import annotate
from scanqa.calibration.table import load_table
from scanqa.cli.common import add_config_argument, add_model_argument, config_from_args
from scanqa.cloud import AnnotatedCloud, read_cloud
from scanqa.config import ScannerConfig
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io.atomic import make_out_dir
from scanqa.qa.blocks import run_qa
from scanqa.qa.budget import load_budget
from scanqa.qa.detect import detect_blocks
from scanqa.qa.layout import load_layout
from scanqa.report import qa as qa_report


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "qa", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="gauge-block QA: plane fits, measured vs predicted std, steps with U",
        epilog="examples:\n  scanqa qa cloud.ply --layout calib/gauge_blocks_paper.toml "
               "--out qa/\n  scanqa qa scan/phase.npz --table table.npz --config "
               "calib/paper_scanner.toml --layout calib/gauge_blocks_paper.toml --out qa/\n\n"
               "writes report.html, blocks.csv, steps.csv, budget.csv, summary.json, "
               "cloud_qa.ply")
    p.add_argument("cloud", metavar="CLOUD",
                   help="annotated cloud (.ply/.las/.csv) or, with --table, a scan")
    p.add_argument("--layout", help="block layout TOML (nominal heights and regions)")
    p.add_argument("--auto", action="store_true",
                   help="find the blocks by plane segmentation; match nominal heights from "
                        "--layout (regions ignored) or --heights")
    p.add_argument("--heights", default=None,
                   help="with --auto and no --layout: id=height_mm pairs, e.g. 1=50.8,2=25.4")
    p.add_argument("--table", help="calibration table, when CLOUD is a scan")
    add_config_argument(p, required=False)
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--margin", type=float, default=1.0, help="edge margin [mm] (default 1)")
    p.add_argument("--outliers", type=float, default=None, metavar="K",
                   help="reject points beyond K robust std of the first plane fit")
    p.add_argument("--tolerance", type=float, default=20.0,
                   help="tolerance on each height difference [um] (default 20)")
    p.add_argument("--k", type=_coverage, default=None,
                   help="coverage factor: a number, or welch-satterthwaite for k from each "
                        "step's effective degrees of freedom (default: the budget file's, "
                        "else 2)")
    p.add_argument("--budget", default=None, metavar="FILE",
                   help="uncertainty budget TOML with the Type B inputs (certificates, "
                        "temperature, stage scale, flatness of the calibration flat); "
                        "without it the report says Type B is not included")
    p.add_argument("--tile", type=float, default=2.0, metavar="MM",
                   help="tile size [mm] over which the noise correlation of each block is "
                        "measured; at least twice the noise's correlation length (default 2)")
    p.set_defaults(func=run)


def _coverage(text: str) -> float | str:
    if text == "welch-satterthwaite":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a number or welch-satterthwaite, got {text!r}") from None


def _load(args: argparse.Namespace) -> tuple[AnnotatedCloud, ScannerConfig | None]:
    if args.table:
        if not args.config:
            raise InputError("--table needs --config (the config the table was built with)")
        config = config_from_args(args)
        cloud = annotate(decode(args.cloud), load_table(args.table), config,
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
        return {int(k): float(v) for k, v in pairs}
    except ValueError:
        raise InputError(f"--heights must look like 1=50.8,2=25.4, got {args.heights!r}"
                         ) from None


def run(args: argparse.Namespace) -> int:
    if not args.layout and not args.auto:
        raise InputError("give --layout FILE, or --auto to find the blocks")
    out = make_out_dir(args.out)
    cloud, config = _load(args)
    layout = detect_blocks(cloud.xyz, _heights(args)) if args.auto else load_layout(args.layout)
    result = run_qa(cloud, layout, config=config, margin_mm=args.margin,
                    outlier_k=args.outliers, tolerance_um=args.tolerance, k=args.k,
                    tile_mm=args.tile,
                    budget=load_budget(args.budget) if args.budget else None)
    info = qa_report.write_outputs(result, out)
    for b in result.blocks:
        print(f"block {b.block_id}: {b.n_points} points, measured {b.measured_std_um:.1f} um, "
              f"predicted {b.predicted_std_um:.1f} um, {b.status}")
    for s in result.steps:
        print(f"step {s.block_a}-{s.block_b}: error {s.error_um:+.1f} um, U {s.expanded_um:.1f}"
              f" um, {s.decision}")
    for note in result.notes:
        print(f"note: {note}")
    frac = info["fraction_within_U"]
    print(f"report: {out / 'report.html'}" + (f" ({100 * frac:.0f} % of the evaluated steps "
                                              "within U)" if frac is not None else ""))
    return 0
