"""The per-node model of a calibration table's build, stage 2 (:mod:`scanqa.calibration.build`).

Each table node's phases over the sweep are fitted by weighted least squares to

    x(zeta) = (a + b zeta + d zeta^2) / (1 + g zeta),    zeta = (z - z0) / half      (1)

(z the stage reading [mm], x the node-centred phase [projector px]); here are that fit,
its inversion zeta(x) with its derivative and standard deviation, the residuals per
position, and the node rays' lateral X, Y, Z.
"""

from __future__ import annotations

import numpy as np

from scanqa.errors import InputError

#: Least median change of the phase over a sweep [projector px]: a real sweep moves it
#: by about 2 px per mm (the paper's scanner); less means the scans are not of the
#: positions listed.
MIN_PHASE_CHANGE_PX = 0.1


def check_phase_changes(x: np.ndarray, w: np.ndarray, z: np.ndarray) -> None:
    """Refuse a sweep whose phases do not move with the stage (the per-node fit of x
    against Z would be singular or meaningless)."""
    used = (w > 0) & np.isfinite(x)
    spread = np.where(used, x, -np.inf).max(-1) - np.where(used, x, np.inf).min(-1)
    finite = spread[np.isfinite(spread)]  # nodes no scan saw give -inf
    change = float(np.median(finite)) if finite.size else 0.0
    if not change >= MIN_PHASE_CHANGE_PX:
        raise InputError(f"the phases barely change over the sweep's {z.min():g} to "
                         f"{z.max():g} mm (median {change:.3g} projector px per node, a real "
                         f"sweep moves them by more than {MIN_PHASE_CHANGE_PX:g}): are the "
                         "scans listed at the positions they were taken at?")


def wls(cols: np.ndarray, x: np.ndarray, w: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted LS per node; covariance scaled by the reduced chi-square."""
    ata = np.einsum("...m,...mi,...mj->...ij", w, cols, cols)
    atb = np.einsum("...m,...mi,...m->...i", w, cols, x)
    n_obs = (w > 0).sum(-1)
    good = n_obs >= 5
    ata[~good] = np.eye(4)
    try:
        inv = np.linalg.inv(ata)
    except np.linalg.LinAlgError:  # a node whose phases do not change with Z
        inv = np.linalg.pinv(ata)
        good &= np.isfinite(np.linalg.cond(ata)) & (np.linalg.cond(ata) < 1e12)
    theta = np.einsum("...ij,...j->...i", inv, atb)
    res = x - np.einsum("...mi,...i->...m", cols, theta)
    chi2 = (w * res**2).sum(-1) / np.maximum(n_obs - 4, 1)
    theta[~good] = np.nan
    return theta, inv * chi2[..., None, None], n_obs


def position_residuals(stats, theta, zeta, x, w, z, report) -> None:
    """Per-position RMS of the fit residual, in projector px and mm along Z, appended to
    ``report.positions`` (a :class:`scanqa.calibration.build.BuildReport`)."""
    a, b, d, g = (theta[..., i, None] for i in range(4))
    pred = (a + b * zeta + d * zeta**2) / (1 + g * zeta)
    res = np.where(w > 0, x - pred, np.nan)
    slope = np.abs((b + 2 * d * zeta - g * pred) / (1 + g * zeta))  # dx/dzeta
    half = 0.5 * (z.max() - z.min())
    res_mm = res / slope * half
    for k, st in enumerate(stats):
        r, rm = res[..., k], res_mm[..., k]
        ok = np.isfinite(r)
        report.positions.append({
            "z_mm": float(st.z_mm), "cells": int(ok.sum()),
            "rms_residual_px": float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else None,
            "rms_residual_um": float(1e3 * np.sqrt(np.mean(rm[ok] ** 2))) if ok.any() else None,
        })


def solve_zeta(theta: np.ndarray, xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """zeta(x) of the node model and dzeta/dx, for x broadcast against theta[..., 0]."""
    a, b, d, g = (theta[..., i, None] for i in range(4))
    lin = (xq - a) / (b - g * xq)
    zeta = lin
    for _ in range(6):  # Newton on F = a + b z + d z^2 - x - g x z
        f = a + b * zeta + d * zeta**2 - xq - g * xq * zeta
        zeta = zeta - f / (b + 2 * d * zeta - g * xq)
    dzdx = (1 + g * zeta) / (b + 2 * d * zeta - g * xq)
    return zeta, dzdx


def solve_x(theta: np.ndarray, zeta: float) -> np.ndarray:
    """x at a scaled position zeta for every node [px]."""
    a, b, d, g = (theta[..., i] for i in range(4))
    return (a + b * zeta + d * zeta**2) / (1 + g * zeta)


def node_sigma(theta, cov, zeta, xq) -> np.ndarray:
    """Std of zeta(x) at each grid node from the parameter covariance [-]."""
    b, d, g = theta[..., 1, None], theta[..., 2, None], theta[..., 3, None]
    dfdz = b + 2 * d * zeta - g * xq
    grad = -np.stack([np.ones_like(zeta), zeta, zeta**2, -xq * zeta], -1) / dfdz[..., None]
    var = np.einsum("...si,...ij,...sj->...s", grad, cov, grad)
    return np.sqrt(np.maximum(var, 0.0))


def lateral_rays(stats, w, z0, half, config, node_u, node_v) -> tuple:
    """X = X0 + kx z, Y = Y0 + ky z, Z = Z0 + kz z per node ray [mm], z the stage
    reading: from lateral maps (Z = z where they give no Z) or from the intrinsics."""
    if all(s.lat is not None for s in stats):
        z = np.array([s.z_mm for s in stats])
        out = []
        n_maps = min(len(s.lat) for s in stats)
        for j in range(n_maps):
            m = np.stack([s.lat[j] for s in stats], -1)
            ww = np.where(np.isfinite(m) & (w > 0), 1.0, 0.0)
            m = np.where(ww > 0, m, 0.0)
            sw, sz, sm = ww.sum(-1), (ww * z).sum(-1), (ww * m).sum(-1)
            szz, szm = (ww * z * z).sum(-1), (ww * z * m).sum(-1)
            with np.errstate(all="ignore"):
                k = (sw * szm - sz * sm) / (sw * szz - sz**2)
            out += [((sm - k * sz) / sw)[..., None], k[..., None]]
        if n_maps == 2:
            out += [np.zeros_like(out[0]), np.ones_like(out[1])]
        return tuple(out)
    cam = config.camera
    f = cam.principal_distance_px
    uu, vv = np.meshgrid(node_u, node_v)
    kx = ((uu - cam.principal_point_px[0]) / f)[..., None]
    ky = ((vv - cam.principal_point_px[1]) / f)[..., None]
    return (np.zeros_like(kx), kx, np.zeros_like(ky), ky, np.zeros_like(kx),
            np.ones_like(kx))
