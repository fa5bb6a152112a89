"""Finding spheres and planes in a point cloud without a layout (RANSAC).

Spheres: Open3D has no sphere RANSAC, so it is written here in numpy. Each hypothesis is
the sphere through 4 random points (the algebraic equation |p|^2 = 2 c.p + d solved
exactly, all hypotheses at once as a batch of 4 x 4 systems). With a radius prior R the
last three points are drawn within 2.2 R of the first, so that a small ball in a large
scene is still hit by many hypotheses, and the prior discards the
hypotheses whose radius is off by more than ``radius_tol_mm``; the rest are scored by
their inliers (|distance to the surface| <= ``threshold_mm``) on a random subset of the
cloud, chunk by chunk. The best hypothesis is refined by a least-squares fit on its
inliers over the whole cloud, twice (inliers, fit, inliers again). Seeded: the same cloud
and seed give the same spheres.

Planes: Open3D's ``segment_plane`` (seeded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanqa.errors import InputError
from scanqa.qa.sphere import algebraic_sphere, check_points

#: Points used to score the hypotheses [-].
SCORE_POINTS = 2000
#: Points the last three points of a hypothesis are drawn from [-].
_POOL = 1000
#: Hypotheses scored at once (memory: chunk x SCORE_POINTS floats) [-].
_CHUNK = 256


@dataclass(frozen=True)
class SphereCandidate:
    """A sphere found by RANSAC.

    Attributes
    ----------
    centre : (3,) float
        Centre of the least-squares refit on the inliers [mm].
    radius : float
        Its radius [mm].
    inliers : (m,) int
        Indices of the points within the threshold of its surface [-].
    """

    centre: np.ndarray
    radius: float
    inliers: np.ndarray


def _samples(pts: np.ndarray, rng, iterations: int, reach: float | None) -> np.ndarray:
    """(m, 4) indices of 4 distinct points per hypothesis: a random first point and three
    more within ``reach`` of it (anywhere when None), drawn from a pool of at most
    ``_POOL`` random points by random keys (no loop over hypotheses)."""
    pool = rng.choice(len(pts), min(_POOL, len(pts)), replace=False)
    first = pool[rng.integers(0, pool.size, iterations)]
    keys = rng.random((iterations, pool.size))
    if reach is not None:
        far = np.linalg.norm(pts[pool][None] - pts[first][:, None], axis=2) > reach
        keys[far] = np.inf
    keys[pool[None, :] == first[:, None]] = np.inf
    pick = np.argpartition(keys, 3, axis=1)[:, :3]
    ok = np.isfinite(np.take_along_axis(keys, pick, axis=1)).all(axis=1)
    return np.column_stack([first, pool[pick]])[ok]


def _hypotheses(pts: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Spheres through the 4 points of each row of idx: centres (m, 3), radii (m,) [mm]."""
    p = pts[idx]
    p = p - p[:, :1]  # first point at the origin: better conditioned
    a = np.concatenate([2.0 * p, np.ones((*p.shape[:2], 1))], axis=2)
    det = np.linalg.det(a)
    scale = np.max(np.abs(p), axis=(1, 2)) ** 3
    ok = np.abs(det) > 1e-9 * np.maximum(scale, 1e-300)
    sol = np.linalg.solve(a[ok], np.sum(p[ok] ** 2, axis=2)[..., None])[..., 0]
    c = sol[:, :3]
    r2 = sol[:, 3] + np.sum(c**2, axis=1)
    good = r2 > 0
    return c[good] + pts[idx[ok][good, 0]], np.sqrt(r2[good])


def _best(sub: np.ndarray, centres: np.ndarray, radii: np.ndarray, thr: float) -> int:
    """Index of the hypothesis with the most inliers in ``sub``: squared distances by
    matrix products, (r - thr)^2 <= |p - c|^2 <= (r + thr)^2, in chunks."""
    m = sub.mean(axis=0)
    p, c = sub - m, centres - m
    p2 = np.sum(p**2, axis=1)
    lo, hi = np.maximum(radii - thr, 0.0) ** 2, (radii + thr) ** 2
    scores = np.empty(len(radii), dtype=int)
    for s in range(0, len(radii), _CHUNK):
        cc = c[s:s + _CHUNK]
        d2 = p2[None, :] - 2.0 * cc @ p.T + np.sum(cc**2, axis=1)[:, None]
        scores[s:s + _CHUNK] = np.sum((d2 >= lo[s:s + _CHUNK, None])
                                      & (d2 <= hi[s:s + _CHUNK, None]), axis=1)
    return int(np.argmax(scores))


def check_positive(where: str, **lengths: float | None) -> None:
    """Refuse a length [mm] that is given but not finite and > 0, naming it.

    Parameters
    ----------
    where : str
        What is being searched, for the message.
    **lengths : float or None
        Name -> value [mm]; None (not given) passes.
    """
    for name, value in lengths.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{where}: the {name.replace('_', ' ')} must be finite and "
                             f"> 0 mm, got {value!r}")


def ransac_sphere(points, radius_mm: float | None = None, radius_tol_mm: float | None = None,
                  threshold_mm: float = 0.1, iterations: int = 1000, min_inliers: int = 50,
                  seed: int = 0) -> SphereCandidate | None:
    """The sphere with the most inliers, or None when no hypothesis has ``min_inliers``.

    Parameters
    ----------
    points : (n, 3) float
        Cloud [mm].
    radius_mm : float, optional
        Expected radius [mm]; give it whenever the artefact is known (otherwise a large
        plane, fitted by a huge sphere, may win).
    radius_tol_mm : float, optional
        Accepted |radius - radius_mm| of a hypothesis [mm]; default 10 % of radius_mm.
    threshold_mm : float
        Inlier distance from the surface [mm]; a few times the noise.
    iterations : int
        Hypotheses drawn [-].
    min_inliers : int
        Fewest inliers of a sphere found [-].
    seed : int
        Random seed [-].

    Returns
    -------
    SphereCandidate or None

    Notes
    -----
    RANSAC (M. A. Fischler and R. C. Bolles (1981), Comm. ACM 24(6), 381-395): the sphere
    through 4 points solves |p|^2 = 2 c . p + d exactly, R = sqrt(d + |c|^2); inliers have
    | |p - c| - R | <= ``threshold_mm``; the best is refined by the least-squares sphere
    (ISO 10360-6) on its inliers.
    """
    pts = check_points(points, "sphere search", 4)
    check_positive("sphere search", radius=radius_mm, radius_tolerance=radius_tol_mm,
                   threshold=threshold_mm)
    rng = np.random.default_rng(seed)
    sub = pts[rng.choice(len(pts), SCORE_POINTS, replace=False)] \
        if len(pts) > SCORE_POINTS else pts
    reach = None if radius_mm is None else 2.2 * radius_mm  # the 4 points on one ball
    centres, radii = _hypotheses(sub, _samples(sub, rng, iterations, reach))
    if radius_mm is not None:
        tol = 0.1 * radius_mm if radius_tol_mm is None else radius_tol_mm
        keep = np.abs(radii - radius_mm) <= tol
        centres, radii = centres[keep], radii[keep]
    if radii.size == 0:
        return None
    i = _best(sub, centres, radii, threshold_mm)
    c, r = centres[i], float(radii[i])
    for _ in range(2):
        inl = np.flatnonzero(np.abs(np.linalg.norm(pts - c, axis=1) - r) <= threshold_mm)
        if inl.size < max(min_inliers, 5):
            return None
        c, r = algebraic_sphere(pts[inl])
    inl = np.flatnonzero(np.abs(np.linalg.norm(pts - c, axis=1) - r) <= threshold_mm)
    if inl.size < max(min_inliers, 5):
        return None
    return SphereCandidate(c, r, inl)


def find_spheres(points, count: int, radius_mm: float | None = None, what: str = "spheres",
                 **kwargs) -> list[SphereCandidate]:
    """Find ``count`` distinct spheres, largest inlier set first.

    Each sphere found removes its inliers and the points inside it (1.05 R) from the
    search for the next.

    Parameters
    ----------
    points : (n, 3) float
        Cloud [mm].
    count : int
        Spheres wanted [-].
    radius_mm : float, optional
        Expected radius [mm].
    what : str
        What is sought, for the message.
    **kwargs
        Passed to :func:`ransac_sphere` (``radius_tol_mm``, ``threshold_mm``,
        ``iterations``, ``min_inliers``, ``seed``).

    Raises
    ------
    InputError
        Fewer than ``count`` spheres found.

    Notes
    -----
    Repeated :func:`ransac_sphere` (M. A. Fischler and R. C. Bolles (1981)), each found
    sphere's inliers and the points within 1.05 R of its centre removed before the next
    search.
    """
    pts = check_points(points, what, 4)
    remaining = np.arange(len(pts))
    found: list[SphereCandidate] = []
    seed = kwargs.pop("seed", 0)
    for i in range(count):
        cand = ransac_sphere(pts[remaining], radius_mm, seed=seed + i, **kwargs) \
            if remaining.size >= 4 else None
        if cand is None:
            prior = "" if radius_mm is None else f" of radius {radius_mm:g} mm"
            raise InputError(
                f"{what}: found {len(found)} of {count} spheres{prior} (RANSAC, inlier "
                f"threshold {kwargs.get('threshold_mm', 0.1):g} mm): check that every sphere "
                "is in the scan and the diameter given, or raise the threshold")
        found.append(SphereCandidate(cand.centre, cand.radius, remaining[cand.inliers]))
        near = np.linalg.norm(pts[remaining] - cand.centre, axis=1) <= 1.05 * cand.radius
        drop = np.zeros(remaining.size, dtype=bool)
        drop[cand.inliers] = True
        remaining = remaining[~(drop | near)]
    return found


def ransac_plane(points, threshold_mm: float = 0.1, iterations: int = 2000,
                 seed: int = 0) -> tuple[np.ndarray, float, np.ndarray]:
    """The plane with the most inliers (Open3D ``segment_plane``, seeded).

    Parameters
    ----------
    points : (n, 3) float
        Cloud [mm].
    threshold_mm : float
        Inlier distance [mm].
    iterations : int
        RANSAC iterations [-].
    seed : int
        Random seed [-].

    Returns
    -------
    normal : (3,) float
        Unit normal [-].
    offset : float
        n . p of the plane [mm].
    inliers : (m,) int
        Indices of the inliers [-].

    Notes
    -----
    RANSAC plane (M. A. Fischler and R. C. Bolles (1981); Open3D ``segment_plane``): the
    plane through 3 points with the most inliers |(p - q) . n| <= ``threshold_mm``.
    """
    import open3d as o3d

    pts = check_points(points, "plane search", 3)
    check_positive("plane search", threshold=threshold_mm)
    o3d.utility.random.seed(seed)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    model, inl = pcd.segment_plane(distance_threshold=threshold_mm, ransac_n=3,
                                   num_iterations=iterations)
    n = np.asarray(model[:3], dtype=float)
    norm = float(np.linalg.norm(n))
    if not math.isfinite(norm) or norm == 0:
        raise InputError("plane search: RANSAC found no plane")
    return n / norm, -float(model[3]) / norm, np.asarray(inl, dtype=int)
