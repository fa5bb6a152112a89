"""Gauge-block layout files (TOML, ``format = "scanqa-gauge-layout/1"``).

Keys: ``name``, optional ``frame``, ``base_z_mm``, ``[base]`` and ``paper_comparison``
(true: the report shows the paper's Tables 3 and 4 beside the results; for the paper's
artefact only); per ``[[block]]``:
``id`` (int), ``nominal_height_mm``, ``region_mm = [x_min, x_max, y_min, y_max]`` (the
top face seen along Z, scanner frame [mm]) and optional ``top_z_mm``. This module reads
and checks the file; :mod:`scanqa.qa.layout` turns it into the QA's types.
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


def _number(value: object) -> bool:
    """A finite TOML number (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


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
    if not isinstance(bid, int) or isinstance(bid, bool):
        raise _err(path, f"{where}: id must be an integer, got {bid!r}")
    if not _number(h) or not h > 0:
        raise _err(path, f"{where} (id {bid}): nominal_height_mm must be > 0 mm and finite, "
                         f"got {h!r}")
    if (not isinstance(region, list) or len(region) != 4
            or not all(_number(v) for v in region)
            or not (region[0] < region[1] and region[2] < region[3])):
        raise _err(path, f"{where} (id {bid}): region_mm must be [x_min, x_max, y_min, y_max] "
                         f"of finite numbers with min < max [mm], got {region!r}")
    top = table.get("top_z_mm")
    if top is not None and not _number(top):
        raise _err(path, f"{where} (id {bid}): top_z_mm must be a finite number [mm], got "
                         f"{top!r}")
    return {"id": bid, "nominal_height_mm": float(h),
            "region_mm": tuple(float(v) for v in region),
            "top_z_mm": None if top is None else float(top)}
