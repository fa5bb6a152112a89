"""Reading ``.npz`` files (numpy zip archives) without trusting them.

``numpy.load`` allocates what an entry's header declares before reading its data, so a
damaged or hostile file (a shape of 10^12 elements) exhausts memory before any check,
and a damaged archive raises ``zlib.error``, ``BadZipFile`` or ``EOFError`` depending on
where the damage is. :func:`load_npz` checks every entry's declared size against the
bytes the archive holds, reads the data incrementally (memory grows with the data that
is really there), verifies the archive's checksums and refuses object (pickled) arrays;
every failure is one :class:`~scanqa.errors.InputError` naming the file and the entry.
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from scanqa.errors import InputError

#: Deflate cannot expand data more than ~1032 times: an entry declaring more is damaged.
MAX_EXPANSION = 1100
#: Bytes read at a time [bytes].
_CHUNK = 1 << 24
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0,
                   (2, 0): np.lib.format.read_array_header_2_0}


def load_npz(path: str | os.PathLike, what: str, keys: Iterable[str] | None = None
             ) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` file, checked before they are allocated.

    Parameters
    ----------
    path : str or PathLike
        The file.
    what : str
        What the file is, for messages ("phase map", "calibration table", ...).
    keys : iterable of str, optional
        Entries to read (others are skipped); default all.

    Returns
    -------
    dict of str to ndarray
        Entry name (without ``.npy``) to array.

    Raises
    ------
    InputError
        Missing or unreadable file, not a zip archive, a checksum error (bit flips), an
        entry whose header declares more data than it holds, an unsupported or object
        (pickled) array.
    """
    p = Path(path)
    wanted = None if keys is None else set(keys)
    try:
        with zipfile.ZipFile(p) as archive:
            return {info.filename[:-4]: _read_entry(archive, info, p, what)
                    for info in archive.infolist()
                    if info.filename.endswith(".npy")
                    and (wanted is None or info.filename[:-4] in wanted)}
    except FileNotFoundError:
        raise InputError(f"{what} {p} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{what} {p} is a folder, not a file") from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, ValueError,
            NotImplementedError) as err:
        raise InputError(f"cannot read {what} {p}: damaged or not an .npz file ({err})"
                         ) from None


def _read_entry(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path,
                what: str) -> np.ndarray:
    """One entry, its declared size checked against the archive's."""
    where = f"{what} {path}, entry {info.filename[:-4]!r}"
    if info.file_size > MAX_EXPANSION * info.compress_size + 4096:
        raise InputError(f"{where}: declares {info.file_size} bytes from "
                         f"{info.compress_size} compressed ones (damaged file)")
    with archive.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        reader = _HEADER_READERS.get(version)
        if reader is None:
            raise InputError(f"{where}: unsupported .npy version {version}")
        shape, fortran, dtype = reader(fh)
        if dtype.hasobject:
            raise InputError(f"{where}: holds Python objects (pickle), which scanqa never "
                             "loads")
        nbytes = math.prod(shape) * dtype.itemsize
        held = info.file_size - fh.tell()
        if nbytes != held:
            raise InputError(f"{where}: its header declares shape {shape} of {dtype} "
                             f"({nbytes} bytes) but the entry holds {held} bytes "
                             "(damaged file)")
        buf = bytearray()
        while len(buf) < nbytes:
            chunk = fh.read(min(_CHUNK, nbytes - len(buf)))
            if not chunk:
                raise InputError(f"{where}: truncated ({len(buf)} of {nbytes} bytes)")
            buf += chunk
        fh.read(1)  # reach the end, where zipfile checks the CRC
    array = np.frombuffer(buf, dtype=dtype) if nbytes else np.empty(0, dtype)
    return array.reshape(shape, order="F" if fortran else "C")
