"""Phase map files (``phase.npz``): the decoded projector coordinate of a scan.

An uncompressed numpy ``.npz`` read without pickle. Arrays:

====================  ===========  ==============================================================
name                  dtype        content
====================  ===========  ==============================================================
format                str scalar   ``"scanqa-phasemap/1"``
xp                    (H, W) f8    projector coordinate along the fringe direction [projector px],
                                   NaN where masked
modulation            (H, W) f4    modulation B of the working period [DN]
offset                (H, W) f4    offset A [DN]
mask                  (H, W) u1    reason code, 0 = valid
                                   (``scanqa.decoding.phasemap.MASK_REASONS``)
sigma_xp              (H, W) f4    predicted standard deviation of xp [projector px], NaN if masked
period_px             f8 scalar    working (finest) period [projector px]
orientation           str scalar   "vertical" (xp is x_p) or "horizontal" (xp is y_p)
projector_width_px    i8 scalar    the coded range [projector px]
provenance            str scalar   JSON: software version, pattern description, sensor model
====================  ===========  ==============================================================

Writes are atomic; a file of another ``format`` version is refused.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.npzfile import load_npz

#: Value of the ``format`` entry written and accepted.
FORMAT = "scanqa-phasemap/1"
#: The per-pixel arrays, in file order.
ARRAYS = ("xp", "modulation", "offset", "mask", "sigma_xp")
_SCALARS = ("period_px", "orientation", "projector_width_px", "provenance")


def write_phase_file(path: str | os.PathLike, arrays: dict, *, period_px: float,
                     orientation: str, projector_width_px: int, provenance: dict) -> Path:
    """Write the arrays and scalars of a phase map to an ``.npz`` file atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    arrays : dict of str to (H, W) array
        ``xp`` [projector px], ``modulation``, ``offset`` [DN], ``mask`` (reason codes)
        and ``sigma_xp`` [projector px].
    period_px : float
        Working period [projector px].
    orientation : str
        "vertical" or "horizontal".
    projector_width_px : int
        Coded range [projector px].
    provenance : dict
        Plain-JSON description of how the map was made.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    InputError
        When the folder does not exist or the provenance is not JSON-serialisable.
    """
    try:
        text = json.dumps(provenance, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise InputError(f"cannot write {path}: provenance is not plain JSON ({err})") from None
    scalars = {"format": np.str_(FORMAT), "period_px": np.float64(period_px),
               "orientation": np.str_(orientation),
               "projector_width_px": np.int64(projector_width_px),
               "provenance": np.str_(text)}
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **{k: arrays[k] for k in ARRAYS}, **scalars)
    return Path(path)


def read_phase_file(path: str | os.PathLike) -> tuple[dict, dict]:
    """Read a phase map file written by :func:`write_phase_file`.

    Returns
    -------
    arrays : dict of str to (H, W) array
        The per-pixel arrays of :data:`ARRAYS`, as stored.
    scalars : dict
        ``period_px`` (float), ``orientation`` (str), ``projector_width_px`` (int) and
        ``provenance`` (dict).

    Raises
    ------
    InputError
        When the file is missing or unreadable, of another format version or lacks an
        entry.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"phase map {p} does not exist (run 'scanqa decode' first)")
    data = load_npz(p, "phase map")
    fmt = str(data["format"]) if "format" in data and data["format"].ndim == 0 else "(none)"
    if fmt != FORMAT:
        raise InputError(f"phase map {p} has format {fmt!r}; this scanqa reads {FORMAT!r} "
                         "(decode the images again with this version)")
    missing = [k for k in (*ARRAYS, *_SCALARS) if k not in data]
    if missing:
        raise InputError(f"phase map {p} lacks {', '.join(missing)} (file truncated or "
                         "not written by scanqa)")
    return _checked_arrays(data, p), _checked_scalars(data, p)


def _checked_arrays(data: dict, p: Path) -> dict:
    """The per-pixel arrays: 2-D, numeric, all of one shape."""
    shape = data["xp"].shape
    for k in ARRAYS:
        a = data[k]
        if a.ndim != 2 or a.shape != shape or a.dtype.kind not in "buif":
            raise InputError(f"phase map {p}: {k} must be a 2-D array of the shape of xp "
                             f"{shape} holding numbers, got {a.dtype} {a.shape} (damaged "
                             "file)")
    exact = (np.asarray(data["mask"]) == 0) & (np.asarray(data["sigma_xp"]) == 0)
    if exact.any():
        row, col = np.argwhere(exact)[0]
        raise InputError(f"phase map {p}: sigma_xp must be > 0 [projector px] where the "
                         f"pixel is valid (no decoder knows a phase exactly): {int(exact.sum())}"
                         f" valid pixels hold 0 (first at row {row}, column {col}); decode the "
                         "images again")
    return {k: data[k] for k in ARRAYS}


def _checked_scalars(data: dict, p: Path) -> dict:
    """period_px, orientation, projector_width_px and provenance, checked."""
    def scalar(key: str, kinds: str):
        a = data[key]
        if a.ndim != 0 or a.dtype.kind not in kinds:
            raise InputError(f"phase map {p}: {key} must be a scalar of kind {kinds!r}, got "
                             f"{a.dtype} {a.shape} (damaged file)")
        return a[()]

    period, width = float(scalar("period_px", "iuf")), scalar("projector_width_px", "iuf")
    if not math.isfinite(period) or not float(width).is_integer() or width < 0:
        raise InputError(f"phase map {p}: period_px {period!r} or projector_width_px "
                         f"{width!r} is not a valid value (damaged file)")
    try:
        provenance = json.loads(str(scalar("provenance", "U")))
    except (json.JSONDecodeError, RecursionError) as err:
        raise InputError(f"phase map {p}: provenance is not valid JSON ({err})") from None
    if not isinstance(provenance, dict):
        raise InputError(f"phase map {p}: provenance must be a JSON object")
    return {"period_px": period, "orientation": str(scalar("orientation", "U")),
            "projector_width_px": int(width), "provenance": provenance}
