"""Batch manifests (``scanqa-batch/1``) and simulation campaigns (``scanqa-campaign/1``).

A batch manifest lists the scans ``scanqa batch`` processes::

    format = "scanqa-batch/1"
    [[scan]]
    path = "line1/part_0001"     # pattern folder or phase .npz, relative to this file
    name = "part_0001"           # optional: output folder name (default: the path's name)

A campaign lists the simulations ``scanqa campaign`` renders::

    format = "scanqa-campaign/1"
    seed = 0                     # the campaign seed (every run's seed derives from it)
    [[run]]
    name = "f11"                 # output folder name; with the seed it keys the noise
    experiment = "gauge-blocks"
    config = "scanner.toml#sample"   # relative to this file; #PROFILE optional
    positions = [0.0]            # optional [mm]; default the experiment's
    repeats = 2                  # optional; default the experiment's
    periods_px = [5.0]           # optional fine periods [projector px]
    mesh = "part.stl"            # the 'mesh' experiment only

docs/formats.rst ("Batch manifests and campaigns") documents both. Parsing only: the
records hold paths resolved against the file's folder and plain values.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io import manifest
from scanqa.io.schema import Field, Schema, at_least, declare
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key of a batch manifest.
BATCH_FORMAT = "scanqa-batch/1"
#: Value of the ``format`` key of a campaign file.
CAMPAIGN_FORMAT = "scanqa-campaign/1"
#: A scan's or run's name: it names an output folder, so no separators and no leading dot.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$")
#: The batch manifest's keys (module notes).
BATCH_SCHEMA = declare(Schema("batch manifest", (
    Field("format", "string", required=True, doc=f"{BATCH_FORMAT!r}"),
    Field("scan", "tables", required=True, doc="one per scan, at least one",
          table=Schema("[[scan]]", (
              Field("path", "string", required=True,
                    doc="pattern folder or phase .npz, relative to the file"),
              Field("name", "string", doc="output folder name (default: the path's name)"),
          ), name_key="name")),
), formats=(BATCH_FORMAT,)))
#: The campaign file's keys (module notes).
CAMPAIGN_SCHEMA = declare(Schema("campaign", (
    Field("format", "string", required=True, doc=f"{CAMPAIGN_FORMAT!r}"),
    Field("seed", "integer", "-", default=0, check=at_least(0),
          doc="the campaign seed (every run's seed derives from it)"),
    Field("run", "tables", required=True, doc="one per simulation, at least one",
          table=Schema("[[run]]", (
              Field("name", "string", required=True,
                    doc="output folder name; with the seed it keys the noise"),
              Field("experiment", "string", required=True, doc="the simulated experiment"),
              Field("config", "string", required=True,
                    doc="scanner config, relative to the file; #PROFILE optional"),
              Field("positions", "numbers", "mm", doc="default: the experiment's"),
              Field("repeats", "integer", "-", check=at_least(1),
                    doc="default: the experiment's"),
              Field("periods_px", "numbers", "px", doc="fine periods"),
              Field("mesh", "string", doc="the 'mesh' experiment only"),
          ), name_key="name")),
), formats=(CAMPAIGN_FORMAT,)))


@dataclass(frozen=True)
class ScanEntry:
    """One scan of a batch: its output name and its input path."""

    name: str
    path: Path


@dataclass(frozen=True)
class CampaignRun:
    """One run of a campaign: an experiment simulated with one scanner config."""

    name: str
    experiment: str
    config: str                          # resolved path, with its #PROFILE suffix if any
    positions: tuple[float, ...] | None  # [mm]; None: the experiment's default
    repeats: int | None
    periods_px: tuple[float, ...] | None  # [projector px]
    mesh: Path | None


def check_name(name: object, where: str) -> str:
    """Return ``name`` if it can name an output folder, else raise one clear error."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputError(f"{where}: name must be letters, digits, '_', '.', '+' or '-' (not "
                         f"starting with '.' or '-'), got {name!r}")
    return name


def default_name(path: Path) -> str:
    """Output name of a scan path: a folder's name, a phase file's stem."""
    return path.stem if path.suffix.lower() == ".npz" else path.name


def read_batch_manifest(path: str | os.PathLike) -> list[ScanEntry]:
    """Read a ``scanqa-batch/1`` manifest, or an experiment folder's ``manifest.toml``
    (``scanqa-simulation/1``: its acquisitions' folders are the scans).

    Raises
    ------
    InputError
        When the file cannot be read, has another format, an entry lacks a path, or two
        scans share a name.
    """
    p = Path(path)
    data = read_toml(p, "batch manifest")
    if data.get("format") == manifest.FORMAT:
        manifest.SCHEMA.validate(data, p)
        items = [{"path": e["folder"]} for e in data["acquisition"]]
        key = "acquisition"
    elif data.get("format") == BATCH_FORMAT:
        items, key = BATCH_SCHEMA.validate(data, p)["scan"], "scan"
    else:
        raise InputError(f"{p}: format must be {BATCH_FORMAT!r} (or an experiment's "
                         f"{manifest.FORMAT!r} manifest), got {data.get('format')!r}")
    if not items:
        raise InputError(f"{p}: needs at least one [[{key}]] entry with a path")
    return unique_scans([_scan(p, i, item) for i, item in enumerate(items)], str(p))


def _scan(file: Path, i: int, item: dict) -> ScanEntry:
    """One scan entry (its keys checked by the schema)."""
    where = f"{file}: scan {i + 1}"
    if not item["path"]:
        raise InputError(f"{where}: path must be a scan folder or phase file, got ''")
    scan = (file.parent / item["path"]) if not os.path.isabs(item["path"]) \
        else Path(item["path"])
    name = item.get("name", default_name(scan))
    return ScanEntry(check_name(name, where), scan)


def unique_scans(scans: list[ScanEntry], source: str) -> list[ScanEntry]:
    """Return ``scans`` unless two share a name (their outputs would collide)."""
    seen: dict[str, Path] = {}
    for s in scans:
        if s.name in seen:
            raise InputError(f"{source}: two scans are named {s.name!r} ({seen[s.name]} and "
                             f"{s.path}); their outputs would collide: list them in a "
                             f"{BATCH_FORMAT} manifest with distinct 'name' keys")
        seen[s.name] = s.path
    return scans


def read_campaign(path: str | os.PathLike) -> tuple[int, list[CampaignRun]]:
    """Read a ``scanqa-campaign/1`` file: the campaign seed and its runs.

    Raises
    ------
    InputError
        When the file cannot be read, has another format, or a run is malformed (the
        message names the run and the key).
    """
    p = Path(path)
    data = CAMPAIGN_SCHEMA.validate(read_toml(p, "campaign"), p)
    seed = CAMPAIGN_SCHEMA.value(data, "seed")
    runs = data["run"]
    if not runs:
        raise InputError(f"{p}: needs at least one [[run]] table")
    out = [_run(p, i, r) for i, r in enumerate(runs)]
    names = [r.name for r in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"{p}: run names must be distinct (they name the output folders and "
                         f"key the noise), {dup[0]!r} appears twice")
    return seed, out


def _numbers(value: list | None) -> tuple[float, ...] | None:
    return None if value is None else tuple(float(v) for v in value)


def _run(campaign: Path, i: int, run: dict) -> CampaignRun:
    """One run (its keys checked by :data:`CAMPAIGN_SCHEMA`)."""
    where = f"{campaign}: run {i + 1}"
    name = check_name(run["name"], where)
    where = f"{campaign}: run {name!r}"
    for key in ("experiment", "config"):
        if not run[key]:
            raise InputError(f"{where}: {key} must be a non-empty string, got ''")
    file, _, profile = run["config"].partition("#")
    config = str(campaign.parent / file) + (f"#{profile}" if profile else "")
    mesh = run.get("mesh")
    return CampaignRun(name, run["experiment"], config, _numbers(run.get("positions")),
                       run.get("repeats"), _numbers(run.get("periods_px")),
                       campaign.parent / mesh if mesh else None)
