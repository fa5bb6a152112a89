"""Experiment manifests (``manifest.toml``): what a folder of sweep or scan captures holds.

``scanqa simulate`` writes one per experiment folder (format ``scanqa-simulation/1``:
``experiment``, ``working_period_px``, the ``config`` it was simulated with, and one
``[[acquisition]]`` per scan with ``folder``, ``stage_mm``, ``camera_offset_mm``,
``projector_offset_mm``); measured sweeps in the same layout are read the same way.
"""

from __future__ import annotations

import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-simulation/1"


def read_manifest(folder: str | os.PathLike) -> dict:
    """Read ``manifest.toml`` of an experiment folder.

    Raises
    ------
    InputError
        When it is missing, unreadable or not a ``scanqa-simulation/1`` manifest.
    """
    path = Path(folder) / "manifest.toml"
    data = read_toml(path, "experiment manifest",
                     missing=f"{path} does not exist (is {folder} a folder written by "
                             "'scanqa simulate'?)")
    if data.get("format") != FORMAT or "acquisition" not in data:
        raise InputError(f"{path} is not a {FORMAT} manifest (no format key or no "
                         "[[acquisition]] entries)")
    return data
