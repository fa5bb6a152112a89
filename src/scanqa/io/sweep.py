"""Calibration sweep manifests (``sweep.toml``): a flat target at known stage positions.

Format (paths relative to the manifest's folder)::

    format = "scanqa-sweep/1"
    description = "flat target, 41 positions, 2 repeats"   # optional
    [[position]]
    z_mm = 430.0                                   # Z of the target plane, scanner frame [mm]
    phase = ["p430_r0/phase.npz", "p430_r1/phase.npz"]    # decoded phase files (repeats)
    # patterns = ["p430_r0", "p430_r1"]            # or pattern folders, decoded on the fly
    lateral = "p430_truth.npz"                     # optional: arrays X, Y [mm] per pixel

Positions are listed once each, in increasing ``z_mm``; repeats go in the same position's
list. At least three positions are needed. Without ``lateral`` the target's X, Y come
from the camera intrinsics of the scanner config.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.npzfile import load_npz
from scanqa.io.tomlfile import read_toml

FORMAT = "scanqa-sweep/1"
_TOP = ("format", "description", "position")
_POS = ("z_mm", "phase", "patterns", "lateral")


@dataclass(frozen=True)
class SweepPosition:
    """One stage position: its Z [mm], scan sources (one per repeat), optional lateral map."""

    z_mm: float
    sources: tuple[Path, ...]
    decoded: bool
    lateral: Path | None


@dataclass(frozen=True)
class Sweep:
    """A validated sweep manifest."""

    path: Path
    positions: tuple[SweepPosition, ...]
    description: str = ""

    def observation_count(self) -> int:
        """Number of scans (positions x repeats)."""
        return sum(len(p.sources) for p in self.positions)

    def provenance(self) -> dict:
        """Plain description for the table file."""
        return {"sweep": str(self.path), "description": self.description,
                "positions": [{"z_mm": p.z_mm, "scans": [str(s) for s in p.sources]}
                              for p in self.positions]}


def _err(path: Path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def load_sweep(path: str | os.PathLike) -> Sweep:
    """Read and validate a sweep manifest; every listed file must exist.

    Raises
    ------
    InputError
        Unreadable manifest, unknown keys, fewer than 3 positions, a position without
        z_mm or scans, duplicate or unsorted positions, a missing file.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "sweep.toml"
    data = read_toml(path, "sweep manifest")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise _err(path, f"unknown key {unknown[0]!r} (known: {', '.join(_TOP)})")
    if data.get("format") != FORMAT:
        raise _err(path, f"format must be {FORMAT!r}, got {data.get('format')!r}")
    raw = data.get("position", [])
    if not isinstance(raw, list) or len(raw) < 3:
        n = len(raw) if isinstance(raw, list) else 0
        raise _err(path, f"a calibration sweep needs at least 3 [[position]] entries, got {n}")
    positions = tuple(_position(path, i, p) for i, p in enumerate(raw))
    _check_order(path, positions)
    return Sweep(path, positions, str(data.get("description", "")))


def _position(path: Path, i: int, table: dict) -> SweepPosition:
    where = f"position {i + 1}"
    if not isinstance(table, dict):
        raise _err(path, f"{where} must be a [[position]] table, got {table!r}")
    unknown = sorted(set(table) - set(_POS))
    if unknown:
        raise _err(path, f"{where}: unknown key {unknown[0]!r} (known: {', '.join(_POS)})")
    z = table.get("z_mm")
    if isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z):
        raise _err(path, f"{where}: z_mm must be a finite number [mm], got {z!r}")
    has_phase, has_pat = "phase" in table, "patterns" in table
    if has_phase == has_pat:
        raise _err(path, f"{where} (z_mm = {z}): give exactly one of 'phase' (decoded files) "
                         "or 'patterns' (pattern folders)")
    items = table["phase" if has_phase else "patterns"]
    items = [items] if isinstance(items, str) else items
    if not isinstance(items, list) or not items or not all(isinstance(s, str) for s in items):
        raise _err(path, f"{where}: list at least one file name")
    sources = tuple(path.parent / s for s in items)
    for s in sources:
        if not s.exists():
            raise _err(path, f"{where} (z_mm = {z}): {s} does not exist")
    lateral = table.get("lateral")
    lat = path.parent / lateral if isinstance(lateral, str) else None
    if lateral is not None and (lat is None or not lat.exists()):
        raise _err(path, f"{where}: lateral file {lateral!r} does not exist")
    return SweepPosition(float(z), sources, has_phase, lat)


def _check_order(path: Path, positions: tuple[SweepPosition, ...]) -> None:
    for k in range(1, len(positions)):
        a, b = positions[k - 1].z_mm, positions[k].z_mm
        if b == a:
            raise _err(path, f"position {k + 1} repeats z_mm = {b}: list repeats of one "
                             "position in its 'phase'/'patterns' list instead")
        if b < a:
            raise _err(path, f"positions must be listed in increasing z_mm: position {k + 1} "
                             f"(z_mm = {b}) follows z_mm = {a}")


def read_lateral(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The lateral maps X, Y [mm] per pixel of a marked target (arrays ``X``, ``Y``)."""
    data = load_npz(path, "lateral map", keys=("X", "Y"))
    x, y = data.get("X"), data.get("Y")
    if x is None or y is None or x.ndim != 2 or x.shape != y.shape \
            or x.dtype.kind not in "iuf" or y.dtype.kind not in "iuf":
        raise InputError(f"{path}: needs 2-D numeric arrays X and Y of one shape [mm]")
    return np.asarray(x, float), np.asarray(y, float)
