"""``scanqa calibrate``: build a weighted calibration table from a plane sweep."""

from __future__ import annotations

import argparse
import json

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
from scanqa.io.atomic import check_out_dir, staged_dir, write_text
from scanqa.io.sweep import load_sweep
from scanqa.report import calibration as report_calibration


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="build a weighted nonparametric calibration table from a plane sweep",
        epilog="example:\n  scanqa calibrate sample_data/calibration_sweep/sweep.toml "
               "--config sample_data/sample_scanner.toml#sample --out table.npz\n\n"
               "writes table.npz and, beside it, table_report.html and table_report.json")
    p.add_argument("sweep", metavar="SWEEP", help="sweep manifest (sweep.toml) or its folder")
    add_config_argument(p)
    add_model_argument(p)
    p.add_argument("--out", required=True, metavar="TABLE.npz", help="table file to write")
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    out = check_out_dir(args.out)
    sweep = load_sweep(args.sweep)
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
    return 0
