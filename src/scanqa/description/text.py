"""The ``patterns.toml`` text of an inferred description, with what it is sure of.

:func:`description_text` renders one :class:`~scanqa.description.inference.Description`
as the file ``scanqa decode`` reads, with a comment block above every ``[[set]]``: how
sure the set is, what it rests on, and the questions the frames could not answer
(lines starting ``# ?``). :func:`read_frames` lists and reads the frames of a folder.
"""

from __future__ import annotations

import os
import re
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scanqa.description.inference import Description
from scanqa.errors import InputError
from scanqa.io.images import read_image
from scanqa.io.patterns import dumps_patterns

#: Suffixes of the image files a folder is searched for.
IMAGE_SUFFIXES = (".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".jpg", ".jpeg")


def natural_key(name: str) -> list:
    """Sort key that orders ``frame_2`` before ``frame_10``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def frame_files(folder: str | os.PathLike, names: Sequence[str] = ()) -> list[Path]:
    """The image files of a folder in name order, or the ones named (in that order).

    Raises
    ------
    InputError
        When the folder has no image, or a named file is missing.
    """
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"{root} is not a folder of camera frames")
    if names:
        paths = [root / n for n in names]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise InputError(f"frames not found: {', '.join(missing)}")
        return paths
    paths = sorted((p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                    and p.is_file()), key=lambda p: natural_key(p.name))
    if len(paths) < 2:
        raise InputError(f"{root} holds {len(paths)} image file(s) "
                         f"({', '.join(IMAGE_SUFFIXES)}); describe needs the frames of a "
                         "capture")
    return paths


def read_frames(paths: Sequence[Path], channel: str = "") -> np.ndarray:
    """(K, H, W) stack of the frames [DN].

    Raises
    ------
    InputError
        When the frames differ in size or type.
    """
    images = [read_image(p, channel) for p in paths]
    first = images[0]
    for p, im in zip(paths, images, strict=True):
        if im.shape != first.shape or im.dtype != first.dtype:
            raise InputError(f"frame {p} is {im.shape[1]} x {im.shape[0]} px {im.dtype}, "
                             f"{paths[0]} is {first.shape[1]} x {first.shape[0]} px "
                             f"{first.dtype}: all frames must come from one camera")
    return np.stack(images)


def description_text(d: Description, source: str, frames: int) -> str:
    """The patterns.toml of one description, with comments per set.

    Parameters
    ----------
    d : Description
        The inferred description.
    source : str
        Where the frames came from (for the header).
    frames : int
        Frames read [-].

    Returns
    -------
    str
        TOML text that :func:`scanqa.decoding.parsing.load_patterns` reads.
    """
    body = dumps_patterns(d.desc.to_dict())
    head = _comment([
        f"Written by 'scanqa describe' from the {frames} frames of {source}: the "
        f"{'columns (x_p)' if d.desc.orientation == 'vertical' else 'rows (y_p)'}.",
        f"Checked with scanqa's decoder on a {d.checked[0]} x {d.checked[1]} px sample of "
        f"the frames: {100 * d.valid_share:.0f} % of its lit pixels decode.",
        f"Confidence: {d.confidence}.",
        *d.notes]) + _questions(d.questions)
    parts = body.split("[[set]]\n")
    out = [head + parts[0]]
    for note, part in zip(d.set_notes, parts[1:], strict=True):
        lines = [f"{note.name}: {note.sure}. " + " ".join(f"{n}." for n in note.notes)]
        out.append(_comment(lines) + _questions(note.questions) + "[[set]]\n" + part)
    return "".join(out)


def _comment(lines: Sequence[str]) -> str:
    wrapped = [w for line in lines for w in textwrap.wrap(line, 86)]
    return "".join(f"# {w}\n" for w in wrapped)


def _questions(questions: Sequence[str]) -> str:
    """Questions as ``# ?`` lines (continuations indented)."""
    out = []
    for q in questions:
        lines = textwrap.wrap(q, 84)
        out.append(f"# ? {lines[0]}\n" + "".join(f"#   {w}\n" for w in lines[1:]))
    return "".join(out)
