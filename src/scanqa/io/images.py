"""Camera images: single-channel PNG/TIFF (8 or 16 bit) and .npy/.npz stacks.

Pillow (installed with matplotlib) reads and writes the image files, so no extra
dependency is needed. Images are returned in their stored integer type (``uint8`` or
``uint16``) so that the decoder knows they are quantised; stacks keep their dtype.
Colour images are refused rather than silently averaged: a phase decoder must know
which channel carries the fringes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path

#: File suffixes read by :func:`read_image` (lower case).
IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
#: File suffixes read by :func:`read_stack`.
STACK_SUFFIXES = (".npy", ".npz")

_PIL_MODES = {"L": np.uint8, "I;16": np.uint16, "I;16B": np.uint16, "I;16L": np.uint16}


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read one single-channel 8- or 16-bit PNG or TIFF image.

    Parameters
    ----------
    path : str or PathLike
        The image file.

    Returns
    -------
    (H, W) uint8 or uint16
        Pixel values [DN].

    Raises
    ------
    InputError
        When the file is missing, unreadable, of another suffix, or not single-channel
        8/16-bit.
    """
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    if p.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(f"cannot read image {p}: suffix {p.suffix!r} is not one of "
                         f"{', '.join(IMAGE_SUFFIXES)} (use a .npy/.npz stack for other data)")
    try:
        with Image.open(p) as img:
            mode = img.mode
            data = np.array(img) if mode in _PIL_MODES or mode in ("I", "1") else None
    except FileNotFoundError:
        raise InputError(f"image file {p} does not exist (check the files list)") from None
    except (OSError, UnidentifiedImageError, ValueError) as err:
        raise InputError(f"cannot read image {p}: {err} (is it a valid PNG/TIFF?)") from None
    return _checked_image(p, mode, data)


def _checked_image(path: Path, mode: str, data: np.ndarray | None) -> np.ndarray:
    """Map a decoded Pillow image to uint8/uint16 or raise naming the mode."""
    if data is None or data.ndim != 2:
        raise InputError(f"image {path} has mode {mode!r}; expected a single-channel 8- or "
                         "16-bit grayscale image (convert colour images to grayscale first)")
    if mode == "1":
        return data.astype(np.uint8)
    if mode == "I":  # 32-bit integer container that Pillow uses for some 16-bit files
        if data.min() < 0 or data.max() > 65535:
            raise InputError(f"image {path} holds values outside 0..65535; expected 8/16 bit")
        return data.astype(np.uint16)
    return data.astype(_PIL_MODES[mode], copy=False)


def read_stack(path: str | os.PathLike, key: str = "") -> np.ndarray:
    """Read an (N, H, W) image stack from a .npy file or one array of a .npz file.

    Parameters
    ----------
    path : str or PathLike
        The .npy or .npz file (read without pickle).
    key : str
        Array name inside a .npz file; may be empty when the file holds one array.

    Returns
    -------
    (N, H, W) array
        The stack in its stored dtype [DN].

    Raises
    ------
    InputError
        When the file is missing or unreadable, the key is absent, or the array is not
        a 3-D real-valued stack.
    """
    p = Path(path)
    if p.suffix.lower() not in STACK_SUFFIXES:
        raise InputError(f"cannot read stack {p}: suffix must be .npy or .npz")
    try:
        if p.suffix.lower() == ".npy":
            data = np.load(p, allow_pickle=False)
        else:
            data = _npz_member(p, key)
    except FileNotFoundError:
        raise InputError(f"stack file {p} does not exist (check the stack entry)") from None
    except (OSError, ValueError, EOFError) as err:
        raise InputError(f"cannot read stack {p}: {err}") from None
    return _checked_stack(p, key, data)


def _npz_member(path: Path, key: str) -> np.ndarray:
    """One array of a .npz file, chosen by key (or the only one)."""
    with np.load(path, allow_pickle=False) as npz:
        names = list(npz.files)
        if not key and len(names) == 1:
            key = names[0]
        if key not in names:
            hint = "name one with stack_key" if not key else "check stack_key"
            raise InputError(f"stack {path} has no array {key!r} (arrays: "
                             f"{', '.join(names) or 'none'}; {hint})")
        return npz[key]


def _checked_stack(path: Path, key: str, data: np.ndarray) -> np.ndarray:
    """Check that a stack is (N, H, W), real and finite."""
    where = f"{path}[{key}]" if key else str(path)
    if data.ndim != 3 or data.dtype.kind not in "uif":
        raise InputError(f"stack {where} must be a real (N, H, W) array, got shape "
                         f"{data.shape} of dtype {data.dtype}")
    if data.dtype.kind == "f" and not np.isfinite(data).all():
        raise InputError(f"stack {where} contains NaN or inf; write 0 for pixels without "
                         "signal (they are then masked for low modulation)")
    return data


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write a single-channel uint8/uint16 image as PNG or TIFF, atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; the suffix (.png, .tif, .tiff) selects the format.
    image : (H, W) uint8 or uint16
        Pixel values [DN].

    Returns
    -------
    Path
        The written file.
    """
    from PIL import Image

    p = Path(path)
    arr = np.asarray(image)
    if p.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(f"cannot write image {p}: suffix must be one of {IMAGE_SUFFIXES}")
    if arr.ndim != 2 or arr.dtype not in (np.uint8, np.uint16):
        raise InputError(f"cannot write image {p}: need a 2-D uint8 or uint16 array, got "
                         f"shape {arr.shape} dtype {arr.dtype} (use a .npy/.npz stack for "
                         "float data)")
    # zlib level 1: 5x faster than Pillow's default 6 for 3 % larger files (16-bit, 5 MP)
    options = {"format": "PNG", "compress_level": 1} if p.suffix.lower() == ".png" \
        else {"format": "TIFF"}
    with atomic_path(p) as tmp:
        Image.fromarray(np.ascontiguousarray(arr)).save(tmp, **options)
    return p
