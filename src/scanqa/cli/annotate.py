"""``scanqa annotate``: a scan and a calibration (table or OpenCV) to an annotated point
cloud."""

from __future__ import annotations

import argparse

from scanqa.annotation.points import annotate
from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    calibration_from_args,
    config_from_args,
    emit,
    warn_sigma,
)
from scanqa.cli.flatten_args import (
    add_flatten_arguments,
    check_flatten_args,
    flatten_from_args,
)
from scanqa.decoding.decoder import decode, decode_images, load_pattern_dir
from scanqa.decoding.phasemap import PhaseMap
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
               "\n  scanqa annotate scan/ --calibration table.npz --config scanner.toml "
               "--out cloud.ply --flatten --tradeoff tradeoff.png"
               "\n\n--flatten (paper Sect. 5.2) decodes the pattern folder, filters its finest "
               "phase set with a range-dependent disc and adds sigma_flat_um, "
               "filter_diameter_px and lateral_resolution_mm to every point (sigma_random_um "
               "and sigma_total_um become the flattened ones); a phase map written by "
               "'scanqa decode --flatten' gets the same attributes."
               "\n\nformats by suffix: " + ", ".join(WRITERS))
    p.add_argument("scan", metavar="SCAN", help="decoded phase file (.npz) or pattern folder")
    add_calibration_argument(p)
    add_config_argument(p)
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output cloud (.ply, .las, .e57, .csv, .parquet)")
    p.add_argument("--repeats", nargs="+", default=[], metavar="SCAN",
                   help="further scans of the same scene: adds the measured per-point std")
    p.add_argument("--keep-invalid", action="store_true",
                   help="keep points outside the calibrated volume (extrapolated, flagged)")
    p.add_argument("--no-normals", dest="normals", action="store_false",
                   help="leave out the normals nx, ny, nz estimated from the pixel grid")
    add_flatten_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_format(check_out_dir(args.out))  # before any work: suffix, Parquet engine
    check_flatten_args(args)
    config = config_from_args(args)
    scan = _scan(args, args.scan)
    calibration = calibration_from_args(args, config, scan)
    if args.flatten and args.target_um is None:  # repeats flattened to the same target
        args.target_um = scan.provenance["flatten"]["target_um"]
    repeats = [_scan(args, r) for r in args.repeats]
    # a .ply is filled while it is computed (no second copy), unless attributes follow
    direct = out.suffix.lower() == ".ply" and "flatten" not in scan.provenance
    cloud = annotate(scan, calibration, config, repeats, args.keep_invalid, source=args.scan,
                     out=out if direct else None, normals=args.normals)
    if "flatten" in scan.provenance:
        from scanqa.annotation.flattening import flattened_attributes

        cloud = cloud.with_attributes(**flattened_attributes(cloud.attributes, cloud.xyz,
                                                             scan, config))
    if not cloud.counts["written"]:
        raise InputError(f"{args.scan}: no point lies inside the calibrated volume; nothing "
                         "written (use --keep-invalid to extrapolate)")
    warn_sigma([cloud])
    if not direct:
        cloud.write(out)
    emit(f"{out}: {cloud.summary()}")
    return 0


def _scan(args: argparse.Namespace, source: str) -> PhaseMap:
    """The decoded scan, flattened with --flatten (which needs the images)."""
    if not args.flatten:
        return decode(source)
    if source.lower().endswith(".npz"):
        raise InputError(f"{source}: --flatten filters the fringe images, so it needs the "
                         "pattern folder, not a phase map (or decode with 'scanqa decode "
                         "--flatten' and annotate its phase.npz without --flatten)")
    desc, stacks = load_pattern_dir(source)
    return flatten_from_args(args, desc, stacks, decode_images(desc, stacks))
