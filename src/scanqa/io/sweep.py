"""Calibration sweep manifests (``sweep.toml``): a flat target at known stage positions.

Format (paths relative to the manifest's folder)::

    format = "scanqa-sweep/1"
    description = "flat target, 41 positions, 2 repeats"   # optional
    [[position]]
    z_mm = 430.0                                   # Z of the target plane, scanner frame [mm]
    phase = ["p430_r0/phase.npz", "p430_r1/phase.npz"]    # decoded phase files (repeats)
    # patterns = ["p430_r0", "p430_r1"]            # or pattern folders, decoded on the fly
    lateral = "p430_truth.npz"                     # optional: arrays X, Y [mm] per pixel
    markers = "markers/p430.png"                   # optional: the marker frame
    # markers = ["markers/p430_0.png", "markers/p430_1.png"]   # or several, averaged

    [target]                                       # with markers: the printed target
    kind = "chessboard"
    square_mm = 4.0
    # marker_cells = [[0, 0], [0, 1], [1, 1]]      # default
    [scanner]                                      # optional: what the images came from
    camera_width_px = 306
    camera_height_px = 256

Positions are listed once each, in increasing ``z_mm`` (the stage reading); repeats go in
the same position's list. At least three positions are needed. ``markers`` (on every
position, with a ``[target]`` table) give the lateral geometry from the printed target;
else ``lateral``; else the camera intrinsics of the scanner config. Several marker frames
of one position (the target not moved between them) are averaged before detection;
every position lists the same number.
``[scanner]`` keys are checked against the config a sweep is calibrated with.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.npzfile import load_npz
from scanqa.io.schema import Field, Schema, declare, greater, one_of
from scanqa.io.tomlfile import read_toml

FORMAT = "scanqa-sweep/1"
#: The camera fields the ``[scanner]`` table records: key -> ``camera.<field>`` of a config.
SCANNER_FIELDS = {"camera_width_px": "width_px", "camera_height_px": "height_px",
                  "camera_pixel_um": "pixel_um", "camera_focal_mm": "focal_mm"}
_POSITION = Schema("[[position]]", (
    Field("z_mm", "number", "mm", required=True,
          doc="Z of the target plane, or the stage reading with markers"),
    Field("phase", "string or strings", doc="decoded phase files, one per repeat"),
    Field("patterns", "string or strings", doc="or pattern folders, decoded on the fly"),
    Field("lateral", "string", doc="file of arrays X, Y [mm] per pixel"),
    Field("markers", "string or strings",
          doc="image(s) of the printed target at this position (several are averaged; "
              "the same number at every position)"),
))
_TARGET = Schema("[target]", (
    Field("kind", "string", required=True, check=one_of("chessboard"),
          doc='the printed target: kind = "chessboard"'),
    Field("square_mm", "number", "mm", required=True, check=greater(0),
          doc="the printed square's side"),
    Field("marker_cells", "list", doc="[[row, column], ...] of the 3 marker cells"),
))
_SCANNER = Schema("[scanner]", (
    Field("config", "string", doc="name of the scanner config"),
    Field("camera_width_px", "integer", "px", check=greater(0), doc="camera.width_px"),
    Field("camera_height_px", "integer", "px", check=greater(0), doc="camera.height_px"),
    Field("camera_pixel_um", "number", "um", check=greater(0), doc="camera.pixel_um"),
    Field("camera_focal_mm", "number", "mm", check=greater(0), doc="camera.focal_mm"),
))
#: The sweep manifest's keys (module notes).
SCHEMA = declare(Schema("sweep manifest", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("description", "string", default="", doc="free text"),
    Field("position", "tables", required=True, table=_POSITION,
          doc="one per stage position, in increasing z_mm, at least 3"),
    Field("target", "table", table=_TARGET, doc="the printed target, with markers"),
    Field("scanner", "table", table=_SCANNER, doc="the config the images came from"),
), formats=(FORMAT,)))
#: Keys of the ``[scanner]`` table: the config values the sweep was captured with.
SCANNER_KEYS = tuple(f.name for f in _SCANNER.fields)


@dataclass(frozen=True)
class SweepPosition:
    """One stage position: its Z [mm], scan sources (one per repeat), optional lateral map
    and marker frames (empty without markers; several are averaged)."""

    z_mm: float
    sources: tuple[Path, ...]
    decoded: bool
    lateral: Path | None
    marker_frames: tuple[Path, ...] = ()


@dataclass(frozen=True)
class Sweep:
    """A validated sweep manifest."""

    path: Path
    positions: tuple[SweepPosition, ...]
    description: str = ""
    target: dict | None = None
    scanner: dict | None = None

    @property
    def has_markers(self) -> bool:
        """Whether every position names a marker frame."""
        return all(p.marker_frames for p in self.positions)

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
    data = SCHEMA.validate(read_toml(path, "sweep manifest"), path)
    raw = data["position"]
    if len(raw) < 3:
        raise _err(path, f"a calibration sweep needs at least 3 [[position]] entries, "
                         f"got {len(raw)}")
    positions = tuple(_position(path, i, p) for i, p in enumerate(raw))
    _check_order(path, positions)
    target = _target(path, data.get("target"), positions)
    scanner = dict(data["scanner"]) if "scanner" in data else None
    return Sweep(path, positions, SCHEMA.value(data, "description"), target, scanner)


def _target(path: Path, table, positions: tuple[SweepPosition, ...]) -> dict | None:
    """The ``[target]`` table (checked by :data:`SCHEMA`), required exactly when
    positions name marker frames."""
    target = None if table is None else dict(table)
    marked = [bool(p.marker_frames) for p in positions]
    if any(marked) and not all(marked):
        k = marked.index(False)
        raise _err(path, f"position {k + 1} (z_mm = {positions[k].z_mm}) has no 'markers': "
                         "give the marker frame of every position or of none")
    counts = [len(p.marker_frames) for p in positions]
    if any(c != counts[0] for c in counts):
        k = next(i for i, c in enumerate(counts) if c != counts[0])
        raise _err(path, f"position {k + 1} (z_mm = {positions[k].z_mm}) lists {counts[k]} "
                         f"marker frames, position 1 lists {counts[0]}: give every position "
                         "the same number (they are averaged, and the report's error and "
                         "frames needed assume one count)")
    if all(marked) and target is None:
        raise _err(path, "positions name marker frames but there is no [target] table: add "
                         "[target] kind = \"chessboard\", square_mm = <printed square> [mm]")
    return target


def _position(path: Path, i: int, table: dict) -> SweepPosition:
    """One ``[[position]]`` entry (its keys checked by :data:`SCHEMA`): files exist."""
    where = f"position {i + 1}"
    z = table["z_mm"]
    has_phase, has_pat = "phase" in table, "patterns" in table
    if has_phase == has_pat:
        raise _err(path, f"{where} (z_mm = {z}): give exactly one of 'phase' (decoded files) "
                         "or 'patterns' (pattern folders)")
    items = table["phase" if has_phase else "patterns"]
    items = [items] if isinstance(items, str) else items
    sources = tuple(path.parent / s for s in items)
    for s in sources:
        if not s.exists():
            raise _err(path, f"{where} (z_mm = {z}): {s} does not exist")
    lateral = table.get("lateral")
    lat = None if lateral is None else path.parent / lateral
    if lat is not None and not lat.exists():
        raise _err(path, f"{where}: lateral file {lateral!r} does not exist")
    markers = table.get("markers")
    names = [] if markers is None else [markers] if isinstance(markers, str) else markers
    frames = tuple(path.parent / m for m in names)
    for name, frame in zip(names, frames, strict=True):
        if not frame.is_file():
            raise _err(path, f"{where}: marker frame {name!r} does not exist")
    return SweepPosition(float(z), sources, has_phase, lat, frames)


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


# ------------------------------------------------------------------- generating one


def read_stage_readings(text: str, source: str = "stage readings") -> list[float]:
    """Stage readings [mm] from a comma list (``"430,432.5"``) or a CSV file's text.

    A CSV holds one reading per line, in its last column (so ``capture,z_mm`` rows
    work); a first line that is not a number is a header; ``#`` starts a comment.

    Raises
    ------
    InputError
        A line whose reading is not a finite number (named by its line number).
    """
    lines = text.splitlines() if "\n" in text.strip() else text.split(",")
    out = []
    for n, line in enumerate(lines, 1):
        cell = line.split("#", 1)[0].strip()
        if not cell:
            continue
        last = cell.split(",")[-1].strip()  # a CSV row's last column; a list item itself
        try:
            value = float(last)
        except ValueError:
            if n == 1 and not out:
                continue  # a header
            raise InputError(f"{source}, line {n}: {line.strip()!r} is not a stage reading "
                             "[mm] (one number per line, or in the last CSV column)") from None
        if not math.isfinite(value):
            raise InputError(f"{source}, line {n}: the stage reading must be finite [mm]")
        out.append(value)
    return out


def scanner_table(camera, name: str | None = None) -> dict:
    """The ``[scanner]`` table of a config's ``camera`` section (and its ``name``)."""
    table = {} if name is None else {"config": name}
    return table | {key: getattr(camera, field) for key, field in SCANNER_FIELDS.items()}


def target_table(square_mm: float) -> dict:
    """The ``[target]`` table of the marked chessboard with squares of ``square_mm``."""
    return {"kind": "chessboard", "square_mm": float(square_mm)}


def sweep_manifest(captures: list[str], readings: list[float], markers: list[str] | None,
                   square_mm: float | None, decoded: bool, scanner: dict | None = None,
                   description: str = "") -> dict:
    """The ``sweep.toml`` content for captures taken at stage readings.

    Parameters
    ----------
    captures : list of str
        Pattern folders (or phase files, ``decoded``), relative to the manifest, one per
        scan in capture order.
    readings : list of float
        The stage reading of each capture [mm]; equal readings are repeats of one
        position.
    markers : list of str, optional
        Marker frames in increasing reading order: one per distinct reading, or N per
        reading (the N of one position consecutive), averaged by ``scanqa calibrate``.
    square_mm : float, optional
        The printed target's square [mm] (required with ``markers``).
    decoded : bool
        Captures are phase files (``phase``) rather than pattern folders (``patterns``).
    scanner : dict, optional
        The ``[scanner]`` table (:data:`SCANNER_KEYS`).
    description : str
        Free text.

    Raises
    ------
    InputError
        Counts that do not match, fewer than 3 positions, markers without a square size.
    """
    if len(captures) != len(readings):
        raise InputError(f"{len(captures)} captures but {len(readings)} stage readings: give "
                         "one reading per capture, in the captures' name order (repeats "
                         "repeat the reading)")
    zs = sorted(set(readings))
    if len(zs) < 3:
        raise InputError(f"a sweep needs at least 3 distinct stage readings, got {len(zs)}")
    if markers is not None and (not markers or len(markers) % len(zs)):
        raise InputError(f"{len(markers)} marker frames but {len(zs)} distinct stage "
                         "readings: give one marker frame per position, or the same number "
                         "for every position (consecutive in name order)")
    if markers is not None and not (square_mm and square_mm > 0):
        raise InputError("marker frames need the printed target's square size (square_mm "
                         "> 0 [mm])")
    key = "phase" if decoded else "patterns"
    rows = []
    for k, z in enumerate(zs):
        row = {"z_mm": z, key: [c for c, r in zip(captures, readings, strict=True) if r == z]}
        if markers is not None:
            n = len(markers) // len(zs)
            row["markers"] = markers[k] if n == 1 else markers[k * n:(k + 1) * n]
        rows.append(row)
    out: dict = {"format": FORMAT, "description": description or
                 f"{len(zs)} positions, {len(captures)} scans"}
    if scanner:
        out["scanner"] = dict(scanner)
    if markers is not None:
        out["target"] = target_table(square_mm)
    out["position"] = rows
    return out
