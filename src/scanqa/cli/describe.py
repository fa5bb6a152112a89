"""``scanqa describe``: the patterns.toml of existing captures (parsing only)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from scanqa.cli.common import emit, flags, number, output_path
from scanqa.description.inference import describe_frames
from scanqa.description.text import description_text, frame_files, read_frames
from scanqa.errors import InputError
from scanqa.io.atomic import write_text

_EPILOG = """\
Reads the frames of FOLDER (its image files in name order, or --frames in projection
order), finds the sets they form - phase sets (period, steps, sign of the shifts),
a Gray code (bits, bit order, inverse frames), white and black frames, columns or
rows - decodes them with scanqa's decoder to check, and writes the patterns.toml
that 'scanqa decode' reads. Each set carries a comment saying how sure it is; lines
starting '# ?' are questions the frames could not answer (answer them before
trusting the cloud). A capture coding both columns and rows gets two files: OUT for
the columns and OUT with '_rows' added for the rows.

The frames give period ratios only; the projector size along the coded direction
(--projector-width for columns, --projector-height for rows) turns them into pixels.

examples:
  scanqa describe scans/skull --projector-width 1824
  scanqa describe scans/board --projector-width 1824 --projector-height 1140
  scanqa decode scans/board/patterns_rows.toml --out board_rows.npz
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``describe`` subcommand."""
    p = sub.add_parser("describe", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="infer the patterns.toml of existing captures from the frames",
                       description="Infer what was projected for each camera frame of a "
                                   "capture, check it by decoding, and write the "
                                   "patterns.toml.",
                       epilog=_EPILOG)
    p.add_argument("folder", metavar="FOLDER", help="folder with the camera frames")
    p.add_argument("--projector-width", type=number(int, gt=0), default=None, metavar="PX",
                   help="projector width [px] (the coded range of columns)")
    p.add_argument("--projector-height", type=number(int, gt=0), default=None,
                   metavar="PX", help="projector height [px] (the coded range of rows)")
    p.add_argument("--frames", default=None, metavar="A,B,...",
                   help="frame files of FOLDER in projection order (default: every "
                        "image file, in name order)")
    p.add_argument("--channel", choices=("red", "green", "blue"), default="",
                   help="channel of colour frames that carries the fringes")
    p.add_argument("--out", default=None, metavar="FILE.toml",
                   help="file to write (default FOLDER/patterns.toml)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read the frames, describe them, write one patterns.toml per coded direction."""
    names = [n.strip() for n in args.frames.split(",")] if args.frames else []
    paths = frame_files(args.folder, names)
    out = output_path(args.out or str(Path(args.folder) / "patterns.toml"))
    images = read_frames(paths, args.channel)
    listed = [_listed(p, out.parent) for p in paths]
    with flags({"give width_px": "give --projector-width",
                "give height_px": "give --projector-height"}):
        found = describe_frames(images, listed, args.projector_width, args.projector_height)
    targets = _targets(out, [d.desc.orientation for d in found])
    for target in targets:
        if target.exists() and not args.force:
            raise InputError(f"{target} exists (give --force to overwrite it, or --out)")
    texts = [description_text(d, str(args.folder), len(paths)) for d in found]
    if args.channel:
        texts = [t.replace('channel = ""', f'channel = "{args.channel}"') for t in texts]
    for target, text in zip(targets, texts, strict=True):
        write_text(target, text)
    for target, d in zip(targets, found, strict=True):
        sets = ", ".join(f"{s.name} ({s.frames})" for s in d.desc.sets)
        asked = sum(len(n.questions) for n in d.set_notes) + len(d.questions)
        emit(f"{d.desc.orientation}: {sets}; {100 * d.valid_share:.0f} % of the lit pixels "
             f"decode; {asked} question(s); {d.confidence.split(':')[0]} -> {target}")
    return 0


def _listed(path: Path, folder: Path) -> str:
    """The frame's name relative to the written file's folder, or absolute outside it."""
    full, base = path.resolve(), folder.resolve()
    return os.path.relpath(full, base) if full.is_relative_to(base) else str(full)


def _targets(out: Path, orientations: list[str]) -> list[Path]:
    """OUT for the columns (or the only direction), OUT_rows for rows beside columns."""
    if len(orientations) == 1:
        return [out]
    return [out if o == "vertical" else out.with_name(f"{out.stem}_rows{out.suffix}")
            for o in orientations]
