"""Covariance files: the covariance of a camera-projector calibration's parameters.

A calibration from another tool (an OpenCV file without ``calibration_covariance``)
carries no calibration term. A covariance file gives it one without editing the
calibration (``--calibration-covariance FILE``, ``load_calibration(...,
covariance=FILE)``), and ``scanqa calibrate --board --covariance-out FILE`` writes its own
result's covariance in the same format, so that a board calibration's term can travel
beside any copy of its matrices.

Two encodings of one content, chosen by suffix:

``.json``::

    {"format": "scanqa-calibration-covariance/1",
     "parameters": ["camera_fx", "camera_fy", ..., "tz"],
     "units": ["px", "px", ..., "mm"],
     "covariance": [[...], ...]}

``.npz``: arrays ``parameters`` (24 strings) and ``covariance`` (24 x 24 float), and
optionally ``format`` (the string above).

``parameters`` names the rows and columns of ``covariance`` in order: the 24 names of
:data:`scanqa.io.opencv.COVARIANCE_PARAMETERS` (camera then projector f_x, f_y, c_x, c_y
[px], k1 k2 p1 p2 k3 [-]; the rotation vector of Rp [rad]; Tp [mm]), in any order (the
matrix is reordered to the canonical one on reading). ``units`` is written for the
reader and not read. The matrix must be finite, symmetric and have no negative
eigenvalue (to a relative 1e-9). Every refusal is one line naming the file and the
field.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path
from scanqa.io.guard import MAX_TEXT_BYTES, loads_json_object, regular_file
from scanqa.io.npzfile import load_npz
from scanqa.io.opencv import COVARIANCE_PARAMETERS, check_covariance

#: The ``format`` of a covariance file.
FORMAT = "scanqa-calibration-covariance/1"
#: Suffixes of covariance files.
SUFFIXES = (".json", ".npz")
#: The unit of each parameter of :data:`COVARIANCE_PARAMETERS` (rows and columns of the
#: covariance; its entries are products of two of them).
UNITS = (*(["px"] * 4 + ["-"] * 5) * 2, "rad", "rad", "rad", "mm", "mm", "mm")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(f"{path}: a calibration covariance file ends in .json or .npz "
                         f"(got {suffix or 'no suffix'!r})")
    return suffix


def write_covariance(path: str | os.PathLike, covariance: np.ndarray) -> Path:
    """Write a calibration's parameter covariance (module notes), atomically.

    Parameters
    ----------
    path : str or PathLike
        ``.json`` or ``.npz``.
    covariance : (24, 24) float
        In the order of :data:`~scanqa.io.opencv.COVARIANCE_PARAMETERS` [px, -, rad, mm
        squared and products].

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    suffix = _suffix(path)
    cov = np.asarray(covariance, dtype=float)
    n = len(COVARIANCE_PARAMETERS)
    if cov.shape != (n, n):
        raise ValueError(f"covariance is {cov.shape}, expected ({n}, {n})")
    with atomic_path(path) as tmp:
        if suffix == ".json":
            text = json.dumps({"format": FORMAT, "parameters": list(COVARIANCE_PARAMETERS),
                               "units": list(UNITS), "covariance": cov.tolist()},
                              allow_nan=False, indent=1)
            tmp.write_text(text + "\n", encoding="utf-8")
        else:
            with open(tmp, "wb") as fh:
                np.savez(fh, format=np.array(FORMAT), covariance=cov,
                         parameters=np.array(COVARIANCE_PARAMETERS))
    return path


def read_covariance(path: str | os.PathLike) -> np.ndarray:
    """Read a covariance file (module notes).

    Parameters
    ----------
    path : str or PathLike
        ``.json`` or ``.npz``.

    Returns
    -------
    (24, 24) float64
        The covariance in the order of :data:`~scanqa.io.opencv.COVARIANCE_PARAMETERS`.

    Raises
    ------
    InputError
        One line naming the file and the field: a missing or unreadable file, a wrong
        ``format``, ``parameters`` that are not the 24 names (each once), a
        ``covariance`` of the wrong shape, not finite, not symmetric or with a negative
        eigenvalue.
    """
    path = regular_file(path, "calibration covariance", MAX_TEXT_BYTES)
    if _suffix(path) == ".json":
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise InputError(f"cannot read calibration covariance {path}: {err}") from None
        data = loads_json_object(text, f"calibration covariance {path}")
        fmt = data.get("format")
    else:
        data = load_npz(path, "calibration covariance")
        fmt = str(data["format"]) if "format" in data else FORMAT
    if fmt != FORMAT:
        raise InputError(f"{path}: format must be {FORMAT!r}, got {fmt!r:.80}")
    for key in ("parameters", "covariance"):
        if key not in data:
            raise InputError(f"{path}: field {key!r} is missing (a covariance file holds "
                             "'parameters', the 24 parameter names in order, and "
                             "'covariance', their 24 x 24 covariance)")
    names = _names(path, data["parameters"])
    cov = _matrix(path, data["covariance"], len(names))
    order = [names.index(name) for name in COVARIANCE_PARAMETERS]
    return check_covariance(path, cov[np.ix_(order, order)], "covariance")


def _names(path: Path, value: object) -> list[str]:
    """``parameters``: the 24 names of COVARIANCE_PARAMETERS, each once, in any order."""
    names = np.asarray(value).ravel().tolist() if not isinstance(value, list) else value
    if not all(isinstance(v, str) for v in names):
        raise InputError(f"{path}: field 'parameters' must be a list of parameter names, "
                         f"got {value!r:.80}")
    unknown = [v for v in names if v not in COVARIANCE_PARAMETERS]
    missing = [v for v in COVARIANCE_PARAMETERS if v not in names]
    if unknown or missing or len(names) != len(COVARIANCE_PARAMETERS):
        what = (f"unknown {unknown[0]!r}" if unknown else f"{missing[0]!r} missing"
                if missing else "a name repeated")
        raise InputError(f"{path}: field 'parameters' must name the 24 calibration "
                         f"parameters once each ({what}; the names: "
                         f"{', '.join(COVARIANCE_PARAMETERS)})")
    return list(names)


def _matrix(path: Path, value: object, n: int) -> np.ndarray:
    """``covariance``: an n x n matrix of finite numbers."""
    try:
        cov = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        cov = None
    if cov is None or cov.shape != (n, n):
        shape = "ragged" if cov is None else " x ".join(map(str, cov.shape)) or "a number"
        raise InputError(f"{path}: field 'covariance' must be a {n} x {n} matrix (rows and "
                         f"columns in the order of 'parameters'), got {shape}")
    if not np.isfinite(cov).all():
        raise InputError(f"{path}: field 'covariance' holds NaN or infinite values")
    return cov
