"""Camera images: any single-channel image file Pillow reads, and .npy/.npz stacks.

Pillow (installed with matplotlib) reads the image files - PNG, TIFF, BMP, JPEG, PGM and
whatever else it knows - so no extra dependency is needed. Images are returned in their
stored integer type (``uint8`` or ``uint16``) so that the decoder knows they are
quantised; stacks keep their dtype. Colour images are refused unless a channel is named:
a phase decoder must know which channel carries the fringes (averaging the channels of a
Bayer camera mixes three differently filtered signals). JPEG files are read, but
:func:`is_lossy` says so: lossy compression biases the phase, and callers warn.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.guard import check_size, regular_file
from scanqa.io.npzfile import load_npy, load_npz

#: File suffixes written by :func:`write_image` (lower case).
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp")
#: File suffixes read by :func:`read_stack`.
STACK_SUFFIXES = (".npy", ".npz")
#: Channel names accepted by :func:`read_image` for colour images.
CHANNELS = ("red", "green", "blue")
#: Pillow formats whose compression loses information.
LOSSY_FORMATS = ("JPEG", "MPO", "WEBP", "JPEG2000")

#: Bound of the decoded images :func:`read_image` keeps for files read again [bytes].
CACHE_BYTES = 96 << 20
_cache: OrderedDict = OrderedDict()  # (file digest, channel) -> (image, header's size)
_cache_lock = threading.Lock()
_cached_bytes = [0]

_PIL_MODES = {"L": np.uint8, "I;16": np.uint16, "I;16B": np.uint16, "I;16L": np.uint16,
              "I;16N": np.uint16}
_COLOUR_MODES = ("RGB", "RGBA", "RGBX", "CMYK", "YCbCr", "LAB", "HSV", "P", "PA", "LA")


def read_image(path: str | os.PathLike, channel: str = "") -> np.ndarray:
    """Read one 8- or 16-bit grey image (or one channel of a colour image).

    Parameters
    ----------
    path : str or PathLike
        The image file, in any format Pillow reads (PNG, TIFF, BMP, JPEG, ...).
    channel : str
        "red", "green" or "blue" to take one channel of a colour image; empty for grey
        images (a colour image then raises).

    Returns
    -------
    (H, W) uint8 or uint16
        Pixel values [DN].

    Raises
    ------
    InputError
        When the file is missing or unreadable, is a stack, is a colour image and no
        channel is named (or a grey image and one is), or holds more than 16 bits.

    Notes
    -----
    A file read again (the same bytes: a BLAKE2 digest of the file, ~30x cheaper than
    inflating a PNG) is copied from the last :data:`CACHE_BYTES` of decoded images
    instead of decoded again: sweeps and test captures are decoded several times per
    process.
    The cache holds at most :data:`CACHE_BYTES` (96 MiB) per process, none of it an image
    over a quarter of that; setting it to 0 turns it off. Callers get their own copy.
    """
    p = Path(path)
    if p.suffix.lower() in STACK_SUFFIXES:
        raise InputError(f"cannot read image {p}: {p.suffix} files are stacks (name them "
                         "with stack = ... instead of files = [...])")
    if not p.exists():
        raise InputError(f"image file {p} does not exist (check the files list)")
    regular_file(p, "image file")
    key, raw = _content_key(p, channel)
    with _cache_lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
    if hit is not None:
        check_size(*_size_check(p, *hit[1]))  # the limit may have changed since
        return hit[0].copy()
    image, declared = _decode(p, channel, raw)
    if key is not None and image.nbytes <= CACHE_BYTES // 4:
        with _cache_lock:
            if key not in _cache:
                _cache[key] = (image.copy(), declared)
                _cached_bytes[0] += image.nbytes
            while _cached_bytes[0] > CACHE_BYTES:
                _cached_bytes[0] -= _cache.popitem(last=False)[1][0].nbytes
    return image


def _content_key(p: Path, channel: str) -> tuple[tuple | None, bytes | None]:
    """The cache's key of an image file (its bytes' digest and the channel) and the bytes
    read for it, which the decoder then reads instead of the file; (None, None) for a
    file too big to keep or that cannot be read (the decoder then says why)."""
    try:
        if p.stat().st_size > CACHE_BYTES // 4:
            return None, None
        raw = p.read_bytes()
    except OSError:
        return None, None
    return (hashlib.blake2b(raw, digest_size=16).digest(), channel), raw


def _size_check(path: Path, width: int, height: int, planes: int) -> tuple:
    """Arguments of :func:`check_size` for an image's header."""
    return (width * height * planes * 4, f"image {path}",
            f"its header declares {width} x {height} px of {planes} band(s)")


def _decode(p: Path, channel: str, raw: bytes | None = None) -> tuple[np.ndarray, tuple]:
    """Decode an image file (:func:`read_image`), from ``raw`` (its bytes, already read)
    when given; also its header's width, height and bands."""
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(p if raw is None else io.BytesIO(raw)) as img:
            declared = _check_dimensions(img, p)
            mode = img.mode
            data = _pil_array(img, mode, channel, p)
    except FileNotFoundError:
        raise InputError(f"image file {p} does not exist (check the files list)") from None
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError, EOFError,
            Image.DecompressionBombError, MemoryError) as err:
        raise InputError(f"cannot read image {p}: {err} (is it an image file Pillow "
                         "reads, e.g. PNG, TIFF, BMP?)") from None
    return _checked_image(p, mode, data), declared


def _check_dimensions(img, path: Path) -> tuple:
    """Refuse the size an image's header declares before its pixels are decoded; return
    width, height and bands."""
    width, height = img.size
    planes = len(img.getbands())
    if width <= 0 or height <= 0:
        raise InputError(f"image {path}: its header declares {width} x {height} px")
    # Pillow decodes into 4 bytes per band at most (modes I and F)
    check_size(*_size_check(path, width, height, planes))
    return width, height, planes


def is_lossy(path: str | os.PathLike) -> bool:
    """True when the image file uses lossy compression (JPEG and the like).

    Parameters
    ----------
    path : str or PathLike
        An image file that :func:`read_image` reads.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(regular_file(path, "image file")) as img:
            return img.format in LOSSY_FORMATS
    except (OSError, UnidentifiedImageError, ValueError, InputError, SyntaxError, EOFError,
            Image.DecompressionBombError):
        return False


def _pil_array(img, mode: str, channel: str, path: Path) -> np.ndarray | None:
    """Pixel array of a Pillow image: grey as stored, colour only by channel."""
    if mode in _COLOUR_MODES:
        if not channel:
            raise InputError(
                f"image {path} is a colour image (mode {mode!r}); name the channel that "
                "carries the fringes with channel = \"red\", \"green\" or \"blue\" in the "
                "[decode] table of patterns.toml (or convert the images to grey)")
        if channel not in CHANNELS:
            raise InputError(f"channel must be one of {', '.join(CHANNELS)}, got {channel!r}")
        rgb = img.convert("RGB")
        return np.array(rgb)[..., CHANNELS.index(channel)]
    if channel:
        raise InputError(f"image {path} is a grey image (mode {mode!r}) but channel = "
                         f"{channel!r} is set; remove channel from the [decode] table")
    if mode in _PIL_MODES or mode in ("I", "1", "F"):
        return np.array(img)
    return None


def _checked_image(path: Path, mode: str, data: np.ndarray | None) -> np.ndarray:
    """Map a decoded Pillow image to uint8/uint16 or raise naming the mode."""
    if data is None or data.ndim != 2:
        raise InputError(f"image {path} has mode {mode!r}; expected a grey 8- or 16-bit "
                         "image (or a colour image with a named channel)")
    if mode == "1":
        return data.astype(np.uint8)
    if mode in ("I", "F"):  # 32-bit containers Pillow uses for some 16-bit files
        if not np.array_equal(data, np.rint(data)) or data.min() < 0 or data.max() > 65535:
            raise InputError(f"image {path} holds values outside 0..65535 or fractions "
                             f"(mode {mode!r}); expected 8 to 16 bit (use a .npy/.npz "
                             "stack for float data)")
        return data.astype(np.uint16)
    return data.astype(_PIL_MODES.get(mode, np.uint8), copy=False)


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
    if not p.exists():
        raise InputError(f"stack file {p} does not exist (check the stack entry)")
    if p.suffix.lower() == ".npy":
        data = load_npy(p, "image stack")
    else:
        data = _npz_member(p, key)
    return _checked_stack(p, key, data)


def _npz_member(path: Path, key: str) -> np.ndarray:
    """One array of a .npz file, chosen by key (or the only one); the archive is read
    by :func:`scanqa.io.npzfile.load_npz`, which checks sizes before decompressing."""
    import zipfile

    try:
        with zipfile.ZipFile(regular_file(path, "image stack")) as archive:
            names = [n[:-4] for n in archive.namelist() if n.endswith(".npy")]
    except (OSError, zipfile.BadZipFile, ValueError, EOFError) as err:
        raise InputError(f"cannot read image stack {path}: damaged or not an .npz file "
                         f"({err})") from None
    if not key and len(names) == 1:
        key = names[0]
    if key not in names:
        hint = "name one with stack_key" if not key else "check stack_key"
        raise InputError(f"stack {path} has no array {key!r} (arrays: "
                         f"{', '.join(names) or 'none'}; {hint})")
    return load_npz(path, "image stack", keys=[key])[key]


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
    """Write a single-channel uint8/uint16 image as PNG, TIFF or BMP, atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; the suffix (.png, .tif, .tiff, .bmp) selects the format.
    image : (H, W) uint8 or uint16
        Pixel values [DN]; BMP takes uint8 only.

    Returns
    -------
    Path
        The written file.
    """
    from PIL import Image

    p = Path(path)
    arr = np.asarray(image)
    suffix = p.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise InputError(f"cannot write image {p}: suffix must be one of {IMAGE_SUFFIXES}")
    if arr.ndim != 2 or arr.dtype not in (np.uint8, np.uint16) or (
            suffix == ".bmp" and arr.dtype != np.uint8):
        raise InputError(f"cannot write image {p}: need a 2-D uint8 (BMP) or uint8/uint16 "
                         f"(PNG, TIFF) array, got shape {arr.shape} dtype {arr.dtype} (use "
                         "a .npy/.npz stack for float data)")
    # zlib level 1: 5x faster than Pillow's default 6 for 3 % larger files (16-bit, 5 MP)
    options = {".png": {"format": "PNG", "compress_level": 1}, ".bmp": {"format": "BMP"}
               }.get(suffix, {"format": "TIFF"})
    with atomic_path(p) as tmp:
        Image.fromarray(np.ascontiguousarray(arr)).save(tmp, **options)
    return p
