"""A parametric camera-projector calibration that matches a scanner config, and scenes
projected through it with OpenCV (an implementation independent of scanqa's).

The projector pose and panel are the config's; the camera gets its own pinhole (a short
focal length, so that a small image sees the whole gauge artefact) and both lenses get
Brown-Conrady distortion. Truth is exact: every camera pixel is undistorted by OpenCV's
iterative undistortion, its ray meets the scene analytically, and the point is projected
into the projector by ``cv2.projectPoints``.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from scanqa.calibration.parametric import Lens, ParametricCalibration
from scanqa.decoding.phasemap import PhaseMap
from scanqa.model.config import ScannerConfig

#: Camera distortion k1 k2 p1 p2 k3: ~5 px at the corners of a 400 x 300 px image.
CAMERA_DISTORTION = np.array([-0.12, 0.05, 4e-4, -3e-4, 0.01])
#: Projector distortion.
PROJECTOR_DISTORTION = np.array([-0.04, 0.01, -2e-4, 1e-4, 0.0])


def config_pinhole(config: ScannerConfig, source: str = "") -> ParametricCalibration:
    """The config's own camera and projector as a distortion-free parametric calibration
    (intrinsics and projector pose from the config, fringes along the projector's
    columns): the exact geometry the simulator renders with."""
    cam, proj = config.camera, config.projector
    f, fp = cam.principal_distance_px, proj.principal_distance_px
    kc = np.array([[f, 0, cam.principal_point_px[0]], [0, f, cam.principal_point_px[1]],
                   [0, 0, 1.0]])
    kp = np.array([[fp, 0, proj.principal_point_px[0]], [0, fp, proj.principal_point_px[1]],
                   [0, 0, 1.0]])
    rot = proj.rotation
    return ParametricCalibration(Lens(kc, np.zeros(5), cam.width_px, cam.height_px),
                                 Lens(kp, np.zeros(5), proj.width_px, proj.height_px), rot,
                                 -rot @ np.asarray(proj.position_mm), "vertical",
                                 source=source)


def small_scanner(config: ScannerConfig, width: int = 400, height: int = 300,
                  focal_px: float = 1300.0, orientation: str = "vertical"
                  ) -> tuple[ParametricCalibration, ScannerConfig]:
    """A calibration with the config's projector and a small distorted camera, and the
    config resized to that camera (its optics, used by the model, unchanged)."""
    cfg = ScannerConfig(replace(config.camera, width_px=width, height_px=height),
                        config.projector, config.fringes, config.model, config.simulator,
                        config.name, "synthetic.toml")
    kc = np.array([[focal_px, 0.0, (width - 1) / 2 + 3.5], [0.0, focal_px * 1.002,
                   (height - 1) / 2 - 2.0], [0.0, 0.0, 1.0]])
    proj = config.projector
    fp = proj.principal_distance_px
    kp = np.array([[fp, 0.0, proj.principal_point_px[0]], [0.0, fp, proj.principal_point_px[1]],
                   [0.0, 0.0, 1.0]])
    rot = proj.rotation
    cal = ParametricCalibration(Lens(kc, CAMERA_DISTORTION, width, height),
                                Lens(kp, PROJECTOR_DISTORTION, proj.width_px, proj.height_px),
                                rot, -rot @ np.asarray(proj.position_mm), orientation,
                                source="synthetic.xml")
    return cal, cfg


def camera_rays(cal: ParametricCalibration) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's undistorted ray (x, y, 1) of every pixel: two (H, W) arrays."""
    v, u = np.indices((cal.height_px, cal.width_px), dtype=float)
    pts = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        und = cv2.undistortPointsIter(pts, cal.camera.matrix, cal.camera.distortion, None,
                                      None, crit)[:, 0]
    else:  # OpenCV 5 took the criteria into undistortPoints
        und = cv2.undistortPoints(pts, cal.camera.matrix, cal.camera.distortion,
                                  criteria=crit)[:, 0]
    return und[:, 0].reshape(u.shape), und[:, 1].reshape(u.shape)


def projector_pixels(cal: ParametricCalibration, points: np.ndarray) -> np.ndarray:
    """(..., 2) projector pixels of (..., 3) camera-frame points, by cv2.projectPoints (with
    R and T applied here: a Rodrigues round trip would re-orthogonalise R)."""
    q = np.asarray(points, dtype=float).reshape(-1, 3)
    qp = q @ cal.rotation.T + cal.translation
    uv, _ = cv2.projectPoints(qp, np.zeros(3), np.zeros(3), cal.projector.matrix,
                              cal.projector.distortion)
    return uv[:, 0].reshape(*np.shape(points)[:-1], 2)


def camera_pixels(cal: ParametricCalibration, points: np.ndarray) -> np.ndarray:
    """(..., 2) camera pixels of (..., 3) camera-frame points (cv2.projectPoints)."""
    q = np.asarray(points, dtype=float).reshape(-1, 3)
    uv, _ = cv2.projectPoints(q, np.zeros(3), np.zeros(3), cal.camera.matrix,
                              cal.camera.distortion)
    return uv[:, 0].reshape(*np.shape(points)[:-1], 2)


def layout_scene(rays: tuple[np.ndarray, np.ndarray], base_z: float, blocks) -> np.ndarray:
    """Points (H, W, 3) where each pixel's ray first meets a top face of ``blocks`` (with
    ``top_z_mm`` and ``region_mm``) or the base plane Z = ``base_z`` [mm]; the blocks'
    side walls are left out."""
    x, y = rays
    z = np.full(x.shape, float(base_z))
    for block in blocks:
        top = block.top_z_mm
        x0, x1, y0, y1 = block.region_mm
        hit = (x * top >= x0) & (x * top <= x1) & (y * top >= y0) & (y * top <= y1)
        z = np.where(hit & (top < z), top, z)
    return np.stack([x * z, y * z, z], -1)


def phase_map(xp: np.ndarray, sigma_xp: np.ndarray, period_px: float, width_px: int,
              orientation: str = "vertical") -> PhaseMap:
    """A decoded scan holding ``xp`` (NaN: masked) [projector px]."""
    valid = np.isfinite(xp)
    shape = xp.shape
    return PhaseMap(xp=xp, modulation=np.full(shape, 400.0), offset=np.full(shape, 900.0),
                    mask=np.where(valid, 0, 2).astype(np.uint8),
                    sigma_xp=np.where(valid, sigma_xp, np.nan), period_px=period_px,
                    orientation=orientation, projector_width_px=width_px)
