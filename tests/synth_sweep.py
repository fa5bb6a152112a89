"""Synthetic plane sweeps from the config's pinhole geometry (for calibration unit tests).

The geometry is exact and independent of the calibration code: each pixel's ray meets
the plane Z = z, and the point is projected into the projector. Noise is drawn from an
explicit profile given here (not from the optics model), so weighting tests are honest.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from scanqa.calibration.build import PlaneObservation
from scanqa.model import geometry
from scanqa.model.config import ScannerConfig


def small_camera(config: ScannerConfig, width: int = 192, height: int = 128) -> ScannerConfig:
    """The config with a smaller sensor (same optics, centred window)."""
    cam = replace(config.camera, width_px=width, height_px=height)
    return ScannerConfig(cam, config.projector, config.fringes, config.model,
                         config.simulator, config.name, config.source)


def plane_truth(config: ScannerConfig, z: float) -> tuple[np.ndarray, np.ndarray]:
    """True x_p map and points of the plane Z = z: ((H, W), (H, W, 3))."""
    cam = config.camera
    v, u = np.indices((cam.height_px, cam.width_px), dtype=float)
    f = cam.principal_distance_px
    q = np.stack([(u - cam.principal_point_px[0]) / f * z,
                  (v - cam.principal_point_px[1]) / f * z, np.full_like(u, z)], -1)
    qp = geometry.to_projector_frame(q, config)
    xp = config.projector.principal_distance_px * qp[..., 0] / qp[..., 2] \
        + config.projector.principal_point_px[0]
    return xp, q


def noise_profile(z: float, focus: float = 450.0) -> float:
    """Phase noise that grows past the depth of field [projector px]."""
    return 0.02 * (1.0 + ((z - focus) / 12.0) ** 4)


def sweep(config: ScannerConfig, zs, seed: int = 0, repeats: int = 1, noise: bool = True,
          jump_fraction: float = 0.0) -> list[PlaneObservation]:
    """Observations at every z (and repeat), with optional injected unwrapping jumps."""
    rng = np.random.default_rng(seed)
    out = []
    for z in zs:
        xp, _ = plane_truth(config, z)
        sig = noise_profile(z)
        for _ in range(repeats):
            x = xp + (rng.normal(0.0, sig, xp.shape) if noise else 0.0)
            if jump_fraction:
                hit = rng.random(xp.shape) < jump_fraction
                x = np.where(hit, x + 5.0 * rng.choice([-1.0, 1.0], xp.shape), x)
            out.append(PlaneObservation(float(z), x, sigma_xp=np.full(xp.shape, sig),
                                        source=f"z={z}"))
    return out
