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
from scanqa.io.schema import Field, Schema, count, declare, greater
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-artefact-layout/1"


def _id() -> Field:
    return Field("id", "string or integer", required=True, doc="the artefact's name")


def _scan() -> Field:
    return Field("scan", "string", default="", doc="only in scans whose name starts so")


def _centre(name: str = "centre_mm", doc: str = "approximate centre") -> Field:
    return Field(name, "numbers", "mm", check=count(3), doc=doc)


_SPHERE = Schema("[[sphere]]", (
    _id(), Field("diameter_mm", "number", "mm", required=True, check=greater(0),
                 doc="nominal diameter"), _centre(), _scan()), name_key="id")
_BALL_BAR = Schema("[[ball_bar]]", (
    _id(), Field("diameter_mm", "number", "mm", required=True, check=greater(0),
                 doc="nominal ball diameter"),
    Field("distance_mm", "number", "mm", required=True, check=greater(0),
          doc="nominal centre distance"),
    _centre("centre_a_mm", "approximate centre of ball A (with centre_b_mm)"),
    _centre("centre_b_mm", "approximate centre of ball B (with centre_a_mm)"),
    Field("bar_diameter_mm", "number", "mm", check=greater(0),
          doc="diameter of the bar joining the balls"), _scan()), name_key="id")
_FLAT = Schema("[[flat]]", (
    _id(), _centre(), Field("normal", "numbers", "-", check=count(3),
                            doc="approximate normal (with centre_mm)"),
    Field("size_mm", "numbers", "mm", check=count(2, greater(0)),
          doc="extent along its in-plane axes"), _scan()), name_key="id")
#: The artefact layout's keys (module notes).
SCHEMA = declare(Schema("artefact layout", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("name", "string", doc="the layout's name (default: the file's stem)"),
    Field("frame", "string", doc="informational"),
    Field("sphere", "tables", table=_SPHERE, doc="test spheres: PF and PS"),
    Field("ball_bar", "tables", table=_BALL_BAR, doc="a ball bar per position: SD"),
    Field("flat", "tables", table=_FLAT, doc="optical flats: F"),
), formats=(FORMAT,)))
#: The artefact tables and their keys (True: required).
KINDS = {kind: {f.name: f.required for f in SCHEMA.field(kind).table.fields}
         for kind in ("sphere", "ball_bar", "flat")}


def _err(path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def _entry(path, kind: str, table: dict) -> dict:
    """One artefact entry (its keys checked by :data:`SCHEMA`) as a plain dict."""
    out: dict = {"id": str(table["id"]), "scan": str(table.get("scan", ""))}
    for key in ("diameter_mm", "distance_mm", "bar_diameter_mm"):
        if key in table:
            out[key] = float(table[key])
    for key in ("centre_mm", "centre_a_mm", "centre_b_mm", "normal", "size_mm"):
        out[key] = tuple(float(v) for v in table[key]) if key in table else None
    _check_entry(path, kind, f"{kind} {out['id']!r}", out)
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
    data = SCHEMA.validate(read_toml(path, "artefact layout"), path)
    out: dict = {"name": str(data.get("name", path.stem)), "source": str(path)}
    for kind in KINDS:
        out[kind] = [_entry(path, kind, t) for t in data.get(kind, [])]
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
