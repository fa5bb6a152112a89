"""``scanqa init``: write a commented scanner config, optionally filled from an OpenCV
camera-projector calibration."""

from __future__ import annotations

import argparse
from pathlib import Path

from scanqa.calibration.parametric import load_opencv_calibration
from scanqa.cli.common import emit, flags, float_list
from scanqa.errors import InputError
from scanqa.io.atomic import check_out_dir, write_text
from scanqa.runs.onboarding import placeholders, scanner_config_text


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "init", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="write a commented scanner config TOML (optionally from an OpenCV calibration)",
        epilog="examples:\n  scanqa init scanner.toml\n  scanqa init scanner.toml "
               "--calibration calibration.xml --pixel-um 5.5 --pitch-um 5.4 --periods 114,1824"
               "\n\nEvery key gets its unit and meaning in a comment; keys the inputs cannot "
               'fill hold "MEASURE",\nand scanqa refuses to load the file until they are '
               "replaced. From a calibration come the\nimage and panel sizes, the projector "
               "pose (position -Rp^T Tp, look-at on its axis) and,\nwith the pixel pitches, "
               "the focal lengths.")
    p.add_argument("out", metavar="CONFIG.toml", help="config file to write")
    p.add_argument("--calibration", metavar="FILE",
                   help="OpenCV calibration (.xml, .yml, .yaml, .json) with Kc, kc, Kp, kp, "
                        "Rp, Tp")
    p.add_argument("--pixel-um", type=float, default=None, metavar="UM",
                   help="camera pixel size [um]: turns Kc's f_x into a focal length")
    p.add_argument("--pitch-um", type=float, default=None, metavar="UM",
                   help="projector pixel pitch along x [um]: turns Kp's f_x into a focal "
                        "length")
    p.add_argument("--camera-focus-mm", type=float, default=None, metavar="MM",
                   help="camera focus distance [mm] (default: where the axes cross, ASSUMED)")
    p.add_argument("--projector-focus-mm", type=float, default=None, metavar="MM",
                   help="projector focus distance [mm] (default: where the axes cross, "
                        "ASSUMED)")
    p.add_argument("--periods", type=float_list, default=None, metavar="P1,P2,..",
                   help="fringe periods, finest first [projector px]")
    p.add_argument("--name", default=None, help="the config's name (default: file stem)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_out_dir(args.out)
    if out.exists() and not args.force:
        raise InputError(f"{out} exists: choose another name or pass --force to overwrite it")
    if out.suffix.lower() != ".toml":
        raise InputError(f"{out}: a scanner config is a .toml file")
    cal = None
    if args.calibration:
        cal = load_opencv_calibration(args.calibration)
    with flags({"check pitch_um": "check --pitch-um",
                "projector.pitch_um must be": "check --pitch-um: projector.pitch_um must be"}):
        text = scanner_config_text(cal, args.pixel_um, args.pitch_um, args.camera_focus_mm,
                                   args.projector_focus_mm, args.periods,
                                   args.name or Path(out).stem)
    write_text(out, text)
    left = placeholders(text)
    emit(f"{out}: scanner config written" + (
        f"; replace the {len(left)} \"MEASURE\" placeholders before use: {', '.join(left)}"
        if left else ""))
    return 0
