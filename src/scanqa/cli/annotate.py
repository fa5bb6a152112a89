"""``scanqa annotate``: a scan and a calibration (table or OpenCV) to an annotated point
cloud."""

from __future__ import annotations

import argparse

from scanqa.annotation import annotate
from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    calibration_from_args,
    config_from_args,
    emit,
    warn_sigma,
)
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io.atomic import check_out_dir
from scanqa.io.cloud import WRITERS, check_format


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "annotate", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="phase map + calibration -> point cloud with per-point sigmas",
        epilog="examples:\n  scanqa annotate scan/phase.npz --calibration table.npz "
               "--config calib/paper_scanner.toml --out cloud.ply --repeats rep1.npz rep2.npz"
               "\n  scanqa annotate scan/ --calibration calibration.xml --config scanner.toml "
               "--out cloud.ply"
               "\n\nformats by suffix: " + ", ".join(WRITERS))
    p.add_argument("scan", metavar="SCAN", help="decoded phase file (.npz) or pattern folder")
    add_calibration_argument(p)
    add_config_argument(p)
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output cloud (.ply, .las, .csv, .parquet)")
    p.add_argument("--repeats", nargs="+", default=[], metavar="SCAN",
                   help="further scans of the same scene: adds the measured per-point std")
    p.add_argument("--keep-invalid", action="store_true",
                   help="keep points outside the calibrated volume (extrapolated, flagged)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_format(check_out_dir(args.out))  # before any work: suffix, Parquet engine
    config = config_from_args(args)
    scan = decode(args.scan)
    calibration = calibration_from_args(args, config, scan)
    repeats = [decode(r) for r in args.repeats]
    cloud = annotate(scan, calibration, config, repeats, args.keep_invalid, source=args.scan)
    if not cloud.counts["written"]:
        raise InputError(f"{args.scan}: no point lies inside the calibrated volume; nothing "
                         "written (use --keep-invalid to extrapolate)")
    warn_sigma([cloud])
    cloud.write(out)
    emit(f"{out}: {cloud.summary()}")
    return 0
