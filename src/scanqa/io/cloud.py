"""Point-cloud files by suffix: ``.ply`` (binary), ``.las`` (1.4, extra bytes, metres),
``.e57`` (ASTM E2807, extension fields, metres; the ``e57`` extra), ``.csv`` and
``.parquet`` (pandas). One small registry, one module per format.

Every format carries an optional metadata dict (plain JSON): a PLY header comment, a LAS
variable-length record, an E57 scan's ``scanqa:metadata`` string, a JSON sidecar
``<name>.csv.json`` beside a CSV (so that the CSV itself is a plain table every reader
loads whole: pandas, CloudCompare), Parquet key-value metadata. A CSV whose first line
is ``# scanqa-meta {...}`` (scanqa before 0.9 wrote its metadata there) is still read.
Coordinates are millimetres in memory whatever the file stores. A cell of a numeric CSV
column that is not a number is an error naming the row and the column, never a silent
NaN.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io import e57, las, ply
from scanqa.io.atomic import atomic_path
from scanqa.io.guard import MAX_TEXT_BYTES, loads_json_object, regular_file
from scanqa.io.schema import Field, within

#: First-line prefix of a CSV point table that carries scanqa's metadata (read only).
CSV_META = "# scanqa-meta "
#: Suffix added to a CSV file's name for its metadata sidecar.
CSV_SIDECAR = ".json"

log = logging.getLogger(__name__)


def _frame(xyz: np.ndarray, attributes: dict):
    import pandas as pd

    return pd.DataFrame({"x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
                         **attributes})


def csv_sidecar(path: str | os.PathLike) -> Path:
    """The metadata sidecar of a CSV point table (``cloud.csv`` -> ``cloud.csv.json``)."""
    path = Path(path)
    return path.with_name(path.name + CSV_SIDECAR)


def _write_csv(path: Path, xyz: np.ndarray, attributes: dict, metadata: dict | None) -> Path:
    frame = _frame(xyz, attributes)
    side = csv_sidecar(path)
    text = json.dumps(metadata or {}, allow_nan=False, indent=1, sort_keys=True) + "\n"
    with atomic_path(path) as tmp, atomic_path(side) as tmp_side:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            frame.to_csv(fh, index=False, float_format="%.9g")
        tmp_side.write_text(text, encoding="utf-8")
    return path


#: Old attribute names still read, each mapped to the name scanqa writes now:
#: ``sigma_table_um`` (the calibration's term, a table's or a parametric calibration's)
#: became ``sigma_calibration_um``.
OLD_NAMES = {"sigma_table_um": "sigma_calibration_um"}


def renamed(attributes: dict) -> dict:
    """``attributes`` with every old name (:data:`OLD_NAMES`) under its new one, in the
    same place; an old name beside its new one is dropped (the new one holds)."""
    if not set(OLD_NAMES) & set(attributes):
        return attributes
    return {OLD_NAMES.get(k, k): v for k, v in attributes.items()
            if not (k in OLD_NAMES and OLD_NAMES[k] in attributes)}


#: Parquet engines pandas can use; scanqa does not depend on one (the ``parquet`` extra
#: installs pyarrow).
PARQUET_ENGINES = ("pyarrow", "fastparquet")


def parquet_engine() -> str | None:
    """The first installed Parquet engine, or None."""
    return next((e for e in PARQUET_ENGINES if importlib.util.find_spec(e) is not None), None)


def check_format(path: str | os.PathLike, write: bool = True) -> Path:
    """Refuse, before any work, a cloud file scanqa cannot write (or read).

    Raises
    ------
    InputError
        An unknown suffix, ``.parquet`` without a Parquet engine installed, or ``.e57``
        without pye57.
    """
    path = Path(path)
    known = WRITERS if write else READERS
    if path.suffix.lower() not in known:
        raise InputError(f"cannot {'write' if write else 'read'} {path}: unknown suffix "
                         f"{path.suffix!r} (use one of {', '.join(known)})")
    if path.suffix.lower() == ".parquet" and parquet_engine() is None:
        raise InputError(f"cannot {'write' if write else 'read'} {path}: Parquet needs pyarrow "
                         "(pip install 'scanqa[parquet]'); or use .csv, .ply or .las")
    if path.suffix.lower() == ".e57" and not e57.available():
        raise InputError(f"cannot {'write' if write else 'read'} {path}: {e57.INSTALL_HINT}")
    return path


def _write_parquet(path: Path, xyz: np.ndarray, attributes: dict,
                   metadata: dict | None) -> Path:
    frame = _frame(xyz, attributes)
    frame.attrs["scanqa"] = metadata or {}
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, index=False, engine=parquet_engine())
    return path


def _read_table(path: Path) -> tuple[np.ndarray, dict, dict]:
    import pandas as pd

    metadata: object = {}
    try:
        if path.suffix.lower() == ".csv":
            with open(path, encoding="utf-8") as fh:
                first = fh.readline()
                if first.startswith(CSV_META):
                    metadata = loads_json_object(first[len(CSV_META):],
                                                 f"{path}: the first line")
                else:
                    fh.seek(0)
                frame = pd.read_csv(fh)
            metadata = _sidecar(path) or metadata
        else:
            frame = pd.read_parquet(path)
            metadata = dict(frame.attrs.get("scanqa", {}))
    except (OSError, ValueError, ImportError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read point table {path}: {' '.join(str(err).split())}"
                         ) from None
    missing = {"x_mm", "y_mm", "z_mm"} - set(frame.columns)
    if missing:
        raise InputError(f"{path}: missing columns {sorted(missing)}")
    columns = {}
    for c in frame.columns:
        values = pd.to_numeric(frame[c], errors="coerce").to_numpy(float)
        if c in ("x_mm", "y_mm", "z_mm") or np.isfinite(values).any() \
                or not frame[c].notna().any():
            _check_cells(path, str(c), values, frame[c].notna().to_numpy())
            columns[str(c)] = values
        else:
            log.info(f"{path}: column {c!r} is not numeric; left out")
    xyz = np.stack([columns.pop(c) for c in ("x_mm", "y_mm", "z_mm")], -1)
    return xyz, columns, metadata


def _sidecar(path: Path) -> dict:
    """The metadata of a CSV's sidecar, or {} when it has none."""
    side = csv_sidecar(path)
    if not side.exists():
        return {}
    regular_file(side, "point-table metadata", MAX_TEXT_BYTES)
    try:
        text = side.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read point-table metadata {side}: {err}") from None
    return loads_json_object(text, f"point-table metadata {side}")


def _check_cells(path: Path, column: str, values: np.ndarray, filled: np.ndarray) -> None:
    """A numeric column's cells are numbers or empty (NaN); text is an error."""
    bad = np.flatnonzero(np.isnan(values) & filled)
    if bad.size:
        raise InputError(f"{path}: column {column!r}, row {bad[0] + 1} (line {bad[0] + 2}) "
                         f"and {bad.size - 1} more: not a number (write a number, or leave "
                         "the cell empty for no value)")


WRITERS = {".ply": ply.write_ply, ".las": las.write_las, ".e57": e57.write_e57,
           ".csv": _write_csv, ".parquet": _write_parquet}
READERS = {".ply": ply.read_ply, ".las": las.read_las, ".e57": e57.read_e57,
           ".csv": _read_table, ".parquet": _read_table}


def write_cloud(path: str | os.PathLike, xyz: np.ndarray, attributes: dict,
                metadata: dict | None = None) -> Path:
    """Write a cloud in the format its suffix names.

    Parameters
    ----------
    path : str or PathLike
        ``.ply``, ``.las``, ``.e57``, ``.csv`` or ``.parquet``.
    xyz : (n, 3) float
        Points [mm].
    attributes : dict of str to (n,) array
        Per-point values.
    metadata : dict, optional
        Plain JSON carried in the file.
    """
    path = check_format(path)
    return WRITERS[path.suffix.lower()](path, xyz, attributes, metadata)


def read_cloud(path: str | os.PathLike) -> tuple[np.ndarray, dict, dict]:
    """Read a cloud written by :func:`write_cloud`: (xyz (n, 3) [mm], attributes,
    metadata), its values checked against :data:`VALUE_LIMITS`; attributes under an old
    name (:data:`OLD_NAMES`) come back under their new one."""
    path = check_format(path, write=False)
    if not path.is_file():
        raise InputError(f"point cloud {path} does not exist" if not path.exists() else
                         f"point cloud {path} is a folder, not a file")
    xyz, attributes, metadata = READERS[path.suffix.lower()](path)
    attributes = renamed(attributes)
    check_values(path, xyz, attributes)
    return xyz, attributes, metadata


#: Physical limits of per-point values, declared as fields named by pattern (first
#: match). NaN means "no value" and passes; a value outside its limits (a negative
#: sigma, a flag of -4, 1e30 anywhere, an overflowed CSV cell read as inf) is a damaged
#: file or one in other units, refused naming the column.
VALUE_LIMITS: tuple[Field, ...] = (
    Field("[xyz]_mm", "number", "mm", check=within(-1e6, 1e6), doc="within a kilometre"),
    *(Field(p, "number", "um", check=within(0, 1e6), doc="a spread")
      for p in ("sigma_*_um", "s[xyz]_um", "*u_deviation_um")),
    Field("table_corr_mm", "number", "mm", check=within(0, 1e4)),
    *(Field(p, "number", "-", check=within(0, 1), doc="a flag")
      for p in ("in_volume", "model_valid", "significant", "in_tolerance")),
    Field("att_*", "number", "-", check=within(0, 1e3)),
    Field("n_repeats", "number", "-", check=within(0, 1e6)),
    Field("*", "number", check=within(-1e15, 1e15), doc="anything else: a finite float64"))


def value_limits(name: str) -> tuple[float, float, str]:
    """(low, high, unit) of a per-point value named ``name`` (:data:`VALUE_LIMITS`)."""
    from fnmatch import fnmatchcase

    return next((f.check.ge, f.check.le, f.unit) for f in VALUE_LIMITS  # type: ignore
                if fnmatchcase(name, f.name))


def check_values(path: str | os.PathLike, xyz: np.ndarray, attributes: dict) -> None:
    """Refuse a cloud whose coordinates or attributes leave their physical limits.

    Raises
    ------
    InputError
        Naming the file, the column, the first point and the limits.
    """
    columns = {"x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2], **attributes}
    for name, values in columns.items():
        v = np.asarray(values)
        if v.dtype.kind not in "iuf":
            continue
        lo, hi, unit = value_limits(str(name))
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~((v >= lo) & (v <= hi)) & ~np.isnan(v)) \
                if v.dtype.kind == "f" else np.flatnonzero((v < lo) | (v > hi))
        if bad.size:
            unit = f" {unit}" if unit and unit != "-" else ""
            raise InputError(f"{path}: {name} of point {bad[0]} is {v[bad[0]].item():.6g}, "
                             f"outside [{lo:g}, {hi:g}]{unit} ({bad.size} such points; a "
                             "damaged file, or one in other units): fix or export the "
                             "cloud again")
