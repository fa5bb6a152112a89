"""What the projector shows: a coding from a few choices, its panel images and the
``patterns.toml`` skeleton for the camera images that will be captured with them.

:func:`standard_coding` builds the layouts of docs/codings.rst (phase sets of any
periods and steps, optionally a Gray code of any cell width with inverse and
white/black frames); :func:`write_projector_patterns` writes one 8- or 16-bit image per
projected frame, numbered in projection order, and the patterns.toml that names the
camera image of each frame, so nobody writes either by hand.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
)
from scanqa.decoding.patternset import projector_patterns
from scanqa.errors import ConfigError
from scanqa.io.atomic import make_out_dir, staged_dir, write_text
from scanqa.io.images import write_image
from scanqa.io.patterns import PATTERNS_FILE, dumps_patterns

#: Folder (inside the output folder) that receives the projector images.
PROJECTOR_DIR = "projector"


def standard_coding(width_px: int, periods_px: Sequence[float] = (), steps: int = 4,
                    gray_cell_px: float | None = None, gray_bits: int | None = None,
                    gray_inverse: str = "none", reference: bool = False,
                    orientation: str = "vertical") -> PatternDescription:
    """A coding of phase sets and/or a Gray code, in projection order.

    Parameters
    ----------
    width_px : int
        Coded range along the fringe direction [projector px].
    periods_px : sequence of float
        Periods of the phase sets, any order (projected coarsest first) [projector px].
    steps : int
        Frames per phase set [-].
    gray_cell_px : float, optional
        Gray-code cell width [projector px]; None: no Gray code.
    gray_bits : int, optional
        Gray-code bits; default the fewest that cover ``width_px``.
    gray_inverse : str
        "none", "grouped" or "interleaved" inverse frames.
    reference : bool
        Project an all-white and an all-black frame first.
    orientation : str
        "vertical" (codes columns) or "horizontal" (codes rows).

    Returns
    -------
    PatternDescription
        Sets in projection order: reference, Gray code, phase sets coarse to fine.
    """
    sets: list = []
    if reference:
        sets.append(ReferenceSet("white_black"))
    if gray_cell_px is not None:
        bits = gray_bits or max(1, math.ceil(math.log2(width_px / gray_cell_px) - 1e-12))
        sets.append(GrayCodeSet("gray", bits, cell_px=float(gray_cell_px),
                                inverse=gray_inverse, orientation=orientation))
    for period in sorted({float(p) for p in periods_px}, reverse=True):
        sets.append(PhaseSet(f"p{period:g}", period, steps, orientation=orientation))
    if not any(isinstance(s, (PhaseSet, GrayCodeSet)) for s in sets):
        raise ConfigError("a coding needs phase periods or a Gray-code cell width "
                          "(periods_px and/or gray_cell_px)")
    return PatternDescription(int(width_px), tuple(sets), description="scanqa patterns")


def write_projector_patterns(directory: str | os.PathLike, desc: PatternDescription,
                             across_px: int, gamma: float = 1.0, bit_depth: int = 8,
                             camera_suffix: str = ".png") -> PatternDescription:
    """Write the panel images of a coding and the patterns.toml for its captures.

    Parameters
    ----------
    directory : str or PathLike
        Output folder (created); the images go to its ``projector/`` folder as
        ``NNN_<set>_<k>.png`` in projection order, the patterns.toml to the folder.
    desc : PatternDescription
        The coding (its files are replaced).
    across_px : int
        Panel size across the fringes (the panel height for vertical fringes) [px].
    gamma : float
        Projector response to pre-distort for (1: none) [-].
    bit_depth : int
        8 or 16 bit panel images [bit].
    camera_suffix : str
        Suffix of the camera images named in patterns.toml (".png", ".bmp", ...).

    Returns
    -------
    PatternDescription
        The coding with the camera file names, as written to patterns.toml.
    """
    if bit_depth not in (8, 16):
        raise ConfigError(f"bit_depth must be 8 or 16, got {bit_depth!r}")
    if not (math.isfinite(gamma) and 0.1 <= gamma <= 10):
        raise ConfigError(f"gamma must be in [0.1, 10], got {gamma!r}")
    full = 2 ** bit_depth - 1
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    sets, frame = [], 0
    with staged_dir(directory) as stage:  # the images and patterns.toml together, or none
        panel_dir = make_out_dir(stage / PROJECTOR_DIR)
        for index, pset in enumerate(desc.sets):
            images = projector_patterns(desc, index, across_px, gamma)
            names = []
            for k, image in enumerate(images):
                stem = f"{frame:03d}_{pset.name}_{k:02d}"
                write_image(panel_dir / f"{stem}.png", np.rint(image * full).astype(dtype))
                names.append(stem + camera_suffix)
                frame += 1
            sets.append(replace(pset, files=tuple(names), stack="", stack_key=""))
        out = replace(desc, sets=tuple(sets), source=str(Path(directory) / PATTERNS_FILE))
        text = _skeleton_header(gamma) + dumps_patterns(out.to_dict())
        write_text(stage / PATTERNS_FILE, text)
    return out


def _skeleton_header(gamma: float) -> str:
    """Comment lines at the top of a written patterns.toml."""
    pre = f" (pre-distorted for a projector gamma of {gamma:g})" if gamma != 1.0 else ""
    return ("# Written by 'scanqa patterns'. Project the images of projector/ in the order of\n"
            f"# their numbers{pre}, save the camera image of each frame\n"
            "# under the name listed in 'files' below (or edit the names), next to this\n"
            "# file, then run 'scanqa decode' on this folder. Without [sensor] gain and read\n"
            "# noise the camera noise is estimated from the images.\n")
