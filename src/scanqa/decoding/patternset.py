"""Pattern sets on disk and on the projector: reading a scan's images, the ideal
projected patterns, synthetic camera images, and writing a pattern folder.

The image model shared with the simulator is, for frame k of a phase set,
``I_k = A + B cos(2 pi x_p / period + delta_k)`` with ``delta_k = 2 pi k / N`` unless
``shifts_rad`` says otherwise; :func:`ideal_patterns` is the one definition of what
the projector shows (values in [0, 1], so ``I = A - B + 2 B p``), used both to write
patterns (:func:`projector_patterns`, :func:`write_pattern_set`) and by the decoder.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, PhaseSet, ReferenceSet
from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path, make_out_dir, write_text
from scanqa.io.images import is_lossy, read_image, read_stack, write_image
from scanqa.io.patterns import PATTERNS_FILE, dumps_patterns

# ----------------------------------------------------------------------------- images

def read_pattern_images(desc: PatternDescription) -> list[np.ndarray]:
    """Read the images of every set, in ``desc.sets`` order, and check their sizes.

    Parameters
    ----------
    desc : PatternDescription
        A description loaded from a file (its ``source`` locates the images).

    Returns
    -------
    list of (N, H, W) arrays
        One stack per set, in the stored dtype [DN].

    Raises
    ------
    InputError
        On a missing/unreadable file, a wrong frame count, mixed sizes or mixed dtypes.
    """
    folder = Path(desc.source).parent if desc.source else Path(".")
    stacks = [_read_set(folder, s, desc.options.channel) for s in desc.sets]
    shape, dtype = stacks[0].shape[1:], stacks[0].dtype
    for pset, stack in zip(desc.sets, stacks, strict=True):
        if stack.shape[1:] != shape:
            raise InputError(f"mismatched image sizes: set {pset.name!r} has images of "
                             f"{stack.shape[2]} x {stack.shape[1]} px, set "
                             f"{desc.sets[0].name!r} of {shape[1]} x {shape[0]} px "
                             f"(in {desc.source}); all images must come from one camera")
        if stack.dtype != dtype:
            raise InputError(f"mixed image types: set {pset.name!r} is {stack.dtype}, set "
                             f"{desc.sets[0].name!r} is {dtype} (in {desc.source})")
    return stacks


def lossy_image_note(desc: PatternDescription) -> str:
    """A warning when the scan's image files use lossy compression (else empty).

    Parameters
    ----------
    desc : PatternDescription
        A description loaded from a file.
    """
    folder = Path(desc.source).parent if desc.source else Path(".")
    lossy = [f for s in desc.sets for f in s.files[:1] if is_lossy(folder / f)]
    if not lossy:
        return ""
    return (f"images are lossy-compressed ({lossy[0]}, ...): JPEG-like compression biases "
            "the phase and its noise; capture to PNG, TIFF or BMP for measurements")


def _read_set(folder: Path, pset: PhaseSet | GrayCodeSet | ReferenceSet,
              channel: str = "") -> np.ndarray:
    """The (N, H, W) stack of one set from its files or its stack."""
    if pset.stack:
        stack = read_stack(folder / pset.stack, pset.stack_key)
        if stack.shape[0] != pset.frames:
            raise InputError(f"wrong count of images in stack {folder / pset.stack} for set "
                             f"{pset.name!r}: got {stack.shape[0]}, need {pset.frames}")
        return stack
    if not pset.files:
        raise InputError(f"set {pset.name!r} names no files and no stack")
    images = [read_image(folder / f, channel) for f in pset.files]
    for f, img in zip(pset.files, images, strict=True):
        if img.shape != images[0].shape or img.dtype != images[0].dtype:
            raise InputError(
                f"mismatched image sizes in set {pset.name!r}: {folder / f} is "
                f"{img.shape[1]} x {img.shape[0]} px {img.dtype}, {folder / pset.files[0]} "
                f"is {images[0].shape[1]} x {images[0].shape[0]} px {images[0].dtype}")
    return np.stack(images)


# ------------------------------------------------------------------- ideal patterns

def ideal_patterns(desc: PatternDescription, index: int,
                   coordinate_px: np.ndarray) -> np.ndarray:
    """Projected values of every frame of set ``index`` at projector coordinates.

    Parameters
    ----------
    desc : PatternDescription
        The pattern description.
    index : int
        Position of the set in ``desc.sets``.
    coordinate_px : (...) float
        Projector coordinate along the fringe direction, x_p or y_p [projector px].

    Returns
    -------
    (N, ...) float64
        Relative intensity in [0, 1]: ``0.5 + 0.5 cos(2 pi x / P + delta_k)`` for a
        phase set, 0 or 1 for a Gray-code or reference set [-].

    Examples
    --------
    >>> d = PatternDescription(8, (PhaseSet("p", 8.0, 4),))
    >>> ideal_patterns(d, 0, np.array([0.0, 2.0]))[:, 0].round(3).tolist()
    [1.0, 0.5, 0.0, 0.5]
    """
    pset = desc.sets[index]
    x = np.asarray(coordinate_px, dtype=np.float64)
    if isinstance(pset, PhaseSet):
        shifts = np.asarray(pset.shifts_rad).reshape((-1,) + (1,) * x.ndim)
        return 0.5 + 0.5 * np.cos(2 * np.pi * x / pset.period_px + shifts)
    if isinstance(pset, ReferenceSet):
        levels = np.array([1.0 if v == "white" else 0.0 for v in pset.levels])
        return np.broadcast_to(levels.reshape((-1,) + (1,) * x.ndim),
                               (len(levels), *x.shape)).copy()
    return _gray_frames(pset, desc.gray_cell_px, x)


def _gray_frames(gray: GrayCodeSet, cell_px: float, x: np.ndarray) -> np.ndarray:
    """Bit frames (and inverses, in the set's layout) of a Gray code at coordinates x."""
    cell = np.clip(np.floor((x + 0.5) / cell_px), 0, 2 ** gray.bits - 1).astype(np.int64)
    code = cell if gray.code == "binary" else cell ^ (cell >> 1)
    bits = np.stack([(code >> (gray.bits - 1 - b)) & 1 for b in range(gray.bits)])
    frames = np.empty((gray.frames, *x.shape))
    plain, inverse = gray.frame_order()
    frames[plain] = bits
    if inverse is not None:
        frames[inverse] = 1 - bits
    return frames


def projector_patterns(desc: PatternDescription, index: int, across_px: int,
                       gamma: float = 1.0) -> np.ndarray:
    """Panel images of set ``index``, evaluated at projector pixel centres.

    Parameters
    ----------
    desc : PatternDescription
        The pattern description.
    index : int
        Position of the set in ``desc.sets``.
    across_px : int
        Panel size across the fringe direction (rows for vertical fringes) [px].
    gamma : float
        Projector response exponent to pre-distort for: the panel gets ``p**(1/gamma)``
        so that a projector emitting ``value**gamma`` shows the ideal pattern p [-].

    Returns
    -------
    (N, rows, cols) float64
        Values in [0, 1]; ``cols = projector_width_px`` for vertical fringes, and
        ``rows = projector_width_px`` for horizontal ones [-].
    """
    coded = ideal_patterns(desc, index, np.arange(desc.projector_width_px, dtype=float))
    if gamma != 1.0:
        coded = coded ** (1.0 / gamma)
    if desc.sets[index].orientation != "horizontal":
        return np.repeat(coded[:, None, :], across_px, axis=1)
    return np.repeat(coded[:, :, None], across_px, axis=2)


def synthesize_images(desc: PatternDescription, coordinate_px: np.ndarray,
                      offset_dn: float | np.ndarray, modulation_dn: float | np.ndarray,
                      gamma: float = 1.0) -> list[np.ndarray]:
    """Noise-free camera images of every set for a known projector coordinate map.

    Parameters
    ----------
    desc : PatternDescription
        The pattern description.
    coordinate_px : (H, W) float
        Projector coordinate seen by each camera pixel [projector px].
    offset_dn : float or (H, W) float
        Offset A [DN].
    modulation_dn : float or (H, W) float
        Modulation B [DN].
    gamma : float
        Response exponent of the projector: it emits ``p**gamma`` for the pattern p
        (1: linear) [-].

    Returns
    -------
    list of (N, H, W) float64
        ``A - B + 2 B p**gamma`` with p from :func:`ideal_patterns`, one stack per set
        [DN].
    """
    return [offset_dn - modulation_dn + 2 * modulation_dn
            * ideal_patterns(desc, i, coordinate_px) ** gamma
            for i in range(len(desc.sets))]


# ---------------------------------------------------------------------------- writing

def write_pattern_set(directory: str | os.PathLike, desc: PatternDescription,
                      images: Sequence[np.ndarray], image_format: str = "png"
                      ) -> PatternDescription:
    """Write camera images and their ``patterns.toml`` into a folder.

    Parameters
    ----------
    directory : str or PathLike
        Output folder (created if missing).
    desc : PatternDescription
        What was projected; its files/stack entries are replaced by the written ones.
    images : sequence of (N, H, W) arrays
        One stack per set, in ``desc.sets`` order [DN]. PNG and TIFF need uint8 or
        uint16; npy and npz take any real dtype (write integers for quantised data).
    image_format : {"png", "tif", "bmp", "npy", "npz"}
        "png"/"tif"/"bmp": one file per frame (BMP: uint8 only); "npy": one stack per
        set; "npz": one file ``images.npz`` holding one array per set, keyed by name.

    Returns
    -------
    PatternDescription
        The description as written (``source`` is the new patterns.toml).
    """
    folder = make_out_dir(directory)
    _check_write_args(desc, images, image_format)
    if image_format == "npz":
        _write_npz(folder / "images.npz", {s.name: im for s, im in zip(desc.sets, images,
                                                                       strict=True)})
    sets = tuple(_write_set(folder, s, np.asarray(im), image_format)
                 for s, im in zip(desc.sets, images, strict=True))
    out = replace(desc, sets=sets, source=str(folder / PATTERNS_FILE))
    write_text(folder / PATTERNS_FILE, dumps_patterns(out.to_dict()))
    return out


def _check_write_args(desc: PatternDescription, images: Sequence[np.ndarray],
                      image_format: str) -> None:
    if image_format not in ("png", "tif", "tiff", "bmp", "npy", "npz"):
        raise InputError(f"image_format must be png, tif, bmp, npy or npz, got "
                         f"{image_format!r}")
    if len(images) != len(desc.sets):
        raise InputError(f"need one image stack per set ({len(desc.sets)}), got {len(images)}")
    for pset, im in zip(desc.sets, images, strict=True):
        if np.ndim(im) != 3 or np.shape(im)[0] != pset.frames:
            raise InputError(f"images of set {pset.name!r} must be ({pset.frames}, H, W), "
                             f"got {np.shape(im)}")


def _write_npz(path: Path, arrays: dict) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **{k: np.asarray(v) for k, v in arrays.items()})


def _write_set(folder: Path, pset: PhaseSet | GrayCodeSet | ReferenceSet,
               stack: np.ndarray, image_format: str) -> PhaseSet | GrayCodeSet | ReferenceSet:
    """Write one set's frames and return the set with its storage filled in."""
    if image_format == "npz":
        return replace(pset, files=(), stack="images.npz", stack_key=pset.name)
    if image_format == "npy":
        name = f"{pset.name}.npy"
        with atomic_path(folder / name) as tmp, open(tmp, "wb") as fh:
            np.save(fh, stack)
        return replace(pset, files=(), stack=name, stack_key="")
    suffix = "." + image_format  # one of IMAGE_SUFFIXES (checked by _check_write_args)
    names = tuple(f"{pset.name}_{k:02d}{suffix}" for k in range(pset.frames))
    # one frame per core: the PNG/TIFF encoders and zlib release the GIL (a 5 MP 16-bit
    # PNG takes ~1 s to compress, the 12 frames of a scan ~12 s on one core)
    workers = min(os.cpu_count() or 1, len(names))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(lambda item: write_image(folder / item[0], item[1]),
                      zip(names, stack, strict=True)))
    return replace(pset, files=names, stack="", stack_key="")
