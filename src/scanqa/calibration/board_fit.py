"""Camera-projector calibration from board poses (:mod:`scanqa.calibration.board`).

The camera and the projector are each calibrated by OpenCV's ``calibrateCamera`` (Zhang's
method, the projector as an inverse camera seeing the board's corners at their decoded
(x_p, y_p)); ``stereoCalibrate`` with both intrinsics held then fits their relative pose
to all poses at once. From there every parameter, the board poses and the board's bow
are refined together, each device's residuals scaled by its measured corner noise, and
that joint fit's Jacobian gives the calibration's covariance, with the left-out lens
terms the data show as stated terms (:mod:`scanqa.calibration.bundle`). The result is
the OpenCV layout every scanqa command reads (:mod:`scanqa.io.opencv`).

Checks that need no reference: the reprojection RMS of each pose (a pose whose RMS is
more than ``FLAG_FACTOR`` times the median of the others is flagged), and leave one pose
out: calibrate on the others, then (a) the held-out pose's projector corners predicted
from its camera corners (its board pose found by ``solvePnP`` with the held-out
calibration's camera) and (b) the RMS of its dense triangulated points about their
fitted plane. The calibrations left one pose out also give the jackknife covariance of
the parameters [1]_ (:mod:`scanqa.calibration.uncertainty`), kept as a check of the
joint fit's: with a handful of poses it is a noisy estimate that also carries the
board's bow as if it were calibration error.

References
----------
.. [1] B. Efron and C. Stein, "The jackknife estimate of variance", Ann. Statist. 9
   (1981) 586-596.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from scanqa.calibration.board import Board, BoardPose, decode_pose
from scanqa.calibration.bundle import (
    BOW_TERMS,
    RELEASE_STD,
    BundleResult,
    bundle_adjust,
    identified,
)
from scanqa.calibration.parametric import ParametricCalibration, from_opencv
from scanqa.calibration.release import calibrate_released
from scanqa.calibration.uncertainty import jackknife_covariance, pack_opencv
from scanqa.decoding.coding import PatternDescription
from scanqa.errors import InputError
from scanqa.io.opencv import COVARIANCE_PARAMETERS, OpenCVCalibration


def _flags() -> dict[str, tuple[int, int]]:
    """OpenCV flags of each lens model: (camera, projector)."""
    import cv2

    k1 = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2
          | cv2.CALIB_FIX_K3)
    k1k2 = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    return {"k1": (k1 | cv2.CALIB_FIX_PRINCIPAL_POINT, k1), "k1k2": (k1k2, k1k2),
            "full": (0, 0)}


#: Lens models: "k1" (square pixels, radial k1 only, the camera's principal point at the
#: image centre - the model of SLStudio's calibration), "k1k2" (free f_x, f_y, principal
#: points, k1 and k2), "full" (k1 k2 p1 p2 k3).
MODELS = ("k1", "k1k2", "full")
#: A pose is flagged when its RMS exceeds this many times the median of the others [-].
FLAG_FACTOR = 2.0


@dataclass(frozen=True)
class PoseResidual:
    """Reprojection RMS of one pose [px] (camera, projector) and whether it is flagged."""

    name: str
    corners: int
    camera_rms_px: float
    projector_rms_px: float
    flagged: bool = False

    def as_dict(self) -> dict:
        return {"pose": self.name, "corners": self.corners,
                "camera_rms_px": self.camera_rms_px,
                "projector_rms_px": self.projector_rms_px, "flagged": self.flagged}


@dataclass(frozen=True)
class BoardCalibration:
    """A calibration from board poses and what was measured on the way.

    Attributes
    ----------
    data : OpenCVCalibration
        Matrices, sizes, reprojection errors (``cam_error``, ``proj_error``,
        ``stereo_error`` [px], OpenCV's sequential fit) and, with ``covariance``, the
        joint fit's refined parameters and covariance
        (:func:`scanqa.calibration.bundle.bundle_adjust`).
    poses : tuple of PoseResidual
        Per-pose reprojection RMS, in the order given.
    model : str
        The lens model (``MODELS``).
    held_out : tuple of dict
        Leave-one-pose-out results (:func:`hold_out`); empty unless asked for.
    comparison : dict
        :func:`compare` with a reference calibration; empty unless asked for.
    fit_std : dict
        OpenCV's std of each lens parameter from its fit (Jacobian, residuals as white
        noise) [px, -], for comparison with the jackknife's.
    flatness : dict
        :func:`board_flatness` of the poses; empty when a corner was not decoded.
    corner_method : str
        The camera's corner detector (:data:`scanqa.calibration.board.CORNER_METHODS`);
        empty when the poses were decoded elsewhere.
    jackknife : (24, 24) float or None
        The covariance from the calibrations that left one pose out (a check).
    bundle : dict
        The joint fit: ``noise_px`` (each device's corner noise), ``model_terms`` (the
        board's bow and the left-out lens terms: estimate, std).
    """

    data: OpenCVCalibration
    poses: tuple
    model: str
    held_out: tuple = field(default=())
    comparison: dict = field(default_factory=dict)
    fit_std: dict = field(default_factory=dict)
    flatness: dict = field(default_factory=dict)
    corner_method: str = ""
    jackknife: np.ndarray | None = None
    bundle: dict = field(default_factory=dict)

    @property
    def flagged(self) -> list[str]:
        """Names of the flagged poses."""
        return [p.name for p in self.poses if p.flagged]

    @property
    def parameter_std(self) -> dict | None:
        """The std of each parameter from the joint fit's covariance (square root of its
        diagonal, :data:`scanqa.io.opencv.COVARIANCE_PARAMETERS`) [px, -, rad, mm];
        None without a covariance."""
        return _std(self.data.covariance)

    @property
    def jackknife_std(self) -> dict | None:
        """As :attr:`parameter_std`, of the jackknife (the check)."""
        return _std(self.jackknife)


def _std(cov: np.ndarray | None) -> dict | None:
    if cov is None:
        return None
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    return dict(zip(COVARIANCE_PARAMETERS, std.tolist(), strict=True))


def calibrate_board(poses: list[BoardPose], board: Board, projector_size: tuple[int, int],
                    model: str = "k1", covariance: bool = True, release=None,
                    jackknife: bool = True) -> BoardCalibration:
    """Calibrate camera, projector and their pose from board poses (module notes).

    Parameters
    ----------
    poses : list of BoardPose
        At least two poses, all from one camera.
    board : Board
        The chessboard (its square size sets the scale) [mm].
    projector_size : (int, int)
        Projector panel (width, height) [px].
    model : str
        Lens model, one of ``MODELS``.
    covariance : bool
        Refine jointly and give the joint fit's covariance
        (:mod:`scanqa.calibration.bundle`); with three or more poses also fit every
        leave-one-out subset for the jackknife covariance (the check).
    release : bool, optional
        Which left-out lens terms may be fitted instead of stated
        (:func:`~scanqa.calibration.bundle.bundle_adjust`'s ``release``). Default (None):
        with three or more poses, those the poses identify (Eq. 6 of
        :mod:`scanqa.calibration.bundle`: their leave-one-pose-out estimates agree within
        their std); True: all; False: none (every one stated, Eq. 3).
    jackknife : bool
        Also give the jackknife covariance (the check; five more joint fits when terms
        are released).

    Returns
    -------
    BoardCalibration
    """
    if model not in MODELS:
        raise InputError(f"lens model must be one of {MODELS}, got {model!r}")
    if len(poses) < 2:
        raise InputError(f"a board calibration needs at least 2 poses, got {len(poses)}")
    _distinct(poses)
    data, residuals, fit_std = _fit(poses, board, projector_size, model)
    if not covariance:
        return BoardCalibration(data, tuple(_flag(residuals)), model, fit_std=fit_std)
    subsets = [poses[:k] + poses[k + 1:] for k in range(len(poses))] if len(
        poses) >= 3 else []
    starts = [_fit(sub, board, projector_size, model)[0] for sub in subsets]
    subs = None
    if release is None:  # Eq. 6: release only the terms the poses identify
        stated = joint_fit(poses, board, data, model, False)
        release = False
        if subsets:
            subs = [joint_fit(sub, board, start, model, False)
                    for sub, start in zip(subsets, starts, strict=True)]
            names = [n for n, t in stated.model_terms.items() if n not in BOW_TERMS]
            ok = identified([[f.model_terms[n]["estimate"] for n in names] for f in subs],
                            [stated.model_terms[n]["std"] for n in names])
            release = [n for n, good in zip(names, ok, strict=True) if good]
        joint = stated
        if release and any(abs(stated.model_terms[n]["estimate"])
                           > RELEASE_STD * stated.model_terms[n]["std"] for n in release):
            joint = joint_fit(poses, board, data, model, release)
        checked = {n: bool(n in release) for n in stated.model_terms if n not in BOW_TERMS}
    else:
        joint = joint_fit(poses, board, data, model, release)
        checked = {}
    jack = None
    if subsets and jackknife:
        if subs is None or any(t.get("released") for t in joint.model_terms.values()):
            subs = [joint_fit(sub, board, start, model, release)
                    for sub, start in zip(subsets, starts, strict=True)]
        jack = jackknife_covariance(np.array([pack_opencv(f.data) for f in subs]))
    terms = {n: ({**t, "identified": checked[n]} if n in checked else t)
             for n, t in joint.model_terms.items()}
    return BoardCalibration(joint.data, tuple(_flag(residuals)), model, fit_std=fit_std,
                            jackknife=jack,
                            bundle={"noise_px": joint.noise_px,
                                    "model_terms": terms})


def joint_fit(poses: list[BoardPose], board: Board, start: OpenCVCalibration,
              model: str, release=False) -> BundleResult:
    """The joint fit of ``poses`` from ``start`` (:func:`bundle_adjust`)."""
    obj, cam, proj = _points(poses, board)
    return bundle_adjust(start, obj, cam, proj, model, board.object_points,
                         release=release)


def calibrate_poses(folders: list[str | os.PathLike], columns: PatternDescription,
                    rows: PatternDescription, board: Board | float, model: str = "k1",
                    held_out: bool = False, reference: OpenCVCalibration | None = None,
                    progress=None, corner_method: str = "model") -> BoardCalibration:
    """Decode board poses and calibrate from them (what ``scanqa calibrate --board`` does).

    Parameters
    ----------
    folders : list of path
        One folder of images per pose.
    columns, rows : PatternDescription
        The projected patterns (:func:`scanqa.calibration.board.decode_pose`); the
        projector panel is ``columns.projector_width_px`` x ``rows.projector_width_px``.
    board : Board or float
        The chessboard, or its square size [mm]: the corner grid is then found in the
        frames (:func:`scanqa.calibration.board.corner_grid`) and must be the same in
        every pose.
    model : str
        Lens model (``MODELS``).
    held_out : bool
        Also leave each pose out in turn (:func:`hold_out`).
    reference : OpenCVCalibration, optional
        A calibration to compare with (:func:`compare`; its plane RMS on each held-out
        pose too).
    progress : callable, optional
        Receives a message per pose.
    corner_method : str
        The camera's corner detector (:data:`scanqa.calibration.board.CORNER_METHODS`;
        default "model", docs/calibration.rst says why).

    Returns
    -------
    BoardCalibration
    """
    poses = []
    for folder in folders:
        poses.append(decode_pose(folder, columns, rows, board, corner_method=corner_method))
        if progress:
            progress(f"pose {poses[-1].name}: {np.isfinite(poses[-1].projector_px).all(1).sum()}"
                     f" of {len(poses[-1].camera_px)} corners in the projector")
    board = _one_board(poses)
    panel = (columns.projector_width_px, rows.projector_width_px)
    result = calibrate_board(poses, board, panel, model)
    ref = None if reference is None else from_opencv(reference)
    complete = all(np.isfinite(p.projector_px).all() for p in poses)
    return replace(result, corner_method=corner_method,
                   comparison=compare(result.data, reference) if reference else {},
                   held_out=tuple(hold_out(poses, board, panel, model, ref)
                                  if held_out and len(poses) >= 3 else ()),
                   flatness=board_flatness(poses, board, panel, model) if complete else {})


#: Two poses whose camera corners are this close (RMS) are one pose given twice [px].
SAME_POSE_PX = 0.5


def _distinct(poses: list[BoardPose]) -> None:
    """Refuse a pose given twice (the same images or corners under two names)."""
    for i, first in enumerate(poses):
        for second in poses[i + 1:]:
            if first.camera_px.shape != second.camera_px.shape:
                continue
            gap = np.sqrt(np.nanmean(np.sum((first.camera_px - second.camera_px) ** 2, 1)))
            if gap < SAME_POSE_PX:
                raise InputError(
                    f"poses {first.name} and {second.name} show the board at the same place "
                    f"(their corners {gap:.2g} px apart, RMS): a calibration needs the board "
                    "moved and tilted between poses - drop the repeat")


#: How far a board calibration's baseline may lie from the config's before it is refused
#: (a wrong square size scales it) [-].
BASELINE_TOLERANCE = 0.2


def check_baseline(data: OpenCVCalibration, expected_mm: np.ndarray, square_mm: float
                   ) -> float:
    """Refuse a calibration whose baseline (camera to projector centre) is more than
    :data:`BASELINE_TOLERANCE` off the expected one (a config's projector position).

    Returns
    -------
    float
        The relative difference [-].
    """
    got = float(np.linalg.norm(data.Rp.T @ np.ravel(data.Tp)))
    want = float(np.linalg.norm(expected_mm))
    rel = got / want - 1 if want > 0 else float("nan")
    if not abs(rel) <= BASELINE_TOLERANCE:
        raise InputError(
            f"the board calibration's baseline is {got:.1f} mm, {100 * rel:+.0f} % off the "
            f"config's projector position ({want:.1f} mm from the camera): check the square "
            f"size ({square_mm:g} mm; a wrong one scales the baseline) or the config")
    return rel


def _one_board(poses: list[BoardPose]) -> Board:
    """The board all poses show, or an error naming the two that differ."""
    first = poses[0]
    for pose in poses[1:]:
        if pose.board != first.board:
            raise InputError(
                f"pose {pose.name} shows a {pose.board.rows} x {pose.board.columns} corner "
                f"grid, pose {first.name} {first.board.rows} x {first.board.columns}: one "
                "board for all poses (is the whole board in view in each?)")
    return first.board


def _fit(poses: list[BoardPose], board: Board, projector_size: tuple[int, int],
         model: str) -> tuple[OpenCVCalibration, list[PoseResidual], dict]:
    """One calibration of all ``poses``, their residuals and OpenCV's std of the
    intrinsics (from the fit's Jacobian, residuals taken as white noise)."""
    import cv2

    cam_flags, proj_flags = _flags()[model]
    obj, cam, proj = _points(poses, board)
    camera_size = poses[0].camera_size
    e_c, kc_m, kc, rc, tc, std_c = cv2.calibrateCameraExtended(
        obj, cam, camera_size, None, None, flags=cam_flags)[:6]
    e_p, kp_m, kp, rp, tp, std_p = cv2.calibrateCameraExtended(
        obj, proj, tuple(projector_size), None, None, flags=proj_flags)[:6]
    e_s, *_, rot, trans, _, _ = cv2.stereoCalibrate(obj, cam, proj, kc_m, kc, kp_m, kp,
                                                    camera_size,
                                                    flags=cv2.CALIB_FIX_INTRINSIC)
    residuals = [PoseResidual(p.name, len(o), _rms(o, c, r, t, kc_m, kc),
                              _rms(o, q, r2, t2, kp_m, kp))
                 for p, o, c, q, r, t, r2, t2 in zip(poses, obj, cam, proj, rc, tc, rp, tp,
                                                     strict=True)]
    data = OpenCVCalibration(
        kc_m, _five(kc), kp_m, _five(kp), rot, trans.ravel(),
        sizes={"frameWidth": camera_size[0], "frameHeight": camera_size[1],
               "screenResX": int(projector_size[0]), "screenResY": int(projector_size[1])},
        errors={"cam_error": float(e_c), "proj_error": float(e_p),
                "stereo_error": float(e_s)})
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    fit_std = {f"{dev}_{n}": float(v) for dev, std in (("camera", std_c), ("projector", std_p))
               for n, v in zip(names, np.ravel(std)[:9], strict=True)}
    for dev in ("camera", "projector"):  # with f_x = f_y OpenCV gives f_y's std only
        fit_std[f"{dev}_fx"] = fit_std[f"{dev}_fx"] or fit_std[f"{dev}_fy"]
    return data, residuals, fit_std


def _points(poses: list[BoardPose], board: Board) -> tuple[list, list, list]:
    """Object, camera and projector points of each pose, float32, where all are known."""
    obj, cam, proj = [], [], []
    for pose in poses:
        if pose.camera_size != poses[0].camera_size:
            raise InputError(f"pose {pose.name} is {pose.camera_size} px, pose "
                             f"{poses[0].name} {poses[0].camera_size}: one camera please")
        if len(pose.camera_px) != len(board.object_points):
            raise InputError(f"pose {pose.name} has {len(pose.camera_px)} corners, the "
                             f"{board.rows} x {board.columns} board {len(board.object_points)}"
                             ": is the whole board in view? (give the board's ROWSxCOLS to "
                             "look for that grid)")
        ok = np.isfinite(pose.projector_px).all(axis=1)
        if ok.sum() < 6:
            raise InputError(f"pose {pose.name}: only {ok.sum()} corners have decoded "
                             "projector coordinates (need 6)")
        obj.append(board.object_points[ok])
        cam.append(pose.camera_px[ok].astype(np.float32))
        proj.append(pose.projector_px[ok].astype(np.float32))
    return obj, cam, proj


def _rms(obj, img, rvec, tvec, matrix, dist) -> float:
    """RMS distance between image points and the board projected at (rvec, tvec) [px]."""
    import cv2

    pred, _ = cv2.projectPoints(obj, rvec, tvec, matrix, dist)
    return float(np.sqrt(np.mean(np.sum((pred.reshape(-1, 2) - img) ** 2, axis=1))))


def _five(dist: np.ndarray) -> np.ndarray:
    return np.pad(np.asarray(dist, dtype=float).ravel()[:5], (0, 5))[:5]


def _flag(residuals: list[PoseResidual]) -> list[PoseResidual]:
    """Flag a pose whose camera or projector RMS exceeds FLAG_FACTOR x the others' median."""
    out = []
    for k, res in enumerate(residuals):
        others = residuals[:k] + residuals[k + 1:]
        off = others and any(
            getattr(res, key) > FLAG_FACTOR * np.median([getattr(o, key) for o in others])
            for key in ("camera_rms_px", "projector_rms_px"))
        out.append(PoseResidual(res.name, res.corners, res.camera_rms_px,
                                res.projector_rms_px, bool(off)))
    return out


def hold_out(poses: list[BoardPose], board: Board, projector_size: tuple[int, int],
             model: str = "k1", reference: ParametricCalibration | None = None
             ) -> list[dict]:
    """Leave each pose out in turn: calibrate on the others, measure on it.

    Parameters
    ----------
    poses, board, projector_size, model
        As :func:`calibrate_board` (three or more poses).
    reference : ParametricCalibration, optional
        Another calibration of the scanner: its plane RMS on the same pose is reported
        beside (the reference may have seen the pose).

    Returns
    -------
    list of dict
        Per pose: ``projector_rms_px`` (corners predicted from the camera corners with
        the held-out calibration), ``plane_rms_mm`` (dense points about their plane) and
        ``reference_plane_rms_mm``.
    """
    out = []
    for k, pose in enumerate(poses):
        data = _fit(poses[:k] + poses[k + 1:], board, projector_size, model)[0]
        row = {"pose": pose.name, "projector_rms_px": predicted_projector_rms(pose, board,
                                                                              data),
               "plane_rms_mm": plane_rms(pose, from_opencv(data))}
        if reference is not None:
            row["reference_plane_rms_mm"] = plane_rms(pose, reference)
        out.append(row)
    return out


def predicted_projector_rms(pose: BoardPose, board: Board, data: OpenCVCalibration) -> float:
    """RMS between a pose's projector corners and those the calibration predicts [px].

    The board's pose is found from the camera corners alone (``solvePnP`` with the
    calibration's camera), carried to the projector by (Rp, Tp) and projected with its
    lens: nothing of the pose's projector corners enters the prediction.
    """
    import cv2

    ok = np.isfinite(pose.projector_px).all(axis=1)
    obj = board.object_points[ok]
    _, rvec, tvec = cv2.solvePnP(obj, pose.camera_px[ok].astype(np.float32), data.Kc,
                                 data.kc)
    rot = data.Rp @ cv2.Rodrigues(rvec)[0]
    return _rms(obj, pose.projector_px[ok].astype(np.float32), cv2.Rodrigues(rot)[0],
                data.Rp @ tvec.ravel() + data.Tp, data.Kp, data.kp)


def plane_rms(pose: BoardPose, cal: ParametricCalibration) -> float:
    """RMS distance of a pose's triangulated points from their least-squares plane [mm].

    Every decoded pixel inside the polygon of the board's outer corners is triangulated
    from its x_p (columns) with ``cal``.
    """
    import cv2

    u0, v0, _, _ = pose.crop
    inside = np.zeros(pose.xp.shape, np.uint8)
    hull = cv2.convexHull((pose.camera_px - (u0, v0)).astype(np.float32))
    cv2.fillConvexPoly(inside, np.round(hull).astype(np.int32), 1)
    rows, cols = np.nonzero(inside.astype(bool) & np.isfinite(pose.xp))
    xyz = cal.apply(cols + u0, rows + v0, pose.xp[rows, cols]).xyz
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    centred = xyz - xyz.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][2]
    return float(np.sqrt(np.mean((centred @ normal) ** 2)))


def compare(ours: OpenCVCalibration, reference: OpenCVCalibration) -> dict:
    """How far a calibration lies from another of the same scanner.

    Returns
    -------
    dict
        ``camera_focal_rel`` and ``projector_focal_rel`` (relative difference of the mean
        of f_x and f_y [-]), ``rotation_deg`` (angle of Rp_ours Rp_ref^T), ``baseline_deg``
        (angle between the projector centres seen from the camera, -Rp^T Tp) and
        ``baseline_rel`` (relative difference of their lengths [-]), and both files'
        reprojection errors [px].
    """
    import cv2

    def focal(m: np.ndarray) -> float:
        return float((m[0, 0] + m[1, 1]) / 2)

    def centre(data: OpenCVCalibration) -> np.ndarray:
        return -data.Rp.T @ np.ravel(data.Tp)

    a, b = centre(ours), centre(reference)
    cos = np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b)
    return {
        "camera_focal_rel": focal(ours.Kc) / focal(reference.Kc) - 1,
        "projector_focal_rel": focal(ours.Kp) / focal(reference.Kp) - 1,
        "rotation_deg": float(np.degrees(np.linalg.norm(
            cv2.Rodrigues(ours.Rp @ reference.Rp.T)[0]))),
        "baseline_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        "baseline_rel": float(np.linalg.norm(a) / np.linalg.norm(b) - 1),
        "errors_px": dict(ours.errors), "reference_errors_px": dict(reference.errors),
        "reference": reference.source,
    }


def board_flatness(poses: list[BoardPose], board: Board, projector_size: tuple[int, int],
                   model: str = "k1") -> dict:
    """How far the board departs from its ideal flat grid, seen by camera and projector.

    The camera is calibrated with the board's corner positions released
    (:func:`~scanqa.calibration.release.calibrate_released`, OpenCV's
    ``calibrateCameraRO`` model, Strobl and Hirzinger [2]_: every corner's 3-D position on
    the board fitted with the lens, the first and the last of the first row held and the
    last corner's height, OpenCV's gauge). The board so measured by the camera is then given to the
    projector's calibration: if the projector's RMS drops too, the camera's residuals
    come from the board (printing, a bent panel) and not from its lens model or its
    corner detector, since the projector's corners come from the decoded phase, not the
    board's texture.

    Parameters
    ----------
    poses, board, projector_size, model
        As :func:`calibrate_board`.

    Returns
    -------
    dict
        ``camera_rms_px`` and ``camera_rms_released_px`` (the camera's RMS with the ideal
        and the fitted board), ``projector_rms_px`` and ``projector_rms_camera_board_px``
        (the projector's with the ideal board and with the camera's; NaN when OpenCV
        will not start from a principal point outside the panel), and
        ``in_plane_mm`` and ``out_of_plane_mm`` (RMS of the fitted board's departure
        from the ideal grid [mm]).

    References
    ----------
    .. [2] K. H. Strobl and G. Hirzinger, "More accurate pinhole camera calibration with
       imperfect planar target", ICCV Workshops 2011, pp. 1068-1075.
    """
    import cv2

    cam_flags, proj_flags = _flags()[model]
    obj, cam, proj = _points(poses, board)
    if any(len(o) != len(board.object_points) for o in obj):
        raise InputError("the board's shape needs every corner decoded in every pose")
    size = poses[0].camera_size
    released = calibrate_released(obj, cam, size, board.columns - 1, cam_flags)
    e_c, e_r = released["ideal_rms_px"], released["rms_px"]  # ideal board, released
    fitted = released["points"].astype(np.float32)
    e_p, kp_m, kp = cv2.calibrateCamera(obj, proj, tuple(projector_size), None, None,
                                        flags=proj_flags)[:3]
    try:  # OpenCV refuses a starting principal point outside the panel (an offset lens)
        e_b = cv2.calibrateCamera([fitted] * len(proj), proj, tuple(projector_size), kp_m,
                                  kp, flags=proj_flags | cv2.CALIB_USE_INTRINSIC_GUESS)[0]
    except cv2.error:
        e_b = np.nan
    dev = fitted - board.object_points
    return {"camera_rms_px": float(e_c), "camera_rms_released_px": float(e_r),
            "projector_rms_px": float(e_p), "projector_rms_camera_board_px": float(e_b),
            "in_plane_mm": float(np.sqrt(np.mean(np.sum(dev[:, :2] ** 2, axis=1)))),
            "out_of_plane_mm": float(np.sqrt(np.mean(dev[:, 2] ** 2)))}
