"""Artefact layout files (TOML, ``format = "scanqa-artefact-layout/1"``): where the
VDI/VDE 2634-2 test artefacts of a scan are and their nominal sizes.

Example (scanner frame: origin at the camera lens, +Z along its axis [mm])::

    format = "scanqa-artefact-layout/1"
    name = "ball bar, 7 positions"         # optional
    frame = "scanner"                      # optional, informational

    [[sphere]]                             # a test sphere: PF and PS
    id = "S1"
    diameter_mm = 12.0                     # nominal diameter (finding, shell)
    centre_mm = [0.0, 0.0, 450.0]          # optional: approximate centre
    scan = "p000"                          # optional: only in scans named p000*

    [[ball_bar]]                           # a ball bar in one position: SD
    id = "P1"
    diameter_mm = 12.0                     # nominal ball diameter
    distance_mm = 42.0                     # nominal centre distance
    centre_a_mm = [-14.0, -11.0, 441.0]    # optional (both or neither): approximate
    centre_b_mm = [14.0, 11.0, 459.0]      #   ball centres
    bar_diameter_mm = 4.0                  # optional: diameter of the bar joining them
    scan = "p000"

    [[flat]]                               # an optical flat: F
    id = "F1"
    centre_mm = [0.0, 0.0, 450.0]          # optional: approximate centre
    normal = [0.0, 0.0, -1.0]              # optional: approximate normal (with centre_mm)
    size_mm = [50.0, 40.0]                 # optional: extent along its in-plane axes

A layout needs at least one artefact. An artefact without an approximate position is
found by RANSAC in the whole cloud (:mod:`scanqa.qa.ransac`). ``scan`` restricts an
artefact to the scans whose file or folder name starts with it (a ball bar moved
through several positions is one layout with one entry per position). This module
reads and checks the file into plain dicts; :mod:`scanqa.qa.artefacts` uses them.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-artefact-layout/1"
#: The artefact tables and their keys (True: required).
KINDS = {
    "sphere": {"id": True, "diameter_mm": True, "centre_mm": False, "scan": False},
    "ball_bar": {"id": True, "diameter_mm": True, "distance_mm": True, "centre_a_mm": False,
                 "centre_b_mm": False, "bar_diameter_mm": False, "scan": False},
    "flat": {"id": True, "centre_mm": False, "normal": False, "size_mm": False,
             "scan": False},
}
_TOP = ("format", "name", "frame", *KINDS)


def _err(path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def _positive(path, where: str, key: str, value) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and value > 0
    if not ok:
        raise _err(path, f"{where}: {key} must be a number > 0 [mm], got {value!r}")
    return float(value)


def _vector(path, where: str, key: str, value, size: int) -> tuple[float, ...]:
    ok = isinstance(value, list) and len(value) == size and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)
    if not ok:
        raise _err(path, f"{where}: {key} must be a list of {size} finite numbers, "
                         f"got {value!r}")
    return tuple(float(v) for v in value)


def _entry(path, kind: str, i: int, table) -> dict:
    where = f"[[{kind}]] {i + 1}"
    if not isinstance(table, dict):
        raise _err(path, f"{where} must be a table")
    keys = KINDS[kind]
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise _err(path, f"{where}: unknown key {unknown[0]!r} (known: {', '.join(keys)})")
    missing = [k for k, required in keys.items() if required and k not in table]
    if missing:
        raise _err(path, f"{where}: {missing[0]} is missing")
    out: dict = {"id": str(table["id"]), "scan": str(table.get("scan", ""))}
    where = f"{kind} {out['id']!r}"
    for key in ("diameter_mm", "distance_mm", "bar_diameter_mm"):
        if key in table:
            out[key] = _positive(path, where, key, table[key])
    for key in ("centre_mm", "centre_a_mm", "centre_b_mm", "normal"):
        out[key] = _vector(path, where, key, table[key], 3) if key in table else None
    out["size_mm"] = tuple(_positive(path, where, "size_mm", v) for v in
                           _vector(path, where, "size_mm", table["size_mm"], 2)) \
        if "size_mm" in table else None
    _check_entry(path, kind, where, out)
    return out


def _check_entry(path, kind: str, where: str, entry: dict) -> None:
    if kind == "ball_bar":
        if (entry["centre_a_mm"] is None) != (entry["centre_b_mm"] is None):
            raise _err(path, f"{where}: give both centre_a_mm and centre_b_mm, or neither")
        if entry.get("bar_diameter_mm", 0.0) >= entry["diameter_mm"]:
            raise _err(path, f"{where}: bar_diameter_mm must be smaller than diameter_mm")
    if kind == "flat":
        if entry["normal"] is not None and entry["centre_mm"] is None:
            raise _err(path, f"{where}: normal needs centre_mm")
        if entry["normal"] is not None and math.hypot(*entry["normal"]) == 0:
            raise _err(path, f"{where}: normal must not be zero")


def read_artefact_layout(path: str | os.PathLike) -> dict:
    """Read and check an artefact layout.

    Parameters
    ----------
    path : str or PathLike
        The layout file (module notes).

    Returns
    -------
    dict
        ``name``, ``source`` and per kind (``sphere``, ``ball_bar``, ``flat``) a list of
        dicts with the keys of :data:`KINDS` (vectors as tuples [mm], missing optional
        keys None, ``scan`` "" when not given).

    Raises
    ------
    InputError
        Unreadable file, wrong format, unknown key, no artefact, bad value, duplicate id.
    """
    path = Path(path)
    data = read_toml(path, "artefact layout")
    if data.get("format") != FORMAT:
        raise _err(path, f"format must be {FORMAT!r}, got {data.get('format')!r}")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise _err(path, f"unknown key {unknown[0]!r} (known: {', '.join(_TOP)})")
    out: dict = {"name": str(data.get("name", path.stem)), "source": str(path)}
    for kind in KINDS:
        raw = data.get(kind, [])
        if not isinstance(raw, list):
            raise _err(path, f"{kind} must be an array of tables ([[{kind}]])")
        out[kind] = [_entry(path, kind, i, t) for i, t in enumerate(raw)]
    ids = [e["id"] for kind in KINDS for e in out[kind]]
    if not ids:
        raise _err(path, "no artefact: add a [[sphere]], [[ball_bar]] or [[flat]] table")
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise _err(path, f"artefact ids must be unique, {dup[0]!r} appears twice")
    return out


def layout_format(path: str | os.PathLike) -> str:
    """The ``format`` key of a layout file ("" when it has none), to tell a gauge-block
    layout from an artefact layout."""
    return str(read_toml(Path(path), "layout").get("format", ""))
