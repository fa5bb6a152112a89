"""Pinhole camera and projector of the virtual scanner, with poses and thin-lens blur.

The world frame is the nominal scanner frame (the camera frame when no stage moves:
origin at the camera lens, +Z along its optical axis, +X right, +Y down) [mm]. A device
pose maps a world point Q to the device frame as ``Q_d = R (Q - centre)``.

Camera: pixel (u, v) centres at integer coordinates, principal point at the sensor
centre, principal distance ``camera.principal_distance_px`` (the thin-lens image
distance at focus). Projector: ``x_p = f_p X_p / Z_p + x_0`` with
``projector.principal_distance_px``, consistent with Eq. 3 at focus.

Lens distortion (``[simulator] camera_k1 .. projector_p2``, zero by default) is the
Brown-Conrady model of OpenCV on normalised pinhole coordinates (x, y) = (X/Z, Y/Z)::

    r2 = x^2 + y^2
    x_d = x (1 + k1 r2 + k2 r2^2) + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y (1 + k1 r2 + k2 r2^2) + p1 (r2 + 2 y^2) + 2 p2 x y

A camera pixel (u, v) sees the ray of the undistorted (x, y) of its distorted
coordinates, solved by Newton's method to 1e-15; the projector lights a point at the
panel position of its distorted coordinates. Both directions are exact, so the truth
files hold the distorted geometry.

Blur is exact thin-lens cone geometry:

* projector: a point at distance Z_p (along the projector axis) receives light from the
  panel disc of diameter ``Phi_p |Z_p - Z_p'| / Z_p' * f_p / Z_p`` [panel px], centred at
  its pinhole projection (the object-side circle of Eq. 1 back-projected);
* camera: a point at Z_c images to a disc of diameter
  ``Phi_c f_c |Z_c - Z_c'| / (Z_c (Z_c' - f_c))`` [mm] on the sensor, which projects to
  Eq. 2's object-side circle exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig


@dataclass(frozen=True)
class Pose:
    """A rigid device pose: ``Q_device = rotation @ (Q_world - centre)``.

    Attributes
    ----------
    rotation : (3, 3) float
        World-to-device rotation [-].
    centre : (3,) float
        Lens centre in the world frame [mm].
    """

    rotation: np.ndarray
    centre: np.ndarray

    def to_device(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 3) device-frame points [mm]."""
        return (np.asarray(points, dtype=float) - self.centre) @ self.rotation.T

    @property
    def axis(self) -> np.ndarray:
        """Optical axis (device +Z) in the world frame [-]."""
        return self.rotation[2]


def camera_pose(offset_mm: float = 0.0) -> Pose:
    """Camera pose after moving it by ``offset_mm`` along its optical axis (+Z) [mm]."""
    return Pose(np.eye(3), np.array([0.0, 0.0, float(offset_mm)]))


def projector_pose(config: ScannerConfig, offset_mm: float = 0.0) -> Pose:
    """Projector pose from the config, moved by ``offset_mm`` along its axis [mm]."""
    rot = config.projector.rotation
    centre = np.asarray(config.projector.position_mm, dtype=float) + float(offset_mm) * rot[2]
    return Pose(rot, centre)


@dataclass(frozen=True)
class Window:
    """The rendered window of the sensor: columns u0..u0+width-1, rows v0..v0+height-1."""

    u0: int
    v0: int
    width: int
    height: int


def sensor_window(config: ScannerConfig) -> Window:
    """The centred region of interest of ``[simulator] roi_*`` (the whole sensor if 0)."""
    cam, sim = config.camera, config.simulator
    w = sim.roi_width_px or cam.width_px
    h = sim.roi_height_px or cam.height_px
    if w > cam.width_px or h > cam.height_px:
        raise InputError(f"simulator.roi_width_px x roi_height_px = {w} x {h} exceeds the "
                         f"sensor ({cam.width_px} x {cam.height_px} px)")
    return Window((cam.width_px - w) // 2, (cam.height_px - h) // 2, w, h)


def camera_principal_point(config: ScannerConfig) -> tuple[float, float]:
    """The simulated camera's principal point: the sensor centre plus ``[simulator]
    camera_cx_offset_px, camera_cy_offset_px`` [px]."""
    u0, v0 = config.camera.principal_point_px
    sim = config.simulator
    return u0 + sim.camera_cx_offset_px, v0 + sim.camera_cy_offset_px


def distortion(config: ScannerConfig, device: str) -> tuple[float, float, float, float]:
    """(k1, k2, p1, p2) of ``device`` ("camera" or "projector") from ``[simulator]`` [-]."""
    sim = config.simulator
    return tuple(float(getattr(sim, f"{device}_{k}")) for k in ("k1", "k2", "p1", "p2"))


def distort(coef: tuple[float, float, float, float], x: np.ndarray, y: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Brown-Conrady distortion of normalised coordinates (x, y) -> (x_d, y_d) [-]."""
    if not any(coef):  # today's pinhole, bit for bit
        return x, y
    k1, k2, p1, p2 = coef
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def undistort(coef: tuple[float, float, float, float], xd: np.ndarray, yd: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`distort` by Newton's method (to 1e-15) [-].

    Raises
    ------
    InputError
        When the iteration does not converge (distortion too strong to be inverted
        inside the field: the lens model folds over).
    """
    xd, yd = np.asarray(xd, float), np.asarray(yd, float)
    if not any(coef):
        return xd, yd
    x, y = xd.copy(), yd.copy()
    eps = 1e-7
    for _ in range(30):
        fx, fy = distort(coef, x, y)
        rx, ry = fx - xd, fy - yd
        if np.nanmax(np.abs(rx) + np.abs(ry), initial=0.0) < 1e-15:
            return x, y
        ax, ay = distort(coef, x + eps, y)
        bx, by = distort(coef, x, y + eps)
        j11, j21, j12, j22 = (ax - fx) / eps, (ay - fy) / eps, (bx - fx) / eps, (by - fy) / eps
        det = j11 * j22 - j12 * j21
        x = x - (j22 * rx - j12 * ry) / det
        y = y - (-j21 * rx + j11 * ry) / det
    if np.nanmax(np.abs(rx) + np.abs(ry), initial=0.0) < 1e-12:
        return x, y
    raise InputError(f"lens distortion {coef} cannot be inverted inside the field of view "
                     "(the model folds over): use smaller simulator k1/k2")


def project_to_camera(config: ScannerConfig, pose: Pose, points: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor coordinates (u, v) of world points, with the camera's distortion [px]."""
    q = pose.to_device(points)
    f = config.camera.principal_distance_px
    u0, v0 = camera_principal_point(config)
    with np.errstate(divide="ignore", invalid="ignore"):
        xd, yd = distort(distortion(config, "camera"), q[..., 0] / q[..., 2],
                         q[..., 1] / q[..., 2])
    return f * xd + u0, f * yd + v0


def camera_rays(config: ScannerConfig, pose: Pose, u: np.ndarray, v: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """World rays through sensor coordinates.

    Parameters
    ----------
    config : ScannerConfig
        Camera intrinsics.
    pose : Pose
        Camera pose.
    u, v : (...) float
        Sensor coordinates, pixel centres at integers [px].

    Returns
    -------
    origins, directions : (..., 3) float
        Ray origin (the lens centre) [mm] and unnormalised direction with unit device Z.
    """
    f = config.camera.principal_distance_px
    u0, v0 = camera_principal_point(config)
    x, y = undistort(distortion(config, "camera"), (np.asarray(u, float) - u0) / f,
                     (np.asarray(v, float) - v0) / f)
    d_cam = np.stack(np.broadcast_arrays(x, y, 1.0), axis=-1)
    if np.array_equal(pose.rotation, np.eye(3)):  # the same numbers, without the product
        return np.broadcast_to(pose.centre, d_cam.shape), d_cam
    directions = d_cam @ pose.rotation
    return np.broadcast_to(pose.centre, directions.shape), directions


def project_to_projector(config: ScannerConfig, pose: Pose, points: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Projector coordinates of world points.

    Returns
    -------
    x_p, y_p : (...) float
        Panel column and row, pixel centres at integers [projector px].
    z_p : (...) float
        Distance along the projector axis [mm].
    """
    q = pose.to_device(points)
    f = config.projector.principal_distance_px
    x0, y0 = config.projector.principal_point_px
    coef = distortion(config, "projector")
    with np.errstate(divide="ignore", invalid="ignore"):
        if not any(coef):  # today's pinhole, bit for bit
            return f * q[..., 0] / q[..., 2] + x0, f * q[..., 1] / q[..., 2] + y0, q[..., 2]
        xd, yd = distort(coef, q[..., 0] / q[..., 2], q[..., 1] / q[..., 2])
    return f * xd + x0, f * yd + y0, q[..., 2]


def projector_blur_px(config: ScannerConfig, z_p: np.ndarray) -> np.ndarray:
    """Diameter of the projector's blur disc on the panel [projector px]."""
    proj = config.projector
    c_obj = proj.aperture_mm * np.abs(z_p - proj.focus_mm) / proj.focus_mm
    return c_obj * proj.principal_distance_px / z_p


def camera_blur_px(config: ScannerConfig, z_c: np.ndarray) -> np.ndarray:
    """Diameter of the camera's defocus disc on the sensor [camera px]."""
    cam = config.camera
    c_img = (cam.aperture_mm * cam.focal_mm * np.abs(z_c - cam.focus_mm)
             / (z_c * (cam.focus_mm - cam.focal_mm)))
    return c_img / (cam.pixel_um * 1e-3)
