"""Experiment manifests (``manifest.toml``): what a folder of sweep or scan captures holds.

``scanqa simulate`` writes one per experiment folder (format ``scanqa-simulation/1``:
``experiment``, ``working_period_px``, the ``config`` it was simulated with, and one
``[[acquisition]]`` per scan with ``folder``, ``stage_mm``, ``camera_offset_mm``,
``projector_offset_mm``); measured sweeps in the same layout are read the same way.
"""

from __future__ import annotations

import math
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
    acq = data["acquisition"]
    if not isinstance(acq, list) or not acq:
        raise InputError(f"{path}: [[acquisition]] must be a non-empty array of tables")
    for i, entry in enumerate(acq):
        _check_entry(path, i, entry)
    period = data.get("working_period_px", 1.0)
    if not _finite(period) or period <= 0:
        raise InputError(f"{path}: working_period_px must be > 0 projector px, got {period!r}")
    if "config" in data and not isinstance(data["config"], dict):
        raise InputError(f"{path}: [config] must be a table, got {data['config']!r}")
    return data


def _finite(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def _check_entry(path: Path, i: int, entry: object) -> None:
    """One ``[[acquisition]]`` entry: a folder name and finite numbers [mm]."""
    where = f"{path}: acquisition {i + 1}"
    if not isinstance(entry, dict):
        raise InputError(f"{where} must be a table, got {entry!r}")
    if not isinstance(entry.get("folder"), str) or not entry["folder"]:
        raise InputError(f"{where}: folder must be a folder name, got {entry.get('folder')!r}")
    for key in ("stage_mm", "camera_offset_mm", "projector_offset_mm"):
        if not _finite(entry.get(key)):
            raise InputError(f"{where}: {key} must be a finite number [mm], got "
                             f"{entry.get(key)!r}")
