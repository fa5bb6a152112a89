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
from scanqa.io.schema import Field, Schema, declare, greater
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-simulation/1"
_ACQUISITION = Schema("[[acquisition]]", (
    Field("folder", "string", required=True, doc="the scan's pattern folder"),
    Field("stage_mm", "number", "mm", required=True, doc="the stage reading"),
    Field("camera_offset_mm", "number", "mm", required=True,
          doc="camera offset along its axis"),
    Field("projector_offset_mm", "number", "mm", required=True,
          doc="projector offset along its axis"),
    Field("index", "integer", "-", doc="position number"),
    Field("repeat", "integer", "-", doc="repeat number"),
    Field("truth", "string", doc="the simulator's truth file"),
))
_WINDOW = Schema("[window]", tuple(
    Field(k, "integer", "px", doc="simulated sensor window") for k in
    ("u0_px", "v0_px", "width_px", "height_px")))
#: The experiment manifest's keys (module notes).
SCHEMA = declare(Schema("experiment manifest", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("experiment", "string", doc="the simulated experiment"),
    Field("scanqa_version", "string", doc="the scanqa that wrote it"),
    Field("seed", "integer", "-", doc="the simulation seed"),
    Field("scene", "string", doc="the simulated scene"),
    Field("stage_meaning", "string", doc="what stage_mm measures"),
    Field("repeats", "integer", "-", doc="scans per position"),
    Field("periods_px", "numbers", "px", doc="fringe periods"),
    Field("working_period_px", "number", "px", default=1.0, check=greater(0),
          doc="the finest period"),
    Field("window", "table", table=_WINDOW, doc="sensor window simulated"),
    Field("truth_frame", "string", doc="frame of the truth files"),
    Field("config", "table", table=Schema("[config]", (), open=True),
          doc="the scanner config simulated with"),
    Field("acquisition", "tables", required=True, table=_ACQUISITION,
          doc="one per scan, at least one"),
), formats=(FORMAT,)))


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
    SCHEMA.validate(data, path)
    if not data["acquisition"]:
        raise InputError(f"{path}: [[acquisition]] must be a non-empty array of tables")
    for i, entry in enumerate(data["acquisition"]):
        if not entry["folder"]:
            raise InputError(f"{path}: [[acquisition]] {i + 1}: folder must be a folder "
                             "name, got ''")
    data.setdefault("working_period_px", SCHEMA.value(data, "working_period_px"))
    return data
