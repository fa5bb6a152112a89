"""Binary PLY point clouds with per-point attributes named ``scalar_<name>``.

Coordinates are ``double x, y, z`` [mm]; every other column is a ``float`` vertex
property called ``scalar_<name>``. CloudCompare's command line loads only ``scalar_*``
properties as scalar fields, and it first matches property names by substring for
colours and normals (RED, GREEN, BLUE, NX, NY, NZ, INTENSITY, GRAY, GREY), so
:func:`check_attribute_name` refuses names that contain any of those. Open3D's tensor
reader (``open3d.t.io.read_point_cloud``) loads the same properties under their names.

A cloud with an ``offset_dn`` attribute (the fringe offset, the scene's brightness) also
carries display fields that viewers colour by: ``float intensity`` (the 16-bit grey level
the LAS export stores as intensity, [-]) and a grey ``uchar red, green, blue`` (its top 8
bits) with ``alpha`` 255. They are derived, not data: a header comment
(:data:`DISPLAY_COMMENT`) marks them, and :func:`read_ply` leaves them out again.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.guard import loads_json_object
from scanqa.io.las import INTENSITY_SOURCE, grey_levels
from scanqa.io.ply_display import (  # noqa: F401 - fill_display, display_scale: public here too
    DISPLAY_COMMENT,
    DISPLAY_FIELDS,
    display_scale,
    fill_display,
    fill_display_grey,
    fill_display_records,
)

#: Substrings CloudCompare claims for colours/normals before it looks for scalar fields.
RESERVED_SUBSTRINGS = ("red", "green", "blue", "nx", "ny", "nz", "intensity", "gray", "grey")
PREFIX = "scalar_"
#: Normals and colours of clouds from Open3D, CloudCompare and others: read and written
#: under their own names (and types), so that those tools show them as such.
STANDARD_PROPERTIES = ("nx", "ny", "nz", "red", "green", "blue", "alpha")
#: The normals among them: float32 fields after the ``scalar_`` ones in
#: :func:`vertex_dtype` (annotate estimates them, :mod:`scanqa.model.normals`).
NORMALS = STANDARD_PROPERTIES[:3]

log = logging.getLogger(__name__)
#: Start of the header comments that carry scanqa's metadata as JSON, in pieces of at
#: most :data:`META_CHUNK` characters: PLY readers (rply in Open3D and CloudCompare)
#: abort on header lines longer than ~1 kB.
META_COMMENT = "comment scanqa-meta"
META_CHUNK = 160


def check_attribute_name(name: str) -> None:
    """Raise if ``name`` would not survive CloudCompare's PLY loader as itself (the
    normals and colours of :data:`STANDARD_PROPERTIES` are what they claim to be)."""
    if name in STANDARD_PROPERTIES:
        return
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
        Packed little-endian ``x, y, z`` (float64, [mm]), one float32 field
        ``scalar_<name>`` per attribute, then float32 ``nx, ny, nz`` where the names hold
        the :data:`NORMALS` and, with an ``offset_dn`` attribute, the
        :data:`DISPLAY_FIELDS` (filled by :func:`write_ply`).
    """
    return _vertex_dtype(tuple(names))


@functools.lru_cache(maxsize=32)
def _vertex_dtype(names: tuple[str, ...]) -> np.dtype:
    """:func:`vertex_dtype` of a tuple of names, made once (chunked producers ask for it
    per chunk)."""
    display = list(DISPLAY_FIELDS) if INTENSITY_SOURCE in names else []
    normals = [(name, "<f4") for name in names if name in NORMALS]
    return np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
                    + [(PREFIX + name, "<f4") for name in names if name not in NORMALS]
                    + normals + display)


def attribute_names(dtype: np.dtype) -> list[str]:
    """The attribute names of a record layout (:func:`vertex_dtype`), in file order: the
    ``scalar_`` ones, then the normals."""
    return list(_attribute_names(dtype))


@functools.lru_cache(maxsize=32)
def _attribute_names(dtype: np.dtype) -> tuple[str, ...]:
    """:func:`attribute_names`, worked out once per layout."""
    return tuple(name[len(PREFIX):] if name.startswith(PREFIX) else name
                 for name in dtype.names[3:] if name.startswith(PREFIX) or name in NORMALS)


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
        One view per ``scalar_<name>`` field, names without the prefix, and per normal.

    Notes
    -----
    A producer that fills records in place (``annotate``) hands these views on like any
    arrays; :func:`write_ply` recognises them and writes the records as they are, with
    one ``tofile`` and no second copy of the cloud.
    """
    names = attribute_names(records.dtype)
    if records.dtype != vertex_dtype(names):
        raise ValueError(f"records must have the layout of vertex_dtype, got {records.dtype}")
    xyz = np.ndarray((records.size, 3), dtype="<f8", buffer=records,
                     strides=(records.itemsize, 8))
    return xyz, {name: records[_field(name)] for name in names}


def attribute_block(records: np.ndarray) -> np.ndarray:
    """The attribute fields of contiguous records (:func:`vertex_dtype`) as one array.

    Parameters
    ----------
    records : (n,) ndarray
        C-contiguous records in the layout of :func:`vertex_dtype`.

    Returns
    -------
    (n, k) float32 ndarray
        A view: column j is ``scalar_`` attribute j (normals not included). Assigning
        a whole block writes every record's attributes in one sequential pass (cheaper
        than k strided field writes).
    """
    words = records.view(np.float32).reshape(records.size, records.itemsize // 4)
    count = sum(name not in NORMALS for name in attribute_names(records.dtype))
    return words[:, 6:6 + count]


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
        Per-point values, written as float properties ``scalar_<name>``; normals and
        colours (:data:`STANDARD_PROPERTIES`) under their own names and types.
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
    Arrays from :func:`vertex_views` are written straight from their record array (its
    display fields filled in place); any others are packed into records one chunk at a
    time. With an ``offset_dn`` attribute and no colours of its own, the cloud gets the
    display fields of the module notes.
    """
    xyz = np.asarray(xyz, dtype="<f8")
    n = xyz.shape[0]
    attributes = {name: np.asarray(values) for name, values in attributes.items()}
    for name, values in attributes.items():
        check_attribute_name(name)
        if values.shape != (n,):
            raise InputError(f"attribute {name!r} has shape {values.shape}, expected ({n},)")
    dtype = _file_dtype(attributes)
    rec = _records_of(xyz, attributes, dtype)
    display = "intensity" in dtype.names
    with atomic_path(path, suffix=".ply") as tmp, open(tmp, "wb") as fh:
        fh.write(_header(dtype, n, metadata))
        if rec is not None:
            if display:
                fill_display_records(rec)
            rec.tofile(fh)
        else:
            grey = grey_levels(attributes[INTENSITY_SOURCE]) if display else None
            _write_records(fh, xyz, attributes, dtype, grey)
    return Path(path)


@contextlib.contextmanager
def vertex_file(path: str | os.PathLike, names, n: int, metadata: dict | None = None,
                display: bool = True) -> Iterator[np.ndarray]:
    """Records of a new binary PLY mapped from the file itself, published on exit.

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    names : iterable of str
        Attribute names, in file order (:func:`vertex_dtype`).
    n : int
        Number of vertices [-].
    metadata : dict, optional
        Plain JSON for the header, as :func:`write_ply` writes it.
    display : bool
        Fill the display fields (with an ``offset_dn`` attribute) from the records after
        the block; False when the producer fills them itself as it writes each chunk
        (:func:`fill_display` with :func:`display_scale`), while the chunk is in cache.

    Yields
    ------
    (n,) ndarray
        Writable records in the layout of :func:`vertex_dtype`, a shared mapping of the
        temporary file's vertex data. After the block the display fields are filled
        (from ``offset_dn``, as :func:`write_ply` fills them; unless ``display`` is
        False), the array is made read-only, and the file is renamed onto ``path``;
        the array stays valid (it maps the published file).

    Notes
    -----
    The same bytes as :func:`write_ply` of the records' views, without the second copy:
    a producer that fills the records here writes the file once, into the page cache,
    instead of into anonymous memory that is then copied into it. The file's space is
    reserved before the mapping (``posix_fallocate``, where the OS has it), so a full
    disk is an :class:`~scanqa.errors.OutputError` here, not a fault while the records
    are filled.
    """
    names = list(names)
    for name in names:
        check_attribute_name(name)
    dtype = vertex_dtype(names)
    header = _header(dtype, n, metadata)
    with atomic_path(path, suffix=".ply") as tmp:
        with open(tmp, "wb+") as fh:
            fh.write(header)
            fh.flush()
            if n and hasattr(os, "posix_fallocate"):  # not on macOS: sized by the map
                os.posix_fallocate(fh.fileno(), len(header), n * dtype.itemsize)
            if n:
                records = np.memmap(fh, dtype=dtype, mode="r+", offset=len(header),
                                    shape=(n,))
            else:
                records = np.empty(0, dtype=dtype)
        yield records
        if display and INTENSITY_SOURCE in names:
            fill_display_records(records)
        records.flags.writeable = False


def _header(dtype: np.dtype, n: int, metadata: dict | None) -> bytes:
    """The ASCII header of a binary PLY of ``n`` records in the layout ``dtype``, with
    ``metadata`` as comment pieces and the display comment when the records have the
    display fields."""
    header = ["ply", "format binary_little_endian 1.0", "comment scanqa point cloud, mm"]
    if metadata:
        text = json.dumps(metadata, allow_nan=False, separators=(",", ":"))
        header += [f"{META_COMMENT} {text[i:i + META_CHUNK]}"
                   for i in range(0, len(text), META_CHUNK)]
    if "intensity" in dtype.names:
        header.append(DISPLAY_COMMENT)
    header.append(f"element vertex {n}")
    header += [f"property {_TYPE_NAMES[dtype[f].str[1:]]} {f}" for f in dtype.names]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode("ascii")


#: PLY type name of each numpy type code written.
_TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
               "u4": "uint", "f4": "float", "f8": "double"}


def _field(name: str) -> str:
    """The PLY property of an attribute: ``scalar_<name>``, or a standard name as is."""
    return name if name in STANDARD_PROPERTIES else PREFIX + name


def _file_dtype(attributes: dict[str, np.ndarray]) -> np.dtype:
    """Records as written: :func:`vertex_dtype`, with normals and colours in their own
    type (float32 when theirs is not a PLY type)."""
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    for name, values in attributes.items():
        code = values.dtype.str[1:] if values.dtype.kind in "uif" else ""
        keep = name in STANDARD_PROPERTIES and code in _TYPE_NAMES
        fields.append((_field(name), "<" + code if keep else "<f4"))
    if INTENSITY_SOURCE in attributes and not set(STANDARD_PROPERTIES[3:]) & set(attributes):
        fields += DISPLAY_FIELDS  # colours of its own win over the derived grey
    return np.dtype(fields)


def _address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


def _records_of(xyz: np.ndarray, attributes: dict[str, np.ndarray], dtype: np.dtype
                ) -> np.ndarray | None:
    """The writable record array (layout ``dtype``) that ``xyz`` and every attribute are
    exactly the fields of, as :func:`vertex_views` makes them; None for any other arrays
    (read-only records, e.g. of :func:`vertex_file`, are packed chunk by chunk)."""
    rec = xyz.base
    if not (isinstance(rec, np.ndarray) and rec.dtype == dtype and rec.ndim == 1
            and rec.flags.c_contiguous and rec.flags.writeable and xyz.shape == (rec.size, 3)
            and xyz.strides == (dtype.itemsize, 8) and _address(xyz) == _address(rec)):
        return None
    for name, values in attributes.items():
        offset = dtype.fields[_field(name)][1]
        if (values.dtype != np.dtype("<f4") or values.strides != (dtype.itemsize,)
                or _address(values) != _address(rec) + offset):
            return None
    return rec


#: Records packed per write when the arrays are not one record array (~6 MB).
_WRITE_CHUNK = 1 << 16


def _write_records(fh, xyz: np.ndarray, attributes: dict[str, np.ndarray],
                   dtype: np.dtype, grey: np.ndarray | None) -> None:
    """Pack separate arrays into records and write them, one chunk at a time (with the
    display fields from the grey levels ``grey`` where given)."""
    buf = np.empty(min(len(xyz), _WRITE_CHUNK), dtype=dtype)
    for a in range(0, len(xyz), _WRITE_CHUNK):
        part = buf[:min(_WRITE_CHUNK, len(xyz) - a)]
        b = a + part.size
        part["x"], part["y"], part["z"] = xyz[a:b, 0], xyz[a:b, 1], xyz[a:b, 2]
        for name, values in attributes.items():
            part[_field(name)] = values[a:b]
        if grey is not None:
            fill_display_grey(part, grey[a:b])
        part.tofile(fh)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
              "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
              "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4",
              "float32": "f4", "float64": "f8"}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "ascii"}
#: Longest header line and whole header read before giving up (a binary file without
#: newlines would otherwise be read whole) [bytes].
MAX_HEADER_LINE, MAX_HEADER = 4096, 1 << 20


@dataclass
class _Element:
    name: str
    count: int
    props: list = field(default_factory=list)  # (name, numpy code or None for a list)


def read_ply(path: str | os.PathLike
             ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    """Read the vertices of a PLY file (binary either endianness, or ascii).

    Other elements (faces of a mesh) are skipped. Properties other than x, y, z are
    returned as attributes: ``scalar_<name>`` as ``<name>``; normals and colours
    (:data:`STANDARD_PROPERTIES`) under their own names, so that they are written back
    as such; names that would not survive CloudCompare as themselves are left out (and
    logged).

    Returns
    -------
    xyz : (n, 3) float64
        Coordinates [mm].
    attributes : dict
        Per-point attributes, as described above.
    metadata : dict
        The ``scanqa-meta`` header comment, or {} when there is none.

    Raises
    ------
    InputError
        When the file is unreadable, not a PLY, has a malformed header, declares more
        vertices than it holds, or has no x, y, z.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            fmt, elements, metadata, derived = _read_header(fh, path)
            data = _read_vertices(fh, fmt, elements, size - fh.tell(), path)
    except OSError as err:
        raise InputError(f"cannot read point cloud {path}: {err.strerror or err}") from None
    names = data.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{path}: PLY vertices have no x, y, z properties (found "
                         f"{', '.join(names) or 'none'})")
    xyz = np.stack([data["x"], data["y"], data["z"]], -1).astype(float)
    return xyz, _attributes(data, path, derived), metadata


def _attributes(data: np.ndarray, path: Path, derived: tuple = ()
                ) -> dict[str, np.ndarray]:
    """The vertex properties other than x, y, z (and the display fields ``derived``)
    under the names scanqa gives them."""
    attrs, left_out = {}, []
    for prop in data.dtype.names:
        if prop in ("x", "y", "z", *derived):
            continue
        name = prop[len(PREFIX):] if prop.startswith(PREFIX) else prop
        try:
            check_attribute_name(name)
        except InputError:
            left_out.append(prop)
            continue
        if name in attrs:
            left_out.append(prop)
            continue
        values = data[prop]
        attrs[name] = values.astype(values.dtype.newbyteorder("="), copy=False)
    if left_out:
        log.info(f"{path}: vertex properties {', '.join(left_out)} left out (names that "
                 "CloudCompare would read as something else, or repeated)")
    return attrs


def _read_header(fh, path: Path) -> tuple[str, list[_Element], dict, tuple]:
    """(format, elements, metadata, derived display fields) of a PLY header; the file is
    left at the data."""
    if fh.readline(MAX_HEADER_LINE).rstrip(b"\r\n") != b"ply":
        raise InputError(f"{path} is not a PLY file (no 'ply' first line)")
    fmt, elements, meta, derived = None, [], [], ()
    while fh.tell() < MAX_HEADER:
        line = fh.readline(MAX_HEADER_LINE)
        if not line:
            raise InputError(f"{path}: PLY header has no end_header")
        if not line.endswith(b"\n") and len(line) == MAX_HEADER_LINE:
            raise InputError(f"{path}: PLY header line longer than {MAX_HEADER_LINE} bytes")
        text = line.decode("ascii", "replace").rstrip("\r\n")
        if text.startswith(META_COMMENT + " "):
            meta.append(text[len(META_COMMENT) + 1:])
            continue
        if text == DISPLAY_COMMENT:
            derived = tuple(name for name, _ in DISPLAY_FIELDS)
            continue
        parts = text.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "end_header":
            if fmt is None:
                raise InputError(f"{path}: PLY header has no format line")
            return fmt, elements, _metadata("".join(meta), path) if meta else {}, derived
        fmt = _header_line(parts, fmt, elements, path)
    raise InputError(f"{path}: PLY header longer than {MAX_HEADER} bytes")


def _header_line(parts: list[str], fmt: str | None, elements: list[_Element],
                 path: Path) -> str | None:
    """Apply one format/element/property line; returns the format."""
    where = f"{path}: PLY header line '{' '.join(parts)}'"
    if parts[0] == "format":
        if len(parts) != 3 or parts[1] not in _FORMATS:
            raise InputError(f"{where}: expected 'format FORMAT 1.0' with FORMAT one of "
                             f"{', '.join(_FORMATS)}")
        return _FORMATS[parts[1]]
    if parts[0] == "element":
        if len(parts) != 3 or not parts[2].isdigit():
            raise InputError(f"{where}: expected 'element NAME COUNT' with a whole "
                             "number COUNT")
        elements.append(_Element(parts[1], int(parts[2])))
    elif parts[0] == "property":
        _property(parts, elements, where)
    else:
        raise InputError(f"{where}: unknown keyword {parts[0]!r}")
    return fmt


def _property(parts: list[str], elements: list[_Element], where: str) -> None:
    if not elements:
        raise InputError(f"{where}: a property before any element")
    if len(parts) == 5 and parts[1] == "list" and parts[2] in _PLY_TYPES \
            and parts[3] in _PLY_TYPES:
        name, code = parts[4], None
    elif len(parts) == 3 and parts[1] in _PLY_TYPES:
        name, code = parts[2], _PLY_TYPES[parts[1]]
    else:
        raise InputError(f"{where}: expected 'property TYPE NAME' or 'property list "
                         f"COUNT_TYPE ITEM_TYPE NAME' with TYPE one of "
                         f"{', '.join(sorted(set(_PLY_TYPES)))}")
    element = elements[-1]
    if any(name == p[0] for p in element.props):
        raise InputError(f"{where}: property {name!r} appears twice in element "
                         f"{element.name!r}")
    element.props.append((name, code))


def _read_vertices(fh, fmt: str, elements: list[_Element], remaining: int,
                   path: Path) -> np.ndarray:
    """The vertex records; earlier elements are skipped."""
    for element in elements:
        fixed = all(code is not None for _, code in element.props)
        if element.name == "vertex":
            if not fixed:
                raise InputError(f"{path}: list properties in the vertex element are not "
                                 "supported")
            if fmt == "ascii":
                return _read_ascii(fh, element, remaining, path)
            dtype = np.dtype([(name, fmt + code) for name, code in element.props])
            need = element.count * dtype.itemsize
            if need > remaining:
                raise InputError(f"{path}: truncated PLY: the header declares "
                                 f"{element.count} vertices of {dtype.itemsize} bytes "
                                 f"({need} bytes) but {remaining} bytes follow it")
            return np.fromfile(fh, dtype=dtype, count=element.count)
        if not fixed:
            raise InputError(f"{path}: element {element.name!r} with list properties "
                             "before the vertices is not supported")
        remaining -= _skip(fh, fmt, element, remaining, path)
    raise InputError(f"{path}: PLY has no vertex element")


def _skip(fh, fmt: str, element: _Element, remaining: int, path: Path) -> int:
    """Skip the records of an element before the vertices; returns the bytes skipped."""
    if fmt == "ascii":
        start = fh.tell()
        for _ in range(element.count):
            if not fh.readline():
                raise InputError(f"{path}: truncated PLY in element {element.name!r}")
        return fh.tell() - start
    size = element.count * sum(np.dtype(code).itemsize for _, code in element.props)
    if size > remaining:
        raise InputError(f"{path}: truncated PLY in element {element.name!r}")
    fh.seek(size, os.SEEK_CUR)
    return size


def _read_ascii(fh, element: _Element, remaining: int, path: Path) -> np.ndarray:
    """Vertices of an ascii PLY as float64 records."""
    width = len(element.props)
    if element.count * 2 * width > remaining:  # each value takes 2 bytes at least
        raise InputError(f"{path}: truncated PLY: the header declares {element.count} "
                         f"vertices of {width} values but only {remaining} bytes follow it")
    try:
        values = np.loadtxt(fh, dtype=float, max_rows=element.count, ndmin=2)
    except ValueError as err:
        raise InputError(f"{path}: ascii PLY vertices are not numbers ({err})") from None
    if values.shape != (element.count, width) and element.count:
        raise InputError(f"{path}: ascii PLY holds {values.shape[0]} vertices of "
                         f"{values.shape[1]} values, the header declares {element.count} "
                         f"of {width}")
    dtype = np.dtype([(name, "f8") for name, _ in element.props])
    out = np.empty(element.count, dtype)
    for k, (name, _) in enumerate(element.props):
        out[name] = values[:, k] if element.count else []
    return out


def _metadata(text: str, path: Path) -> dict:
    return loads_json_object(text, f"{path}: the scanqa-meta header comment")
