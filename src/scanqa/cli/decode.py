"""``scanqa decode``: fringe images to a phase map file (parsing only)."""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace

from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    emit,
    flags,
    output_path,
)
from scanqa.cli.flatten_args import (
    add_flatten_arguments,
    check_flatten_args,
    flatten_from_args,
)
from scanqa.decoding.decoder import (
    decode_images,
    load_pattern_dir,
    measure_response,
    named_response,
)
from scanqa.decoding.patternset import lossy_image_note
from scanqa.decoding.phasemap import save_phase_map
from scanqa.decoding.response import save_response

log = logging.getLogger(__name__)

_EPILOG = """\
PATTERN_DIR holds the camera images and a patterns.toml describing them
(docs/codings.rst; 'scanqa patterns' writes one). The output phase.npz holds xp
[projector px], modulation and offset [DN], mask (0 valid, 1 saturated,
2 low_modulation, 3 inconsistent, 4 out_of_range) and sigma_xp [projector px].
The summary says where the noise model came from, how the periods disagree, and -
when most pixels are masked - why, and which key would change it.

Projector nonlinearity (gamma): scan a flat once with --measure-response FILE to
write its phase-error tables; decode later scans with --response FILE (or name the
file in patterns.toml, [decode] response = "FILE").

examples:
  scanqa decode scans/plane_010 --out scans/plane_010/phase.npz
  scanqa decode scans/flat --out flat.npz --measure-response projector_response.toml
  scanqa decode scans/part --out part.npz --response projector_response.toml
  scanqa decode scans/part --out part.npz --flatten --calibration table.npz --config scanner.toml

--flatten (paper Sect. 5.2) filters the finest phase set with a disc whose size depends
on each pixel's range, so that the random sigma is the same at every range; it needs the
calibration (for the range) and the config (for the model). The trade-off - sigma and
lateral resolution against range - is printed and kept in the phase map's provenance.
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``decode`` subcommand."""
    p = sub.add_parser("decode", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="decode fringe images into x_p, modulation, mask and sigma_xp",
                       description="Decode a structured-light pattern set (N-step phase "
                                   "shifting, multi-period, heterodyne or Gray-code "
                                   "unwrapping, or a Gray code alone).",
                       epilog=_EPILOG)
    p.add_argument("pattern_dir", metavar="PATTERN_DIR",
                   help="folder with patterns.toml and the images (or the toml itself)")
    p.add_argument("--out", required=True, metavar="FILE.npz",
                   help="phase map file to write (atomically)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--response", metavar="FILE.toml", default=None,
                       help="projector response (phase-error tables) to correct with; "
                            "overrides [decode] response of patterns.toml")
    group.add_argument("--measure-response", metavar="FILE.toml", default=None,
                       help="measure the projector response on this scan (a flat) and "
                            "write it; the phase map is then decoded with it")
    p.add_argument("--fuse-periods", action="store_true",
                   help="fuse every period into x_p by inverse variance (default: the "
                        "finest period alone; systematic differences bias a fusion)")
    add_flatten_arguments(p)
    add_calibration_argument(p, required=False, when=" (with --flatten)")
    add_config_argument(p, required=False)
    add_model_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load, (measure,) decode, write, and print the summary."""
    out = output_path(args.out)
    measure_out = output_path(args.measure_response)
    check_flatten_args(args)
    output_path(args.tradeoff)
    progress = _progress  # through the scanqa logger: -q/--quiet silence it
    desc, stacks = load_pattern_dir(args.pattern_dir, progress)
    if args.fuse_periods:
        desc = replace(desc, options=replace(desc.options, fuse_periods=True))
    note = lossy_image_note(desc)
    if measure_out is not None:
        response, _ = measure_response(desc, stacks, f"measured by scanqa decode on "
                                                     f"{desc.source}")
        response = replace(response, source=str(measure_out))
    else:
        with flags(_MEASURE):
            response = named_response(desc, args.response)
    with flags(_MEASURE):
        phase_map = decode_images(desc, stacks, progress=progress,
                                  notes=[note] if note else [], response=response)
    phase_map = flatten_from_args(args, desc, stacks, phase_map)
    if measure_out is not None:
        save_response(measure_out, response)
        for table in response.tables:
            emit(f"response: {table.period_px:g} px x {table.steps} steps: phase error "
                 f"rms {table.rms_rad:.4f} rad = {table.rms_rad * table.period_px / 6.2832:.3f}"
                 f" px -> {measure_out}")
    save_phase_map(out, phase_map)
    first, *rest = phase_map.summary().splitlines()
    emit("\n".join([f"{first} -> {out}", *rest]))
    return 0


#: The response's words for measuring one, in this command's.
_MEASURE = {"measure one on a flat": "measure one with 'scanqa decode SCAN "
                                     "--measure-response FILE' on a flat"}


def _progress(message: str) -> None:
    log.info(f"scanqa decode: {message}")
