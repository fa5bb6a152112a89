"""Projector response files: phase-error tables measured for one projector.

A small TOML file the user keeps with the scanner (``scanqa decode --measure-response``
writes it; ``[decode] response = "..."`` in patterns.toml or ``scanqa decode
--response`` applies it)::

    format = "scanqa-response/1"
    description = "measured on a flat, scan plane_000"

    [[set]]
    period_px = 114.0
    steps = 3
    shifts_rad = [0.0, -2.0943951, -4.1887902]
    phase_error_rad = [0.012, 0.019, ...]   # at measured phase (i + 1/2) 2 pi / n

This module reads and writes the file only; :mod:`scanqa.decoding.response` validates
and applies it.
"""

from __future__ import annotations

import os
from pathlib import Path

from scanqa.errors import ConfigError
from scanqa.io.atomic import write_text
from scanqa.io.schema import Field, Schema, declare, greater
from scanqa.io.tomlfile import dumps_toml, read_toml

#: Value of the ``format`` key written and read.
FORMAT = "scanqa-response/1"
#: The projector response file's keys (module notes).
SCHEMA = declare(Schema("projector response", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("description", "string", default="", doc="free text"),
    Field("set", "tables", required=True, doc="one table per pattern set measured",
          table=Schema("[[set]]", (
              Field("period_px", "number", "px", required=True, check=greater(0),
                    doc="the set's period"),
              Field("steps", "integer", "-", required=True, check=greater(0),
                    doc="the set's frames"),
              Field("shifts_rad", "numbers", "rad", required=True, doc="the set's shifts"),
              Field("phase_error_rad", "numbers", "rad", required=True,
                    doc="error at measured phase (i + 1/2) 2 pi / n, n >= 4, abs(e) < pi/2"),
          ))),
), formats=(FORMAT,)))


def read_response_file(path: str | os.PathLike) -> dict:
    """Parse a projector response file.

    Parameters
    ----------
    path : str or PathLike
        The TOML file.

    Returns
    -------
    dict
        The parsed TOML, checked against :data:`SCHEMA` (the tables not yet
        validated).

    Raises
    ------
    ConfigError
        When the file is missing, unreadable, not TOML or of another format.
    """
    p = Path(path)
    data = read_toml(p, "projector response", ConfigError,
                     missing=f"no projector response file {p} (measure one on a flat "
                             "with the same pattern set)")
    return SCHEMA.validate(data, p, ConfigError)


def write_response_file(path: str | os.PathLike, data: dict) -> Path:
    """Write a projector response file atomically (``format`` is set here).

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    data : dict
        ``description`` and ``set`` (a list of tables), as documented above.

    Returns
    -------
    Path
        The written file.
    """
    return write_text(path, dumps_toml({"format": FORMAT, **data}))
