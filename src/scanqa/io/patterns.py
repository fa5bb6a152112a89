"""The ``patterns.toml`` file: what was projected for one scan (docs/formats.rst).

This module reads and writes the file only; :mod:`scanqa.decoding.coding` validates
its content into the decoder's types.
"""

from __future__ import annotations

import os
from pathlib import Path

from scanqa.errors import ConfigError
from scanqa.io.tomlfile import dumps_toml, read_toml

#: Value of the ``format`` key this version reads and writes.
FORMAT = "scanqa-patterns/1"
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
                             "docs/formats.rst, 'patterns.toml')")
    return data, p


def dumps_patterns(data: dict) -> str:
    """The text of a ``patterns.toml`` from its plain-dict form (keys in file order)."""
    return dumps_toml(data)
