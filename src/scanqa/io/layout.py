"""Gauge-block layout files (TOML, ``format = "scanqa-gauge-layout/1"``).

Keys: ``name``, optional ``frame``, ``base_z_mm``, ``[base]`` and ``paper_comparison``
(true: the report shows the paper's Tables 3 and 4 beside the results; for the paper's
artefact only); per ``[[block]]``:
``id`` (int), ``nominal_height_mm``, ``region_mm = [x_min, x_max, y_min, y_max]`` (the
top face seen along Z, scanner frame [mm]) and optional ``top_z_mm``. This module reads
and checks the file; :mod:`scanqa.qa.layout` turns it into the QA's types.

Limits (a value outside them is an error naming the block and the field, never a silent
result): at least two blocks (the QA measures steps between blocks); ``id`` an integer
in [0, 2^31); ``nominal_height_mm`` in (0, :data:`MAX_HEIGHT_MM`] (the longest gauge
blocks of ISO 3650); coordinates within :data:`MAX_COORD_MM` of the origin; ``[base]``
holds ``region_mm`` and ``normal`` only.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.schema import Field, Schema, count, declare, within
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-gauge-layout/1"
#: Largest nominal height accepted [mm] (ISO 3650 gauge blocks end at 1000 mm).
MAX_HEIGHT_MM = 1000.0
#: Largest |coordinate| of a region, a top or the base [mm].
MAX_COORD_MM = 1e5
#: Block ids lie in [0, MAX_ID) (they are stored as 32-bit integers per point).
MAX_ID = 2**31
_COORD = within(-MAX_COORD_MM, MAX_COORD_MM)
_REGION_DOC = "[x_min, x_max, y_min, y_max] of the top face seen along Z, min < max"
_BLOCK = Schema("[[block]]", (
    Field("id", "integer", "-", required=True, check=within(0, MAX_ID - 1),
          doc="the block's number"),
    Field("nominal_height_mm", "number", "mm", required=True,
          check=within(0, MAX_HEIGHT_MM, open_low=True), doc="nominal height"),
    Field("region_mm", "numbers", "mm", required=True, check=count(4, _COORD),
          doc=_REGION_DOC),
    Field("top_z_mm", "number", "mm", check=_COORD, doc="Z of the top face"),
), name_key="id")
_BASE = Schema("[base]", (
    Field("region_mm", "numbers", "mm", check=count(4, _COORD), doc=_REGION_DOC),
    Field("normal", "numbers", "-", check=count(3, within(-1, 1)), doc="unit vector [x, y, z]"),
))
#: The gauge-block layout's keys (module notes).
SCHEMA = declare(Schema("gauge-block layout", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("name", "string", doc="the layout's name (default: the file's stem)"),
    Field("frame", "string", doc="informational"),
    Field("base_z_mm", "number", "mm", check=_COORD, doc="Z of the base plate"),
    Field("base", "table", table=_BASE, doc="the base plate's region and normal"),
    Field("block", "tables", required=True, table=_BLOCK,
          doc="one per gauge block, at least two"),
    Field("paper_comparison", "boolean", default=False,
          doc="show the paper's Tables 3 and 4 (the paper's artefact only)"),
), formats=(FORMAT,)))


def _err(path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def read_layout_file(path: str | os.PathLike) -> dict:
    """Read and check a layout file.

    Returns
    -------
    dict
        ``name`` (str), ``source`` (str), ``paper_comparison`` (bool) and ``blocks``: a
        list of dicts with ``id``
        (int), ``nominal_height_mm`` [mm], ``region_mm`` (4 floats [mm]) and
        ``top_z_mm`` [mm] or None.

    Raises
    ------
    InputError
        Unreadable file, wrong format, unknown key, no block, bad value, duplicate id.
    """
    path = Path(path)
    data = SCHEMA.validate(read_toml(path, "gauge-block layout"), path)
    raw = data["block"]
    if not raw:
        raise _err(path, "no [[block]] entries")
    if len(raw) < 2:
        raise _err(path, "holds one [[block]]; the QA measures height steps between "
                         "blocks, so a layout needs at least two")
    _check_base(path, data.get("base"))
    blocks = [_block(path, i, b) for i, b in enumerate(raw)]
    ids = [b["id"] for b in blocks]
    if len(set(ids)) != len(ids):
        raise _err(path, f"block ids must be unique, got {ids}")
    _check_overlap(path, blocks)
    return {"name": str(data.get("name", path.stem)), "source": str(path), "blocks": blocks,
            "paper_comparison": SCHEMA.value(data, "paper_comparison")}


def _check_base(path, base: dict | None) -> None:
    """The [base] table beyond its declared types: a region with min < max, a non-zero
    normal."""
    if base is None:
        return
    region, normal = base.get("region_mm"), base.get("normal")
    if region is not None and not _region(region):
        raise _err(path, "[base]: region_mm must be [x_min, x_max, y_min, y_max] of finite "
                         f"numbers with min < max [mm], got {region!r}")
    if normal is not None and not any(v != 0 for v in normal):
        raise _err(path, f"[base]: normal must be a unit vector [x, y, z], got {normal!r}")


def _region(region: list) -> bool:
    return region[0] < region[1] and region[2] < region[3]


def _check_overlap(path, blocks: list[dict]) -> None:
    """Two blocks' top faces cannot overlap seen along Z: their points would be shared."""
    for a, b in itertools.combinations(blocks, 2):
        ra, rb = a["region_mm"], b["region_mm"]
        if ra[0] < rb[1] and rb[0] < ra[1] and ra[2] < rb[3] and rb[2] < ra[3]:
            raise _err(path, f"the regions of blocks {a['id']} {list(ra)} and {b['id']} "
                             f"{list(rb)} overlap: each point must belong to one block [mm]")


def _block(path, i: int, table: dict) -> dict:
    """One block (its keys and limits checked by :data:`SCHEMA`)."""
    bid, h, region = table["id"], table["nominal_height_mm"], table["region_mm"]
    if not _region(region):
        raise _err(path, f"block {i + 1} (id {bid}): region_mm must be [x_min, x_max, y_min, "
                         f"y_max] with min < max [mm], got {region!r}")
    top = table.get("top_z_mm")
    return {"id": bid, "nominal_height_mm": float(h),
            "region_mm": tuple(float(v) for v in region),
            "top_z_mm": None if top is None else float(top)}
