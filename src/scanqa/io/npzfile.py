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
from scanqa.io.guard import check_size, regular_file

#: Deflate cannot expand data more than ~1032 times: an entry declaring more is damaged.
MAX_EXPANSION = 1100
#: General-purpose flag bits of an encrypted entry: 0 (encrypted), 6 (strong encryption),
#: 13 (masked local header); zipfile checks bit 0 only and would read the others as plain.
_ENCRYPTION_FLAGS = 0x1 | 0x40 | 0x2000
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
        regular_file(p, what)
        with zipfile.ZipFile(p) as archive:
            infos = [info for info in archive.infolist() if info.filename.endswith(".npy")
                     and (wanted is None or info.filename[:-4] in wanted)]
            _check_directory(infos, p, what)
            return {info.filename[:-4]: _read_entry(archive, info, p, what)
                    for info in infos}
    except FileNotFoundError:
        raise InputError(f"{what} {p} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{what} {p} is a folder, not a file") from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, ValueError,
            NotImplementedError, RuntimeError, OverflowError) as err:
        raise InputError(f"cannot read {what} {p}: damaged or not an .npz file ({err})"
                         ) from None


def _check_directory(infos: list[zipfile.ZipInfo], path: Path, what: str) -> None:
    """Refuse encrypted entries and declared sizes beyond the limit, before reading."""
    for info in infos:
        where = f"{what} {path}, entry {info.filename[:-4]!r}"
        if info.flag_bits & _ENCRYPTION_FLAGS:
            raise InputError(f"{where}: encrypted (scanqa reads plain numpy .npz files; "
                             "write it again with numpy.savez)")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise InputError(f"{where}: zip compression method {info.compress_type} "
                             "(numpy writes stored or deflated entries; write it again with "
                             "numpy.savez)")
    total = sum(info.file_size for info in infos)
    check_size(total, f"{what} {path}", f"its entries declare {total} bytes "
               "uncompressed")


def _read_entry(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path,
                what: str) -> np.ndarray:
    """One entry, its declared size checked against the archive's."""
    where = f"{what} {path}, entry {info.filename[:-4]!r}"
    if info.file_size > MAX_EXPANSION * info.compress_size + 4096:
        raise InputError(f"{where}: declares {info.file_size} bytes from "
                         f"{info.compress_size} compressed ones (damaged file)")
    with archive.open(info) as fh:
        return _read_array(fh, info.file_size, where, crc=True)


def load_npy(path: str | os.PathLike, what: str) -> np.ndarray:
    """The array of a ``.npy`` file, its header checked against the file's size and
    :func:`scanqa.io.guard.max_input_bytes` before anything is allocated.

    Parameters
    ----------
    path : str or PathLike
        The file.
    what : str
        What the file is, for messages ("image stack", ...).

    Returns
    -------
    ndarray
        The array as stored.

    Raises
    ------
    InputError
        Missing, not a regular file, not an .npy file, a header declaring more (or
        less) than the file holds, or an object (pickled) array.
    """
    p = regular_file(path, what)
    where = f"{what} {p}"
    try:
        with open(p, "rb") as fh:
            return _read_array(fh, os.fstat(fh.fileno()).st_size, where, crc=False)
    except (OSError, EOFError, ValueError) as err:
        raise InputError(f"cannot read {where}: damaged or not an .npy file ({err})"
                         ) from None


def _read_array(fh, size: int, where: str, crc: bool) -> np.ndarray:
    """The array of an open .npy stream of ``size`` bytes, read incrementally after its
    header's size is checked (module notes)."""
    version = np.lib.format.read_magic(fh)
    reader = _HEADER_READERS.get(version)
    if reader is None:
        raise InputError(f"{where}: unsupported .npy version {version}")
    shape, fortran, dtype = reader(fh)
    if dtype.hasobject:
        raise InputError(f"{where}: holds Python objects (pickle), which scanqa never "
                         "loads")
    nbytes = math.prod(shape) * dtype.itemsize
    held = size - fh.tell()
    if nbytes != held:
        raise InputError(f"{where}: its header declares shape {shape} of {dtype} "
                         f"({nbytes} bytes) but the entry holds {held} bytes "
                         "(damaged file)")
    check_size(nbytes, where, f"its header declares shape {shape} of {dtype}")
    buf = bytearray()
    while len(buf) < nbytes:
        chunk = fh.read(min(_CHUNK, nbytes - len(buf)))
        if not chunk:
            raise InputError(f"{where}: truncated ({len(buf)} of {nbytes} bytes)")
        buf += chunk
    if crc:
        fh.read(1)  # reach the end, where zipfile checks the CRC
    array = np.frombuffer(buf, dtype=dtype) if nbytes else np.empty(0, dtype)
    return array.reshape(shape, order="F" if fortran else "C")
