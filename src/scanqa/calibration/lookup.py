"""Applying a calibration table: bilinear in (u, v), cubic Hermite in s (docs/calibration.rst).

The table (:class:`scanqa.calibration.table.CalibrationTable`, or anything with its arrays:
:class:`TableGrid`) is rearranged once for lookups:

* :class:`Packed` holds per (node, s segment) the Hermite coefficients of Z and the
  table's sigma as float32 rows (half the memory traffic of the gathers; Z is stored
  relative to its mean so that the rounding stays below 10 nm over a +-100 mm sweep), the
  lateral ray X = X0 + kx Z, Y = Y0 + ky Z per node, and per cell the phase range that all
  four nodes were calibrated for.
* :class:`ImageGrid` exploits the structure of a whole image: every pixel of a column
  shares its node column and u weight, every pixel of a row its node row and v weight, so
  the lateral coefficients are interpolated along u once per node row and then only
  blended between two node rows per image row, and the shear x_shear(u, v)
  (:mod:`scanqa.calibration.shear`) is a product of per-row and per-column power tables; no
  per-pixel gathers but the four Hermite rows.

Images are processed in bands of rows on every core (:mod:`scanqa.chunks`);
:func:`apply_rows` is the building block that chunked pipelines (``annotate``) call
directly, so that a scan never needs full-size intermediate arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scanqa.calibration.shear import DEGREE, eval_shear
from scanqa.chunks import row_bands, run_bands
from scanqa.errors import InputError


class TableGrid(Protocol):
    """What a lookup needs of a table (:class:`~scanqa.calibration.table.CalibrationTable`
    has it): the node grid, its values and the cached lookup constants."""

    node_u: np.ndarray
    node_v: np.ndarray
    x_ref: np.ndarray
    s_nodes: np.ndarray
    xyz: np.ndarray
    dxyz: np.ndarray
    sigma_node: np.ndarray
    s_lo: np.ndarray
    s_hi: np.ndarray
    shear: np.ndarray
    width_px: int
    height_px: int

    @property
    def cell_px(self) -> float: ...

    @property
    def packed(self) -> Packed: ...

    @property
    def image_grid(self) -> ImageGrid: ...


@dataclass(frozen=True)
class TableLookup:
    """Result of applying a table: arrays shaped like the query."""

    xyz: np.ndarray          # (..., 3) [mm]
    slope: np.ndarray        # (..., 3) dQ/dx_p [mm / projector px]
    sigma_table: np.ndarray  # (...,) table's own std along the line of sight [mm]
    in_volume: np.ndarray    # (...,) bool: phase inside the pixel's calibrated range

    @property
    def s_t(self) -> np.ndarray:
        """Triangulation scale |dQ/dx_p| [mm / projector px]."""
        return np.linalg.norm(self.slope, axis=-1)


def check_rows(xp: np.ndarray, row0: int, width_px: int, height_px: int, whole: bool,
               camera: str, built_for: str) -> None:
    """Raise unless ``xp`` is rows row0.. (``whole``: all rows) of a phase map of a
    ``width_px`` x ``height_px`` camera [px]; ``camera`` ("the table's camera") and
    ``built_for`` ("the table was built for") name the calibration in the messages.

    Raises
    ------
    InputError
        Rows outside the camera, or a phase map of another size.
    """
    if xp.ndim == 2 and xp.shape[1] == width_px and not whole:
        if 0 <= row0 and row0 + xp.shape[0] <= height_px:
            return
        raise InputError(f"rows {row0} to {row0 + xp.shape[0] - 1} are outside the "
                         f"{height_px} rows of {camera}")
    if xp.shape != (height_px, width_px):
        shape = " x ".join(str(n) for n in xp.shape[::-1])
        raise InputError(f"phase map is {shape} px but {built_for} a {width_px} x "
                         f"{height_px} px camera")


def empty_lookup(shape: tuple[int, ...]) -> TableLookup:
    """Uninitialised lookup arrays for a query of ``shape``."""
    return TableLookup(np.empty((*shape, 3)), np.empty((*shape, 3)), np.empty(shape),
                       np.empty(shape, dtype=bool))


def _flat(look: TableLookup, rows: slice = slice(None)) -> TableLookup:
    """Views of ``look`` (rows ``rows`` of an image lookup) as 1-D point arrays."""
    return TableLookup(look.xyz[rows].reshape(-1, 3), look.slope[rows].reshape(-1, 3),
                       look.sigma_table[rows].reshape(-1), look.in_volume[rows].reshape(-1))


# --------------------------------------------------------------------------- packing


@dataclass(frozen=True)
class Packed:
    """A table rearranged for fast lookups (module notes)."""

    coef: np.ndarray   # (n_v n_u n_s, 6) float32: Z - z_off, 3 cubic terms, sigma, d sigma
    z_off: float       # [mm]
    lat: np.ndarray    # (n_v n_u, 4): X0 [mm], kx [-], Y0 [mm], ky [-]
    lo: np.ndarray     # (n_v - 1, n_u - 1): highest s_lo of a cell's 4 nodes [px]
    hi: np.ndarray     # (n_v - 1, n_u - 1): lowest s_hi of a cell's 4 nodes [px]
    s0: float          # first node of the s grid [px]
    h: float           # s node spacing [px]
    n_s: int           # s nodes
    corners: tuple     # coef row offsets of a cell's 4 nodes from its lower-left one


def pack(t: TableGrid) -> Packed:
    """Hermite coefficients per (node, segment), lateral rays per node, phase range per cell.

    Parameters
    ----------
    t : CalibrationTable
        The table.

    Returns
    -------
    Packed
        Coefficient row ``(i_v n_u + i_u) n_s + k`` holds segment k of node (i_v, i_u).
    """
    h = t.s_nodes[1] - t.s_nodes[0]
    z_off = float(np.nanmean(t.xyz[..., 2]))
    coef = np.empty((*t.sigma_node.shape, 6), dtype=np.float32)
    for i in range(coef.shape[0]):  # per node row: temporaries stay in cache
        coef[i] = _segments(t.xyz[i, ..., 2], t.dxyz[i, ..., 2] * h, t.sigma_node[i], z_off)
    n_u, n_s = t.node_u.size, t.s_nodes.size
    corners = (0, n_s, n_u * n_s, (n_u + 1) * n_s)
    return Packed(coef.reshape(-1, 6), z_off, _lateral_rays(t), *_cell_range(t),
                  float(t.s_nodes[0]), float(h), n_s, corners)


def _segments(z: np.ndarray, dz: np.ndarray, sig: np.ndarray, z_off: float) -> np.ndarray:
    """Cubic Hermite coefficients of Z on every s segment, and the sigma at its ends.

    Parameters
    ----------
    z : (..., n_s) float
        Z at the s nodes [mm].
    dz : (..., n_s) float
        dZ/ds times the node spacing [mm].
    sig : (..., n_s) float
        Table sigma at the nodes [mm].
    z_off : float
        Offset subtracted from Z [mm].

    Returns
    -------
    (..., n_s, 6) float32
        Z(t) - z_off = c0 + c1 t + c2 t^2 + c3 t^3 and sigma(t) = c4 + c5 t on [0, 1]
        (the last segment wraps around and is never used).
    """
    p0, p1 = z, np.roll(z, -1, axis=-1)
    m0, m1 = dz, np.roll(dz, -1, axis=-1)
    return np.stack([p0 - z_off, m0, -3 * p0 + 3 * p1 - 2 * m0 - m1,
                     2 * p0 - 2 * p1 + m0 + m1, sig, np.roll(sig, -1, axis=-1) - sig],
                    -1).astype(np.float32)


def _lateral_rays(t: TableGrid) -> np.ndarray:
    """X0, kx, Y0, ky per node from the centre of its s grid: (n_v n_u, 4)."""
    centre = t.s_nodes.size // 2
    with np.errstate(invalid="ignore", divide="ignore"):
        kx = t.dxyz[..., centre, 0] / t.dxyz[..., centre, 2]
        ky = t.dxyz[..., centre, 1] / t.dxyz[..., centre, 2]
    zc = t.xyz[..., centre, 2]
    return np.stack([t.xyz[..., centre, 0] - kx * zc, kx, t.xyz[..., centre, 1] - ky * zc, ky],
                    -1).reshape(-1, 4)


def _cell_range(t: TableGrid) -> tuple[np.ndarray, np.ndarray]:
    """The s range calibrated at all 4 nodes of each cell [px]; NaN if any node has none."""
    def corners(a: np.ndarray) -> list[np.ndarray]:
        return [a[:-1, :-1], a[:-1, 1:], a[1:, :-1], a[1:, 1:]]

    return np.maximum.reduce(corners(t.s_lo)), np.minimum.reduce(corners(t.s_hi))


def node_index(t: TableGrid, coord: np.ndarray, axis: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """Lower node index and fraction along u (axis 1) or v (axis 0).

    Returns
    -------
    i : intp ndarray
        Node below ``coord``, clipped so that i + 1 is a node (extrapolation at the edges).
    t : ndarray
        (coord - node_i) / cell [-].
    """
    nodes = t.node_u if axis == 1 else t.node_v
    f = (coord - nodes[0]) / t.cell_px
    i = np.clip(np.floor(f), 0, max(nodes.size - 2, 0)).astype(np.intp)
    return i, f - i


# --------------------------------------------------------------------------- kernel


def _hermite(p: Packed, s: np.ndarray, base: np.ndarray, weights: list[np.ndarray]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z, dZ/dx_p and the table sigma of points, blended over their cell's 4 nodes.

    Parameters
    ----------
    p : Packed
        The packed table.
    s : (n,) float
        Sheared phase x_p - x_ref [projector px].
    base : (n,) intp
        Coefficient row of segment 0 of each point's lower-left node.
    weights : list of 4 (n,) float32
        Bilinear weights of the nodes at ``p.corners`` [-].

    Returns
    -------
    z : (n,) float
        Z [mm] (extrapolated past the s grid).
    dz : (n,) float
        dZ/dx_p [mm / projector px].
    sigma : (n,) float
        The table's sigma [mm].
    """
    fs = (s - p.s0) / p.h
    seg = np.floor(np.fmin(np.fmax(fs, 0.0), p.n_s - 2))  # fmax: NaN -> segment 0
    ts = fs - seg
    row = base + seg.astype(np.intp)
    c = np.empty((s.size, 6), dtype=np.float32)
    g = np.empty_like(c)
    for k, (off, w) in enumerate(zip(p.corners, weights, strict=True)):
        # np.take is several times faster than fancy indexing for row gathers
        np.take(p.coef, row + off, axis=0, out=g)
        if k == 0:
            np.multiply(g, w[:, None], out=c)
        else:
            c += np.multiply(g, w[:, None], out=g)
    c = c.astype(np.float64)
    z = p.z_off + c[:, 0] + ts * (c[:, 1] + ts * (c[:, 2] + ts * c[:, 3]))
    dz = (c[:, 1] + ts * (2 * c[:, 2] + 3 * ts * c[:, 3])) / p.h
    return z, dz, c[:, 4] + ts * c[:, 5]


def _store(z, dz, sigma, lat, inside, extrapolate: bool, out: TableLookup) -> None:
    """Write one chunk's points into the (n,)-shaped views ``out``.

    ``lat`` are X0, kx, Y0, ky per point; points outside the calibrated range are NaN
    unless ``extrapolate``.
    """
    x0, kx, y0, ky = lat
    out.xyz[:, 0] = x0 + kx * z
    out.xyz[:, 1] = y0 + ky * z
    out.xyz[:, 2] = z
    out.slope[:, 0] = kx * dz
    out.slope[:, 1] = ky * dz
    out.slope[:, 2] = dz
    out.sigma_table[:] = sigma
    out.in_volume[:] = inside
    if not extrapolate and not inside.all():
        outside = ~inside
        out.xyz[outside] = np.nan
        out.slope[outside] = np.nan
        out.sigma_table[outside] = np.nan


# --------------------------------------------------------------------------- points


def apply_points(t: TableGrid, u: np.ndarray, v: np.ndarray, xp: np.ndarray,
                 extrapolate: bool) -> TableLookup:
    """Lookup of arbitrary (u, v, x_p) of one shape, in chunks on every core."""
    shape = xp.shape
    u, v, xp = u.ravel(), v.ravel(), xp.ravel()
    out = empty_lookup((u.size,))
    t.packed  # noqa: B018 - computed once, before the threads share it

    def chunk(a: int, b: int) -> None:
        _points(t, u[a:b], v[a:b], xp[a:b], extrapolate, _flat(out, slice(a, b)))

    run_bands(chunk, row_bands(u.size, 1))
    return TableLookup(out.xyz.reshape(*shape, 3), out.slope.reshape(*shape, 3),
                       out.sigma_table.reshape(shape), out.in_volume.reshape(shape))


def _points(t: TableGrid, u, v, xp, extrapolate: bool, out: TableLookup) -> None:
    """One chunk of :func:`apply_points`: every node quantity gathered per point."""
    p = t.packed
    n_u = t.node_u.size
    iu, tu = node_index(t, u, 1)
    iv, tv = node_index(t, v, 0)
    node = iv * n_u + iu
    weights = ((1 - tv) * (1 - tu), (1 - tv) * tu, tv * (1 - tu), tv * tu)
    offsets = (0, 1, n_u, n_u + 1)
    s = xp - eval_shear(t.shear, u, v, (t.width_px, t.height_px))
    cell = iv * (n_u - 1) + iu
    with np.errstate(invalid="ignore"):
        inside = (s >= np.take(p.lo, cell)) & (s <= np.take(p.hi, cell))
    lat = sum(w[:, None] * np.take(p.lat, node + o, axis=0)
              for o, w in zip(offsets, weights, strict=True))
    z, dz, sig = _hermite(p, s, node * p.n_s, [w.astype(np.float32) for w in weights])
    _store(z, dz, sig, lat.T, inside, extrapolate, out)


# --------------------------------------------------------------------------- images


@dataclass(frozen=True)
class ImageGrid:
    """Interpolation constants of every row and column of the table's camera."""

    col: np.ndarray      # (W,) intp: i_u n_s, coef row of a column's left node
    tu: np.ndarray       # (W,) fraction along u [-]
    row: np.ndarray      # (H,) intp: i_v n_u n_s
    iv: np.ndarray       # (H,) intp: node row above each image row
    tv: np.ndarray       # (H,) fraction along v [-]
    along_u: np.ndarray  # (4, n_v, W): X0, kx, Y0, ky interpolated along u
    step_v: np.ndarray   # (4, n_v - 1, W): their change to the next node row
    lo: np.ndarray       # (n_v - 1, W): cell's lowest calibrated s per column [px]
    hi: np.ndarray       # (n_v - 1, W): cell's highest calibrated s per column [px]
    shear_u: np.ndarray  # (d + 1, W): powers of the normalised column coordinate
    shear_c: np.ndarray  # (d + 1, d + 1): shear coefficients c[i, j] of u^i v^j


def image_grid(t: TableGrid) -> ImageGrid:
    """Per-column and per-row constants for whole-image lookups (module notes)."""
    p = t.packed
    n_v, n_u = t.x_ref.shape
    iu, tu = node_index(t, np.arange(t.width_px, dtype=float), 1)
    iv, tv = node_index(t, np.arange(t.height_px, dtype=float), 0)
    nodes = p.lat.reshape(n_v, n_u, 4).transpose(2, 0, 1)  # the shear is a polynomial
    along = (1 - tu) * nodes[..., iu] + tu * nodes[..., iu + 1]
    # C order: np.take copies a non-contiguous source whole on every call
    along, step, lo, hi = (np.ascontiguousarray(a) for a in
                           (along, np.diff(along, axis=1), p.lo[:, iu], p.hi[:, iu]))
    un = 2.0 * np.arange(t.width_px) / max(t.width_px - 1, 1) - 1.0
    coef = np.zeros((DEGREE + 1, DEGREE + 1))
    k = 0
    for i in range(DEGREE + 1):
        for j in range(DEGREE + 1 - i):
            coef[i, j] = t.shear[k]
            k += 1
    return ImageGrid(iu * p.n_s, tu, iv * n_u * p.n_s, iv, tv, along, step, lo, hi,
                     np.ascontiguousarray(un[None, :] ** np.arange(DEGREE + 1)[:, None]),
                     coef)


def _band_shear(g: ImageGrid, rows: slice, height: int) -> np.ndarray:
    """The shear polynomial on image rows ``rows``: (rows, W) [projector px]."""
    r = np.arange(height)[rows]
    vn = 2.0 * r / max(height - 1, 1) - 1.0
    per_row = (vn[:, None] ** np.arange(DEGREE + 1)[None, :]) @ g.shear_c.T  # (rows, d+1)
    return per_row @ g.shear_u


def _band_nodes(g: ImageGrid, which: slice, rows: slice) -> np.ndarray:
    """Quantities ``which`` of ``g.along_u`` interpolated to image rows ``rows``:
    (k, rows, W)."""
    iv = g.iv[rows]
    along = np.take(g.along_u[which], iv, axis=1)
    along += g.tv[rows, None] * np.take(g.step_v[which], iv, axis=1)
    return along


def _band_phase(g: ImageGrid, xp: np.ndarray, rows: slice) -> tuple[np.ndarray, np.ndarray]:
    """Sheared phase s = x_p - x_ref [projector px] and the in-volume flag of image rows
    ``rows`` (``xp``), each (rows, W)."""
    s = xp - _band_shear(g, rows, g.tv.size)
    iv = g.iv[rows]
    with np.errstate(invalid="ignore"):
        inside = (s >= np.take(g.lo, iv, axis=0)) & (s <= np.take(g.hi, iv, axis=0))
    return s, inside


def _band_weights(g: ImageGrid, rows: slice) -> list[np.ndarray]:
    """Bilinear node weights of every pixel of image rows ``rows``: 4 (rows, W) float32."""
    v1 = g.tv[rows, None]
    v0, u0, u1 = 1 - v1, 1 - g.tu, g.tu
    shape = (v1.shape[0], g.tu.size)
    return [np.multiply(a, b, out=np.empty(shape, np.float32), casting="same_kind")
            for a, b in ((v0, u0), (v0, u1), (v1, u0), (v1, u1))]


def in_volume_rows(t: TableGrid, xp: np.ndarray, row0: int) -> np.ndarray:
    """Whether each phase of image rows row0.. is inside its pixel's calibrated range."""
    return _band_phase(t.image_grid, xp, slice(row0, row0 + xp.shape[0]))[1]


def apply_rows(t: TableGrid, xp: np.ndarray, row0: int, select: np.ndarray | None,
               extrapolate: bool, out: TableLookup | None = None) -> TableLookup:
    """Lookup of image rows row0.. (all pixels, or the flat indices ``select``).

    Returns (and fills, if given) ``out``, shaped (rows, W) or (len(select),).
    """
    g = t.image_grid
    rows = slice(row0, row0 + xp.shape[0])
    s, inside = _band_phase(g, xp, rows)
    lat = _band_nodes(g, slice(0, 4), rows)  # X0, kx, Y0, ky
    terms = [s, inside, g.row[rows, None] + g.col, *_band_weights(g, rows), *lat]
    if select is None:
        terms = [a.ravel() for a in terms]
        shape = xp.shape
    else:
        terms = [np.take(a, select) for a in terms]
        shape = (select.size,)
    out = empty_lookup(shape) if out is None else out
    s, inside, base, w, lat = terms[0], terms[1], terms[2], terms[3:7], terms[7:]
    z, dz, sig = _hermite(t.packed, s, base, w)
    _store(z, dz, sig, lat, inside, extrapolate, _flat(out))
    return out


def apply_image(t: TableGrid, xp: np.ndarray, extrapolate: bool) -> TableLookup:
    """Lookup of a whole (H, W) phase map, in bands of rows on every core."""
    out = empty_lookup(xp.shape)
    t.image_grid  # noqa: B018 - computed once, before the threads share it

    def band(r0: int, r1: int) -> None:
        apply_rows(t, xp[r0:r1], r0, None, extrapolate, _flat(out, slice(r0, r1)))

    run_bands(band, row_bands(*xp.shape))
    return out
