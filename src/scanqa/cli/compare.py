"""``scanqa compare``: an annotated cloud against a reference cloud or mesh (parsing only;
:func:`scanqa.api.compare`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from scanqa.cli.common import emit, number, warn_sigma
from scanqa.errors import InputError

_EPILOG = """examples:
  scanqa compare scan.ply reference.ply --out cmp
  scanqa compare scan.ply part.stl --tolerance-um 50 --out cmp
  scanqa compare scan.ply part.stl --align --out cmp      # best-fit the part first

Writes cmp/report.html, cmp/summary.json and cmp/cloud_compare.ply (the scan with
deviation_um, u_deviation_um, U_deviation_um, significance, significant and, with a
tolerance, in_tolerance). Mesh references: .stl, .obj, .off, .glb (trimesh); cloud
references: .ply, .las, .e57, .csv, .parquet (a .ply holding faces is read as a mesh)."""

def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="deviation from a reference cloud or mesh vs the scan's own "
                            "uncertainty", epilog=_EPILOG)
    p.add_argument("cloud", metavar="CLOUD", help="annotated cloud (scanqa annotate)")
    p.add_argument("reference", metavar="REFERENCE", help="reference cloud or mesh")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("-k", type=number(gt=0), default=2.0, help="coverage factor (default 2)")
    p.add_argument("--tolerance-um", type=number(gt=0), default=None,
                   help="tolerance on |deviation| [um]: adds a verdict")
    p.add_argument("--reference-sigma-um", type=number(ge=0), default=0.0,
                   help="sigma of the reference where it carries none [um] (default 0)")
    p.add_argument("--neighbours", type=number(int, ge=3), default=16,
                   help="reference points per local plane (default 16)")
    p.add_argument("--max-distance-mm", type=number(gt=0), default=1.0,
                   help="farther from the reference: not compared (default 1 mm)")
    p.add_argument("--align", action="store_true",
                   help="best-fit the reference onto the scan first (rigid, point-to-plane "
                        "ICP, robust); the transform and its uncertainty go into the report")
    p.add_argument("--align-region", metavar="[NAME=]X0,X1,Y0,Y1", default=None,
                   help="fit only on the scan's points in this box [mm] (implies --align)")
    p.add_argument("--align-max-distance-mm", type=number(gt=0), default=5.0,
                   help="pairs farther apart are not used by the fit (default 5 mm)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scanqa.api import compare
    from scanqa.io.annotated_cloud import read_cloud
    from scanqa.report.compare import write_outputs

    cloud = read_cloud(args.cloud)
    warn_sigma([cloud])
    if args.align_region is not None:  # a bad region is named before the reference is read
        from scanqa.qa.align import parse_region

        parse_region(args.align_region)
    try:
        result = compare(cloud, args.reference, None, args.k, args.tolerance_um,
                         args.reference_sigma_um, args.neighbours, args.max_distance_mm,
                         args.align, args.align_region, args.align_max_distance_mm)
    except InputError as err:   # the library names its parameter; the CLI names the flag
        raise InputError(str(err).replace("max_distance_mm", "--max-distance-mm")) from None
    info = write_outputs(result, args.out)
    emit(f"{info['compared']} of {info['points']} points compared: median deviation "
         f"{info['median_deviation_um']:.1f} um, RMS {info['rms_deviation_um']:.1f} um, "
         f"{100 * info['significant_fraction']:.1f} % significant (|dev| > U, k = {args.k:g})"
         + (f"; verdict {info['verdict']}" if "verdict" in info else ""))
    emit(f"report: {Path(args.out) / 'report.html'}")
    return 0
