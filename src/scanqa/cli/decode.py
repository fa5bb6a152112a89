"""``scanqa decode``: fringe images to a phase map file (parsing only)."""

from __future__ import annotations

import argparse
import sys

from scanqa.cli.common import output_path
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.decoding.phasemap import save_phase_map

_EPILOG = """\
PATTERN_DIR holds the camera images and a patterns.toml describing them
(docs/formats.rst, "patterns.toml"). The output phase.npz holds xp [projector px],
modulation and offset [DN], mask (0 valid, 1 saturated, 2 low_modulation,
3 inconsistent, 4 out_of_range) and sigma_xp [projector px].

example:
  scanqa decode scans/plane_010 --out scans/plane_010/phase.npz
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``decode`` subcommand."""
    p = sub.add_parser("decode", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="decode fringe images into x_p, modulation, mask and sigma_xp",
                       description="Decode a phase-shift pattern set (N-step phase "
                                   "shifting, multi-period or Gray-code unwrapping).",
                       epilog=_EPILOG)
    p.add_argument("pattern_dir", metavar="PATTERN_DIR",
                   help="folder with patterns.toml and the images (or the toml itself)")
    p.add_argument("--out", required=True, metavar="FILE.npz",
                   help="phase map file to write (atomically)")
    p.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load, decode, write, and print the one-line summary."""
    out = output_path(args.out)
    progress = None if args.quiet else _progress
    phase_map = decode_pattern_dir(args.pattern_dir, progress=progress)
    save_phase_map(out, phase_map)
    print(f"{phase_map.summary()} -> {out}")
    return 0


def _progress(message: str) -> None:
    print(f"scanqa decode: {message}", file=sys.stderr, flush=True)
