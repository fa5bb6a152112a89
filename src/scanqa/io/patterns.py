"""The ``patterns.toml`` file: what was projected for one scan (docs/codings.rst).

This module reads and writes the file only; :mod:`scanqa.decoding.parsing` validates
its content into the decoder's types. Version 2 added Gray codes of any cell width
with white/black reference frames, the ``[decode]`` table and ``gray_edge_cells``;
version 1 files are still read (with their meaning unchanged).
"""

from __future__ import annotations

import os
from pathlib import Path

from scanqa.errors import ConfigError
from scanqa.io.schema import Field, Schema, declare, greater
from scanqa.io.tomlfile import dumps_toml, read_toml

#: Value of the ``format`` key this version writes.
FORMAT = "scanqa-patterns/2"
#: Values of the ``format`` key this version reads.
READ_FORMATS = ("scanqa-patterns/1", FORMAT)
#: File name looked up when a folder is given.
PATTERNS_FILE = "patterns.toml"
#: Keys of a ``[[set]]`` entry, over all kinds; which kind takes which (and version 1's
#: fewer) is checked by :mod:`scanqa.decoding.parsing`.
_SET = Schema("[[set]]", (
    Field("kind", "string", required=True, doc='"phase", "gray" or "reference" (version 2)'),
    Field("name", "string", doc="the set's name (default: kind and index)"),
    Field("period_px", "number", "px", doc="phase: fringe period"),
    Field("steps", "integer", "-", doc="phase: number of shifts"),
    Field("shifts_rad", "numbers", "rad", doc="phase: the shifts (default: equal steps)"),
    Field("bits", "integer", "-", doc="gray: number of bits"),
    Field("cell_px", "number", "px", doc="gray: cell width (version 2)"),
    Field("orders", "string", doc="gray: the phase set it orders"),
    Field("inverse", "boolean or string", doc="gray: inverse frames"),
    Field("threshold", "string", doc="gray: bit threshold (version 2)"),
    Field("code", "string", doc='gray: "reflected" (default) or "binary" (version 2)'),
    Field("orientation", "string", doc="fringe direction"),
    Field("levels", "strings", doc='reference: default ["white", "black"]'),
    Field("files", "strings", doc="image files, one per frame (or stack)"),
    Field("stack", "string", doc="one file holding all frames (or files)"),
    Field("stack_key", "string", doc="array name in a .npz stack"),
))
#: The pattern description's keys (docs/codings.rst). The keys of ``[sensor]``,
#: ``[thresholds]`` and ``[decode]`` are the decoder's options, declared by its
#: dataclasses (:mod:`scanqa.decoding.coding`).
SCHEMA = declare(Schema("pattern description", (
    Field("format", "string", required=True, doc=" or ".join(map(repr, READ_FORMATS))),
    Field("projector_width_px", "integer", "px", required=True, check=greater(0),
          doc="the coded range along the fringe direction"),
    Field("description", "string", default="", doc="free text"),
    Field("sensor", "table", table=Schema("[sensor]", (), open=True),
          doc="camera gain, read noise, saturation"),
    Field("thresholds", "table", table=Schema("[thresholds]", (), open=True),
          doc="decoder thresholds"),
    Field("decode", "table", table=Schema("[decode]", (), open=True),
          doc="decoding options (version 2)"),
    Field("set", "tables", required=True, table=_SET,
          doc="one or more [[set]] tables, one per pattern set"),
), formats=READ_FORMATS))


def read_patterns_file(path: str | os.PathLike) -> tuple[dict, Path]:
    """Parse a ``patterns.toml`` (or the one inside a pattern folder).

    Parameters
    ----------
    path : str or PathLike
        The file, or the folder that holds it.

    Returns
    -------
    data : dict
        The parsed TOML, its keys checked against :data:`SCHEMA` (the values of the
        decoder's options not yet validated).
    path : Path
        The file that was read (image paths are relative to its folder).
    """
    p = Path(path)
    if p.is_dir():
        p = p / PATTERNS_FILE
    data = read_toml(p, "pattern description", ConfigError,
                     missing=f"no pattern description {p} (write a {PATTERNS_FILE}; see "
                             "docs/codings.rst, or let 'scanqa patterns' write one)")
    return SCHEMA.validate(data, p, ConfigError), p


def dumps_patterns(data: dict) -> str:
    """The text of a ``patterns.toml`` from its plain-dict form (keys in file order)."""
    return dumps_toml(data)
