"""The scanner's pinhole geometry in the model: scanner-frame points in the projector's
frame, their projector depth Z_p, and the triangulation scale s_T of Eq. 18 from the
config's pose (no calibration table). :mod:`scanqa.model.optics` builds the noise model
on them."""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike

from scanqa.compiled import jitable
from scanqa.model.config import ProjectorConfig, ScannerConfig


@functools.lru_cache(maxsize=16)
def _cached_rotation(projector: ProjectorConfig) -> np.ndarray:
    rot = projector.rotation
    rot.setflags(write=False)
    return rot


def projector_rotation(projector: ProjectorConfig) -> np.ndarray:
    """The projector's rotation (:attr:`ProjectorConfig.rotation`), computed once per pose:
    the model runs per band of a few thousand points."""
    try:
        return _cached_rotation(projector)
    except TypeError:  # a config built with unhashable (list) fields
        return projector.rotation


def to_projector_frame(points: ArrayLike, config: ScannerConfig) -> np.ndarray:
    """Express scanner-frame points in the projector frame.

    Parameters
    ----------
    points : (..., 3) array_like
        Points in the scanner (camera) frame [mm].
    config : ScannerConfig
        Gives the projector pose.

    Returns
    -------
    (..., 3) ndarray
        Q_p = R (Q - position) [mm].
    """
    q = np.asarray(points, dtype=float)
    proj = config.projector
    d = [q[..., i] - proj.position_mm[i] for i in range(3)]
    rot = projector_rotation(proj)
    # explicit sums: a (n, 3) @ (3, 3) matmul is far slower for large n
    return np.stack([rot[j, 0] * d[0] + rot[j, 1] * d[1] + rot[j, 2] * d[2]
                     for j in range(3)], axis=-1)


def projector_depth(points: ArrayLike, config: ScannerConfig) -> np.ndarray:
    """Z of scanner-frame points in the projector frame, Z_p [mm]; shape (...)."""
    q = np.asarray(points, dtype=float)
    proj = config.projector
    return depth_along(q[..., 0], q[..., 1], q[..., 2], projector_rotation(proj)[2],
                       proj.position_mm)


@jitable
def depth_along(x: ArrayLike, y: ArrayLike, z: ArrayLike, rz: ArrayLike,
                position: ArrayLike) -> np.ndarray:
    """Z_p of the points (x, y, z) [mm] for a projector at ``position`` [mm] whose
    rotation's third row is ``rz`` [-] (:func:`projector_depth`)."""
    depth = rz[0] * (x - position[0]) + rz[1] * (y - position[1])
    return depth + rz[2] * (z - position[2])


def triangulation_scale(points: ArrayLike, config: ScannerConfig) -> np.ndarray:
    """Triangulation scale s_T from the config's pinhole geometry (no table).

    Parameters
    ----------
    points : (..., 3) array_like
        Points in the scanner frame [mm].
    config : ScannerConfig
        Camera and projector geometry.

    Returns
    -------
    (...,) ndarray
        |dQ/dx_p| along the camera's line of sight [mm / projector px].

    Notes
    -----
    The point moves along its camera ray Q(t) = t d; its projector column is
    x_p = f_p X_p / Z_p + x_0, so dx_p/dt = f_p (X_p' Z_p - X_p Z_p') / Z_p^2 with
    X_p' = R_x . d and Z_p' = R_z . d. With a calibration table, use the table's slope
    instead (docs/model.rst).
    """
    q = np.asarray(points, dtype=float)
    rot = projector_rotation(config.projector)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = q / np.linalg.norm(q, axis=-1, keepdims=True)
        qp = to_projector_frame(q, config)
        dx, dz = d @ rot[0], d @ rot[2]
        dxp_dt = config.projector.principal_distance_px * (dx * qp[..., 2] - qp[..., 0] * dz) \
            / qp[..., 2] ** 2
        return 1.0 / np.abs(dxp_dt)
