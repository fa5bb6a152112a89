"""The marked calibration target: detect it, and estimate the sweep's geometry from it.

The target is a chessboard larger than the camera's field of view, with three marker
dots in an L around its origin (OpenCV's "radon checkerboard", docs/calibration.rst,
"The marked target"). In one marker frame per stage position (a uniformly lit image,
:ref:`sweep-format`), :func:`detect_chessboard` finds the inner corners with
``cv2.findChessboardCornersSBWithMeta`` (sub-pixel, Duda & Frese 2018) and labels each
with its target coordinates from the dots, so that every position shares one target
frame however much of the board is in view.

:func:`fit_sweep_geometry` then fits, to all corners of all positions at once, one
camera (focal length, principal point, Brown-Conrady k1 k2 p1 p2; square pixels, no
skew) and the target's pose at every position, constrained to a rigid stage: one
rotation (the target's tilt) and a translation that moves along one straight axis by
the stage readings. The stage axis and the target's tilt are estimated, not assumed;
the principal point is fitted where the sweep identifies it (the distortion's centre, a
tilted target's perspective) and otherwise held at the sensor centre, and the result
says which (``principal_point_fitted``).

:meth:`SweepGeometry.plane_points` gives, per pixel, the 3-D point of the target plane it
sees at a stage reading (pose + distortion): the lateral X, Y, Z that the calibration
table is built with (:mod:`scanqa.calibration.sweep`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from scanqa.calibration.parametric import Lens
from scanqa.config import ScannerConfig
from scanqa.errors import InputError

#: Target kinds a sweep manifest may name.
TARGET_KINDS = ("chessboard",)
#: Smallest block of inner corners the detector accepts (columns, rows).
MIN_PATTERN = (5, 4)
#: A principal-point std above this counts as not identified by the sweep [px].
PRINCIPAL_POINT_LIMIT_PX = 0.5


@dataclass(frozen=True)
class ChessboardSpec:
    """The marked chessboard: square size, the marker cells and their dot radius.

    Cell (i, j) spans target x in [i, i + 1) and y in [j, j + 1) squares; it is white
    when i + j is even. Inner corner (i, j) lies at (i, j) x ``square_mm``. Each marker
    cell carries a dot of the opposite colour at its centre.

    Attributes
    ----------
    square_mm : float
        Side of a square [mm].
    marker_cells : tuple of (int, int)
        Cells carrying the dots (an L of three: its corner cell fixes the orientation).
    dot_radius : float
        Dot radius as a fraction of the square [-] (OpenCV's generator uses 0.17).
    """

    square_mm: float
    marker_cells: tuple = ((0, 0), (0, 1), (1, 1))
    dot_radius: float = 0.17

    def __post_init__(self) -> None:
        if not (isinstance(self.square_mm, (int, float)) and self.square_mm > 0):
            raise InputError(f"target square_mm must be > 0 mm, got {self.square_mm!r}")
        cells = tuple(tuple(int(v) for v in c) for c in self.marker_cells)
        if len(cells) != 3 or len(set(cells)) != 3:
            raise InputError(f"target marker_cells must be 3 distinct cells, got {cells}")
        object.__setattr__(self, "marker_cells", cells)

    @staticmethod
    def is_white(i: int, j: int) -> bool:
        """Whether cell (i, j) is white."""
        return (i + j) % 2 == 0


@dataclass(frozen=True)
class Detection:
    """Labelled corners of one marker frame.

    Attributes
    ----------
    image_points : (n, 2) float
        Sensor coordinates, pixel centres at integers [px].
    target_points : (n, 2) float
        Target-plane coordinates of the same corners [mm].
    source : str
        The image, for messages.
    """

    image_points: np.ndarray
    target_points: np.ndarray
    source: str = ""


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """Stretch an image to 8 bits between its 1st and 99th percentiles."""
    img = np.asarray(image, dtype=float)
    if img.ndim == 3:
        img = img.mean(axis=-1)
    lo, hi = np.percentile(img, [1.0, 99.0])
    scale = 255.0 / max(hi - lo, 1e-9)
    return np.clip((img - lo) * scale, 0, 255).astype(np.uint8)


def detect_chessboard(image: np.ndarray, spec: ChessboardSpec, source: str = ""
                      ) -> Detection:
    """Find and label the inner corners of the marked chessboard in one image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        A uniformly lit frame of the target [DN].
    spec : ChessboardSpec
        The printed target.
    source : str
        Name of the image for messages.

    Returns
    -------
    Detection

    Raises
    ------
    InputError
        No chessboard found, or its marker dots not found or ambiguous.
    """
    import cv2

    img8 = _to_uint8(image)
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_MARKER | cv2.CALIB_CB_EXHAUSTIVE
    ok, corners, meta = cv2.findChessboardCornersSBWithMeta(img8, MIN_PATTERN, flags)
    if not ok or corners is None:
        raise InputError(f"{source or 'image'}: no marked chessboard found (need at least "
                         f"{MIN_PATTERN[0]} x {MIN_PATTERN[1]} inner corners and the three "
                         "marker dots in view, uniformly lit, in focus enough for the "
                         "squares to show)")
    grid = np.asarray(corners, float).reshape(*meta.shape, 2)
    valid = meta > 0
    dots, white = _dot_cells(np.asarray(img8, float), grid, valid)
    mapping = _label(dots, white, grid, valid, spec, source)
    rows, cols = np.nonzero(valid)
    ij = np.array([mapping(c, r) for r, c in zip(rows, cols, strict=True)], float)
    points, ok = refine_corners(image, grid[rows, cols])
    return Detection(points[ok], ij[ok] * spec.square_mm, source)


#: Gaussian pre-smoothing of the corner refinement [px] and its half window [px].
REFINE_SIGMA_PX, REFINE_HALF_WINDOW_PX = 1.5, 5


def refine_corners(image: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel corners by ``cv2.cornerSubPix`` on the image smoothed by a Gaussian.

    The detector's own positions carry a bias that depends on where a corner falls
    within its pixel when the image is sharp (undersampled); smoothing by
    :data:`REFINE_SIGMA_PX` first and refining by gradient orthogonality over
    ``2 x REFINE_HALF_WINDOW_PX + 1`` px removes most of it (on simulated frames of the
    sample camera, 0.08 -> 0.03 px RMS in focus; see docs/calibration.rst,
    "The marked target").

    Returns
    -------
    points : (n, 2) float
        Refined corners [px].
    ok : (n,) bool
        False where the refinement moved a corner by more than 1 px (not a corner).
    """
    import cv2
    from scipy.ndimage import gaussian_filter

    img = np.asarray(image, dtype=float)
    img = img.mean(axis=-1) if img.ndim == 3 else img
    smooth = gaussian_filter(img, REFINE_SIGMA_PX).astype(np.float32)
    start = np.asarray(points, np.float32).reshape(-1, 1, 2).copy()
    half = REFINE_HALF_WINDOW_PX
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    out = cv2.cornerSubPix(smooth, start.copy(), (half, half), (-1, -1), crit).reshape(-1, 2)
    ok = np.hypot(*(out - start.reshape(-1, 2)).T) < 1.0
    return out.astype(float), ok


def _sample(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of an image at (n, 2) points (u, v) [DN]."""
    import cv2

    m = pts.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(img.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).ravel()


def _dot_cells(img: np.ndarray, grid: np.ndarray, valid: np.ndarray
               ) -> tuple[list[tuple[int, int]], dict]:
    """Cells (col, row of their top-left corner) holding a dot, and each cell's colour."""
    quads = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    rr, cc = np.nonzero(quads)
    if rr.size == 0:
        return [], {}
    c4 = np.stack([grid[rr, cc], grid[rr + 1, cc], grid[rr, cc + 1], grid[rr + 1, cc + 1]], 1)
    centre = c4.mean(axis=1)
    ring = _sample(img, (centre[:, None] + 0.35 * (c4 - centre[:, None])).reshape(-1, 2))
    level = ring.reshape(-1, 4).mean(axis=1)
    mid = _sample(img, centre)
    span = np.percentile(level, 95) - np.percentile(level, 5)
    is_white = level > 0.5 * (np.percentile(level, 95) + np.percentile(level, 5))
    dot = np.abs(mid - level) > 0.4 * span
    colours = {(int(c), int(r)): bool(w) for r, c, w in zip(rr, cc, is_white, strict=True)}
    return [(int(c), int(r)) for r, c in zip(rr[dot], cc[dot], strict=True)], colours


_ROTATIONS = [np.array(m) for m in itertools.product((-1, 0, 1), repeat=4)]
_ROTATIONS = [m.reshape(2, 2) for m in _ROTATIONS
              if abs(round(np.linalg.det(m.reshape(2, 2)))) == 1
              and (np.abs(m.reshape(2, 2)).sum(axis=0) == 1).all()
              and (np.abs(m.reshape(2, 2)).sum(axis=1) == 1).all()]


def _label(dots, colours, grid, valid, spec: ChessboardSpec, source: str):
    """The map (col, row) of the detector's grid -> target corner (i, j) (module notes)."""
    where = source or "image"
    if len(dots) != 3:
        raise InputError(f"{where}: found {len(dots)} marker dots, the target has 3 (are the "
                         "dots in view and the frame uniformly lit?)")
    want = sorted(spec.marker_cells)
    for m in _ROTATIONS:
        cells = []
        for c, r in dots:  # a cell's target index is the smallest of its mapped corners
            quad = [m @ (c + dc, r + dr) for dc in (0, 1) for dr in (0, 1)]
            cells.append(tuple(np.min(quad, axis=0)))
        off = np.subtract(want[0], sorted(cells)[0])
        if sorted(tuple(np.add(x, off)) for x in cells) != want:
            continue
        mapping = _mapper(m, off)
        if not _consistent(mapping, colours, grid, valid, spec):
            continue
        return mapping
    raise InputError(f"{where}: the three marker dots do not match the target's marker "
                     f"cells {spec.marker_cells} in any orientation")


def _mapper(m: np.ndarray, off: np.ndarray):
    def mapping(c: int, r: int) -> tuple[int, int]:
        i, j = m @ (c, r) + off
        return int(i), int(j)
    return mapping


def _consistent(mapping, colours: dict, grid: np.ndarray, valid: np.ndarray,
                spec: ChessboardSpec) -> bool:
    """A cell's colour matches the target (one cell fixes the parity) and the labelling
    is not mirrored."""
    first = next(iter(colours.items()), None)
    if first is not None:
        (c, r), white = first
        quad = [mapping(c + dc, r + dr) for dc in (0, 1) for dr in (0, 1)]
        i, j = np.min(quad, axis=0)
        if spec.is_white(int(i), int(j)) != white:
            return False
    rows, cols = np.nonzero(valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:])
    r, c = rows[0], cols[0]
    e_c, e_r = grid[r, c + 1] - grid[r, c], grid[r + 1, c] - grid[r, c]
    t_c = np.subtract(mapping(c + 1, r), mapping(c, r))
    t_r = np.subtract(mapping(c, r + 1), mapping(c, r))
    image_det = e_c[0] * e_r[1] - e_c[1] * e_r[0]
    target_det = t_c[0] * t_r[1] - t_c[1] * t_r[0]
    return image_det * target_det > 0  # seen from the front: no mirror


# ----------------------------------------------------------------- sweep geometry


def _rodrigues(rvec: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(rvec, float))[0]


def plane_to_camera(xy: np.ndarray, rotation: np.ndarray, translation: np.ndarray
                    ) -> np.ndarray:
    """(n, 2) target-plane points -> (n, 3) camera-frame points [mm]; ``translation`` is
    the target origin, (3,) or one per point (n, 3)."""
    xy = np.asarray(xy, float)
    return xy[:, :1] * rotation[:, 0] + xy[:, 1:2] * rotation[:, 1] + translation


def _direction(a: float, b: float) -> np.ndarray:
    """Unit vector from two small angles about the camera axis [-]."""
    v = np.array([math.tan(a), math.tan(b), 1.0])
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class SweepGeometry:
    """Camera and rigid-stage geometry fitted to a marked sweep (module notes).

    Attributes
    ----------
    camera : Lens
        Camera matrix and distortion (k1 k2 p1 p2 0) [px], [-].
    rotation : (3, 3) float
        Target -> camera rotation; its third column is the target's normal [-].
    origin_mm : (3,) float
        Target origin in the camera frame at stage reading ``stage_ref_mm`` [mm].
    axis : (3,) float
        Stage direction in the camera frame (unit, + with the readings) [-].
    stage_ref_mm : float
        The reading at which ``origin_mm`` holds [mm].
    rms_px : float
        RMS reprojection error of all corners [px].
    plane_rms_px : dict
        RMS reprojection error per stage reading [px].
    principal_point_fitted : bool
        Whether the sweep identified the principal point (else: the sensor centre).
    std : dict
        Standard deviations of the main parameters from the fit's covariance.
    """

    camera: Lens
    rotation: np.ndarray
    origin_mm: np.ndarray
    axis: np.ndarray
    stage_ref_mm: float
    rms_px: float
    plane_rms_px: dict = field(default_factory=dict)
    principal_point_fitted: bool = True
    std: dict = field(default_factory=dict)

    def translation(self, stage_mm: float) -> np.ndarray:
        """Target origin in the camera frame at a stage reading [mm]."""
        return self.origin_mm + (float(stage_mm) - self.stage_ref_mm) * self.axis

    @property
    def stage_tilt_deg(self) -> float:
        """Angle between the stage axis and the camera axis [deg]."""
        return math.degrees(math.acos(min(1.0, abs(float(self.axis[2])))))

    @property
    def target_tilt_deg(self) -> float:
        """Angle between the target's normal and the camera axis [deg]."""
        return math.degrees(math.acos(min(1.0, abs(float(self.rotation[2, 2])))))

    def project(self, target_xy: np.ndarray, stage_mm: float) -> np.ndarray:
        """Sensor coordinates of target-plane points at a stage reading: (n, 2) [px]."""
        pts = plane_to_camera(target_xy, self.rotation, self.translation(stage_mm))
        return np.stack(self.camera.project(pts), -1)

    def plane_points(self, stage_mm: float, width: int, height: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, Y, Z maps [mm] of the target plane seen by every pixel at a stage reading.

        Each pixel's ray (undistorted) meets the plane of the target's pose; NaN where
        the undistortion fails.
        """
        v, u = np.mgrid[0:height, 0:width].astype(float)
        x, y, ok = self.camera.undistort(u, v)
        n = self.rotation[:, 2]
        lam = (n @ self.translation(stage_mm)) / (n[0] * x + n[1] * y + n[2])
        lam = np.where(ok, lam, np.nan)
        return lam * x, lam * y, lam

    def summary(self) -> dict:
        """Plain numbers for reports."""
        k = self.camera.matrix
        return {"focal_px": float(k[0, 0]), "principal_point_px": [float(k[0, 2]),
                                                                   float(k[1, 2])],
                "principal_point_fitted": self.principal_point_fitted,
                "distortion_k1_k2_p1_p2": [float(v) for v in self.camera.distortion[:4]],
                "stage_axis": [float(v) for v in self.axis],
                "stage_tilt_deg": self.stage_tilt_deg,
                "target_tilt_deg": self.target_tilt_deg, "rms_px": self.rms_px,
                "std": dict(self.std)}


def _unpack(p: np.ndarray, fixed_pp: tuple[float, float] | None):
    """Parameters -> (K, dist, R, t0, axis)."""
    if fixed_pp is not None:
        p = np.concatenate([p[:1], fixed_pp, p[1:]])
    f, cx, cy = p[:3]
    k = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    dist = np.array([*p[3:7], 0.0])
    return k, dist, _rodrigues(p[7:10]), p[10:13], _direction(p[13], p[14])


def _residuals(p, fixed_pp, xy, stage, uv, size):
    k, dist, rot, t0, axis = _unpack(p, fixed_pp)
    pts = plane_to_camera(xy, rot, t0 + stage[:, None] * axis)
    u, v = Lens(k, dist, *size).project(pts)
    return np.concatenate([u - uv[:, 0], v - uv[:, 1]])


def fit_sweep_geometry(detections: list[Detection], stage_mm: list[float],
                       config: ScannerConfig, width: int, height: int) -> SweepGeometry:
    """Fit the camera and the rigid stage to the labelled corners of a sweep.

    Parameters
    ----------
    detections : list of Detection
        One per stage position.
    stage_mm : list of float
        The stage reading of each [mm].
    config : ScannerConfig
        Starting values (focal length, pixel size) only.
    width, height : int
        Image size [px].

    Returns
    -------
    SweepGeometry

    Raises
    ------
    InputError
        Fewer than 3 positions, or a fit that does not converge to sub-pixel residuals.
    """
    from scipy.optimize import least_squares

    if len(detections) < 3:
        raise InputError(f"the marked target was found at {len(detections)} positions; the "
                         "sweep's geometry needs at least 3")
    ref = 0.5 * (min(stage_mm) + max(stage_mm))
    xy = np.concatenate([d.target_points for d in detections])
    uv = np.concatenate([d.image_points for d in detections])
    stage = np.concatenate([np.full(len(d.target_points), s - ref)
                            for d, s in zip(detections, stage_mm, strict=True)])
    p0 = _start(detections, stage_mm, ref, config, width, height)
    centre = ((width - 1) / 2.0, (height - 1) / 2.0)
    args = (xy, stage, uv, (width, height))
    fit = least_squares(_residuals, p0, args=(None, *args), x_scale="jac", method="lm")
    std = _std(fit)
    fitted = bool(max(std[1], std[2]) < PRINCIPAL_POINT_LIMIT_PX)
    if not fitted:
        q0 = np.concatenate([p0[:1], p0[3:]])
        fit = least_squares(_residuals, q0, args=(centre, *args), x_scale="jac", method="lm")
        std = np.insert(_std(fit), 1, [0.0, 0.0])
    return _geometry(fit, None if fitted else centre, detections, stage_mm, ref, width,
                     height, std)


def _std(fit) -> np.ndarray:
    """Parameter standard deviations from the Jacobian, scaled by the residual RMS."""
    j = fit.jac
    dof = max(j.shape[0] - j.shape[1], 1)
    s2 = float(fit.fun @ fit.fun) / dof
    try:
        cov = np.linalg.inv(j.T @ j) * s2
    except np.linalg.LinAlgError:
        return np.full(j.shape[1], np.inf)
    return np.sqrt(np.abs(np.diag(cov)))


def _start(detections, stage_mm, ref, config, width, height) -> np.ndarray:
    """Starting parameters: the config's pinhole and two PnP poses."""
    import cv2

    f = config.camera.principal_distance_px
    k = np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1.0]])
    poses = []
    for d in (detections[0], detections[-1]):
        obj = np.column_stack([d.target_points, np.zeros(len(d.target_points))])
        ok, rvec, tvec = cv2.solvePnP(obj, d.image_points, k, None)
        if not ok:
            raise InputError(f"{d.source}: cannot estimate the target's pose")
        poses.append((rvec.ravel(), tvec.ravel()))
    s0, s1 = stage_mm[0], stage_mm[-1]
    axis = (poses[1][1] - poses[0][1]) / (s1 - s0)
    t_ref = poses[0][1] + (ref - s0) * axis
    axis = axis / np.linalg.norm(axis)
    angles = [math.atan2(axis[0], axis[2]), math.atan2(axis[1], axis[2])]
    return np.array([f, k[0, 2], k[1, 2], 0, 0, 0, 0, *poses[0][0], *t_ref, *angles])


def _geometry(fit, fixed_pp, detections, stage_mm, ref, width, height, std
              ) -> SweepGeometry:
    k, dist, rot, t0, axis = _unpack(fit.x, fixed_pp)
    res = fit.fun.reshape(2, -1)
    err = np.hypot(res[0], res[1])
    rms = float(np.sqrt(np.mean(err**2)))
    if not rms < 1.0:
        raise InputError(f"the marked sweep does not fit one camera on a straight stage "
                         f"(RMS reprojection error {rms:.2f} px): check the stage readings "
                         "and that the target did not move on the stage")
    per, start = {}, 0
    for d, s in zip(detections, stage_mm, strict=True):
        n = len(d.target_points)
        per[float(s)] = float(np.sqrt(np.mean(err[start:start + n] ** 2)))
        start += n
    names = ("focal_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2")
    return SweepGeometry(Lens(k, dist, width, height), rot, np.asarray(t0, float), axis,
                         float(ref), rms, per, fixed_pp is None,
                         {n: float(s) for n, s in zip(names, std, strict=False)})
