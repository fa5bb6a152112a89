"""Checks of a scan's geometry from the data, at annotation (:mod:`scanqa.annotation.points`).

Three checks, each stated in the scan's own numbers and what to do, none tuned to one
symptom:

* **Sensitivity along the coded direction** (parametric calibrations,
  :func:`fringe_sensitivity`): at the image centre and the config's working distance,
  the epipolar direction in the projector panel (where a camera ray's point moves when
  its depth changes) against the fringe normal (the coded axis: columns for vertical
  fringes). Depth is coded by how fast the coded coordinate moves along the epipolar
  line, so s_T = |dQ/dx_p| grows as 1 / cos of the angle between the two; fringes that
  run along the epipolar lines (a projector beside the camera with horizontal fringes,
  or above it with vertical ones) code no depth. Warned above
  :data:`EPIPOLAR_ANGLE_WARNED`, refused above :data:`EPIPOLAR_ANGLE_REFUSED` (s_T
  then exceeds the other direction's ten-fold): use fringes along the other direction.
* **Share of decoded pixels out of the calibrated volume** (:func:`volume_warning`):
  a decoded pixel saw the projector's light, so its coordinate must triangulate inside
  the panel, in front of both devices and within the depth range; when more than
  :data:`OUT_OF_VOLUME_WARNED` of them do not, the calibration does not describe the
  scan - most often its projector rows or columns are in other units than the panel's
  (half or double pixels of a diamond-pixel DMD, a resized pattern), or it belongs to
  another scanner, pose or fringe orientation.
* **Units of the projector's axes** (parametric calibrations, :func:`units_warning`):
  K_p's f_x and f_y against the config's projector principal distance (square pixels of
  one pitch); an axis off by more than :data:`UNITS_RATIO_WARNED` (2 for half rows) is
  in other units than the panel the scan was decoded in.
* **Plausible depths** (:func:`depth_warning`): the share of the cloud's points whose
  depth Z lies outside [1 / :data:`DEPTH_FACTOR`, :data:`DEPTH_FACTOR`] times the config's
  working distance (the camera's focus distance); a scanner does not resolve a scene
  several times nearer or farther than it is focused at. Warned above
  :data:`IMPLAUSIBLE_DEPTH_WARNED`.
"""

from __future__ import annotations

import math

import numpy as np

from scanqa.calibration.base import Calibration
from scanqa.calibration.parametric import ParametricCalibration
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig

#: Angle between the fringe normal and the epipolar direction above which a scan is
#: warned of: the coded direction then codes depth at less than half the sensitivity
#: of the best direction [deg].
EPIPOLAR_ANGLE_WARNED = 60.0
#: ... and above which it is refused: s_T over ten times the other direction's [deg].
EPIPOLAR_ANGLE_REFUSED = 84.0
#: Ratio of K_p's focal length along an axis to the config's projector principal
#: distance beyond which (or below its inverse) that axis is warned of [-].
UNITS_RATIO_WARNED = 1.25
#: Share of the decoded pixels out of the calibrated volume that is warned of [-].
OUT_OF_VOLUME_WARNED = 0.25
#: Depths within [1 / DEPTH_FACTOR, DEPTH_FACTOR] x the working distance are plausible.
DEPTH_FACTOR = 2.0
#: Share of points at implausible depths that is warned of [-].
IMPLAUSIBLE_DEPTH_WARNED = 0.1
#: Points the depth check samples at most (evenly spaced through the cloud).
DEPTH_SAMPLE = 200_000


def fringe_sensitivity(cal: ParametricCalibration, z_mm: float) -> dict:
    """Depth sensitivity of each projector direction at the image centre.

    Parameters
    ----------
    cal : ParametricCalibration
        The camera-projector model.
    z_mm : float
        Depth of the point on the centre pixel's ray [mm] (the working distance).

    Returns
    -------
    dict
        ``angle_deg``: angle between the coded axis (the fringe normal) and the epipolar
        direction in the projector panel [deg] (0: depth moves across the fringes, 90:
        along them); ``s_t_mm_px``: |dQ/dx_p| of the coded coordinate and
        ``s_t_other_mm_px`` that of the other one [mm / projector px]; NaN where the
        centre ray has no projection.
    """
    x, y, ok = cal.camera.undistort(np.array([(cal.width_px - 1) / 2.0]),
                                    np.array([(cal.height_px - 1) / 2.0]))
    nan = {"angle_deg": math.nan, "s_t_mm_px": math.nan, "s_t_other_mm_px": math.nan}
    if not ok[0]:
        return nan
    ray = np.array([x[0], y[0], 1.0])
    h = 1e-4 * z_mm
    ends = np.stack([(z_mm - h) * ray, (z_mm + h) * ray]) @ cal.rotation.T + cal.translation
    if not (ends[:, 2] > 0).all():
        return nan
    u, v = cal.projector.project(ends)
    du, dv = (u[1] - u[0]) / (2 * h), (v[1] - v[0]) / (2 * h)  # [projector px / mm of Z]
    coded, other = (du, dv) if cal.orientation == "vertical" else (dv, du)
    length = float(np.linalg.norm(ray))  # |dQ/dZ|
    with np.errstate(divide="ignore"):
        return {"angle_deg": math.degrees(math.atan2(abs(other), abs(coded))),
                "s_t_mm_px": length / abs(coded) if coded else math.inf,
                "s_t_other_mm_px": length / abs(other) if other else math.inf}


def sensitivity_warning(cal: Calibration, config: ScannerConfig, source: str) -> str:
    """A warning when the scan's fringes run near the epipolar lines ("" otherwise).

    Raises
    ------
    InputError
        Above :data:`EPIPOLAR_ANGLE_REFUSED`: the coded coordinate codes (almost) no
        depth; the message gives s_T of both directions and says to use the other.
    """
    if not isinstance(cal, ParametricCalibration):
        return ""  # a table's slopes come from its own sweep, in its own fringes
    z = config.camera.focus_mm
    s = fringe_sensitivity(cal, z)
    if not s["angle_deg"] > EPIPOLAR_ANGLE_WARNED:  # NaN: nothing to say
        return ""
    fringes = cal.orientation
    other = "horizontal" if fringes == "vertical" else "vertical"
    text = (f"{source}: its {fringes} fringes run {90 - s['angle_deg']:.1f} deg off the "
            f"epipolar lines of the calibration {cal.source or '(parametric)'} (at the image "
            f"centre, Z = {z:g} mm): depth moves along them, and each projector px of "
            f"{('x_p', 'y_p')[fringes == 'horizontal']} is s_T = {s['s_t_mm_px']:.3g} mm "
            f"of depth where {other} fringes would give {s['s_t_other_mm_px']:.3g} mm/px; "
            f"scan with {other} fringes (the projector's other direction)")
    if s["angle_deg"] > EPIPOLAR_ANGLE_REFUSED:
        raise InputError(text + f" - refused: above {EPIPOLAR_ANGLE_REFUSED:g} deg the "
                                "points carry almost no depth information")
    return text


def units_warning(cal: Calibration, config: ScannerConfig, source: str) -> str:
    """A warning when the calibration's projector columns or rows are in other units
    than the config's panel ("" otherwise, and for a table)."""
    if not isinstance(cal, ParametricCalibration):
        return ""
    fp = config.projector.principal_distance_px
    k = cal.projector.matrix
    odd = [(axis, key, float(f) / fp) for axis, key, f in
           (("columns", "f_x", k[0, 0]), ("rows", "f_y", k[1, 1]))
           if not 1 / UNITS_RATIO_WARNED <= f / fp <= UNITS_RATIO_WARNED]
    if not odd:
        return ""
    axis, key, ratio = odd[0]
    coded, coded_axis = (("x_p", "columns") if cal.orientation == "vertical"
                         else ("y_p", "rows"))
    effect = (f"the scan's decoded {coded} is read in other units: every depth is off"
              if axis == coded_axis else
              f"the {axis} place each point in the panel (the fringes code {coded}): points "
              "whose place falls off the panel are dropped as out of volume")
    return (f"{source}: the calibration {cal.source or '(parametric)'} has the projector's "
            f"{axis} at x{ratio:.2f} the config's (K_p {key} = {ratio * fp:.6g} px, the "
            f"config {config.source or ''} projector's principal distance {fp:.6g} px, "
            "square pixels): its projector pixels are in other units than the panel's (half "
            f"rows or doubled columns of a diamond-pixel DMD?); {effect}. Recalibrate in the "
            "panel's units, or make the scan and the config count the calibration's pixels")


def volume_warning(counts: dict, n_pixels: int, source: str, cal: Calibration) -> str:
    """A warning when a large share of the decoded pixels is out of the calibrated
    volume ("" otherwise); ``counts`` as :func:`scanqa.annotation.points.annotate` keeps."""
    decoded = n_pixels - counts["decoder_masked"]
    if decoded <= 0:
        return ""
    share = counts["out_of_volume"] / decoded
    if share <= OUT_OF_VOLUME_WARNED:
        return ""
    lo, hi = cal.z_range_mm
    return (f"{source}: {100 * share:.0f} % of the decoded pixels ({counts['out_of_volume']} "
            f"of {decoded}) fall outside the calibrated volume (the projector panel, in "
            f"front of both devices, Z in [{lo:g}, {hi:g}] mm), though each was lit by the "
            "projector: the calibration does not describe this scan. Likely causes: the "
            "calibration's projector rows or columns in other units than the panel's (half "
            "or double pixels, as a diamond-pixel DMD's half rows; a resized pattern), the "
            "calibration of another scanner or pose, or the wrong fringe orientation")


def depth_warning(z_mm: np.ndarray, config: ScannerConfig, source: str) -> str:
    """A warning when many points lie at depths the config's scanner cannot be
    focused at ("" otherwise); ``z_mm`` the cloud's Z [mm]."""
    z = np.asarray(z_mm)
    if z.size > DEPTH_SAMPLE:
        z = z[:: z.size // DEPTH_SAMPLE]
    z = z[np.isfinite(z)].astype(float)
    if not z.size:
        return ""
    work = config.camera.focus_mm
    near, far = work / DEPTH_FACTOR, work * DEPTH_FACTOR
    share = float(np.mean((z < near) | (z > far)))
    if share <= IMPLAUSIBLE_DEPTH_WARNED:
        return ""
    p1, p50, p99 = np.percentile(z, [1, 50, 99])
    return (f"{source}: {100 * share:.0f} % of the points lie outside [{near:g}, {far:g}] mm, "
            f"half to twice the working distance of the config {config.source or ''} "
            f"(camera.focus_mm = {work:g}): depths from {p1:.4g} to {p99:.4g} mm, median "
            f"{p50:.4g} mm. Check the config's working distance (camera.focus_mm), the "
            "calibration's units (mm; projector pixels of the panel), that it is this "
            "scanner's, and the fringe direction against the baseline")
