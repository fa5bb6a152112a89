"""``scanqa patterns``: projector images of a coding and its patterns.toml (parsing only)."""

from __future__ import annotations

import argparse

from scanqa.cli.common import add_config_argument, config_from_args, emit, flags, float_list
from scanqa.decoding.projection import standard_coding, write_projector_patterns
from scanqa.errors import ConfigError

_EPILOG = """\
Writes OUT_DIR/projector/NNN_<set>_<k>.png (the panel images, in projection order)
and OUT_DIR/patterns.toml naming the camera image of every frame (docs/codings.rst
describes the layouts). Capture the frames, save them under those names next to the
patterns.toml, and run 'scanqa decode OUT_DIR --out phase.npz'.

The panel size comes from --config (projector.width_px, height_px) or from --width
and --height. With --config and neither --periods nor --gray-cell, the periods are
the simulator's (simulator.unwrap_periods_px and the working period).

examples:
  scanqa patterns scans/flat --config calib/paper_scanner.toml
  scanqa patterns scans/gray --width 1824 --height 1140 --gray-cell 2 --reference
  scanqa patterns scans/mixed --width 1280 --height 800 --periods 48,40 --steps 3 \\
      --gray-cell 8 --gray-inverse interleaved --reference --gamma 2.2
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``patterns`` subcommand."""
    p = sub.add_parser("patterns", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="write the projector images of a coding and its patterns.toml",
                       description="Write the projector images of a phase-shift and/or "
                                   "Gray-code coding, and the patterns.toml that decodes "
                                   "the camera images captured with them.",
                       epilog=_EPILOG)
    p.add_argument("out_dir", metavar="OUT_DIR", help="folder to write (created)")
    add_config_argument(p, required=False)  # the panel size and default periods
    p.add_argument("--width", type=int, default=None, help="panel width [px]")
    p.add_argument("--height", type=int, default=None, help="panel height [px]")
    p.add_argument("--periods", type=float_list, default=None, metavar="P1,P2,...",
                   help="phase-set periods [projector px]")
    p.add_argument("--steps", type=int, default=4, help="frames per phase set (default 4)")
    p.add_argument("--gray-cell", type=float, default=None, metavar="PX",
                   help="add a Gray code of cells this wide [projector px]")
    p.add_argument("--gray-bits", type=int, default=None,
                   help="Gray-code bits (default: the fewest that cover the panel)")
    p.add_argument("--gray-inverse", choices=("none", "grouped", "interleaved"),
                   default="none", help="inverse frames of the Gray code")
    p.add_argument("--reference", action="store_true",
                   help="project an all-white and an all-black frame first")
    p.add_argument("--orientation", choices=("vertical", "horizontal"), default="vertical",
                   help="vertical fringes code columns (x_p), horizontal ones rows (y_p)")
    p.add_argument("--gamma", type=float, default=1.0,
                   help="pre-distort for a projector that emits value**gamma (default 1)")
    p.add_argument("--bit-depth", type=int, choices=(8, 16), default=8,
                   help="bits of the panel images (default 8)")
    p.add_argument("--camera-suffix", default=".png",
                   help="suffix of the camera file names in patterns.toml (default .png)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build the coding, write the images and the patterns.toml, say what was written."""
    width, height, periods = _panel_and_periods(args)
    coded, across = (width, height) if args.orientation == "vertical" else (height, width)
    with flags({"(periods_px and/or gray_cell_px)": "(--periods and/or --gray-cell)"}):
        desc = standard_coding(coded, periods, args.steps, args.gray_cell, args.gray_bits,
                               args.gray_inverse, args.reference, args.orientation)
    written = write_projector_patterns(args.out_dir, desc, across, args.gamma,
                                       args.bit_depth, args.camera_suffix)
    frames = sum(s.frames for s in written.sets)
    kinds = ", ".join(f"{s.name} ({s.frames})" for s in written.sets)
    emit(f"{frames} projector images of {width} x {height} px -> {args.out_dir}/projector;"
         f" sets: {kinds}; patterns.toml -> {written.source}")
    return 0


def _panel_and_periods(args: argparse.Namespace) -> tuple[int, int, list[float]]:
    """Panel size and periods from the config and the flags (flags win)."""
    periods = list(args.periods or [])
    width, height = args.width, args.height
    if args.config:
        config = config_from_args(args)
        width = width or config.projector.width_px
        height = height or config.projector.height_px
        if args.periods is None and args.gray_cell is None:
            sim = config.simulator
            periods = [*sim.unwrap_periods_px, config.fringes.working_period_px]
    if not width or not height:
        raise ConfigError("the panel size is unknown: give --config FILE or --width and "
                          "--height [projector px]")
    return int(width), int(height), periods
