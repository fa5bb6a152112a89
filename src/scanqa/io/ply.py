"""Binary PLY point clouds with per-point attributes named ``scalar_<name>``.

Coordinates are ``double x, y, z`` [mm]; every other column is a ``float`` vertex
property called ``scalar_<name>``. CloudCompare's command line loads only ``scalar_*``
properties as scalar fields, and it first matches property names by substring for
colours and normals (RED, GREEN, BLUE, NX, NY, NZ, INTENSITY, GRAY, GREY), so
:func:`check_attribute_name` refuses names that contain any of those. Open3D's tensor
reader (``open3d.t.io.read_point_cloud``) loads the same properties under their names.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path

#: Substrings CloudCompare claims for colours/normals before it looks for scalar fields.
RESERVED_SUBSTRINGS = ("red", "green", "blue", "nx", "ny", "nz", "intensity", "gray", "grey")
PREFIX = "scalar_"
#: Start of the header comments that carry scanqa's metadata as JSON, in pieces of at
#: most :data:`META_CHUNK` characters: PLY readers (rply in Open3D and CloudCompare)
#: abort on header lines longer than ~1 kB.
META_COMMENT = "comment scanqa-meta"
META_CHUNK = 160


def check_attribute_name(name: str) -> None:
    """Raise if ``name`` would not survive CloudCompare's PLY loader as itself."""
    low = f"{PREFIX}{name}".lower()
    for bad in RESERVED_SUBSTRINGS:
        if bad in low:
            raise InputError(f"attribute name {name!r} contains {bad!r}, which CloudCompare "
                             "would read as a colour or normal: rename it")
    if not re.fullmatch(r"[A-Za-z0-9_]+", name):
        raise InputError(f"attribute name {name!r} must be letters, digits and underscores")


def vertex_dtype(names) -> np.dtype:
    """Record layout of a vertex as :func:`write_ply` writes it.

    Parameters
    ----------
    names : iterable of str
        Attribute names, in file order.

    Returns
    -------
    numpy.dtype
        Packed little-endian ``x, y, z`` (float64, [mm]) and one float32 field
        ``scalar_<name>`` per attribute.
    """
    return np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
                    + [(PREFIX + name, "<f4") for name in names])


def vertex_views(records: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Coordinates and attributes of a record array, as views that :func:`write_ply`
    writes without a copy.

    Parameters
    ----------
    records : (n,) ndarray
        Records in the layout of :func:`vertex_dtype`.

    Returns
    -------
    xyz : (n, 3) float64
        Coordinates [mm] (a strided, unaligned view).
    attributes : dict of str to (n,) float32
        One view per ``scalar_<name>`` field, names without the prefix.

    Notes
    -----
    A producer that fills records in place (``annotate``) hands these views on like any
    arrays; :func:`write_ply` recognises them and writes the records as they are, with
    one ``tofile`` and no second copy of the cloud.
    """
    names = [name[len(PREFIX):] for name in records.dtype.names[3:]]
    if records.dtype != vertex_dtype(names):
        raise ValueError(f"records must have the layout of vertex_dtype, got {records.dtype}")
    xyz = np.ndarray((records.size, 3), dtype="<f8", buffer=records,
                     strides=(records.itemsize, 8))
    return xyz, {name: records[PREFIX + name] for name in names}


def attribute_block(records: np.ndarray) -> np.ndarray:
    """The attribute fields of contiguous records (:func:`vertex_dtype`) as one array.

    Parameters
    ----------
    records : (n,) ndarray
        C-contiguous records in the layout of :func:`vertex_dtype`.

    Returns
    -------
    (n, k) float32 ndarray
        A view: column j is attribute j. Assigning a whole block writes every record's
        attributes in one sequential pass (cheaper than k strided field writes).
    """
    words = records.view(np.float32).reshape(records.size, records.itemsize // 4)
    return words[:, 6:]


def write_ply(path: str | os.PathLike, xyz: np.ndarray, attributes: dict[str, np.ndarray],
              metadata: dict | None = None) -> Path:
    """Write points and attributes as a binary little-endian PLY, atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    xyz : (n, 3) float
        Coordinates [mm], written as double.
    attributes : dict of str to (n,) array
        Per-point values, written as float properties ``scalar_<name>``.
    metadata : dict, optional
        Plain JSON written as header lines ``comment scanqa-meta <piece>`` (the
        pieces concatenate to the JSON text); readers that do not know it skip them as
        comments.

    Returns
    -------
    Path
        The written file.

    Notes
    -----
    Arrays from :func:`vertex_views` are written straight from their record array;
    any others are packed into records one chunk at a time.
    """
    xyz = np.asarray(xyz, dtype="<f8")
    n = xyz.shape[0]
    attributes = {name: np.asarray(values) for name, values in attributes.items()}
    for name, values in attributes.items():
        check_attribute_name(name)
        if values.shape != (n,):
            raise InputError(f"attribute {name!r} has shape {values.shape}, expected ({n},)")
    dtype = vertex_dtype(attributes)
    header = ["ply", "format binary_little_endian 1.0", "comment scanqa point cloud, mm"]
    if metadata:
        text = json.dumps(metadata, allow_nan=False, separators=(",", ":"))
        header += [f"{META_COMMENT} {text[i:i + META_CHUNK]}"
                   for i in range(0, len(text), META_CHUNK)]
    header.append(f"element vertex {n}")
    header += [f"property {'double' if dtype[f] == np.dtype('<f8') else 'float'} {f}"
               for f in dtype.names]
    header.append("end_header")
    rec = _records_of(xyz, attributes, dtype)
    with atomic_path(path, suffix=".ply") as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        if rec is not None:
            rec.tofile(fh)
        else:
            _write_records(fh, xyz, attributes, dtype)
    return Path(path)


def _address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


def _records_of(xyz: np.ndarray, attributes: dict[str, np.ndarray], dtype: np.dtype
                ) -> np.ndarray | None:
    """The record array (layout ``dtype``) that ``xyz`` and every attribute are exactly
    the fields of, as :func:`vertex_views` makes them; None for any other arrays."""
    rec = xyz.base
    if not (isinstance(rec, np.ndarray) and rec.dtype == dtype and rec.ndim == 1
            and rec.flags.c_contiguous and xyz.shape == (rec.size, 3)
            and xyz.strides == (dtype.itemsize, 8) and _address(xyz) == _address(rec)):
        return None
    for name, values in attributes.items():
        offset = dtype.fields[PREFIX + name][1]
        if (values.dtype != np.dtype("<f4") or values.strides != (dtype.itemsize,)
                or _address(values) != _address(rec) + offset):
            return None
    return rec


#: Records packed per write when the arrays are not one record array (~6 MB).
_WRITE_CHUNK = 1 << 16


def _write_records(fh, xyz: np.ndarray, attributes: dict[str, np.ndarray],
                   dtype: np.dtype) -> None:
    """Pack separate arrays into records and write them, one chunk at a time."""
    buf = np.empty(min(len(xyz), _WRITE_CHUNK), dtype=dtype)
    for a in range(0, len(xyz), _WRITE_CHUNK):
        part = buf[:min(_WRITE_CHUNK, len(xyz) - a)]
        b = a + part.size
        part["x"], part["y"], part["z"] = xyz[a:b, 0], xyz[a:b, 1], xyz[a:b, 2]
        for name, values in attributes.items():
            part[PREFIX + name] = values[a:b]
        part.tofile(fh)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
              "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
              "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4",
              "float32": "f4", "float64": "f8"}


def read_ply(path: str | os.PathLike
             ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    """Read a binary little-endian PLY vertex element (as written by :func:`write_ply`).

    Returns
    -------
    xyz : (n, 3) float64
        Coordinates [mm].
    attributes : dict
        Every other vertex property, ``scalar_`` prefix removed.
    metadata : dict
        The ``scanqa-meta`` header comment, or {} when there is none.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            fields, n, metadata = _read_header(fh, path)
            data = np.fromfile(fh, dtype=fields, count=n)
    except OSError as err:
        raise InputError(f"cannot read point cloud {path}: {err.strerror}") from None
    if data.size != n:
        raise InputError(f"{path}: truncated PLY ({data.size} of {n} vertices)")
    names = data.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{path}: PLY has no x, y, z vertex properties")
    xyz = np.stack([data["x"], data["y"], data["z"]], -1).astype(float)
    attrs = {(k[len(PREFIX):] if k.startswith(PREFIX) else k): np.asarray(data[k])
             for k in names if k not in ("x", "y", "z")}
    return xyz, attrs, metadata


def _read_header(fh, path: Path) -> tuple[list, int, dict]:
    if fh.readline().strip() != b"ply":
        raise InputError(f"{path} is not a PLY file")
    fields, n, in_vertex, meta = [], 0, False, []
    while True:
        line = fh.readline()
        if not line:
            raise InputError(f"{path}: PLY header has no end_header")
        text = line.decode("ascii", "replace")
        if text.startswith(META_COMMENT + " "):
            meta.append(text[len(META_COMMENT) + 1:].rstrip("\r\n"))
            continue
        parts = text.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format" and parts[1] != "binary_little_endian":
            raise InputError(f"{path}: only binary_little_endian PLY is supported, got "
                             f"{parts[1]}")
        if parts[0] == "element":
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                n = int(parts[2])
            elif n:
                raise InputError(f"{path}: elements after 'vertex' are not supported")
        elif parts[0] == "property" and in_vertex:
            if parts[1] == "list" or parts[1] not in _PLY_TYPES:
                raise InputError(f"{path}: unsupported vertex property {' '.join(parts[1:])}")
            fields.append((parts[2], "<" + _PLY_TYPES[parts[1]]))
        elif parts[0] == "end_header":
            return fields, n, _metadata("".join(meta), path) if meta else {}


def _metadata(text: str, path: Path) -> dict:
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(f"{path}: the scanqa-meta header comment is not valid JSON ({err}); "
                         "delete that header line or write the cloud again") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: the scanqa-meta header comment must be a JSON object")
    return meta
