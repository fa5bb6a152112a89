"""Checks of a parametric calibration: the model itself, and a scan or scanner config
against it (:mod:`scanqa.calibration.parametric` calls them; each raises one
:class:`~scanqa.errors.InputError` naming the file and the field). ``cal`` is a
:class:`~scanqa.calibration.parametric.ParametricCalibration` throughout (not imported
here: the model imports its checks)."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig

log = logging.getLogger(__name__)

#: A config's projector position may differ from the calibration's by this much [mm].
POSITION_TOLERANCE_MM = 1.0
#: A config's projector axis may differ from the calibration's by this much [deg].
AXIS_TOLERANCE_DEG = 0.5
#: Fringe orientations: "vertical" fringes code x_p, "horizontal" ones y_p.
ORIENTATIONS = ("vertical", "horizontal")
#: Share of a device's frame over which its lens model may fold over (no undistorted ray)
#: before the model is refused: a fit extrapolated past its board may fold in the
#: corners, a lens model of the device does not over a quarter of it [-].
FOLD_SHARE_REFUSED = 0.25
#: Pixels per side of the grid the fold and the distortion are checked on.
LENS_GRID = 33
#: Radial displacement by the distortion, as a share of the distorted radius, above which
#: the frame's corner is warned of (a lens this strong wants a fisheye model) [-].
DISTORTION_WARNED = 0.3


def calibration_term(cal) -> dict:
    """Where a parametric calibration's own sigma comes from.

    Returns
    -------
    dict
        ``kind``: "covariance" (its parameters' covariance propagated per point),
        "stated" (a std stated for every point) or "none" (no term:
        sigma_calibration_um is 0); ``detail``: in words, naming the file that gave it
        (the calibration's own keys, or a covariance file / stated std given beside it).
    """
    given = cal.term_source
    if cal.covariance is not None:
        where = given or f"{cal.source} (calibration_covariance)"
        return {"kind": "covariance", "detail": f"{where}: the covariance of the 24 "
                "parameters of " + (cal.source or "the calibration")
                + " propagated to every point"}
    if cal.stated_sigma_mm is not None:
        where = given or f"{cal.source} (calibration_sigma_um)"
        return {"kind": "stated", "detail": f"{where}: a stated "
                f"{1e3 * cal.stated_sigma_mm:g} um at every point"}
    return {"kind": "none", "detail": f"{cal.source} carries no covariance: the "
            "calibration's own error is not in sigma_total_um; give a covariance file "
            "(--calibration-covariance) or a stated std (--calibration-sigma-um), add "
            "calibration_covariance or calibration_sigma_um to the file, or calibrate "
            "from board poses (scanqa calibrate --board)"}


def check_calibration(cal) -> None:
    """Raise one :class:`InputError` naming the file and field of an implausible model."""
    where = cal.source or "the parametric calibration"
    if cal.orientation not in ORIENTATIONS:
        raise InputError(f"{where}: orientation must be one of {ORIENTATIONS}, got "
                         f"{cal.orientation!r}")
    for name, lens, mat, dist in (("camera", cal.camera, "Kc", "kc"),
                                  ("projector", cal.projector, "Kp", "kp")):
        k = np.asarray(lens.matrix, dtype=float)
        if k.shape != (3, 3) or not np.isfinite(k).all() or k[1, 0] != 0 \
                or not np.allclose(k[2], [0, 0, 1]) or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise InputError(f"{where}: {mat} must be a camera matrix [[fx, s, cx], [0, fy, "
                             f"cy], [0, 0, 1]] with fx, fy > 0 [px], got {k.tolist()}")
        if np.shape(lens.distortion) != (5,) or not np.isfinite(lens.distortion).all():
            raise InputError(f"{where}: {dist} must be 5 finite numbers k1 k2 p1 p2 k3")
        if min(lens.width_px, lens.height_px) < 1:
            raise InputError(f"{where}: the {name} size must be >= 1 px, got "
                             f"{lens.width_px} x {lens.height_px}")
    for name, lens, mat, dist in (("camera", cal.camera, "Kc", "kc"),
                                  ("projector", cal.projector, "Kp", "kp")):
        share = lens_fold_share(lens)
        if share > FOLD_SHARE_REFUSED:
            raise InputError(
                f"{where}: the {name}'s lens model ({mat} with {dist} = "
                f"{lens.distortion.tolist()}) folds over at {100 * share:.0f} % of its frame "
                f"(no ray reaches those pixels): not a lens model of this {name}; check "
                f"{mat}'s focal lengths and principal point [px] and {dist}'s order (k1 k2 p1 "
                "p2 k3)")
    _check_pose(cal, where)
    lo, hi = (*cal.depth_range_mm, math.nan, math.nan)[:2]
    if len(cal.depth_range_mm) != 2 or not (0 <= lo < hi):
        raise InputError(f"{where}: the depth range must satisfy 0 <= near < far [mm], got "
                         f"{lo!r}, {hi!r}")


def _lens_grid(lens) -> tuple[np.ndarray, np.ndarray]:
    """A LENS_GRID x LENS_GRID grid of pixels over a device's frame, corners included."""
    u = np.linspace(0.0, lens.width_px - 1.0, LENS_GRID)
    v = np.linspace(0.0, lens.height_px - 1.0, LENS_GRID)
    return np.meshgrid(u, v)


def lens_fold_share(lens) -> float:
    """Share of a device's frame whose pixels have no undistorted ray (the distortion
    folds over or the undistortion does not converge there) [-]."""
    u, v = _lens_grid(lens)
    return float(1.0 - lens.undistort(u, v)[2].mean())


def lens_warnings(cal) -> list[str]:
    """Warnings for lens models that reach their frame but bend it implausibly: a fold in
    part of the frame (those pixels get no point), or a corner moved by more than
    :data:`DISTORTION_WARNED` of its radius."""
    where = cal.source or "the parametric calibration"
    out = []
    for name, lens, dist in (("camera", cal.camera, "kc"), ("projector", cal.projector, "kp")):
        if not np.any(lens.distortion):
            continue
        u, v = _lens_grid(lens)
        x, y, ok = lens.undistort(u, v)
        if not ok.all():
            out.append(f"{where}: the {name}'s distortion {dist} folds over at "
                       f"{100 * (1 - ok.mean()):.0f} % of its frame (its corners, where a fit "
                       "is extrapolated): pixels there get no point")
        k = lens.matrix
        yd = (v - k[1, 2]) / k[1, 1]
        xd = (u - k[0, 2] - k[0, 1] * yd) / k[0, 0]
        rd, r = np.hypot(xd, yd)[ok], np.hypot(x, y)[ok]
        far = rd > 0.5 * rd.max(initial=0.0)
        moved = float(np.max(np.abs(rd - r)[far] / rd[far], initial=0.0))
        if moved > DISTORTION_WARNED:
            out.append(f"{where}: the {name}'s distortion {dist} = {lens.distortion.tolist()} "
                       f"moves the frame's outer pixels by up to {100 * moved:.0f} % of their "
                       "distance from the principal point - more than a lens for the "
                       f"Brown-Conrady model does; check {dist}'s order (k1 k2 p1 p2 k3)")
    return out


def _check_pose(cal, where: str) -> None:
    """R must be a rotation (to float32 precision) and T a non-zero baseline."""
    r, t = np.asarray(cal.rotation, float), np.asarray(cal.translation, float)
    if r.shape != (3, 3) or not np.isfinite(r).all():
        raise InputError(f"{where}: Rp must be a finite 3 x 3 rotation")
    off = float(np.abs(r @ r.T - np.eye(3)).max())
    if off > 1e-4 or np.linalg.det(r) <= 0:
        raise InputError(f"{where}: Rp is not a rotation (|R R^T - I| = {off:.2g}, det = "
                         f"{np.linalg.det(r):.4g}); check that the file holds the "
                         "camera-to-projector rotation, not a Rodrigues vector")
    if t.shape != (3,) or not np.isfinite(t).all() or np.linalg.norm(t) == 0:
        raise InputError(f"{where}: Tp must be a non-zero translation of 3 numbers [mm], got "
                         f"{t.tolist()}")


def check_scan(cal, config: ScannerConfig, phase_map: PhaseMap,
               source: str = "scan") -> None:
    """Raise unless a scan and a scanner config describe the calibrated scanner.

    Checked, each with its own message naming both values: the scan's image size
    against the calibration's camera (``frameWidth`` x ``frameHeight``); the scan's fringe
    orientation and coded range against the projector panel (``screenResX`` for
    vertical fringes, ``screenResY`` for horizontal); the config's camera and projector
    sizes; and the config's projector position and axis against -R^T T and R^T e_z
    (within :data:`POSITION_TOLERANCE_MM`, :data:`AXIS_TOLERANCE_DEG`; the model's Z_p
    comes from the config's pose). The config's projector has no roll: the model uses
    only Z_p, which roll does not change.
    """
    where = cal.source or "the parametric calibration"
    h, w = phase_map.xp.shape
    if (w, h) != (cal.width_px, cal.height_px):
        raise InputError(f"{source} is {w} x {h} px but the calibration {where} is for a "
                         f"{cal.width_px} x {cal.height_px} px camera (frameWidth x "
                         "frameHeight): use the calibration of this camera")
    if phase_map.orientation != cal.orientation:
        raise InputError(f"{source} has {phase_map.orientation} fringes but the calibration "
                         f"{where} was loaded for {cal.orientation} ones")
    p = 0 if cal.orientation == "vertical" else 1
    panel = (cal.projector.width_px, cal.projector.height_px)[p]
    if phase_map.projector_width_px and phase_map.projector_width_px != panel:
        key = ("screenResX", "screenResY")[p]
        raise InputError(f"{source} codes {('x_p', 'y_p')[p]} over "
                         f"{phase_map.projector_width_px} projector px but the calibration "
                         f"{where} has a projector panel of {panel} px ({key}): the "
                         "patterns were made for another projector")
    check_config(cal, config)


def check_config(cal, config: ScannerConfig) -> None:
    """Raise unless the config's sizes and projector pose match the calibration's
    (:func:`check_scan`)."""
    where = cal.source or "the parametric calibration"
    for name, lens, keys in (("camera", cal.camera, "frameWidth x frameHeight"),
                             ("projector", cal.projector, "screenResX x screenResY")):
        mine = getattr(config, name)
        if (mine.width_px, mine.height_px) != (lens.width_px, lens.height_px):
            raise InputError(f"config {config.source}: {name}.width_px x height_px is "
                             f"{mine.width_px} x {mine.height_px} but the calibration {where} "
                             f"has {lens.width_px} x {lens.height_px} ({keys})")
    pos = np.asarray(config.projector.position_mm, dtype=float)
    dist = float(np.linalg.norm(pos - cal.projector_position_mm))
    if dist > POSITION_TOLERANCE_MM:
        raise InputError(f"config {config.source}: projector.position_mm is {pos.tolist()} but "
                         f"the calibration {where} puts the projector at "
                         f"{np.round(cal.projector_position_mm, 4).tolist()} mm (-Rp^T Tp), "
                         f"{dist:.1f} mm away; a config written from this calibration "
                         "('scanqa init' given it) has its pose")
    axis = np.subtract(config.projector.look_at_mm, pos)
    angle = math.degrees(math.acos(np.clip(axis @ cal.projector_axis / np.linalg.norm(axis),
                                           -1.0, 1.0)))
    if angle > AXIS_TOLERANCE_DEG:
        raise InputError(f"config {config.source}: the projector axis (look_at_mm - "
                         f"position_mm) is {angle:.2f} deg off the calibration's (Rp^T e_z "
                         f"of {where}); put look_at_mm on the axis "
                         f"{np.round(cal.projector_axis, 6).tolist()}")


def with_calibrated_geometry(cal, config: ScannerConfig) -> ScannerConfig:
    """The config with the scanner's geometry taken from a parametric calibration.

    A parametric calibration knows the projector's pose (-R^T T and R^T e_z); the config
    supplies only what it cannot know (apertures, focus, the noise model). So a config
    keeps working with a recalibration of the same scanner: its camera and projector
    sizes are still checked (:func:`check_config` raises on those), its projector pose is
    replaced by the calibration's, keeping the distance from ``position_mm`` to
    ``look_at_mm``, and a change beyond :data:`POSITION_TOLERANCE_MM` or
    :data:`AXIS_TOLERANCE_DEG` is reported as a warning (a rebuilt scanner wants its
    optics checked). A calibration table (no projector pose) returns the config as is.

    Parameters
    ----------
    cal : Calibration
        The calibration; parametric ones have ``projector_position_mm`` and
        ``projector_axis``.
    config : ScannerConfig
        The scanner config.

    Returns
    -------
    ScannerConfig
        The config whose projector pose is the calibration's (the same object when
        nothing changes).
    """
    if not (hasattr(cal, "projector_position_mm") and hasattr(cal, "projector_axis")):
        return config
    where = getattr(cal, "source", "") or "the parametric calibration"
    pos = np.asarray(config.projector.position_mm, dtype=float)
    look = np.asarray(config.projector.look_at_mm, dtype=float)
    new_pos = np.asarray(cal.projector_position_mm, dtype=float)
    axis = np.asarray(cal.projector_axis, dtype=float)
    reach = float(np.linalg.norm(look - pos)) or 1.0
    moved = float(np.linalg.norm(pos - new_pos))
    old_axis = (look - pos) / reach
    turned = math.degrees(math.acos(float(np.clip(old_axis @ axis, -1.0, 1.0))))
    if moved <= 1e-9 and turned <= 1e-9:
        return config
    if moved > POSITION_TOLERANCE_MM or turned > AXIS_TOLERANCE_DEG:
        log.warning(f"config {config.source}: the projector pose is taken from the "
                    f"calibration {where}: position {np.round(new_pos, 3).tolist()} mm, "
                    f"{moved:.1f} mm from the config's {pos.tolist()}, axis turned "
                    f"{turned:.2f} deg (a recalibration; if the scanner was rebuilt, check "
                    "its optics in the config)")
    projector = replace(config.projector, position_mm=tuple(float(v) for v in new_pos),
                        look_at_mm=tuple(float(v) for v in new_pos + reach * axis))
    return replace(config, projector=projector)
