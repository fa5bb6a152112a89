"""OpenCV camera-projector calibrations (FileStorage XML, YAML or JSON).

The layout is the one structured-light tools built on OpenCV's stereo calibration write
(SLStudio's ``calibration.xml`` is one). Keys read, all at the top level:

=================================  ========  ===============================================
key                                required  meaning
=================================  ========  ===============================================
``Kc``                             yes       camera matrix, 3 x 3 [camera px]
``kc``                             yes       camera distortion k1 k2 p1 p2 [k3] (4 or 5
                                             numbers, a row or a column) [-]
``Kp``                             yes       projector matrix, 3 x 3 [projector px]
``kp``                             yes       projector distortion, as ``kc`` [-]
``Rp``                             yes       rotation, 3 x 3 [-]
``Tp``                             yes       translation, 3 numbers [mm]
``frameWidth``, ``frameHeight``    no        camera image size [camera px]
``screenResX``, ``screenResY``     no        projector panel size [projector px]
``cam_error``, ``proj_error``,     no        RMS reprojection errors of the calibration
``stereo_error``                             [px]
``calibration_covariance``         no        covariance of the 24 calibration parameters
                                             (order: ``COVARIANCE_PARAMETERS``), written
                                             by ``scanqa calibrate --board`` [px, -, rad,
                                             mm squared]; other tools ignore the key
``calibration_sigma_um``           no        a stated std of every point along its line of
                                             sight from the calibration's own error [um],
                                             for a calibration without a covariance (add
                                             it to another tool's file by hand)
=================================  ========  ===============================================

Other names (:data:`ALIASES`): files written by other public projector-camera
calibration tools name the six matrices ``cam_int``, ``cam_dist``, ``proj_int``,
``proj_dist``, ``rotation`` and ``translation`` (``cv::stereoCalibrate`` with the camera
first, so ``rotation`` and ``translation`` are ``Rp`` and ``Tp``: X_p = R X_c + T).
Either name is read; a file holding both names of one matrix is refused.

A calibration with neither ``calibration_covariance`` nor ``calibration_sigma_um``
carries no calibration term: every output of it says so (its cloud's ``sigma_source``).

Conventions (OpenCV's): ``Rp``, ``Tp`` map camera coordinates to projector coordinates,
X_p = Rp X_c + Tp [mm], so the projector's centre in the camera frame is -Rp^T Tp. A
point at normalised coordinates (x, y) = (X/Z, Y/Z) of a device is distorted by
Brown-Conrady, r^2 = x^2 + y^2::

    x' = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
    y' = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y

and lands on pixel (u, v, 1) = K (x', y', 1). Longer OpenCV distortion vectors (8, 12
or 14 numbers: rational, thin-prism and tilt terms) are accepted only when the terms
past k3 are all zero. This module parses and checks shapes; what the numbers mean is
:mod:`scanqa.calibration.parametric`'s business.
"""

from __future__ import annotations

import importlib.util
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanqa.errors import InputError

#: pip's name for OpenCV in scanqa's extras: the board and printed-target detectors,
#: OpenCV's calibration solvers and its FileStorage files (``pip install 'scanqa[calib]'``).
INSTALL_HINT = "pip install 'scanqa[calib]'"


def opencv_available() -> bool:
    """True when OpenCV (``cv2``) can be imported (the ``calib`` extra)."""
    return importlib.util.find_spec("cv2") is not None


def require_opencv(what: str) -> None:
    """Refuse ``what`` at once, naming the extra, when OpenCV is not installed.

    Raises
    ------
    InputError
        ``"{what} needs OpenCV (pip install 'scanqa[calib]')"``.
    """
    if not opencv_available():
        raise InputError(f"{what} needs OpenCV ({INSTALL_HINT})")

#: Suffixes OpenCV's FileStorage reads (optionally gzip-compressed: ``.xml.gz``).
SUFFIXES = (".xml", ".yml", ".yaml", ".json")
#: Matrices every calibration must hold, with their shapes.
MATRICES = {"Kc": (3, 3), "kc": "distortion", "Kp": (3, 3), "kp": "distortion",
            "Rp": (3, 3), "Tp": (3,)}
#: Other names of the required matrices, as public projector-camera calibration tools
#: write them (module notes).
ALIASES = {"Kc": ("cam_int",), "kc": ("cam_dist",), "Kp": ("proj_int",),
           "kp": ("proj_dist",), "Rp": ("rotation",), "Tp": ("translation",)}
#: Optional integer sizes.
SIZES = ("frameWidth", "frameHeight", "screenResX", "screenResY")
#: Optional reprojection errors [px].
ERRORS = ("cam_error", "proj_error", "stereo_error")
#: The parameters of ``calibration_covariance``, in order: camera and projector (f_x, f_y,
#: c_x, c_y [px], k1 k2 p1 p2 k3 [-]), the rotation vector of Rp [rad], Tp [mm].
COVARIANCE_PARAMETERS = (
    *(f"{dev}_{name}" for dev in ("camera", "projector")
      for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")),
    "rotation_x", "rotation_y", "rotation_z", "tx", "ty", "tz")
#: Lengths OpenCV uses for distortion vectors.
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class OpenCVCalibration:
    """The contents of an OpenCV camera-projector calibration file.

    Attributes
    ----------
    Kc, Kp : (3, 3) float64
        Camera and projector matrices [px].
    kc, kp : (5,) float64
        Distortion k1 k2 p1 p2 k3 [-] (k3 = 0 when the file gives 4 numbers).
    Rp : (3, 3) float64
        Rotation camera -> projector [-].
    Tp : (3,) float64
        Translation camera -> projector [mm].
    sizes : dict of str to int
        Those of ``frameWidth``, ``frameHeight``, ``screenResX``, ``screenResY`` the file
        holds [px].
    errors : dict of str to float
        Those of ``cam_error``, ``proj_error``, ``stereo_error`` it holds [px].
    source : str
        The file.
    covariance : (24, 24) float64 or None
        Covariance of the parameters ``COVARIANCE_PARAMETERS``, when the file has one.
    stated_sigma_um : float or None
        ``calibration_sigma_um``: a stated calibration std of every point [um].
    """

    Kc: np.ndarray
    kc: np.ndarray
    Kp: np.ndarray
    kp: np.ndarray
    Rp: np.ndarray
    Tp: np.ndarray
    sizes: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    source: str = ""
    covariance: np.ndarray | None = None
    stated_sigma_um: float | None = None


def is_opencv_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` has a FileStorage suffix (``.xml``, ``.yml``, ``.yaml``, ``.json``,
    optionally followed by ``.gz``)."""
    name = Path(path).name.lower().removesuffix(".gz")
    return name.endswith(SUFFIXES)


def read_opencv_calibration(path: str | os.PathLike) -> OpenCVCalibration:
    """Read a camera-projector calibration from an OpenCV FileStorage file.

    Parameters
    ----------
    path : str or PathLike
        ``.xml``, ``.yml``/``.yaml`` or ``.json`` file (module notes list the keys).

    Returns
    -------
    OpenCVCalibration
        Matrices as float64 arrays, sizes and reprojection errors.

    Raises
    ------
    InputError
        When the file is missing or not a FileStorage file, a required matrix is missing,
        not a matrix, of the wrong shape or not finite, or a size is not a positive whole
        number.
    """
    require_opencv("reading an OpenCV calibration file (.xml, .yml, .yaml, .json)")
    p = Path(path)
    if not p.is_file():
        raise InputError(f"OpenCV calibration {p} does not exist")
    if p.stat().st_size == 0:
        raise InputError(f"OpenCV calibration {p} is empty")
    import cv2  # deferred: loading OpenCV costs ~0.2 s that other commands need not pay

    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as err:
        raise InputError(f"{p} is not an OpenCV FileStorage file (XML, YAML or JSON as "
                         f"written by cv::FileStorage): {_first_line(err)}") from None
    if not opened:
        raise InputError(f"cannot open {p} as an OpenCV FileStorage file")
    try:
        return _read_nodes(fs, p)
    finally:
        fs.release()


def _first_line(err: Exception) -> str:
    """The informative part of an OpenCV exception ("Parsing error: f.xml(3): ...")."""
    text = str(err.__cause__ or err).strip().splitlines()
    line = text[-1] if text else type(err).__name__
    found = re.search(r"error: \(-?\d+:([^)]*)\) (.*)$", line)
    if not found:
        return line
    detail = re.sub(r"^\w+ in function '(.*)'$", r"\1", found.group(2))
    return f"{found.group(1)}: {detail}"


def _read_nodes(fs, p: Path) -> OpenCVCalibration:
    """Every key of the module notes from an open FileStorage."""
    mats = {name: _matrix(fs, p, _key(fs, p, name), shape) for name, shape in MATRICES.items()}
    sizes = {name: _size(fs, p, name) for name in SIZES}
    errors = {name: _real(fs, p, name) for name in ERRORS}
    n = len(COVARIANCE_PARAMETERS)
    cov = (None if fs.getNode("calibration_covariance").empty()
           else check_covariance(p, _matrix(fs, p, "calibration_covariance", (n, n))))
    stated = _real(fs, p, "calibration_sigma_um", "um (a std along the line of sight)")
    return OpenCVCalibration(**mats, sizes={k: v for k, v in sizes.items() if v is not None},
                             errors={k: v for k, v in errors.items() if v is not None},
                             source=str(p), covariance=cov, stated_sigma_um=stated)


def _key(fs, p: Path, name: str) -> str:
    """The name a required matrix goes by in the file (``name`` or one of its
    :data:`ALIASES`); ``name`` when it has none (the missing-matrix error follows)."""
    present = [key for key in (name, *ALIASES.get(name, ())) if not fs.getNode(key).empty()]
    if len(present) > 1:
        raise InputError(f"{p}: the file holds {' and '.join(map(repr, present))}, two names of "
                         f"one matrix ({name}): keep one")
    return present[0] if present else name


def write_opencv_calibration(path: str | os.PathLike, data: OpenCVCalibration) -> Path:
    """Write a calibration as an OpenCV FileStorage file (the keys of the module notes).

    The file is written beside its final name and renamed into place, so a reader never
    sees half a file. :func:`read_opencv_calibration` reads it back unchanged (float64).

    Parameters
    ----------
    path : str or PathLike
        ``.xml``, ``.yml``/``.yaml`` or ``.json``.
    data : OpenCVCalibration
        What to write; ``source`` is not written.

    Returns
    -------
    Path
        The file written.
    """
    require_opencv("writing an OpenCV calibration file")
    import cv2

    p = Path(path)
    if not is_opencv_file(p):
        raise InputError(f"{p}: an OpenCV calibration file must end in "
                         f"{', '.join(SUFFIXES)}")
    tmp = p.with_name(f".{p.name}.tmp{p.suffix}")
    fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
    try:
        for name in MATRICES:
            value = np.asarray(getattr(data, name), dtype=float)
            fs.write(name, value.reshape(-1, 1) if value.ndim == 1 else value)
        for name, value in {**data.errors, **data.sizes}.items():
            fs.write(name, value)
        if data.covariance is not None:
            fs.write("calibration_covariance", np.asarray(data.covariance, dtype=float))
        if data.stated_sigma_um is not None:
            fs.write("calibration_sigma_um", float(data.stated_sigma_um))
    finally:
        fs.release()
    os.replace(tmp, p)
    return p


def _matrix(fs, p: Path, name: str, shape) -> np.ndarray:
    """A required matrix node as float64 of ``shape`` (or a distortion vector)."""
    import cv2

    node = fs.getNode(name)
    if node.empty():
        others = {a: n for n, al in ALIASES.items() for a in al}
        canonical = others.get(name, name)
        also = "".join(f" or {a!r}" for a in ALIASES.get(canonical, ()))
        raise InputError(f"{p}: matrix {canonical!r}{also} is missing (a camera-projector "
                         f"calibration needs {', '.join(MATRICES)}, or the names "
                         f"{', '.join(a for al in ALIASES.values() for a in al)})")
    try:
        mat = node.mat() if node.isMap() else None
    except cv2.error as err:
        raise InputError(f"{p}: {name!r} is not a readable OpenCV matrix "
                         f"({_first_line(err)})") from None
    if mat is None:
        raise InputError(f"{p}: {name!r} is not an OpenCV matrix (expected a node of "
                         "type opencv-matrix with rows, cols, dt and data)")
    mat = np.asarray(mat, dtype=float)
    if shape == "distortion":
        return _distortion(p, name, mat)
    if mat.size != int(np.prod(shape)) or (len(shape) == 2 and mat.shape != shape):
        want = " x ".join(map(str, shape)) if len(shape) == 2 else f"{shape[0]} numbers"
        raise InputError(f"{p}: {name!r} is {' x '.join(map(str, mat.shape))}, expected "
                         f"{want}")
    if not np.isfinite(mat).all():
        raise InputError(f"{p}: {name!r} holds NaN or infinite values")
    return mat.reshape(shape)


#: Relative tolerance of the covariance's symmetry and of its smallest eigenvalue (text
#: files round-trip float64 to ~1e-16; a covariance computed as a sum of outer products
#: is symmetric to ~1e-15 of its largest entry) [-].
COVARIANCE_TOLERANCE = 1e-9


def check_covariance(p: str | os.PathLike, cov: np.ndarray,
                     name: str = "calibration_covariance") -> np.ndarray:
    """A parameter covariance ``cov`` (field ``name`` of file ``p``) checked to be one:
    symmetric and without a negative eigenvalue (to :data:`COVARIANCE_TOLERANCE` of its
    largest entry); returned unchanged.

    Raises
    ------
    InputError
        Naming the file and the field.
    """
    scale = float(np.abs(cov).max())
    asym = float(np.abs(cov - cov.T).max())
    if asym > COVARIANCE_TOLERANCE * scale:
        raise InputError(f"{p}: {name!r} is not symmetric (largest |C - C^T| {asym:.3g} "
                         f"against entries up to {scale:.3g}): write the fit's covariance "
                         "matrix, or leave the key out")
    low = float(np.linalg.eigvalsh((cov + cov.T) / 2).min())
    if low < -COVARIANCE_TOLERANCE * scale:
        raise InputError(f"{p}: {name!r} has a negative eigenvalue ({low:.3g}), so it is "
                         "no covariance: write the fit's covariance matrix, or leave the "
                         "key out")
    return cov


def _distortion(p: Path, name: str, mat: np.ndarray) -> np.ndarray:
    """A distortion vector (a row or a column) as k1 k2 p1 p2 k3."""
    if (mat.ndim == 2 and min(mat.shape) != 1) or mat.size not in DISTORTION_LENGTHS:
        raise InputError(f"{p}: {name!r} is {' x '.join(map(str, mat.shape))}, expected a "
                         f"row or column of {', '.join(map(str, DISTORTION_LENGTHS))} "
                         "distortion coefficients (k1 k2 p1 p2 [k3 ...])")
    k = mat.ravel()
    if not np.isfinite(k).all():
        raise InputError(f"{p}: {name!r} holds NaN or infinite values")
    if np.any(k[5:] != 0):
        raise InputError(f"{p}: {name!r} has rational, thin-prism or tilt terms ({k[5:]}) "
                         "that scanqa does not model: recalibrate with the 5-coefficient "
                         "model k1 k2 p1 p2 k3")
    return np.pad(k[:5], (0, 5 - min(k.size, 5)))


def _size(fs, p: Path, name: str) -> int | None:
    """An optional positive integer node, or None."""
    node = fs.getNode(name)
    if node.empty():
        return None
    value = node.real() if (node.isInt() or node.isReal()) else float("nan")
    if not (np.isfinite(value) and value >= 1 and float(value).is_integer()):
        raise InputError(f"{p}: {name} must be a positive whole number of pixels, got "
                         f"{_show(node)}")
    return int(value)


def _real(fs, p: Path, name: str, unit: str = "px (an RMS error)") -> float | None:
    """An optional finite, non-negative real node (an RMS error), or None."""
    node = fs.getNode(name)
    if node.empty():
        return None
    if not (node.isInt() or node.isReal()) or not np.isfinite(node.real()) or \
            node.real() < 0:
        raise InputError(f"{p}: {name} must be a number >= 0 [{unit.split(' ', 1)[0]}] "
                         f"{unit.split(' ', 1)[1] if ' ' in unit else ''}, got "
                         f"{_show(node)}".replace("  ", " "))
    return float(node.real())


def _show(node) -> str:
    """A node's value for messages."""
    if node.isString():
        return repr(node.string())
    if node.isInt() or node.isReal():
        return f"{node.real():g}"
    return "a map or sequence"
