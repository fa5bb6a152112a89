"""Compiled per-point loop of ``annotate`` (numba): table lookup, model and records in one pass.

``annotate`` (:mod:`scanqa.annotation.points`) took about a hundred numpy passes per band
of a 5 MP scan: the table lookup (the sheared phase, the node rows, four Hermite row
gathers and the blend; :func:`scanqa.calibration.lookup.apply_rows`), the optics model
per point (:func:`scanqa.model.optics.predict`, ~60 passes and two Bessel functions) and
the float32 attributes, transposed into the records. :func:`annotate_band` does all of
it in three loops over the band's points (the lookup and the blur ratios; the
attenuations; the model's scales, the attributes and the display fields), on the calling
thread with the GIL released (the band pool runs one per core), with a few band-sized
scratch arrays that stay in the core's cache, writing each record once.

The loop repeats numpy's arithmetic in numpy's order: the lookup's float32 blend of the
four nodes, its float64 Hermite cubic, each attribute rounded once to float32 from the
same float64 value. The model's chain (Eqs. 1-4, 13-19) it does not repeat: it calls
per point the equations :func:`scanqa.model.optics.optical_terms` calls on arrays
(:mod:`scanqa.model.equations`), the config one named record
(:class:`~scanqa.model.equations.ModelRecord`, :class:`Constants`). What differs is J1,
which numba cannot call from scipy: :func:`bessel_j1` sums its power series below x = 12
and the Hankel asymptotic expansion above (Eqs. 9.1.10 and 9.2.5 in [1]_), within 4e-16
of scipy's J1 on the main lobe of the attenuation, and the shear polynomial is summed in
another order than BLAS's, so an attribute may differ from the numpy path's by one
float32 rounding step. ``tests/test_annotkernels.py`` checks J1 and A(r) against scipy
and :func:`scanqa.model.optics.attenuation`, the model against
:func:`~scanqa.model.optics.predict` for every reading (to a tolerance from A's
agreement and the chain's roundings), and the records against the numpy path.

References
----------
.. [1] M. Abramowitz, I. A. Stegun, "Handbook of Mathematical Functions", Dover, 1965.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from scanqa.calibration.lookup import TableGrid
from scanqa.compiled import njit
from scanqa.model import equations, geometry, optics, readings
from scanqa.model.config import ScannerConfig
from scanqa.model.equations import ModelRecord

#: Below this argument J1 is its power series, above it the asymptotic expansion [-].
SERIES_LIMIT = 12.0
#: 1 / (k (k + 1)), the ratio of J1's series terms without a division per term [-].
_SERIES_STEP = 1.0 / (np.arange(1, 61) * np.arange(2, 62))
#: 2 J1(x) / x = sum_k c_k (x^2 / 4)^k, c_k = (-1)^k / (k! (k + 1)!) (Eq. 9.1.10 in the
#: module's reference), to k = 17: below :data:`POLYNOMIAL_LIMIT` the last term is
#: < 1e-19 [-].
_DISC_SERIES = np.array([(-1) ** k / (math.factorial(k) * math.factorial(k + 1))
                         for k in range(18)])
#: Largest pi r at which :func:`attenuations` uses the fixed polynomial [-] (the main
#: lobe, past the first zero 3.83, is below it).
POLYNOMIAL_LIMIT = 4.0
#: Columns of the attribute block (``scanqa.annotation.points.ATTRIBUTES`` order).
ATTRIBUTE_COLUMNS = ("sigma_total_um", "sx_um", "sy_um", "sz_um", "sigma_scene_um",
                     "sigma_sensor_um", "sigma_phase_um", "sigma_calibration_um",
                     "sigma_random_um", "sigma_model_um", "att_camera", "att_projector",
                     "filter_factor", "s_o", "s_t_um_px", "modulation_dn", "offset_dn",
                     "in_volume", "model_valid", "pixel_u", "pixel_v", "table_corr_mm",
                     "sigma_meas_um", "n_repeats")


@njit(cache=True, nogil=True)
def bessel_j1(x: float) -> float:
    """Bessel function of the first kind of order one, J1(x) [-].

    Parameters
    ----------
    x : float
        Argument [-].

    Returns
    -------
    float
        J1(x): the power series sum_k (-1)^k (x/2)^(2k+1) / (k! (k+1)!) for |x| < 12
        (Eq. 9.1.10 in the module's reference), else sqrt(2 / (pi x)) (P cos(x - 3 pi
        / 4) - Q sin(x - 3 pi / 4)) with P and Q the asymptotic series of Eq. 9.2.5 for
        mu = 4, summed to their smallest term; odd in x.

    Notes
    -----
    Within 4e-16 of scipy's J1 for |x| < 4 (the attenuation's main lobe), within 1e-12
    around the switch at 12 (the series' cancellation below, the asymptotic series'
    smallest term above) and 2e-16 from x = 20 (``tests/test_annotkernels.py``).
    """
    if x != x:
        return x
    a = abs(x)
    if a < SERIES_LIMIT:
        q = -0.25 * a * a
        term = 0.5 * a
        total = term
        for k in range(60):
            term *= q * _SERIES_STEP[k]
            total += term
            if abs(term) < 1e-17 * abs(total):
                break
        return total if x >= 0 else -total
    mu, z8 = 4.0, 8.0 * a
    p, q = 1.0, (mu - 1.0) / z8
    tp, tq, last = 1.0, q, 1.0
    for k in range(1, 40):  # up to the smallest term of the asymptotic series
        tp *= -(mu - (4 * k - 3) ** 2) * (mu - (4 * k - 1) ** 2) / ((2 * k - 1) * 2 * k * z8 * z8)
        tq *= -(mu - (4 * k - 1) ** 2) * (mu - (4 * k + 1) ** 2) / (2 * k * (2 * k + 1) * z8 * z8)
        size = max(abs(tp), abs(tq))
        if size >= last or size < 1e-18:
            break
        p += tp
        q += tq
        last = size
    phase = a - 0.75 * math.pi
    value = math.sqrt(2.0 / (math.pi * a)) * (p * math.cos(phase) - q * math.sin(phase))
    return value if x >= 0 else -value


@njit(cache=True, nogil=True)
def attenuation(r: float) -> float:
    """A(r) = (2 J1(pi r) / (pi r))^2, Eq. 12 (:func:`scanqa.model.optics.attenuation`) [-].

    ``r`` is the blur-to-period ratio [-]; A(0) = 1, NaN stays NaN.
    """
    x = abs(r) * math.pi
    if x < 1e-8:
        return 1.0 if x == x else x
    ratio = 2.0 * bessel_j1(x) / x
    return ratio * ratio


@njit(cache=True, nogil=True)
def attenuations(r: np.ndarray, out: np.ndarray) -> None:
    """:func:`attenuation` of every ratio ``r`` [-] into ``out`` [-].

    The main lobe (pi r < :data:`POLYNOMIAL_LIMIT`) is the fixed polynomial
    :data:`_DISC_SERIES` of (pi r / 2)^2 in a loop without branches, whose iterations
    the processor overlaps; the rest (and 0, NaN) goes through :func:`attenuation`.
    """
    n = r.size
    for i in range(n):
        x = abs(r[i]) * math.pi
        q = 0.25 * (x * x)
        p = _DISC_SERIES[17]
        for k in range(16, -1, -1):
            p = p * q + _DISC_SERIES[k]
        out[i] = p * p
    for i in range(n):
        x = abs(r[i]) * math.pi
        if not (1e-8 <= x < POLYNOMIAL_LIMIT):
            out[i] = attenuation(r[i])


class Constants(NamedTuple):
    """What annotate adds to the model's record (:func:`model_parameters`).

    The projector's position [mm] and its rotation's third row [-] (Z_p of a point); the
    systematic sigma [mm]; the table's correlation length [camera px] (NaN without one)
    and the camera's principal distance [px]; whether the random sigma is s_T times a
    phase sigma per point (else the model's).
    """

    position_mm: tuple
    rz: tuple
    systematic_mm: float
    table_corr_px: float
    principal_px: float
    random_phase: bool


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ratios(x: float, y: float, z: float, m: ModelRecord, run: Constants) -> tuple:
    """C_c [mm] and the blur ratios r_c, r_p [-] of one point (Eqs. 1-4)."""
    z_p = geometry.depth_along(x, y, z, run.rz, run.position_mm)
    _, coc_c, r_c, r_p = equations.blur_ratios(z, z_p, m)
    return coc_c, r_c, r_p


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _scales(z: float, coc_c: float, r_c: float, r_p: float, a_c: float, a_p: float,
            s_t: float, m: ModelRecord) -> tuple:
    """F_gamma, s_O [-], sigma, its scene and sensor parts [mm] and the validity of one
    point from its ratios and attenuations (Eqs. 13-19 and the readings)."""
    c_image = equations.image_blur(z, m.cam_focal_mm, coc_c) if z > m.cam_focal_mm \
        else np.nan
    f = equations.filter_factors(z, c_image, m)[2]
    scene, sensor = optics.scales_by_code(f, a_p, a_c, m.reading, m.sensor_ratio)
    if r_c >= optics.FIRST_ZERO_RATIO or r_p >= optics.FIRST_ZERO_RATIO:
        scene, sensor = np.nan, np.nan
    s_o = equations.optical_scale_of(scene, sensor, m)
    sigma, scene, sensor, valid = equations.point_sigma(s_t, s_o, scene, sensor, r_c, r_p, m)
    return f, s_o, sigma, scene, sensor, valid


def model_parameters(config: ScannerConfig, random: str = "model",
                     table_corr_px: float = np.nan) -> tuple[ModelRecord, Constants]:
    """The config's numbers and readings as :func:`annotate_band` takes them: the
    model's record (:func:`scanqa.model.equations.model_record`) and annotate's, with
    the random sigma's source ``random`` (``scanqa.annotation.points.sigma_source``) and
    the table's correlation length ``table_corr_px`` [camera px] (NaN without one)."""
    proj = config.projector
    rz = geometry.projector_rotation(proj)[2]
    return equations.model_record(config), Constants(
        tuple(float(v) for v in proj.position_mm), tuple(float(v) for v in rz),
        float(config.model.systematic_sigma_mm), float(table_corr_px),
        float(config.camera.principal_distance_px), random != "model")


@njit(cache=True, nogil=True)
def model_points(points: np.ndarray, s_t: np.ndarray, m: ModelRecord,
                 run: Constants) -> np.ndarray:
    """The model at ``points`` (n, 3) [mm] with triangulation scales ``s_t`` (n,) [mm / px]
    as the loop forms it, for :func:`~scanqa.model.optics.predict` to check: (n, 8), A_c,
    A_p, F_gamma, s_O [-], sigma, its scene and sensor parts [mm], valid (0/1)."""
    out = np.empty((points.shape[0], 8))
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        coc_c, r_c, r_p = _ratios(x, y, z, m, run)
        a_c, a_p = attenuation(r_c), attenuation(r_p)
        f, s_o, sigma, scene, sensor, valid = _scales(z, coc_c, r_c, r_p, a_c, a_p, s_t[i], m)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = a_c, a_p, f, s_o
        out[i, 4], out[i, 5], out[i, 6], out[i, 7] = sigma, scene, sensor, valid
    return out


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lookup_point(s: float, base: int, w0: np.float32, w1: np.float32, w2: np.float32,
                  w3: np.float32, coef: np.ndarray, pk: np.ndarray,
                  n_s: int, corners: np.ndarray) -> tuple:
    """Z [mm], dZ/dx_p [mm / px] and the table sigma [mm] of one point: the float32
    blend of its cell's 4 nodes and the float64 cubic
    (``scanqa.calibration.lookup._hermite``)."""
    fs = (s - pk[1]) / pk[2]
    seg = 0.0 if not fs >= 0.0 else fs  # np.fmax: NaN -> segment 0
    seg = math.floor(min(seg, n_s - 2.0))
    ts = fs - seg
    row = base + int(seg)
    a = row + corners[0]
    c0, c1, c2, c3 = coef[a, 0] * w0, coef[a, 1] * w0, coef[a, 2] * w0, coef[a, 3] * w0
    c4, c5 = coef[a, 4] * w0, coef[a, 5] * w0
    for j, wj in ((1, w1), (2, w2), (3, w3)):
        a = row + corners[j]
        c0 += coef[a, 0] * wj
        c1 += coef[a, 1] * wj
        c2 += coef[a, 2] * wj
        c3 += coef[a, 3] * wj
        c4 += coef[a, 4] * wj
        c5 += coef[a, 5] * wj
    d0, d1, d2, d3 = np.float64(c0), np.float64(c1), np.float64(c2), np.float64(c3)
    z = pk[0] + d0 + ts * (d1 + ts * (d2 + ts * d3))
    dz = (d1 + ts * (2 * d2 + 3 * ts * d3)) / pk[2]
    return z, dz, np.float64(c4) + ts * np.float64(c5)


@njit(cache=True, nogil=True, error_model="numpy")
def annotate_band(xp: np.ndarray, select: np.ndarray, row0: int, grid: tuple, table: tuple,
                  extrapolate: bool, per_point: tuple, m: ModelRecord, run: Constants,
                  xyz: np.ndarray, words: np.ndarray, floats: np.ndarray,
                  grey: float) -> int:
    """Look up, model and write the kept points of one band of image rows.

    Parameters
    ----------
    xp : (rows, W) float
        The band's phase [projector px].
    select : (n,) intp
        Flat indices of the kept pixels in the band; empty when every pixel is kept.
    row0 : int
        Image row of the band's first row [px].
    grid : tuple
        The table's image constants (:func:`grid_arrays`) and the band's shear rows.
    table : tuple
        Packed Hermite rows (n, 6) float32, (z_off [mm], s0 [px], h [px]), n_s, the
        4 corner offsets (:class:`scanqa.calibration.lookup.Packed`).
    extrapolate : bool
        Keep the values of points outside the calibrated range (else NaN).
    per_point : tuple of (n,) float
        Modulation, offset [DN], decoder sigma_xp [px], the random source's phase sigma
        [px], the repeats' std [mm] and count (empty arrays without repeats).
    m, run : ModelRecord, Constants
        :func:`model_parameters` (with the table's correlation).
    xyz : (n, 3) float64
        The points, written [mm] (the caller copies them into the records).
    words, floats : (n, m) uint32, float32
        Two views of C-contiguous records (:func:`scanqa.io.ply.vertex_dtype`) as 4-byte
        words: the attributes (words 6.., :data:`ATTRIBUTE_COLUMNS` order) are written,
        and with ``grey`` >= 0 the display fields, the last two words
        (:func:`scanqa.io.ply.fill_display`). Plain aligned arrays, so that numba
        compiles one signature whatever the output file's header length.
    grey : float
        The cloud's grey scale (:func:`scanqa.io.ply.display_scale`) [1/DN], or -1.

    Returns
    -------
    int
        Points outside the model's validity.
    """
    col, tu, row, iv, tv, along, step, lo, hi, shear_rows, shear_u = grid
    coef, pk, n_s, corners = table
    width, n = xp.shape[1], xyz.shape[0]
    block = floats[:, 6:]
    deg = shear_u.shape[0]
    slope, sig_tab, pixel = np.empty((n, 3)), np.empty(n), np.empty((n, 2), dtype=np.intp)
    inside, ratio, coc = np.empty(n, dtype=np.bool_), np.empty((2, n)), np.empty(n)
    for i in range(n):  # the lookup and the blur ratios
        p = i if select.size == 0 else select[i]
        b, cu = p // width, p % width
        r = row0 + b
        shear = 0.0
        for k in range(deg):
            shear += shear_rows[b, k] * shear_u[k, cu]
        s = xp[b, cu] - shear
        j = iv[r]
        inside[i] = s >= lo[j, cu] and s <= hi[j, cu]
        v1, u1 = tv[r], tu[cu]
        v0, u0 = 1 - v1, 1 - u1
        lat1 = along[1, j, cu] + v1 * step[1, j, cu]
        lat3 = along[3, j, cu] + v1 * step[3, j, cu]
        z, dz, sig = _lookup_point(s, row[r] + col[cu], np.float32(v0 * u0),
                                   np.float32(v0 * u1), np.float32(v1 * u0),
                                   np.float32(v1 * u1), coef, pk, n_s, corners)
        x = along[0, j, cu] + v1 * step[0, j, cu] + lat1 * z
        y = along[2, j, cu] + v1 * step[2, j, cu] + lat3 * z
        slope[i, 0], slope[i, 1], slope[i, 2] = lat1 * dz, lat3 * dz, dz
        if not extrapolate and not inside[i]:
            x = y = z = sig = np.nan
            slope[i, 0] = slope[i, 1] = slope[i, 2] = np.nan
        xyz[i, 0], xyz[i, 1], xyz[i, 2] = x, y, z
        sig_tab[i], pixel[i, 0], pixel[i, 1] = sig, cu, r
        coc[i], ratio[0, i], ratio[1, i] = _ratios(x, y, z, m, run)
    att = np.empty((2, n))
    attenuations(ratio[0], att[0])
    attenuations(ratio[1], att[1])
    mod, off, sxp, phase, std, count = per_point
    invalid = 0
    for i in range(n):  # the model's scales and the records
        invalid += _fill_record(i, xyz[i, 2], slope[i, 0], slope[i, 1], slope[i, 2],
                                sig_tab[i], inside[i], pixel[i, 0], pixel[i, 1], coc[i],
                                ratio[0, i], ratio[1, i], att[0, i], att[1, i], mod[i],
                                off[i], sxp[i], phase[i] if run.random_phase else 0.0, m,
                                run, block)
    if std.size:
        for i in range(n):
            block[i, 22], block[i, 23] = std[i] * 1e3, count[i]
    if grey >= 0:
        _fill_display(block, words, floats, grey)
    return invalid


@njit(cache=True, nogil=True)
def _fill_display(block: np.ndarray, words: np.ndarray, floats: np.ndarray,
                  grey: float) -> None:
    """The display fields of records from their ``offset_dn`` (column 16 of ``block``)
    and the grey scale ``grey`` [1/DN]: the 16-bit level (``scanqa.io.las.scaled_grey``:
    NaN as 0, rounded half to even, clipped) as float32 intensity, and red = green =
    blue = its top 8 bits with alpha 255, as ``scanqa.io.ply_display`` packs them."""
    last = words.shape[1] - 1
    for i in range(block.shape[0]):
        level = np.float64(block[i, 16])
        level = np.rint((0.0 if level != level else level) * grey)
        level = min(max(level, 0.0), 65535.0)
        g = np.uint32(level)
        floats[i, last - 1] = np.float32(g)
        words[i, last] = (g >> np.uint32(8)) * np.uint32(0x010101) + np.uint32(0xFF000000)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _fill_record(i: int, z: float, sx: float, sy: float, sz: float, sig_tab: float,
                 inside: bool, u: int, v: int, coc_c: float, r_c: float, r_p: float,
                 a_c: float, a_p: float, mod: float, off: float, sxp: float, phase: float,
                 m: ModelRecord, run: Constants, block: np.ndarray) -> int:
    """The attributes of record ``i`` (``scanqa.annotation.points._annotate_points``) from
    its lookup and blur ratios, but the repeats' two; returns 1 where the model is not
    valid, else 0."""
    s_t = math.sqrt(sx * sx + sy * sy + sz * sz)
    f, s_o, sigma, scene, sensor, valid = _scales(z, coc_c, r_c, r_p, a_c, a_p, s_t, m)
    if not valid:
        sigma = scene = sensor = np.nan
    random = s_t * phase if run.random_phase else sigma
    um, random_um = 1e3 * s_t, 1e3 * random
    block[i, 9], block[i, 4], block[i, 5] = sigma * 1e3, scene * 1e3, sensor * 1e3
    block[i, 6], block[i, 7], block[i, 8] = um * sxp, sig_tab * 1e3, random_um
    total = random * random
    total += sig_tab * sig_tab
    total += run.systematic_mm * run.systematic_mm
    block[i, 0] = math.sqrt(total) * 1e3  # first: the field viewers colour by by default
    block[i, 1], block[i, 2], block[i, 3] = random_um * abs(sx / s_t), random_um * abs(sy / s_t), \
        random_um * abs(sz / s_t)
    block[i, 10], block[i, 11], block[i, 12], block[i, 13], block[i, 14] = a_c, a_p, f, s_o, um
    block[i, 15], block[i, 16], block[i, 17], block[i, 18] = mod, off, 1.0 if inside else 0.0, \
        1.0 if valid else 0.0
    block[i, 19], block[i, 20], block[i, 21] = u, v, run.table_corr_px * z / run.principal_px
    return 0 if valid else 1


def table_arrays(table: TableGrid) -> tuple[tuple, tuple]:
    """A calibration table's lookup constants as :func:`annotate_band` takes them: the
    image grid (without the band's shear rows) and the packed Hermite rows."""
    g, p = table.image_grid, table.packed
    grid = (g.col, g.tu, g.row, g.iv, g.tv, g.along_u, g.step_v, g.lo, g.hi)
    pk = np.array([p.z_off, p.s0, p.h])
    return grid, (p.coef, pk, int(p.n_s), np.asarray(p.corners, dtype=np.intp))


def shear_rows(grid_u: np.ndarray, shear_c: np.ndarray, rows: range, height: int
               ) -> np.ndarray:
    """Per-row factors of the shear polynomial on image ``rows``: (rows, d + 1), whose
    product with the per-column powers ``grid_u`` (d + 1, W) is the shear [px]
    (``scanqa.calibration.lookup._band_shear``)."""
    vn = 2.0 * np.asarray(rows, dtype=float) / max(height - 1, 1) - 1.0
    return (vn[:, None] ** np.arange(grid_u.shape[0])[None, :]) @ shear_c.T


def load() -> None:
    """Load :func:`annotate_band` for the argument types ``annotate`` gives it, from
    numba's cache (compiled there on a first run, 8-9 s of CPU): numba's one-time start
    of a process, 0.4-0.6 s of CPU, which a benchmark can keep out of the annotate it
    times."""
    f8, ip = np.zeros(1), np.zeros(1, dtype=np.intp)
    plane = np.zeros((1, 1))
    grid = (ip, f8, ip, ip, f8, np.zeros((4, 1, 1)), np.zeros((4, 1, 1)), plane, plane,
            plane, plane)
    table = (np.zeros((2, 6), dtype=np.float32), np.array([0.0, 0.0, 1.0]), 2,
             np.zeros(4, dtype=np.intp))
    words = np.zeros((1, 6 + len(ATTRIBUTE_COLUMNS) + 2), dtype=np.uint32)
    phases = plane.view()
    phases.flags.writeable = False  # as ``annotate`` passes them
    annotate_band(phases, np.empty(0, dtype=np.intp), 0, grid, table, False, (f8,) * 6,
                  ModelRecord(*(1.0,) * 13, 0, 0, 0),
                  Constants((0.0,) * 3, (0.0,) * 3, 0.0, 0.0, 1.0, False), np.zeros((1, 3)),
                  words, words.view(np.float32), -1.0)


def stamp_equations(*functions: object) -> None:
    """Key numba's cache of ``functions`` by the equations they inline too.

    numba keeps a compiled function while its own file is unchanged, not the files of the
    functions it calls; the loop inlines :mod:`scanqa.model.equations`,
    :mod:`~scanqa.model.readings` and :mod:`~scanqa.model.geometry`, so their sources
    join the stamp numba compares, and a change of an equation compiles the loop again.
    """
    digest = hashlib.sha256(b"".join(Path(m.__file__).read_bytes()
                                     for m in (equations, readings, geometry))).hexdigest()
    for func in functions:  # numba's own cache record; none without numba
        cache_file = getattr(getattr(func, "_cache", None), "_cache_file", None)
        if cache_file is not None:
            cache_file._source_stamp = (cache_file._source_stamp, digest)


stamp_equations(annotate_band, model_points)
