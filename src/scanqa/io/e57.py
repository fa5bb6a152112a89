"""E57 point clouds (ASTM E2807, the exchange format of 3D imaging systems) through
pye57's bindings of libE57Format (the ``e57`` extra).

What :func:`write_e57` writes, in one scan (``/data3D/0``):

* ``cartesianX/Y/Z``: the points as 64-bit floats in metres (the E57 unit of length),
  with the scan's ``cartesianBounds``; no pose (the scanner frame);
* ``intensity`` [DN]: the fringe offset (the scene's brightness) when the cloud has an
  ``offset_dn`` attribute, with ``intensityLimits``; viewers colour by it;
* every per-point attribute as a 32-bit float extension field ``scanqa:<name>`` (the
  names of the PLY and LAS exports, units in the names), and its unit and description
  in the scan's ``scanqa:fields`` structure (``scanqa:fields/<name>/unit``);
* normals ``nx, ny, nz`` as the fields ``nor:normalX/Y/Z`` of the E57 surface-normals
  extension, which CloudCompare and other readers load as normals;
* scanqa's metadata (model, config, calibration, software: the provenance) as JSON in
  the scan's string ``scanqa:metadata``, and a one-line summary in its ``description``.

:func:`read_e57` reads these files back whole (coordinates in mm), and any other E57
file with Cartesian points: every scan, each moved by its pose into the file's frame;
points whose ``cartesianInvalidState`` is not 0 left out; extension fields under their
names without the prefix, standard fields under scanqa names (``intensity`` ->
``brightness``, ``colorRed`` -> ``red``, ``timeStamp`` -> ``time_s``, ...).
"""

from __future__ import annotations

import importlib.util
import json
import os
import uuid
from pathlib import Path

import numpy as np

from scanqa.errors import InputError, OutputError
from scanqa.io.atomic import atomic_path
from scanqa.io.guard import loads_json_object
from scanqa.io.las import INTENSITY_SOURCE, UNIT_SUFFIXES

#: Namespace prefix and URI of scanqa's E57 extension (per-point attributes, their
#: units and the provenance). A URI names the extension; it need not resolve.
NAMESPACE = ("scanqa", "urn:x-scanqa:e57:1.0")
#: The E57 surface-normals extension (libE57's), which CloudCompare reads as normals.
NORMALS = ("nor", "http://www.libe57.org/E57_NOR_surface_normals.txt")
#: scanqa attribute -> E57 field of the normals extension.
NORMAL_FIELDS = {"nx": "nor:normalX", "ny": "nor:normalY", "nz": "nor:normalZ"}
#: Standard E57 point fields read under scanqa names (ending in their unit).
STANDARD_NAMES = {"intensity": "brightness", "colorRed": "red", "colorGreen": "green",
                  "colorBlue": "blue", "rowIndex": "row_px", "columnIndex": "column_px",
                  "timeStamp": "time_s", "returnIndex": "return_index",
                  "returnCount": "return_count"}
#: Fields that say whether another is valid: read to drop points, not kept.
VALIDITY_FIELDS = ("cartesianInvalidState", "sphericalInvalidState", "isColorInvalid",
                   "isIntensityInvalid", "isTimeStampInvalid")
#: Points written or read per block [-].
CHUNK = 1 << 20
#: What ``check_format`` says when pye57 is missing.
INSTALL_HINT = "E57 needs pye57 (pip install 'scanqa[e57]'); or use .ply, .las or .csv"


def available() -> bool:
    """pye57 (libE57Format) is installed."""
    return importlib.util.find_spec("pye57") is not None


def _pye57():
    try:
        import pye57
        from pye57 import libe57
    except ImportError:
        raise InputError(INSTALL_HINT) from None
    return pye57, libe57


def unit_of(name: str) -> str:
    """The unit of an attribute by its name's suffix (``sigma_total_um`` -> ``um``),
    ``-`` when it names none."""
    for suffix, unit in sorted(UNIT_SUFFIXES.items(), key=lambda kv: -len(kv[0])):
        if name.endswith(suffix):
            return unit
    return "-"


def write_e57(path: str | os.PathLike, xyz: np.ndarray, attributes: dict[str, np.ndarray],
              metadata: dict | None = None) -> Path:
    """Write an E57 file (module notes for the layout), atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file.
    xyz : (n, 3) float
        Points [mm]; written in metres.
    attributes : dict of str to (n,) array
        Per-point values: ``nx, ny, nz`` as normals, the rest as 32-bit float extension
        fields.
    metadata : dict, optional
        Plain JSON stored in the scan's ``scanqa:metadata`` string.
    """
    pye57, libe57 = _pye57()
    xyz_m = np.asarray(xyz, dtype=float) * 1e-3
    if xyz_m.ndim != 2 or xyz_m.shape[1] != 3:
        raise InputError(f"cannot write {path}: points must be (n, 3), got {xyz_m.shape}")
    for name in attributes:
        if not name.replace("_", "").isalnum() or not name[0].isalpha():
            raise InputError(f"cannot write {path}: attribute name {name!r} is not a valid "
                             "E57 element name (letters, digits and underscores, starting "
                             "with a letter)")
    normals = all(n in attributes for n in NORMAL_FIELDS)
    text = json.dumps(metadata or {}, allow_nan=False, sort_keys=True)
    with atomic_path(path, suffix=".e57") as tmp:
        try:
            e57 = pye57.E57(str(tmp), mode="w")
            try:
                _write_scan(e57, libe57, xyz_m, attributes, text, normals)
            finally:
                e57.close()
        except libe57.E57Exception as err:
            raise OutputError(f"cannot write {path}: {_reason(err)}") from None
    return Path(path)


def _reason(err: Exception) -> str:
    """The first line of a libE57 error (the rest is its debug trace)."""
    lines = [ln.strip(" *") for ln in str(err).splitlines() if ln.strip(" *")]
    return lines[0] if lines else type(err).__name__


def _write_scan(e57, libe57, xyz_m: np.ndarray, attributes: dict, text: str,
                normals: bool) -> None:
    imf = e57.image_file
    imf.extensionsAdd(*NAMESPACE)
    if normals:
        imf.extensionsAdd(*NORMALS)
    n = len(xyz_m)
    scan = libe57.StructureNode(imf)
    scan.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
    scan.set("name", libe57.StringNode(imf, "scanqa cloud"))
    summary = json.loads(text).get("sigma_source", {}).get("detail", "")
    scan.set("description", libe57.StringNode(
        imf, "scanqa annotated point cloud (scanner frame, metres); per-point "
        "attributes in scanqa:* fields, units in scanqa:fields"
        + (f"; sigmas: {summary}" if summary else "")))
    lo = np.nanmin(xyz_m, axis=0) if n else np.zeros(3)
    hi = np.nanmax(xyz_m, axis=0) if n else np.zeros(3)
    bounds = libe57.StructureNode(imf)
    for i, axis in enumerate("xyz"):
        bounds.set(f"{axis}Minimum", libe57.FloatNode(imf, float(lo[i])))
        bounds.set(f"{axis}Maximum", libe57.FloatNode(imf, float(hi[i])))
    scan.set("cartesianBounds", bounds)
    proto = libe57.StructureNode(imf)
    columns: dict[str, np.ndarray] = {}
    for i, axis in enumerate("XYZ"):
        proto.set(f"cartesian{axis}", libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
        columns[f"cartesian{axis}"] = xyz_m[:, i]
    single = libe57.E57_SINGLE
    if INTENSITY_SOURCE in attributes:
        level = np.asarray(attributes[INTENSITY_SOURCE], dtype=np.float32)
        finite = level[np.isfinite(level)]
        top = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
        limits = libe57.StructureNode(imf)
        limits.set("intensityMinimum", libe57.FloatNode(imf, top[0]))
        limits.set("intensityMaximum", libe57.FloatNode(imf, top[1]))
        scan.set("intensityLimits", limits)
        proto.set("intensity", libe57.FloatNode(imf, 0.0, single))
        columns["intensity"] = level
    fields = libe57.StructureNode(imf)
    for name, values in attributes.items():
        if normals and name in NORMAL_FIELDS:
            key = NORMAL_FIELDS[name]
        else:
            key = f"{NAMESPACE[0]}:{name}"
            entry = libe57.StructureNode(imf)
            entry.set("unit", libe57.StringNode(imf, unit_of(name)))
            entry.set("description", libe57.StringNode(imf, _description(name)))
            fields.set(name, entry)
        proto.set(key, libe57.FloatNode(imf, 0.0, single))
        columns[key] = np.asarray(values, dtype=np.float32)
    scan.set(f"{NAMESPACE[0]}:fields", fields)
    scan.set(f"{NAMESPACE[0]}:metadata", libe57.StringNode(imf, text))
    points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
    scan.set("points", points)
    e57.data3d.append(scan)
    size = max(1, min(n, CHUNK))
    blocks = {k: np.empty(size, v.dtype) for k, v in columns.items()}
    buffers = libe57.VectorSourceDestBuffer()
    for key, block in blocks.items():
        buffers.append(libe57.SourceDestBuffer(imf, key, block, size, True, False))
    writer = points.writer(buffers)
    try:
        for a in range(0, n, size):
            m = min(size, n - a)
            for key, block in blocks.items():
                block[:m] = columns[key][a:a + m]
            writer.write(m)
    finally:
        writer.close()


def _description(name: str) -> str:
    """What an attribute is, with its unit in brackets (``sigma_total_um [um]``)."""
    return f"{name} [{unit_of(name)}]"


def read_e57(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    """Read the points [mm], per-point fields and scanqa metadata of an E57 file.

    Parameters
    ----------
    path : str or PathLike
        An E57 file with Cartesian points (module notes for how fields are named).

    Returns
    -------
    xyz : (n, 3) float64 ndarray
        Points of every scan in the file's frame [mm].
    attributes : dict of str to (n,) ndarray
        Per-point fields: scanqa's float32 as written, others float64.
    metadata : dict
        The first scan's ``scanqa:metadata`` JSON, or {}.
    """
    pye57, libe57 = _pye57()
    try:
        e57 = pye57.E57(str(path), mode="r")
    except libe57.E57Exception as err:
        raise InputError(f"cannot read E57 file {path}: {_reason(err)}") from None
    try:
        scans = [_read_scan(e57, libe57, i, Path(path)) for i in range(e57.scan_count)]
    except libe57.E57Exception as err:
        raise InputError(f"cannot read E57 file {path}: {_reason(err)}") from None
    finally:
        e57.close()
    if not scans:
        raise InputError(f"E57 file {path} holds no 3D scan (data3D is empty)")
    names = set(scans[0][1])
    for i, (_, attrs, _) in enumerate(scans[1:], 1):
        if set(attrs) != names:
            raise InputError(f"{path}: scan {i} has fields {sorted(attrs)}, scan 0 has "
                             f"{sorted(names)}: write the scans to separate files")
    xyz = np.concatenate([s[0] for s in scans]) if len(scans) > 1 else scans[0][0]
    attributes = {k: (np.concatenate([s[1][k] for s in scans]) if len(scans) > 1
                      else scans[0][1][k]) for k in scans[0][1]}
    return xyz, attributes, scans[0][2]


def _read_scan(e57, libe57, index: int, path: Path):
    header = e57.get_header(index)
    fields = list(header.point_fields)
    missing = {"cartesianX", "cartesianY", "cartesianZ"} - set(fields)
    if missing:
        raise InputError(f"{path}: scan {index} has no Cartesian points ({sorted(missing)} "
                         "missing; spherical coordinates are not read): convert it to "
                         "Cartesian (e.g. with CloudCompare)")
    n = header.point_count
    node = header.node
    imf = e57.image_file
    declared = {imf.extensionsPrefix(i) for i in range(imf.extensionsCount())}
    ours = NAMESPACE[0] in declared and node.isDefined(f"{NAMESPACE[0]}:metadata")
    metadata = {}
    if ours:
        text = node[f"{NAMESPACE[0]}:metadata"].value()
        metadata = loads_json_object(text, f"{path}: the scanqa:metadata string")
    wanted = {k: np.float32 if k.startswith(f"{NAMESPACE[0]}:") else np.float64
              for k in fields}
    data = {k: np.empty(n, dt) for k, dt in wanted.items()}
    if n:
        size = min(n, CHUNK)
        blocks = {k: np.empty(size, dt) for k, dt in wanted.items()}
        buffers = libe57.VectorSourceDestBuffer()
        for key, block in blocks.items():
            buffers.append(libe57.SourceDestBuffer(e57.image_file, key, block, size,
                                                   True, True))
        reader = header.points.reader(buffers)
        try:
            done = 0
            while done < n:
                got = reader.read()
                if got == 0:
                    raise InputError(f"{path}: scan {index} ends after {done} of {n} "
                                     "points (a truncated file?)")
                for key, block in blocks.items():
                    data[key][done:done + got] = block[:got]
                done += got
        finally:
            reader.close()
    keep = np.ones(n, bool)
    if "cartesianInvalidState" in data:
        keep = data["cartesianInvalidState"] == 0
    xyz = np.stack([data[f"cartesian{a}"] for a in "XYZ"], -1)
    if header.has_pose():
        xyz = e57.to_global(xyz, header.rotation, header.translation)
    xyz = 1e3 * xyz[keep]
    attributes: dict[str, np.ndarray] = {}
    normal_of = {v: k for k, v in NORMAL_FIELDS.items()}
    for key, values in data.items():
        if key.startswith("cartesian") or key in VALIDITY_FIELDS:
            continue
        if ours and key == "intensity":
            continue  # scanqa's intensity is its offset_dn field, which travels as itself
        name = normal_of.get(key) or STANDARD_NAMES.get(key) or _plain(key)
        attributes[name] = values[keep]
    return xyz, attributes, metadata


def _plain(key: str) -> str:
    """An E57 field name as a scanqa attribute name: scanqa's prefix dropped, another
    extension's prefix joined with an underscore."""
    prefix, _, name = key.rpartition(":")
    if prefix == NAMESPACE[0]:
        return name
    return f"{prefix}_{name}" if prefix else name
