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
from scanqa.io.tomlfile import dumps_toml, read_toml

#: Value of the ``format`` key this version writes.
FORMAT = "scanqa-patterns/2"
#: Values of the ``format`` key this version reads.
READ_FORMATS = ("scanqa-patterns/1", FORMAT)
#: File name looked up when a folder is given.
PATTERNS_FILE = "patterns.toml"


def read_patterns_file(path: str | os.PathLike) -> tuple[dict, Path]:
    """Parse a ``patterns.toml`` (or the one inside a pattern folder).

    Parameters
    ----------
    path : str or PathLike
        The file, or the folder that holds it.

    Returns
    -------
    data : dict
        The parsed TOML, not yet validated.
    path : Path
        The file that was read (image paths are relative to its folder).
    """
    p = Path(path)
    if p.is_dir():
        p = p / PATTERNS_FILE
    data = read_toml(p, "pattern description", ConfigError,
                     missing=f"no pattern description {p} (write a {PATTERNS_FILE}; see "
                             "docs/codings.rst, or let 'scanqa patterns' write one)")
    return data, p


def dumps_patterns(data: dict) -> str:
    """The text of a ``patterns.toml`` from its plain-dict form (keys in file order)."""
    return dumps_toml(data)
