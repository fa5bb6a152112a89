"""Calibration table files (``table.npz``): one npz without pickle.

Entries: ``meta`` (a JSON string: ``format``, ``width_px``, ``height_px``, ``weights``,
``config``, ``provenance``) and the arrays of :data:`ARRAYS` (docs/formats.rst gives
their shapes and units). Writes are atomic; another format version is refused.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.npzfile import load_npz

#: Value of the ``format`` key this version writes and reads.
FORMAT = "scanqa-table/2"
#: The table's arrays, in file order.
ARRAYS = ("node_u", "node_v", "x_ref", "s_nodes", "xyz", "dxyz", "sigma_node", "s_lo",
          "s_hi", "shear")
_META = ("width_px", "height_px", "weights", "config", "provenance")


def write_table_file(path: str | os.PathLike, arrays: dict, meta: dict) -> Path:
    """Write a table's arrays and metadata to ``path`` (npz, stored), atomically.

    Stored, not deflated: a table's float arrays barely compress (the sample table 28.7
    MB deflated against 30.9 MB stored) and deflating cost ~0.4 s of CPU per write.

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    arrays : dict of str to ndarray
        Every entry of :data:`ARRAYS`.
    meta : dict
        ``width_px``, ``height_px`` [px], ``weights``, ``config`` and ``provenance``
        (plain JSON); ``format`` is added.
    """
    text = json.dumps({"format": FORMAT, **meta})
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, meta=np.array(text), **{k: arrays[k] for k in ARRAYS})
    return Path(path)


def read_table_file(path: str | os.PathLike) -> tuple[dict, dict]:
    """Read a table file: (arrays of :data:`ARRAYS`, metadata dict).

    Raises
    ------
    InputError
        When the file is missing, unreadable, of another format version or incomplete.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"calibration table {path} does not exist")
    data = load_npz(path, "calibration table")
    try:
        meta = json.loads(str(data["meta"][()])) if data.get("meta") is not None else None
    except (json.JSONDecodeError, IndexError, RecursionError) as err:
        raise InputError(f"{path}: table metadata is not JSON ({err}); rebuild it") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise InputError(f"{path}: table format {found!r} is not supported by this "
                         f"scanqa (reads {FORMAT!r}); rebuild it with 'scanqa calibrate'")
    missing = [k for k in _META if k not in meta] + [k for k in ARRAYS if k not in data]
    if missing:
        raise InputError(f"{path}: table lacks {', '.join(missing)} (file not written by "
                         "scanqa calibrate, or damaged); rebuild it")
    _check_meta(meta, path)
    # float16 or extended floats: read as float64 (the lookups are compiled for 32 and 64)
    arrays = {k: data[k].astype(np.float64) if data[k].dtype.kind == "f"
              and data[k].dtype not in (np.float32, np.float64) else data[k] for k in ARRAYS}
    _check_arrays(arrays, meta, path)
    return arrays, meta


#: Largest camera side a table may declare [px].
MAX_SIDE_PX = 100_000


def _check_meta(meta: dict, path: Path) -> None:
    for key in ("width_px", "height_px"):
        v = meta[key]
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_SIDE_PX:
            raise InputError(f"{path}: table metadata {key} must be a whole number of px "
                             f"from 1 to {MAX_SIDE_PX}, got {v!r} (damaged); rebuild it")
    for key, kind in (("weights", str), ("config", dict), ("provenance", dict)):
        if not isinstance(meta[key], kind):
            raise InputError(f"{path}: table metadata {key} must be a {kind.__name__}, got "
                             f"{meta[key]!r} (damaged); rebuild it")
    positions = meta["provenance"].get("positions", [])
    if not isinstance(positions, list) or not all(
            isinstance(p, dict) and _is_number(p.get("z_mm")) for p in positions):
        raise InputError(f"{path}: table metadata provenance.positions must be a list of "
                         "tables with a finite number z_mm [mm] (damaged); rebuild it")


def _is_number(value: object) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and \
        bool(np.isfinite(value))


def _check_arrays(a: dict, meta: dict, path: Path) -> None:
    """Shapes and values that the lookups rely on."""
    n_u, n_v, n_s = a["node_u"].shape, a["node_v"].shape, a["s_nodes"].shape
    grid, full = (*n_v, *n_u), (*n_v, *n_u, *n_s)
    expect = {"node_u": n_u, "node_v": n_v, "s_nodes": n_s, "x_ref": grid, "s_lo": grid,
              "s_hi": grid, "sigma_node": full, "xyz": (*full, 3), "dxyz": (*full, 3),
              "shear": a["shear"].shape}
    for k, shape in expect.items():
        if a[k].dtype.kind != "f" or a[k].shape != shape or a[k].ndim != len(shape) \
                or a[k].ndim == 0:
            raise InputError(f"{path}: table array {k} is {a[k].dtype} {a[k].shape}, expected "
                             f"floats of shape {shape} (damaged); rebuild it")
    for k, fewest in (("node_u", 1), ("node_v", 1), ("s_nodes", 2)):
        if a[k].size < fewest or not np.isfinite(a[k]).all() or not (np.diff(a[k]) > 0).all():
            raise InputError(f"{path}: table nodes {k} must be at least {fewest}, finite and "
                             "increasing (damaged); rebuild it")
