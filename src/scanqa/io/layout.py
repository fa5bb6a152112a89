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
import math
import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-gauge-layout/1"
_TOP = ("format", "name", "frame", "base_z_mm", "base", "block", "paper_comparison")
_BLOCK = ("id", "nominal_height_mm", "region_mm", "top_z_mm")
_BASE = ("region_mm", "normal")
#: Largest nominal height accepted [mm] (ISO 3650 gauge blocks end at 1000 mm).
MAX_HEIGHT_MM = 1000.0
#: Largest |coordinate| of a region, a top or the base [mm].
MAX_COORD_MM = 1e5
#: Block ids lie in [0, MAX_ID) (they are stored as 32-bit integers per point).
MAX_ID = 2**31


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
    data = read_toml(path, "gauge-block layout")
    if data.get("format") != FORMAT:
        raise _err(path, f"format must be {FORMAT!r}, got {data.get('format')!r}")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise _err(path, f"unknown key {unknown[0]!r} (known: {', '.join(sorted(_TOP))})")
    raw = data.get("block", [])
    if not isinstance(raw, list) or not raw:
        raise _err(path, "no [[block]] entries")
    if len(raw) < 2:
        raise _err(path, "holds one [[block]]; the QA measures height steps between "
                         "blocks, so a layout needs at least two")
    _check_top(path, data)
    blocks = [_block(path, i, b) for i, b in enumerate(raw)]
    ids = [b["id"] for b in blocks]
    if len(set(ids)) != len(ids):
        raise _err(path, f"block ids must be unique, got {ids}")
    _check_overlap(path, blocks)
    paper = data.get("paper_comparison", False)
    if not isinstance(paper, bool):
        raise _err(path, f"paper_comparison must be true or false, got {paper!r}")
    return {"name": str(data.get("name", path.stem)), "source": str(path), "blocks": blocks,
            "paper_comparison": paper}


def _number(value: object, limit: float = MAX_COORD_MM) -> bool:
    """A finite TOML number (not a bool) with |value| <= limit."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and abs(value) <= limit


def _check_top(path, data: dict) -> None:
    """name, frame, base_z_mm and the [base] table."""
    for key in ("name", "frame"):
        if key in data and not isinstance(data[key], str):
            raise _err(path, f"{key} must be a string, got {data[key]!r}")
    if "base_z_mm" in data and not _number(data["base_z_mm"]):
        raise _err(path, f"base_z_mm must be a finite number within {MAX_COORD_MM:g} mm, "
                         f"got {data['base_z_mm']!r}")
    base = data.get("base")
    if base is None:
        return
    if not isinstance(base, dict):
        raise _err(path, f"[base] must be a table, got {base!r}")
    unknown = sorted(set(base) - set(_BASE))
    if unknown:
        raise _err(path, f"[base]: unknown key {unknown[0]!r} (known: {', '.join(_BASE)})")
    region, normal = base.get("region_mm"), base.get("normal")
    if region is not None and not _region(region):
        raise _err(path, "[base]: region_mm must be [x_min, x_max, y_min, y_max] of finite "
                         f"numbers with min < max [mm], got {region!r}")
    if normal is not None and not (isinstance(normal, list) and len(normal) == 3
                                   and all(_number(v, 1.0) for v in normal)
                                   and any(v != 0 for v in normal)):
        raise _err(path, f"[base]: normal must be a unit vector [x, y, z], got {normal!r}")


def _region(region: object) -> bool:
    return (isinstance(region, list) and len(region) == 4
            and all(_number(v) for v in region)
            and region[0] < region[1] and region[2] < region[3])


def _check_overlap(path, blocks: list[dict]) -> None:
    """Two blocks' top faces cannot overlap seen along Z: their points would be shared."""
    for a, b in itertools.combinations(blocks, 2):
        ra, rb = a["region_mm"], b["region_mm"]
        if ra[0] < rb[1] and rb[0] < ra[1] and ra[2] < rb[3] and rb[2] < ra[3]:
            raise _err(path, f"the regions of blocks {a['id']} {list(ra)} and {b['id']} "
                             f"{list(rb)} overlap: each point must belong to one block [mm]")


def _block(path, i: int, table: dict) -> dict:
    where = f"block {i + 1}"
    if not isinstance(table, dict):
        raise _err(path, f"{where} must be a [[block]] table, got {table!r}")
    unknown = sorted(set(table) - set(_BLOCK))
    if unknown:
        raise _err(path, f"{where}: unknown key {unknown[0]!r}")
    bid, h, region = table.get("id"), table.get("nominal_height_mm"), table.get("region_mm")
    if not isinstance(bid, int) or isinstance(bid, bool) or not 0 <= bid < MAX_ID:
        raise _err(path, f"{where}: id must be an integer from 0 to {MAX_ID - 1}, got "
                         f"{bid!r}")
    if not _number(h, MAX_HEIGHT_MM) or not h > 0:
        raise _err(path, f"{where} (id {bid}): nominal_height_mm must be > 0 mm and finite, "
                         f"at most {MAX_HEIGHT_MM:g} mm, got {h!r}")
    if not _region(region):
        raise _err(path, f"{where} (id {bid}): region_mm must be [x_min, x_max, y_min, y_max] "
                         f"of finite numbers with min < max [mm], got {region!r}")
    top = table.get("top_z_mm")
    if top is not None and not _number(top):
        raise _err(path, f"{where} (id {bid}): top_z_mm must be a finite number [mm], got "
                         f"{top!r}")
    return {"id": bid, "nominal_height_mm": float(h),
            "region_mm": tuple(float(v) for v in region),
            "top_z_mm": None if top is None else float(top)}
