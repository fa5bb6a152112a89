"""``scanqa sweep-manifest``: write a sweep.toml from a folder of captures and the stage
readings, so that nobody writes one by hand."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

from scanqa.cli.common import add_config_argument, config_from_args, emit, flags
from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.sweep import load_sweep, read_stage_readings, scanner_table, sweep_manifest
from scanqa.io.tomlfile import dumps_toml


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep-manifest", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="write the sweep.toml of a calibration sweep from its captures and stage "
             "readings",
        epilog="examples:\n  scanqa sweep-manifest captures --stage-mm readings.csv "
               "--markers 'markers/*.png' --square-mm 4 --config scanner.toml\n"
               "  scanqa sweep-manifest captures --stage-mm 430,432,434,436\n\n"
               "Captures are the pattern folders (with patterns.toml) or phase files "
               "(.npz) directly\nin FOLDER, in name order; give one stage reading per "
               "capture (equal readings are repeats).\nWrites FOLDER/sweep.toml (or --out) "
               "and reads it back to check it.")
    p.add_argument("folder", metavar="FOLDER", help="folder holding the captures")
    p.add_argument("--stage-mm", required=True, metavar="CSV|LIST",
                   help="stage readings [mm]: a CSV/text file (one per line, last column) "
                        "or a comma list")
    p.add_argument("--markers", metavar="GLOB", default=None,
                   help="marker frames relative to FOLDER in reading order, one per "
                        "position or N per position (consecutive in name order; "
                        "calibrate averages them), e.g. 'markers/*.png'")
    p.add_argument("--square-mm", type=float, default=None, metavar="MM",
                   help="side of the printed chessboard's squares [mm] (with --markers)")
    add_config_argument(p, required=False)
    p.add_argument("--out", default=None, metavar="SWEEP.toml",
                   help="manifest to write (default FOLDER/sweep.toml)")
    p.set_defaults(func=run)


def _captures(folder: Path) -> tuple[list[str], bool]:
    """Pattern folders, else phase files, directly in ``folder`` (name order)."""
    dirs = sorted(d.name for d in folder.iterdir() if (d / "patterns.toml").is_file())
    if dirs:
        return dirs, False
    files = sorted(f.name for f in folder.glob("*.npz"))
    if files:
        return files, True
    raise InputError(f"{folder}: no captures found (pattern folders holding a "
                     "patterns.toml, or phase files *.npz)")


def _marker_files(folder: Path, pattern: str) -> list[str]:
    """The marker frames ``pattern`` matches, relative to ``folder`` (name order); an
    absolute pattern too, as long as what it matches lies in ``folder``."""
    if not Path(pattern).is_absolute():
        return sorted(str(p.relative_to(folder)) for p in folder.glob(pattern))
    base = folder.resolve()
    found = sorted(Path(p).resolve() for p in glob.glob(pattern))
    outside = [p for p in found if not p.is_relative_to(base)]
    if outside:
        raise InputError(f"--markers {pattern!r} matches {outside[0]}, outside {folder}: "
                         "the manifest's paths are relative to its folder; put the marker "
                         "frames under it")
    return [str(p.relative_to(base)) for p in found]


def run(args: argparse.Namespace) -> int:
    folder = Path(args.folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder of captures")
    captures, decoded = _captures(folder)
    stage = Path(args.stage_mm)
    readings = read_stage_readings(stage.read_text(), str(stage)) if stage.is_file() \
        else read_stage_readings(args.stage_mm, "--stage-mm")
    markers = None
    if args.markers:
        markers = _marker_files(folder, args.markers)
        if not markers:
            raise InputError(f"--markers {args.markers!r} matches no file in {folder}")
    scanner = scanner_table(config_from_args(args).camera) if args.config else None
    with flags({"(square_mm > 0 [mm])": "(--square-mm > 0 [mm])"}):
        data = sweep_manifest(captures, readings, markers, args.square_mm, decoded, scanner)
    out = Path(args.out) if args.out else folder / "sweep.toml"
    if out.resolve().parent != folder.resolve():
        raise InputError(f"--out {out} must be in {folder}: the manifest's paths are "
                         "relative to its folder")
    with atomic_path(out) as tmp:   # validated next to its captures, then published
        tmp.write_text(dumps_toml(data), encoding="utf-8")
        try:
            sweep = load_sweep(tmp)
        except InputError as err:   # name the file the user asked for, not the temporary
            raise InputError(str(err).replace(str(tmp), str(out))) from None
    emit(f"{out}: {len(sweep.positions)} positions, {sweep.observation_count()} scans"
         + (", marker frames" if markers else ""))
    return 0
