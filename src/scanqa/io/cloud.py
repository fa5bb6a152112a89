"""Point-cloud files by suffix: ``.ply`` (binary), ``.las`` (1.4, extra bytes),
``.csv`` and ``.parquet`` (pandas). One small registry, one module per format."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io import las, ply
from scanqa.io.atomic import atomic_path


def _write_table(path: Path, xyz: np.ndarray, attributes: dict) -> Path:
    import pandas as pd

    frame = pd.DataFrame({"x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
                          **attributes})
    with atomic_path(path) as tmp:
        if path.suffix == ".csv":
            frame.to_csv(tmp, index=False, float_format="%.9g")
        else:
            try:
                frame.to_parquet(tmp, index=False)
            except ImportError as err:
                raise InputError(f"Parquet export needs pyarrow or fastparquet ({err}); "
                                 "install one or write .csv") from None
    return path


def _read_table(path: Path) -> tuple[np.ndarray, dict]:
    import pandas as pd

    try:
        frame = pd.read_csv(path) if path.suffix == ".csv" else pd.read_parquet(path)
    except (OSError, ValueError, ImportError) as err:
        raise InputError(f"cannot read point table {path}: {err}") from None
    missing = {"x_mm", "y_mm", "z_mm"} - set(frame.columns)
    if missing:
        raise InputError(f"{path}: missing columns {sorted(missing)}")
    xyz = frame[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    return xyz, {c: frame[c].to_numpy() for c in frame.columns if c not in
                 ("x_mm", "y_mm", "z_mm")}


WRITERS = {".ply": ply.write_ply, ".las": las.write_las, ".csv": _write_table,
           ".parquet": _write_table}
READERS = {".ply": ply.read_ply, ".las": las.read_las, ".csv": _read_table,
           ".parquet": _read_table}


def write_cloud(path: str | os.PathLike, xyz: np.ndarray, attributes: dict) -> Path:
    """Write a cloud in the format its suffix names."""
    path = Path(path)
    writer = WRITERS.get(path.suffix.lower())
    if writer is None:
        raise InputError(f"cannot write {path}: unknown suffix {path.suffix!r} "
                         f"(use one of {', '.join(WRITERS)})")
    return writer(path, xyz, attributes)


def read_cloud(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read a cloud written by :func:`write_cloud`: (xyz (n, 3) [mm], attributes)."""
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        raise InputError(f"cannot read {path}: unknown suffix {path.suffix!r} "
                         f"(use one of {', '.join(READERS)})")
    if not path.exists():
        raise InputError(f"point cloud {path} does not exist")
    return reader(path)
