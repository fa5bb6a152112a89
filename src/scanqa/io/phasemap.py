"""Phase map files (``phase.npz``): the decoded projector coordinate of a scan.

An uncompressed numpy ``.npz`` read without pickle. Arrays:

==============  ===========  ==============================================================
name            dtype        content
==============  ===========  ==============================================================
format          str scalar   ``"scanqa-phasemap/1"``
xp              (H, W) f8    projector coordinate along the fringe direction [projector px],
                             NaN where masked
modulation      (H, W) f4    modulation B of the working period [DN]
offset          (H, W) f4    offset A [DN]
mask            (H, W) u1    reason code, 0 = valid (``scanqa.phase.MASK_REASONS``)
sigma_xp        (H, W) f4    predicted standard deviation of xp [projector px], NaN if masked
period_px       f8 scalar    working (finest) period [projector px]
orientation     str scalar   "vertical" (xp is x_p) or "horizontal" (xp is y_p)
projector_...   i8 scalar    ``projector_width_px``, the coded range [projector px]
provenance      str scalar   JSON: software version, pattern description, sensor model
==============  ===========  ==============================================================

Writes are atomic; a file of another ``format`` version is refused.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.phase import (
    MASK_INCONSISTENT,
    MASK_LOW_MODULATION,
    MASK_OUT_OF_RANGE,
    MASK_REASONS,
    MASK_SATURATED,
    MASK_VALID,
    PhaseMap,
)

#: Value of the ``format`` entry written and accepted.
FORMAT = "scanqa-phasemap/1"
_ARRAYS = ("xp", "modulation", "offset", "mask", "sigma_xp")
_SCALARS = ("period_px", "orientation", "projector_width_px", "provenance")


def save_phase_map(path: str | os.PathLike, phase_map: PhaseMap) -> Path:
    """Write a phase map to an ``.npz`` file atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file (conventionally ``phase.npz``); its folder must exist.
    phase_map : PhaseMap
        The map to store.

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
        provenance = json.dumps(phase_map.provenance, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise InputError(f"cannot write {path}: provenance is not plain JSON ({err})") from None
    arrays = {name: getattr(phase_map, name) for name in _ARRAYS}
    scalars = {"format": np.str_(FORMAT), "period_px": np.float64(phase_map.period_px),
               "orientation": np.str_(phase_map.orientation),
               "projector_width_px": np.int64(phase_map.projector_width_px),
               "provenance": np.str_(provenance)}
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays, **scalars)
    return Path(path)


def load_phase_map(path: str | os.PathLike) -> PhaseMap:
    """Read a phase map written by :func:`save_phase_map`.

    Parameters
    ----------
    path : str or PathLike
        The ``.npz`` file.

    Returns
    -------
    PhaseMap
        The map, with validated shapes, mask codes and NaN convention.

    Raises
    ------
    InputError
        When the file is missing or unreadable, of another format version, lacks an
        entry, or its arrays are inconsistent.
    """
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as npz:
            data = {name: npz[name] for name in npz.files}
    except FileNotFoundError:
        raise InputError(f"phase map {p} does not exist (run 'scanqa decode' first)") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise InputError(f"cannot read phase map {p}: {err} (is it a scanqa phase.npz?)"
                         ) from None
    return _from_arrays(p, data)


def _from_arrays(path: Path, data: dict) -> PhaseMap:
    fmt = str(data.get("format", "(none)"))
    if fmt != FORMAT:
        raise InputError(f"phase map {path} has format {fmt!r}; this scanqa reads {FORMAT!r} "
                         "(decode the images again with this version)")
    missing = [k for k in (*_ARRAYS, *_SCALARS) if k not in data]
    if missing:
        raise InputError(f"phase map {path} lacks {', '.join(missing)} (file truncated or "
                         "not written by scanqa)")
    try:
        provenance = json.loads(str(data["provenance"]))
    except json.JSONDecodeError as err:
        raise InputError(f"phase map {path}: provenance is not valid JSON ({err})") from None
    try:
        return PhaseMap(**{k: data[k] for k in _ARRAYS}, period_px=float(data["period_px"]),
                        orientation=str(data["orientation"]),
                        projector_width_px=int(data["projector_width_px"]),
                        provenance=provenance)
    except InputError as err:
        raise InputError(f"phase map {path}: {err}") from None


__all__ = ["FORMAT", "MASK_INCONSISTENT", "MASK_LOW_MODULATION", "MASK_OUT_OF_RANGE",
           "MASK_REASONS", "MASK_SATURATED", "MASK_VALID", "PhaseMap", "load_phase_map",
           "save_phase_map"]
