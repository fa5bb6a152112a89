"""Gauge-block layouts: the blocks of an artefact, their nominal heights and regions.

A layout comes from a file (:func:`load_layout`, format in :mod:`scanqa.io.layout`) or
from :func:`scanqa.qa.detect.detect_blocks`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from scanqa.io.layout import FORMAT as LAYOUT_FORMAT
from scanqa.io.layout import read_layout_file

__all__ = ["LAYOUT_FORMAT", "BlockSpec", "Layout", "load_layout"]


@dataclass(frozen=True)
class BlockSpec:
    """One block of a layout: id, nominal height [mm], top-face region [mm]."""

    block_id: int
    nominal_height_mm: float
    region_mm: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max
    top_z_mm: float | None = None


@dataclass(frozen=True)
class Layout:
    """A gauge-block artefact: blocks in the scanner frame."""

    name: str
    blocks: tuple[BlockSpec, ...]
    source: str = ""
    paper_comparison: bool = False  # the report shows the paper's Tables 3 and 4


def load_layout(path: str | os.PathLike) -> Layout:
    """Read a layout TOML (``format = "scanqa-gauge-layout/1"``, :mod:`scanqa.io.layout`).

    Parameters
    ----------
    path : str or PathLike
        The layout file.

    Returns
    -------
    Layout
        Its blocks in file order.
    """
    data = read_layout_file(path)
    blocks = tuple(BlockSpec(b["id"], b["nominal_height_mm"], b["region_mm"], b["top_z_mm"])
                   for b in data["blocks"])
    return Layout(data["name"], blocks, data["source"], data["paper_comparison"])
