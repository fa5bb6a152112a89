"""Synthetic VDI/VDE 2634-2 artefacts as a scanner at the origin sees them: one side only,
noise along the line of sight, exact truth."""

from __future__ import annotations

import numpy as np


def visible_cap(rng, centre, radius: float, n: int, max_incidence_deg: float = 70.0):
    """n points uniform over the part of a sphere a camera at the origin sees with an
    incidence angle (surface normal to line of sight) below ``max_incidence_deg``.

    Returns the exact points (n, 3) [mm] and their outward unit normals (n, 3).
    """
    centre = np.asarray(centre, dtype=float)
    out_p, out_n = [], []
    while sum(len(p) for p in out_p) < n:
        u = rng.normal(size=(4 * n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        p = centre + radius * u
        los = -p / np.linalg.norm(p, axis=1, keepdims=True)  # from the point to the camera
        keep = np.sum(u * los, axis=1) > np.cos(np.radians(max_incidence_deg))
        out_p.append(p[keep])
        out_n.append(u[keep])
    return np.vstack(out_p)[:n], np.vstack(out_n)[:n]


def along_sight(rng, points, sigma):
    """Points displaced along their line of sight from the origin by N(0, sigma) [mm]."""
    los = points / np.linalg.norm(points, axis=1, keepdims=True)
    return points + los * (np.asarray(sigma) * rng.normal(size=len(points)))[:, None]


def sight_cosine(points, normals):
    """|cos| of the angle between each line of sight and the surface normal [-]."""
    los = points / np.linalg.norm(points, axis=1, keepdims=True)
    return np.abs(np.sum(los * normals, axis=1))


def flat_patch(rng, centre, normal, size: float, n: int):
    """n points uniform on a square patch of side ``size`` [mm] of a plane, and their
    in-plane coordinates (n, 2) [mm]."""
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    st = rng.uniform(-size / 2, size / 2, (n, 2))
    return np.asarray(centre, dtype=float) + st[:, :1] * e1 + st[:, 1:] * e2, st


def rigid(rng):
    """A random rotation (det +1) and translation [mm]."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q, rng.normal(0.0, 200.0, 3)
