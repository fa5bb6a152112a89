"""Compiled per-sample loops of the renderer (numba): hits, projections, light, frames.

The renderer's geometry of a grid of rays (``scanqa.simulator.render._geometry``) took
about twenty numpy passes over (n, 3) float64 arrays (the float64 refinement of the
hits, the world points, the camera depth, the projector coordinates, the lighting and
the shadow rays' set-up); here each is one loop over the samples, on the calling thread
with the GIL released (the renderer's tile pool runs one per core). open3d still finds
the hit triangle; the float64 refinement against that triangle's plane is the formula
of :meth:`scanqa.simulator.scene.Scene.cast`. The frame loops (:func:`add_fringe`,
:func:`add_cell_noise`, :func:`add_pixel_means`), :func:`phasor_parts`,
:func:`noise_cells`, :func:`hash_normal` (the scene noise's counter-based normals, most
of a small frame's CPU in numpy passes) and :func:`ladder_groups` replace numpy passes of
the tiles and of the blur plan.

Every loop repeats numpy's arithmetic in numpy's order (einsum's three-term dot product
as ``(a0 b0 + a2 b2) + a1 b1``, matrix products with fused multiply-adds as BLAS forms
them, a mean over two axes as the sum of row sums, numpy's interpolation slopes), so
the renderer's images and the ground truth (:func:`scanqa.simulator.render.truth_for`
uses :func:`tile_geometry` too) are the same bytes as with the numpy passes on this
machine (docs/benchmarks.rst, "Fourth pass"); on a BLAS that sums otherwise the
geometry may differ by an ulp. ``tests/test_simulator_raykernels.py`` checks each
loop against the numpy expressions it replaces; the numpy geometry stays for a
distorted projector.

numba is optional (``pip install 'scanqa[fast]'``, :mod:`scanqa.compiled`). Without it
:func:`tile_geometry` answers None (the renderer's numpy geometry), and the frame and
plan loops are replaced by their numpy twins (``*_numpy`` below: the expressions the
loops replaced, vectorised, never a Python loop over samples), which agree with the
loops to rounding (``tests/test_lean_install.py``).
"""

from __future__ import annotations

import numpy as np

from scanqa import compiled
from scanqa.compiled import njit
from scanqa.model.config import ScannerConfig
from scanqa.simulator import devices
from scanqa.simulator.devices import Pose
from scanqa.simulator.scene import Scene

#: open3d's primitive id of a ray that hits nothing.
NO_HIT = np.iinfo(np.uint32).max


def tile_geometry(config: ScannerConfig, scene: Scene, camera: Pose, projector: Pose,
                  u: np.ndarray, v: np.ndarray, threads: int = 0) -> tuple | None:
    """Camera rays through sensor coordinates (u, v), their hits and lighting.

    Parameters
    ----------
    config : ScannerConfig
        Intrinsics and panel size.
    scene : Scene
        What the rays hit.
    camera, projector : Pose
        Device poses.
    u, v : (H, W) float
        Sensor coordinates [px].
    threads : int
        open3d's threads per cast (1 inside a pool of tiles) [-].

    Returns
    -------
    tuple or None
        hit, world (H, W, 3) [mm], z_c [mm], x_p, y_p [projector px], z_p [mm], lit and
        shade [-] as the renderer's ``_geometry`` computes them; None for a distorted
        projector or without numba (the caller then uses the numpy path).
    """
    if not compiled.HAVE_NUMBA or any(devices.distortion(config, "projector")):
        return None
    shape = np.shape(u)
    origins, dirs = devices.camera_rays(config, camera, u, v)
    origin = np.ascontiguousarray(origins.reshape(-1, 3)[0], np.float64)
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    prim, t32 = scene.first_hits(camera_rays32(origin, d), threads)
    proj, normals, v0 = config.projector, scene.face_normals, scene.face_origins
    hit, world, z_c, x_p, y_p, z_p, shade, cand = light_hits(
        prim, t32, d, origin, normals, _offsets(scene, origin, d.shape[0]), v0,
        np.asarray(camera.centre, np.float64), np.asarray(camera.rotation[2:3], np.float64),
        np.asarray(projector.centre, np.float64),
        np.ascontiguousarray(projector.rotation, np.float64),
        float(proj.principal_distance_px), float(proj.principal_point_px[0]),
        float(proj.principal_point_px[1]), float(proj.width_px), float(proj.height_px))
    del prim, t32
    centre = np.asarray(projector.centre, np.float64)
    rays = shadow_rays32(world, cand, centre)
    prim, t32 = scene.first_hits(rays, threads)
    lit = unshadowed(cand, shade, world, prim, t32, centre, normals,
                     _offsets(scene, centre, rays.shape[0]), v0)
    return (hit.reshape(shape), world.reshape(*shape, 3), z_c.reshape(shape),
            x_p.reshape(shape), y_p.reshape(shape), z_p.reshape(shape), lit.reshape(shape),
            shade.reshape(shape))


def _offsets(scene: Scene, origin: np.ndarray, n_rays: int) -> np.ndarray:
    """Per-face numerators when the scene has fewer faces than rays, else empty (the
    choice of :meth:`~scanqa.simulator.scene.Scene.cast`, so the same rounding)."""
    faces = scene.face_normals.shape[0]
    return scene.face_offsets(origin) if faces < n_rays else np.zeros(0)


@njit(cache=True, nogil=True)
def camera_rays32(origin: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(n, 6) float32 rays of one origin (3,) and directions (n, 3) [mm]."""
    n = d.shape[0]
    rays = np.empty((n, 6), np.float32)
    for i in range(n):
        for k in range(3):
            rays[i, k] = origin[k]
            rays[i, 3 + k] = d[i, k]
    return rays


@njit(cache=True, nogil=True, fastmath={"contract"})
def _row(r0: float, r1: float, r2: float, x0: float, x1: float, x2: float) -> float:
    """r . x with fused multiply-adds, as numpy's matmul (BLAS) sums it."""
    return (x0 * r0 + x1 * r1) + x2 * r2


@njit(cache=True, nogil=True, inline="always")
def _dot(n0: float, n1: float, n2: float, x0: float, x1: float, x2: float) -> float:
    """n . x summed as numpy's einsum('ij,ij->i') does: (0 + 2) + 1."""
    return (n0 * x0 + n2 * x2) + n1 * x1


@njit(cache=True, nogil=True, inline="always")
def _numerator(face_n: np.ndarray, face_offset: np.ndarray, face_v0: np.ndarray, f: int,
               o0: float, o1: float, o2: float) -> float:
    """``n . (v0 - origin)`` of face f: the per-face table when there is one (more rays
    than faces), else per ray, as :meth:`~scanqa.simulator.scene.Scene.cast` does."""
    if face_offset.size:
        return face_offset[f]
    return _dot(face_n[f, 0], face_n[f, 1], face_n[f, 2], face_v0[f, 0] - o0,
                face_v0[f, 1] - o1, face_v0[f, 2] - o2)


@njit(cache=True, nogil=True)
def light_hits(prim: np.ndarray, t32: np.ndarray, d: np.ndarray, origin: np.ndarray,
               face_n: np.ndarray, face_offset: np.ndarray, face_v0: np.ndarray,
               cam_centre: np.ndarray,
               cam_axis: np.ndarray, proj_centre: np.ndarray, proj_rot: np.ndarray,
               proj_f: float, proj_x0: float, proj_y0: float, width_px: float,
               height_px: float):
    """Refine camera hits in float64, project them and test their lighting.

    Parameters
    ----------
    prim, t32 : (n,) uint32, float32
        open3d's hit triangles and distances of the camera rays.
    d : (n, 3) float64
        Ray directions [mm]; ``origin`` (3,) their common origin [mm].
    face_n, face_offset, face_v0 : (F, 3), (F,) or (0,), (F, 3) float64
        Unit face normals, ``n . (v0 - origin)`` per face (empty: computed per ray from
        the faces' first vertices ``face_v0``) [mm].
    cam_centre, cam_axis : (3,) float64
        Camera centre [mm] and optical axis (device Z) [-].
    proj_centre, proj_rot : (3,), (3, 3) float64
        Projector centre [mm] and rotation (world to device rows) [-].
    proj_f, proj_x0, proj_y0 : float
        Principal distance and point of the projector [projector px] (1, 0, 0 give the
        normalised coordinates, for a distorted projector).
    width_px, height_px : float
        Panel size [projector px].

    Returns
    -------
    hit (n,) bool, world (n, 3), z_c, x_p, y_p, z_p, shade (n,) float64, candidate (n,)
    bool (hit, on the panel and facing the projector: lit unless shadowed) [mm],
    [projector px], [-].
    """
    n = d.shape[0]
    hit = np.zeros(n, np.bool_)
    cand = np.zeros(n, np.bool_)
    world = np.full((n, 3), np.nan)
    z_c = np.full(n, np.nan)
    x_p = np.full(n, np.nan)
    y_p = np.full(n, np.nan)
    z_p = np.full(n, np.nan)
    shade = np.zeros(n)
    for i in range(n):
        f = prim[i]
        if f == NO_HIT or not np.isfinite(t32[i]):
            continue
        hit[i] = True
        n0, n1, n2 = face_n[f, 0], face_n[f, 1], face_n[f, 2]
        t = (_numerator(face_n, face_offset, face_v0, f, origin[0], origin[1], origin[2])
             / _dot(n0, n1, n2, d[i, 0], d[i, 1], d[i, 2]))
        w0 = origin[0] + t * d[i, 0]
        w1 = origin[1] + t * d[i, 1]
        w2 = origin[2] + t * d[i, 2]
        world[i, 0], world[i, 1], world[i, 2] = w0, w1, w2
        c0, c1, c2 = w0 - cam_centre[0], w1 - cam_centre[1], w2 - cam_centre[2]
        z_c[i] = _row(cam_axis[0, 0], cam_axis[0, 1], cam_axis[0, 2], c0, c1, c2)
        p0, p1, p2 = w0 - proj_centre[0], w1 - proj_centre[1], w2 - proj_centre[2]
        q0 = _row(proj_rot[0, 0], proj_rot[0, 1], proj_rot[0, 2], p0, p1, p2)
        q1 = _row(proj_rot[1, 0], proj_rot[1, 1], proj_rot[1, 2], p0, p1, p2)
        q2 = _row(proj_rot[2, 0], proj_rot[2, 1], proj_rot[2, 2], p0, p1, p2)
        xp = proj_f * q0 / q2 + proj_x0
        yp = proj_f * q1 / q2 + proj_y0
        x_p[i], y_p[i], z_p[i] = xp, yp, q2
        dist = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        towards_cam = _dot(n0, n1, n2, -c0, -c1, -c2)
        s = _dot(n0, n1, n2, -p0, -p1, -p2) / dist
        if towards_cam < 0:
            s = -s
        shade[i] = s
        cand[i] = (q2 > 0 and xp >= -0.5 and xp <= width_px - 0.5 and yp >= -0.5
                   and yp <= height_px - 0.5 and s > 0)
    return hit, world, z_c, x_p, y_p, z_p, shade, cand


@njit(cache=True, nogil=True)
def shadow_rays32(world: np.ndarray, cand: np.ndarray, proj_centre: np.ndarray
                  ) -> np.ndarray:
    """(m, 6) float32 rays from the projector to the m candidate points [mm]."""
    m = 0
    for i in range(cand.shape[0]):
        m += cand[i]
    rays = np.empty((m, 6), np.float32)
    j = 0
    for i in range(cand.shape[0]):
        if cand[i]:
            for k in range(3):
                rays[j, k] = proj_centre[k]
                rays[j, 3 + k] = world[i, k] - proj_centre[k]
            j += 1
    return rays


@njit(cache=True, nogil=True)
def unshadowed(cand: np.ndarray, shade: np.ndarray, world: np.ndarray, prim: np.ndarray,
               t32: np.ndarray, proj_centre: np.ndarray, face_n: np.ndarray,
               face_offset: np.ndarray, face_v0: np.ndarray) -> np.ndarray:
    """Lit mask: candidates whose shadow ray (projector to point) is not blocked before
    the point (float64 distance >= 1 - 1e-7); ``shade`` is set to 0 where unlit.

    ``prim``, ``t32`` are open3d's answers for the rays of :func:`shadow_rays32`;
    ``face_offset`` is ``n . (v0 - proj_centre)`` per face or empty (as in
    :func:`light_hits`) [mm].
    """
    lit = np.zeros(cand.shape[0], np.bool_)
    j = 0
    for i in range(cand.shape[0]):
        if not cand[i]:
            shade[i] = 0.0
            continue
        f = prim[j]
        reach = True
        if f != NO_HIT and np.isfinite(t32[j]):
            d0 = world[i, 0] - proj_centre[0]
            d1 = world[i, 1] - proj_centre[1]
            d2 = world[i, 2] - proj_centre[2]
            t = (_numerator(face_n, face_offset, face_v0, f, proj_centre[0],
                            proj_centre[1], proj_centre[2])
                 / _dot(face_n[f, 0], face_n[f, 1], face_n[f, 2], d0, d1, d2))
            reach = not t < 1.0 - 1e-7  # NaN (parallel face) reaches, as np.nan_to_num(inf)
        j += 1
        lit[i] = reach
        if not reach:
            shade[i] = 0.0
    return lit


@njit(cache=True, nogil=True)
def add_fringe(radiance: np.ndarray, cos_h: np.float32, q_re: np.ndarray,
               sin_h: np.float32, q_im: np.ndarray) -> None:
    """``radiance += cos_h q_re; radiance -= sin_h q_im`` in one pass, float32 [e-]."""
    r, a, b = radiance.reshape(-1), q_re.reshape(-1), q_im.reshape(-1)
    for i in range(r.size):
        r[i] = (r[i] + cos_h * a[i]) - sin_h * b[i]


@njit(cache=True, nogil=True)
def add_cell_noise(radiance: np.ndarray, cells: np.ndarray, index: np.ndarray,
                   scale: np.ndarray) -> None:
    """``radiance += cells.ravel()[index] * scale`` in one pass, float32 [e-]."""
    r, c = radiance.reshape(-1), cells.reshape(-1)
    idx, s = index.reshape(-1), scale.reshape(-1)
    for i in range(r.size):
        r[i] += c[idx[i]] * s[i]


@njit(cache=True, nogil=True)
def add_pixel_means(out: np.ndarray, fine: np.ndarray, s: int) -> None:
    """``out += fine.reshape(n0, s, n1, s).mean(axis=(1, 3))`` in one pass, float32, in
    numpy's order (the sum of each supersample row's sum, then / s**2) [e-]."""
    count = np.float32(s * s)
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            acc = np.float32(0.0)
            for a in range(s):
                part = np.float32(0.0)
                for b in range(s):
                    part += fine[r * s + a, c * s + b]
                acc += part
            out[r, c] += acc / count


@njit(cache=True, nogil=True)
def noise_cells(world: np.ndarray, hit: np.ndarray, cell: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Cell indices ``floor(X / cell)``, ``floor(Y / cell)`` of every sample (n,) int64;
    a sample that sees nothing takes the first hit sample's cell (0 if none) [-]."""
    n = hit.shape[0]
    fx, fy = 0.0, 0.0
    for i in range(n):
        if hit[i]:
            fx, fy = world[i, 0], world[i, 1]
            break
    ix = np.empty(n, np.int64)
    iy = np.empty(n, np.int64)
    for i in range(n):
        x, y = (world[i, 0], world[i, 1]) if hit[i] else (fx, fy)
        ix[i] = np.int64(np.floor(x / cell))
        iy[i] = np.int64(np.floor(y / cell))
    return ix, iy


@njit(cache=True, nogil=True)
def _interp(x: float, xp: np.ndarray, fp: np.ndarray, slopes: np.ndarray,
            inv_step: float) -> float:
    """``np.interp(x, xp, fp)`` for a finite x >= xp[0] on an evenly spaced, increasing
    xp (``inv_step`` its inverse spacing, a first guess of the interval; ``slopes`` numpy's
    ``(fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])``): the same interval and the same
    arithmetic as numpy's [-]."""
    n = xp.shape[0]
    if x > xp[n - 1]:
        return fp[n - 1]
    j = min(max(int(x * inv_step), 0), n - 1)
    while j > 0 and xp[j] > x:
        j -= 1
    while j < n - 1 and xp[j + 1] <= x:
        j += 1
    if j == n - 1 or xp[j] == x:
        return fp[j]
    return slopes[j] * (x - xp[j]) + fp[j]


@njit(cache=True, nogil=True)
def phasor_parts(lit: np.ndarray, d_panel: np.ndarray, x_p: np.ndarray, harmonic: int,
                 period: float, table_u: np.ndarray, table_m: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Contrast ``M(pi d h / P)`` and fringe angle ``2 pi frac(h x_p / P)`` of lit samples
    (0 elsewhere), both float32, as the renderer's ``_phasor`` forms them [-], [rad]."""
    n = lit.shape[0]
    contrast = np.zeros(n, np.float32)
    angle = np.zeros(n, np.float32)
    scale = harmonic / period
    slopes = (table_m[1:] - table_m[:-1]) / (table_u[1:] - table_u[:-1])
    inv_step = (table_u.shape[0] - 1) / (table_u[-1] - table_u[0])
    for i in range(n):
        if lit[i]:
            contrast[i] = np.float32(_interp(np.pi * d_panel[i] * harmonic / period,
                                             table_u, table_m, slopes, inv_step))
            cycles = x_p[i] * scale
            angle[i] = np.float32((cycles - np.floor(cycles)) * (2.0 * np.pi))
    return contrast, angle


@njit(cache=True, nogil=True)
def ladder_groups(diameter: np.ndarray, hit: np.ndarray, d_step: float, d_lin: float,
                  log_ratio: float):
    """The hit samples sorted by their blur-ladder layer (a stable counting sort).

    ``diameter`` (n,) [supersamples] and ``hit`` (n,) are flat; the ladder position is
    ``d / d_step`` up to ``d_lin``, ``d_lin / d_step + log(d / d_lin) / log_ratio``
    beyond (``scanqa.simulator.blur.layer_coord``). Returns the flat indices (int64) and
    the fractions ``lam - floor(lam)`` of the samples in layer order (within a layer in
    flat order), the layers present and where each starts in those arrays.
    """
    lin = d_lin / d_step
    m = 0
    for i in range(hit.shape[0]):
        m += hit[i]
    lam = np.empty(m)
    flat = np.empty(m, np.int64)
    j = 0
    for i in range(hit.shape[0]):
        if hit[i]:
            d = diameter[i]
            if d <= d_lin:
                lam[j] = d / d_step
            else:
                lam[j] = lin + np.log(max(d, d_lin) / d_lin) / log_ratio
            flat[j] = i
            j += 1
    level = np.floor(lam).astype(np.int64)
    lo = level.min() if m else 0
    counts = np.zeros((level.max() - lo + 2) if m else 1, np.int64)
    for k in range(m):
        counts[level[k] - lo + 1] += 1
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    out_flat = np.empty(m, np.int64)
    out_frac = np.empty(m)
    for k in range(m):
        slot = fill[level[k] - lo]
        out_flat[slot] = flat[k]
        out_frac[slot] = lam[k] - level[k]
        fill[level[k] - lo] += 1
    present = np.flatnonzero(counts[1:]) if m else np.zeros(0, np.int64)
    return out_flat, out_frac, present + lo, starts[present], starts[present + 1]


#: splitmix64's constants (its finaliser's multipliers and the golden-ratio increment).
_M1, _M2, _GOLD = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB), \
    np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, nogil=True, inline="always")
def _mix64(x: np.uint64) -> np.uint64:
    """splitmix64 finaliser of one uint64 (wrapping arithmetic)."""
    x = x + _GOLD
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def hash_normal(key: int, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """Standard normal values that depend only on (key, ix, iy), float32 [-].

    A counter-based stream: splitmix64 of the 63-bit ``key`` and the int64 cell indices
    ``ix``, ``iy`` (any shape, the same for both) gives two uniforms, Box-Muller one
    normal; in float64, rounded to float32 once, in the order of :func:`hash_normal_numpy`.
    """
    x, y = ix.reshape(-1), iy.reshape(-1)
    out = np.empty(x.size, np.float32)
    k = np.uint64(key)
    for i in range(x.size):
        h = _mix64(_mix64(k ^ np.uint64(x[i])) ^ np.uint64(y[i]))
        h2 = _mix64(h)
        u1 = (np.float64(h >> np.uint64(11)) + 1.0) * 2.0 ** -53
        u2 = np.float64(h2 >> np.uint64(11)) * 2.0 ** -53
        out[i] = np.float32(np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2))
    return out.reshape(ix.shape)


# --------------------------------------------------------------- numpy twins (no numba)

def add_fringe_numpy(radiance: np.ndarray, cos_h: np.float32, q_re: np.ndarray,
                     sin_h: np.float32, q_im: np.ndarray) -> None:
    """:func:`add_fringe` in two numpy passes (the same float32 operations) [e-]."""
    radiance += cos_h * q_re
    radiance -= sin_h * q_im


def add_cell_noise_numpy(radiance: np.ndarray, cells: np.ndarray, index: np.ndarray,
                         scale: np.ndarray) -> None:
    """:func:`add_cell_noise` by numpy fancy indexing, float32 [e-]."""
    radiance += cells.reshape(-1)[index] * scale


def add_pixel_means_numpy(out: np.ndarray, fine: np.ndarray, s: int) -> None:
    """:func:`add_pixel_means` by numpy's mean over each pixel's s x s supersamples [e-]."""
    n0, n1 = out.shape
    out += fine[:n0 * s, :n1 * s].reshape(n0, s, n1, s).mean(axis=(1, 3), dtype=np.float32)


def noise_cells_numpy(world: np.ndarray, hit: np.ndarray, cell: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`noise_cells` in numpy passes (int64 cell indices) [-]."""
    first = np.flatnonzero(hit)
    fill = world[first[0], :2] if first.size else np.zeros(2)
    xy = np.where(hit[:, None], world[:, :2], fill[None, :])
    cells = np.floor(xy / cell).astype(np.int64)
    return cells[:, 0].copy(), cells[:, 1].copy()


def phasor_parts_numpy(lit: np.ndarray, d_panel: np.ndarray, x_p: np.ndarray,
                       harmonic: int, period: float, table_u: np.ndarray,
                       table_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`phasor_parts` by ``np.interp`` and float64 passes, float32 results [-], [rad]."""
    contrast = np.where(lit, np.interp(np.pi * d_panel * harmonic / period, table_u,
                                       table_m), 0.0).astype(np.float32)
    cycles = np.where(lit, x_p, 0.0) * (harmonic / period)
    angle = np.where(lit, (cycles - np.floor(cycles)) * (2.0 * np.pi), 0.0)
    return contrast, angle.astype(np.float32)


def ladder_groups_numpy(diameter: np.ndarray, hit: np.ndarray, d_step: float, d_lin: float,
                        log_ratio: float):
    """:func:`ladder_groups` by a stable numpy argsort of the ladder layers (the same
    flat indices and layers; fractions to rounding)."""
    flat = np.flatnonzero(hit)
    d = diameter[flat]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(d <= d_lin, d / d_step,
                       d_lin / d_step + np.log(np.maximum(d, d_lin) / d_lin) / log_ratio)
    level = np.floor(lam).astype(np.int64)
    order = np.argsort(level, kind="stable")
    flat, level, frac = flat[order], level[order], (lam - np.floor(lam))[order]
    present, start, count = np.unique(level, return_index=True, return_counts=True)
    return flat, frac, present, start, start + count


def _mix_numpy(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 arrays."""
    x = x + _GOLD
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


def hash_normal_numpy(key: int, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """:func:`hash_normal` in numpy passes over uint64 and float64 arrays [-]."""
    with np.errstate(over="ignore"):
        h = _mix_numpy(_mix_numpy(np.uint64(key) ^ ix.astype(np.int64).view(np.uint64))
                       ^ iy.astype(np.int64).view(np.uint64))
        h2 = _mix_numpy(h)
    u1 = ((h >> np.uint64(11)).astype(np.float64) + 1.0) * 2.0 ** -53
    u2 = (h2 >> np.uint64(11)).astype(np.float64) * 2.0 ** -53
    return (np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)).astype(np.float32)


#: The compiled loops and their numpy twins, by name.
NUMPY_TWINS = {"add_fringe": add_fringe_numpy, "add_cell_noise": add_cell_noise_numpy,
               "add_pixel_means": add_pixel_means_numpy, "noise_cells": noise_cells_numpy,
               "phasor_parts": phasor_parts_numpy, "ladder_groups": ladder_groups_numpy,
               "hash_normal": hash_normal_numpy}

if not compiled.HAVE_NUMBA:  # a Python loop over every sample would be far too slow
    globals().update(NUMPY_TWINS)
