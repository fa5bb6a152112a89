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

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key of a batch manifest.
BATCH_FORMAT = "scanqa-batch/1"
#: Value of the ``format`` key of a campaign file.
CAMPAIGN_FORMAT = "scanqa-campaign/1"
#: A scan's or run's name: it names an output folder, so no separators and no leading dot.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$")


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
    if data.get("format") == "scanqa-simulation/1":
        acq = data.get("acquisition")
        items = [{"path": e.get("folder")} for e in acq if isinstance(e, dict)] \
            if isinstance(acq, list) else []
        key = "acquisition"
    elif data.get("format") == BATCH_FORMAT:
        items, key = data.get("scan"), "scan"
    else:
        raise InputError(f"{p}: format must be {BATCH_FORMAT!r} (or an experiment's "
                         f"'scanqa-simulation/1' manifest), got {data.get('format')!r}")
    if not isinstance(items, list) or not items:
        raise InputError(f"{p}: needs at least one [[{key}]] entry with a path")
    return unique_scans([_scan(p, i, item) for i, item in enumerate(items)], str(p))


def _scan(manifest: Path, i: int, item: object) -> ScanEntry:
    where = f"{manifest}: scan {i + 1}"
    if not isinstance(item, dict) or not isinstance(item.get("path"), str) \
            or not item["path"]:
        raise InputError(f"{where}: path must be a scan folder or phase file, got "
                         f"{item.get('path') if isinstance(item, dict) else item!r}")
    scan = (manifest.parent / item["path"]) if not os.path.isabs(item["path"]) \
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
    data = read_toml(p, "campaign")
    if data.get("format") != CAMPAIGN_FORMAT:
        raise InputError(f"{p}: format must be {CAMPAIGN_FORMAT!r}, got "
                         f"{data.get('format')!r}")
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise InputError(f"{p}: seed must be an integer >= 0, got {seed!r}")
    runs = data.get("run")
    if not isinstance(runs, list) or not runs or not all(isinstance(r, dict) for r in runs):
        raise InputError(f"{p}: needs at least one [[run]] table")
    out = [_run(p, i, r) for i, r in enumerate(runs)]
    names = [r.name for r in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"{p}: run names must be distinct (they name the output folders and "
                         f"key the noise), {dup[0]!r} appears twice")
    return seed, out


def _numbers(value: object, where: str, key: str) -> tuple[float, ...] | None:
    if value is None:
        return None
    ok = isinstance(value, list) and value and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)
    if not ok:
        raise InputError(f"{where}: {key} must be a non-empty list of finite numbers, got "
                         f"{value!r}")
    return tuple(float(v) for v in value)


def _run(campaign: Path, i: int, run: dict) -> CampaignRun:
    where = f"{campaign}: run {i + 1}"
    name = check_name(run.get("name"), where)
    where = f"{campaign}: run {name!r}"
    for key in ("experiment", "config"):
        if not isinstance(run.get(key), str) or not run[key]:
            raise InputError(f"{where}: {key} must be a string, got {run.get(key)!r}")
    unknown = sorted(set(run) - {"name", "experiment", "config", "positions", "repeats",
                                 "periods_px", "mesh"})
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r} (known: name, experiment, "
                         "config, positions, repeats, periods_px, mesh)")
    repeats = run.get("repeats")
    if repeats is not None and (not isinstance(repeats, int) or isinstance(repeats, bool)
                                or repeats < 1):
        raise InputError(f"{where}: repeats must be an integer >= 1, got {repeats!r}")
    file, _, profile = run["config"].partition("#")
    config = str(campaign.parent / file) + (f"#{profile}" if profile else "")
    mesh = run.get("mesh")
    if mesh is not None and not isinstance(mesh, str):
        raise InputError(f"{where}: mesh must be a file name, got {mesh!r}")
    return CampaignRun(name, run["experiment"], config,
                       _numbers(run.get("positions"), where, "positions"), repeats,
                       _numbers(run.get("periods_px"), where, "periods_px"),
                       campaign.parent / mesh if mesh else None)
