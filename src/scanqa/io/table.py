"""Calibration table files (``table.npz``): one npz without pickle.

Entries: ``meta`` (a JSON string: ``format``, ``width_px``, ``height_px``, ``weights``,
``config``, ``provenance``) and the arrays of :data:`ARRAYS` (docs/formats.rst gives
their shapes and units). Writes are atomic; another format version is refused.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path

#: Value of the ``format`` key this version writes and reads.
FORMAT = "scanqa-table/2"
#: The table's arrays, in file order.
ARRAYS = ("node_u", "node_v", "x_ref", "s_nodes", "xyz", "dxyz", "sigma_node", "s_lo",
          "s_hi", "shear")
_META = ("width_px", "height_px", "weights", "config", "provenance")


def write_table_file(path: str | os.PathLike, arrays: dict, meta: dict) -> Path:
    """Write a table's arrays and metadata to ``path`` (compressed npz), atomically.

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
        np.savez_compressed(fh, meta=np.array(text), **{k: arrays[k] for k in ARRAYS})
    return Path(path)


def read_table_file(path: str | os.PathLike) -> tuple[dict, dict]:
    """Read a table file: (arrays of :data:`ARRAYS`, metadata dict).

    Raises
    ------
    InputError
        When the file is missing, unreadable, of another format version or incomplete.
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"][()]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                found = meta.get("format") if isinstance(meta, dict) else None
                raise InputError(f"{path}: table format {found!r} is not supported by this "
                                 f"scanqa (reads {FORMAT!r}); rebuild it with 'scanqa "
                                 "calibrate'")
            arrays = {k: data[k] for k in ARRAYS}
    except FileNotFoundError:
        raise InputError(f"calibration table {path} does not exist") from None
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise InputError(f"{path} is not a scanqa calibration table ({err})") from None
    missing = [k for k in _META if k not in meta]
    if missing:
        raise InputError(f"{path}: table metadata lacks {', '.join(missing)} (file not "
                         "written by scanqa calibrate, or damaged); rebuild it")
    return arrays, meta
