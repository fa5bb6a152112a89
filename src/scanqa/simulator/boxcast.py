"""First hits of rays on a scene of axis-aligned boxes, in a compiled loop without the GIL.

open3d's ``cast_rays`` holds the GIL for the whole call, so the renderer's two tile
threads cannot cast at the same time, and casting is about a fifth of a 5 MP scan's
CPU. For a scene that is a union of axis-aligned boxes (the gauge-block artefact), the
hit triangle follows from plane intersections: per ray, every box face that faces the
ray is intersected in float64 and the nearest face that contains its intersection
wins; of that face's two triangles, the one on the intersection's side of their shared
diagonal. Rays of one origin (a tile's camera rays, its shadow rays) skip a box by the
window of direction ratios it covers (:func:`_windows`), others by a slab test.

The renderer's geometry depends on the hit *triangle* (its plane and first vertex give
the float64 hit, :func:`scanqa.simulator.raykernels.light_hits`), so it must be the
triangle open3d picks. open3d decides in float32 on the float32 vertices; its answer
can differ from the exact one only for rays that pass close to a face's edge, a
triangle's diagonal, or hit two faces at nearly the same distance. Every ray within
:data:`AMBIGUOUS_MM` of such a decision (in the face's plane, or along the ray) is
marked ambiguous and cast by open3d instead (:meth:`scanqa.simulator.scene.Scene.first_hits`),
so the triangles are open3d's for every ray (``tests/test_simulator_boxcast.py``
compares every ray of the gauge scene's tiles and shadow rays with open3d's). Without
numba (:mod:`scanqa.compiled`) the scene casts every ray with open3d.
"""

from __future__ import annotations

import numpy as np

from scanqa.compiled import njit

#: Distance from a decision (a face's edge, a diagonal, a tie between two faces) within
#: which a ray is left to open3d [mm]. open3d's float32 arithmetic on coordinates of
#: ~500 mm errs by ~1e-4 mm (float32's spacing there is 6e-5 mm); 100 times that.
AMBIGUOUS_MM = 1e-2
#: The hit-triangle code of an ambiguous ray (cast by open3d) [-].
AMBIGUOUS = -2
#: The hit-triangle code of a ray that hits nothing [-].
MISS = -1


def box_table(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """The boxes of a mesh made of axis-aligned boxes of 12 triangles each, in order.

    Parameters
    ----------
    vertices : (V, 3) float64
        Mesh vertices [mm].
    faces : (F, 3) int
        Triangles; triangles 12 k .. 12 k + 11 are box k's (as
        ``trimesh.util.concatenate`` of ``trimesh.creation.box`` meshes leaves them).

    Returns
    -------
    (B, 3, 2, 7) float64 or None
        Per box, axis a and side (0: low, 1: high): the side's coordinate [mm], its two
        triangles' indices, a point of their shared diagonal and the diagonal's unit
        normal in the side's plane (axes (a+1) % 3 and (a+2) % 3) [mm], [-], the first
        triangle on the normal's side; the box's bounds are those of its sides. None
        when the mesh is not such boxes.
    """
    if len(faces) == 0 or len(faces) % 12:
        return None
    table = np.full((len(faces) // 12, 3, 2, 7), np.nan)
    for k in range(len(faces) // 12):
        corners = vertices[faces[12 * k:12 * k + 12]]  # (12, 3, 3)
        lo, hi = corners.reshape(-1, 3).min(axis=0), corners.reshape(-1, 3).max(axis=0)
        if not _fill_box(table[k], corners, lo, hi, 12 * k):
            return None
    return table


def _fill_box(box: np.ndarray, corners: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              first: int) -> bool:
    """Fill one box's sides from its 12 triangles; False if they are not a box's."""
    seen = {}
    for j, tri in enumerate(corners):
        axes = [a for a in range(3) if np.all(tri[:, a] == tri[0, a])]
        if len(axes) != 1 or tri[0, axes[0]] not in (lo[axes[0]], hi[axes[0]]):
            return False
        a = axes[0]
        seen.setdefault((a, int(tri[0, a] == hi[a])), []).append((first + j, tri))
    if sorted(seen) != [(a, s) for a in range(3) for s in range(2)] or any(
            len(v) != 2 for v in seen.values()):
        return False
    for (a, s), ((f0, t0), (f1, t1)) in seen.items():
        b, c = (a + 1) % 3, (a + 2) % 3
        shared = [p for p in t0 if any(np.array_equal(p, q) for q in t1)]
        if len(shared) != 2:
            return False
        (p0, p1), third = shared, next(p for p in t0 if not any(
            np.array_equal(p, q) for q in shared))
        ex, ey = p1[b] - p0[b], p1[c] - p0[c]
        nb, nc = -ey / np.hypot(ex, ey), ex / np.hypot(ex, ey)  # the diagonal's normal
        side = (third[b] - p0[b]) * nb + (third[c] - p0[c]) * nc
        first_pos = (f0, f1) if side > 0 else (f1, f0)
        box[a, s] = (lo[a] if s == 0 else hi[a], *first_pos, p0[b], p0[c], nb, nc)
    return True


@njit(cache=True, nogil=True)
def first_triangles(rays: np.ndarray, table: np.ndarray, tol: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Hit triangle of every ray, :data:`MISS` or :data:`AMBIGUOUS`.

    Parameters
    ----------
    rays : (n, 6) float32
        Origins and directions, as open3d casts them [mm].
    table : (B, 3, 2, 7) float64
        The boxes of :func:`box_table`.
    tol : float
        Distance from a decision within which a ray is ambiguous [mm].

    Returns
    -------
    code : (n,) int64
        Triangle index, -1 (miss) or -2 (ambiguous: ask open3d).
    t : (n,) float32
        The ray parameter of the hit (inf for a miss or an ambiguous ray) [-].
    """
    n, n_box = rays.shape[0], table.shape[0]
    code, t = np.empty(n, np.int64), np.full(n, np.inf, np.float32)
    # the boxes grown by 2 tol: a ray that misses one meets every plane of its faces
    # more than tol outside the face
    grown = np.empty((n_box, 3, 2))
    for k in range(n_box):
        for a in range(3):
            grown[k, a, 0] = table[k, a, 0, 0] - 2.0 * tol
            grown[k, a, 1] = table[k, a, 1, 0] + 2.0 * tol
    window = _windows(rays, grown)
    windowed = window[:, 4].all()  # no slab test needed
    o, d, inv = np.empty(3), np.empty(3), np.empty(3)
    for i in range(n):
        for a in range(3):
            o[a], d[a] = rays[i, a], rays[i, 3 + a]
            if not windowed:
                inv[a] = 1.0 / d[a] if d[a] != 0.0 else np.inf
        norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        rx, ry = (d[0] / d[2], d[1] / d[2]) if d[2] > 0.0 else (np.nan, np.nan)
        best, second, hit = np.inf, np.inf, MISS
        for k in range(n_box):
            if window[k, 4]:
                if not (window[k, 0] <= rx <= window[k, 1]
                        and window[k, 2] <= ry <= window[k, 3]):
                    continue  # outside the box's window (NaN: the ray turns away)
            elif not _meets(o, d, inv, grown, k, tol, norm):
                continue
            for a in range(3):
                if d[a] == 0.0:
                    continue
                s = 0 if d[a] > 0.0 else 1  # the side that faces the ray
                tk = (table[k, a, s, 0] - o[a]) / d[a]
                face = _in_face(o, d, tk, table, k, a, s, tol)
                if face == MISS:
                    continue
                if face == AMBIGUOUS or tk * norm <= tol:
                    best, hit = -1.0, AMBIGUOUS
                    break
                if tk < best:
                    best, second, hit = tk, best, face
                elif tk < second:
                    second = tk
            if hit == AMBIGUOUS:
                break
        if hit >= 0 and (second - best) * norm <= tol:
            hit = AMBIGUOUS  # two faces at (nearly) the same distance
        code[i] = hit
        if hit >= 0:
            t[i] = best
    return code, t


@njit(cache=True, nogil=True)
def _windows(rays: np.ndarray, grown: np.ndarray) -> np.ndarray:
    """Per grown box, the range of x/z and y/z of the directions of the rays that can meet
    it, when every ray starts at one origin with the whole box ahead in z (a central
    projection maps the convex box into the hull of its corners' images), and 1 in
    column 4; 0 there when this does not apply (the slab test alone decides) [-]."""
    window = np.zeros((grown.shape[0], 5))
    n = rays.shape[0]
    for i in range(1, n):
        if rays[i, 0] != rays[0, 0] or rays[i, 1] != rays[0, 1] or rays[i, 2] != rays[0, 2]:
            return window
    if n == 0:
        return window
    o0, o1, o2 = float(rays[0, 0]), float(rays[0, 1]), float(rays[0, 2])
    for k in range(grown.shape[0]):
        if grown[k, 2, 0] - o2 <= 0.0:
            continue
        lo_x, hi_x, lo_y, hi_y = np.inf, -np.inf, np.inf, -np.inf
        for cx in (grown[k, 0, 0], grown[k, 0, 1]):
            for cy in (grown[k, 1, 0], grown[k, 1, 1]):
                for cz in (grown[k, 2, 0], grown[k, 2, 1]):
                    x, y = (cx - o0) / (cz - o2), (cy - o1) / (cz - o2)
                    lo_x, hi_x = min(lo_x, x), max(hi_x, x)
                    lo_y, hi_y = min(lo_y, y), max(hi_y, y)
        margin = 1e-9  # rounding of the ratios, far inside the boxes' 2 tol growth
        window[k] = (lo_x - margin, hi_x + margin, lo_y - margin, hi_y + margin, 1.0)
    return window


@njit(cache=True, nogil=True, inline="always")
def _meets(o: np.ndarray, d: np.ndarray, inv: np.ndarray, grown: np.ndarray, k: int,
           tol: float, norm: float) -> bool:
    """Does the ray meet grown box k ahead of its origin (slab test)?"""
    t_in, t_out = -np.inf, np.inf
    for a in range(3):
        if d[a] == 0.0:
            if o[a] < grown[k, a, 0] or o[a] > grown[k, a, 1]:
                return False
            continue
        t0, t1 = (grown[k, a, 0] - o[a]) * inv[a], (grown[k, a, 1] - o[a]) * inv[a]
        if t0 > t1:
            t0, t1 = t1, t0
        t_in, t_out = max(t_in, t0), min(t_out, t1)
    return t_in <= t_out and t_out * norm > -tol


@njit(cache=True, nogil=True, inline="always")
def _in_face(o: np.ndarray, d: np.ndarray, t: float, table: np.ndarray, k: int, a: int,
             s: int, tol: float) -> int:
    """The triangle of box k's side (a, s) that the ray's point at t lies in, MISS when it
    lies more than tol outside the side, AMBIGUOUS within tol of its edge or diagonal."""
    b, c = (a + 1) % 3, (a + 2) % 3
    pb, pc = o[b] + t * d[b], o[c] + t * d[c]
    outside = max(table[k, b, 0, 0] - pb, pb - table[k, b, 1, 0], table[k, c, 0, 0] - pc,
                  pc - table[k, c, 1, 0])
    if outside > tol:
        return MISS
    if outside >= -tol:
        return AMBIGUOUS
    side = (pb - table[k, a, s, 3]) * table[k, a, s, 5] + (pc - table[k, a, s, 4]) * \
        table[k, a, s, 6]  # from the diagonal [mm]
    if abs(side) <= tol:
        return AMBIGUOUS
    return int(table[k, a, s, 1]) if side > 0 else int(table[k, a, s, 2])
