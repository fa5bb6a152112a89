"""Weighted nonparametric calibration table (Bumbaca-Blais style, docs/calibration.rst).

No global lens model is fitted for range. A flat target is scanned at K known stage
positions; the table maps raw sensor coordinates (u, v) and the unwrapped projector
coordinate x_p to metric X, Y, Z [mm].

The table is a regular grid over (u, v, s) with s = x_p - x_ref(u, v) [projector px]: the
x_p axis is sheared per column band by a smooth reference phase x_ref (the phase of the
middle of the sweep at that node), so that a grid line of constant s stays near one depth
across a cell and interpolation in (u, v) is accurate. Each node holds X, Y, Z and the
slope dQ/dx_p; a query is bilinear in (u, v) and cubic Hermite in s (constant time per
point, smooth, no quantisation to the calibrated planes).

Building a node is a weighted aggregation in two stages:

1. Per observed plane, the samples of a cell of ``cell_px`` x ``cell_px`` pixels are fitted
   with a local plane x_p = a + b du + c dv (orthogonal regression is not needed: u, v
   are exact). Samples flagged by the decoder (low modulation, saturation, unwrapping
   inconsistency) are rejected first; then samples whose residual exceeds a robust
   threshold (unwrapping jumps of the scan) are rejected, both counted per reason.
2. Per node, the cell estimates x_k of all planes (and repeats) are fitted with the
   projective model of one camera ray, x (1 + g z) = a + b z + d z^2 with z the scaled
   stage position (exact, d = 0, for pinhole optics; d absorbs mild distortion), by
   weighted least squares with weight 1 / var(x_k). ``weights="model"`` takes var(x_k)
   from the optics model at that node and plane (s_O sigma_p)^2 / n; ``"modulation"`` from
   the decoder's per-pixel sigma_xp; ``"none"`` weighs every sample equally.

The table's own uncertainty (per node, along the line of sight) is propagated from the
parameter covariance of stage 2, scaled by the fit's reduced chi-square.
"""
from __future__ import annotations

import functools
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from scanqa._version import __version__
from scanqa.calibration.node_model import (
    MIN_PHASE_CHANGE_PX,  # noqa: F401 (importable from here)
    check_phase_changes,
    lateral_rays,
    node_sigma,
    position_residuals,
    solve_x,
    solve_zeta,
    wls,
)
from scanqa.calibration.shear import eval_shear, fit_shear
from scanqa.calibration.table import CalibrationTable
from scanqa.chunks import row_bands, run_bands
from scanqa.errors import InputError
from scanqa.model import optics
from scanqa.model.config import ScannerConfig
from scanqa.numeric import MAD_TO_SIGMA, ill_conditioned
from scanqa.progress import Progress

log = logging.getLogger(__name__)

WEIGHT_MODES = ("model", "modulation", "none")
#: Reasons a calibration sample is rejected, in report order.
REJECT_REASONS = ("decoder_mask", "low_modulation", "unwrap_jump", "sparse_cell")
#: Fewest valid samples for a cell's plane fit.
_MIN_CELL_SAMPLES = 6


@dataclass(frozen=True)
class PlaneObservation:
    """One decoded scan of the flat target at one stage position.

    Parameters
    ----------
    z_mm : float
        Z of the target plane in the scanner frame (the stage position) [mm].
    xp : (H, W) ndarray
        Unwrapped projector coordinate, NaN where invalid [projector px].
    mask : (H, W) uint8 ndarray, optional
        Decoder reason codes, 0 = valid.
    modulation : (H, W) ndarray, optional
        Fringe modulation B [DN].
    sigma_xp : (H, W) ndarray, optional
        Decoder's per-pixel phase noise [projector px].
    x_mm, y_mm : (H, W) ndarray, optional
        Lateral coordinates of the target per pixel (a marked target) [mm]; otherwise
        they come from the camera intrinsics.
    z_map_mm : (H, W) ndarray, optional
        Z of the target per pixel [mm] (a marked target, whose plane need not be
        perpendicular to the camera axis nor move along it); otherwise ``z_mm``.
    source : str
        Where it came from, for messages and provenance.
    """

    z_mm: float
    xp: np.ndarray
    mask: np.ndarray | None = None
    modulation: np.ndarray | None = None
    sigma_xp: np.ndarray | None = None
    x_mm: np.ndarray | None = None
    y_mm: np.ndarray | None = None
    source: str = ""
    z_map_mm: np.ndarray | None = None


@dataclass
class BuildReport:
    """What the build did: counts per rejection reason and per-position residuals."""

    rejected: dict = field(default_factory=lambda: dict.fromkeys(REJECT_REASONS, 0))
    used_samples: int = 0
    positions: list = field(default_factory=list)
    #: cells whose smoothing window was singular (cells in a line): kept unsmoothed
    unsmoothed_cells: int = 0

    def as_dict(self) -> dict:
        return {"rejected": dict(self.rejected), "used_samples": self.used_samples,
                "unsmoothed_cells": self.unsmoothed_cells, "positions": self.positions}


# --------------------------------------------------------------------------- building


def _block_rows(img: np.ndarray, cell: int, rows: tuple[int, int], n_u: int,
                fill: float = np.nan) -> np.ndarray:
    """Cell rows ``rows`` of an (H, W) image as (n_rows, n_u, cell*cell) samples per cell.

    Pixels past the image are ``fill`` (partial last cells); pixels past the last cell
    are cropped. Float images come back as float64.
    """
    (j0, j1), width = rows, n_u * cell
    part = img[j0 * cell:j1 * cell, :width]
    if part.shape != ((j1 - j0) * cell, width):
        pad = np.full(((j1 - j0) * cell, width), fill, dtype=np.result_type(part, fill))
        pad[:part.shape[0], :part.shape[1]] = part
        part = pad
    block = part.reshape(j1 - j0, cell, n_u, cell).transpose(0, 2, 1, 3)
    out = block.reshape(j1 - j0, n_u, cell * cell)
    return out.astype(float, copy=False) if out.dtype.kind == "f" else out


@functools.lru_cache(maxsize=8)
def _cell_design(cell: int) -> tuple[np.ndarray, np.ndarray]:
    """Plane design [1, du, dv] of a cell's samples (P, 3) and the products that make up
    its normal matrix [1, du, dv, du^2, du dv, dv^2] (P, 6); du, dv from the cell centre
    [camera px], samples in row-major order."""
    c = (cell - 1) / 2.0
    dv, du = np.divmod(np.arange(cell * cell, dtype=float), cell)
    du, dv = du - c, dv - c
    design = np.stack([np.ones_like(du), du, dv], -1)
    return design, np.stack([np.ones_like(du), du, dv, du * du, du * dv, dv * dv], -1)


#: Entries of the symmetric normal matrix in the columns of _cell_design's products.
_NORMAL = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


def _fit_cells(x: np.ndarray, ok: np.ndarray, cell: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane x = a + b du + c dv per cell.

    Parameters
    ----------
    x : (..., P) float
        Samples of each cell (P = cell^2, row-major) [px or mm].
    ok : (..., P) bool
        Samples that take part.
    cell : int
        Cell size [camera px].

    Returns
    -------
    a : (...,) float
        Value at the cell centre; NaN with fewer than ``_MIN_CELL_SAMPLES`` samples.
    res : (..., P) float
        Residuals of every sample (NaN where x is).
    n : (...,) float
        Samples used.

    Notes
    -----
    The normal equations are two matrix products with the fixed design of a cell. The
    curvature of x_p(u, v) biases a by ~c <du^2>, which grows with the square of the
    cell's size on the object; :func:`default_cell_px` keeps cells ~0.45 mm wide, where
    the bias is a few nm. (A quadratic fit removes it but more than doubles the noise.)
    """
    design, products = _cell_design(cell)
    sums = ok.astype(float) @ products            # n, sum du, sum dv, sum du^2, ...
    ata = sums[..., _NORMAL]
    atb = np.where(ok, x, 0.0) @ design
    n = sums[..., 0]
    good = n >= _MIN_CELL_SAMPLES
    ata[~good] = np.eye(3)
    coef = np.linalg.solve(ata, atb[..., None])[..., 0]
    return np.where(good, coef[..., 0], np.nan), x - coef @ design.T, n


def _robust_sigma(res: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Per-cell robust std of the residuals, 1.4826 MAD [px]; NaN for an empty cell.

    The median of each cell's valid |res| is picked from the sorted row (invalid samples
    sort last as +inf), which is several times faster than ``np.nanmedian`` on short rows.
    """
    r = np.where(ok, np.abs(res), np.inf)
    r.sort(axis=-1)
    n = ok.sum(-1)[..., None]
    lo = np.take_along_axis(r, np.maximum(n - 1, 0) // 2, -1)[..., 0]
    hi = np.take_along_axis(r, np.minimum(n // 2, r.shape[-1] - 1), -1)[..., 0]
    return np.where(n[..., 0] > 0, MAD_TO_SIGMA * ((lo + hi) / 2), np.nan)

@dataclass(frozen=True)
class _CellStats:
    """Stage-1 output for one observation: one estimate per cell."""

    z_mm: float
    x: np.ndarray       # (n_v, n_u) phase at the cell centre [px]
    var: np.ndarray     # (n_v, n_u) variance used for the weight [px^2]
    n: np.ndarray       # (n_v, n_u) samples used
    scatter: np.ndarray  # (n_v, n_u) robust residual std [px]
    lat: tuple | None   # (X, Y[, Z]) cell estimates [mm] from lateral maps


def _stage1(obs: PlaneObservation, cell: int, n_v: int, n_u: int, jump_px: float,
            min_modulation: float, report: BuildReport) -> _CellStats:
    """Cell estimates of one observation with rejections counted.

    Bands of cell rows run on every core (:mod:`scanqa.chunks`); each band's samples
    stay in cache from the block view to the second plane fit.
    """
    def band(j0: int, j1: int) -> tuple:
        return _stage1_band(obs, cell, (j0, j1), n_u, jump_px, min_modulation)

    parts = run_bands(band, row_bands(n_v, n_u * cell * cell))
    for counts in (p[-1] for p in parts):
        report.used_samples += counts.pop("used")
        for reason, count in counts.items():
            report.rejected[reason] += count
    a, var, n, scatter, *lat = (None if f[0] is None else np.concatenate(f)
                                for f in zip(*(p[:-1] for p in parts), strict=True))
    lat = tuple(m for m in lat if m is not None)
    return _CellStats(obs.z_mm, a, var, n, scatter, lat or None)


def _stage1_band(obs: PlaneObservation, cell: int, rows: tuple[int, int], n_u: int,
                 jump_px: float, min_modulation: float) -> tuple:
    """Stage 1 on cell rows ``rows``: (a, var, n, scatter, lat_x, lat_y, counts)."""
    x = _block_rows(obs.xp, cell, rows, n_u)
    ok, counts = _decoder_rejects(obs, x, cell, rows, n_u, min_modulation)
    a, res, n = _fit_cells(x, ok, cell)
    sig = _robust_sigma(res, ok)
    # an unwrapping jump is a sizeable fraction of a period; 8 robust std (floor 0.02 px)
    # keeps the few-sample MAD of small cells from rejecting ordinary noise
    thr = np.minimum(jump_px, np.maximum(8.0 * sig, 0.02))[..., None]
    jump = ok & (np.abs(res) > thr)
    counts["unwrap_jump"] = int(jump.sum())
    if counts["unwrap_jump"]:  # refit without them (the same fit otherwise)
        ok &= ~jump
        a, res, n = _fit_cells(x, ok, cell)
    sparse = n < _MIN_CELL_SAMPLES
    counts["sparse_cell"] = int(n[sparse].sum())
    counts["used"] = int(n[~sparse].sum())
    scatter = np.sqrt((np.where(ok, res, 0.0) ** 2).sum(-1) / np.maximum(n - 3, 1))
    lat = (None, None, None)
    if obs.x_mm is not None and obs.y_mm is not None:
        maps = (obs.x_mm, obs.y_mm, obs.z_map_mm)
        lat = tuple(None if m is None else _fit_cells(_block_rows(m, cell, rows, n_u), ok,
                                                      cell)[0] for m in maps)
    return (np.where(sparse, np.nan, a), _sample_var(obs, ok, cell, rows, n_u),
            np.where(sparse, 0, n), scatter, *lat, counts)


def _decoder_rejects(obs: PlaneObservation, x: np.ndarray, cell: int, rows: tuple[int, int],
                     n_u: int, min_modulation: float) -> tuple[np.ndarray, dict]:
    """Valid samples of a band after the decoder's mask and the modulation floor, and the
    counts per reason."""
    ok = np.isfinite(x)
    counts = dict.fromkeys(REJECT_REASONS, 0)
    if obs.mask is not None:
        masked = _block_rows(obs.mask, cell, rows, n_u, fill=0) > 0
        counts["decoder_mask"] = int(masked.sum())  # NaN or not: the decoder rejected it
        ok &= ~masked
    if obs.modulation is not None and min_modulation > 0:
        low = ok & (_block_rows(obs.modulation, cell, rows, n_u) < min_modulation)
        counts["low_modulation"] = int(low.sum())
        ok &= ~low
    return ok, counts


def _sample_var(obs: PlaneObservation, ok: np.ndarray, cell: int, rows: tuple[int, int],
                n_u: int) -> np.ndarray | None:
    """Mean decoder variance per cell (for modulation weights), or None."""
    if obs.sigma_xp is None:
        return None
    s = _block_rows(obs.sigma_xp, cell, rows, n_u)
    with np.errstate(all="ignore"):
        return np.where(ok, s**2, 0.0).sum(-1) / np.maximum(ok.sum(-1), 1)


def _node_points(config: ScannerConfig, node_u: np.ndarray, node_v: np.ndarray,
                 z: float) -> np.ndarray:
    """Points on the node rays at plane Z = z from the camera intrinsics [mm]."""
    cam = config.camera
    f = cam.principal_distance_px
    uu, vv = np.meshgrid(node_u, node_v)
    return np.stack([(uu - cam.principal_point_px[0]) / f * z,
                     (vv - cam.principal_point_px[1]) / f * z, np.full_like(uu, z)], -1)


def _weights(st: _CellStats, mode: str, config: ScannerConfig, node_u: np.ndarray,
             node_v: np.ndarray) -> np.ndarray:
    """Stage-2 weight of each cell estimate: 1 / var(x_k) [1/px^2]."""
    n = st.n.astype(float)
    if mode == "none":
        w = n
    elif mode == "model":
        pred = optics.predict(_node_points(config, node_u, node_v, st.z_mm), config)
        sig_x = pred.s_o * config.model.sigma_p_px
        w = n / sig_x**2
    else:
        if st.var is None:
            raise InputError("weights 'modulation' needs the decoder's sigma_xp in every "
                             "phase file of the sweep; use weights 'model' or 'none'")
        w = n / st.var
    return np.where(np.isfinite(st.x) & np.isfinite(w) & (n > 0), w, 0.0)


#: Half-width of the local quadratic that smooths each plane's cell phases [cells].
SMOOTH_HALF_WIDTH = 2


def _window_terms(half: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (di, dj) of a (2h+1)^2 window and the quadratic basis on them: (6, k, k)."""
    d = np.arange(-half, half + 1, dtype=float)
    di, dj = np.meshgrid(d, d, indexing="ij")
    return np.stack([np.ones_like(di), di, dj, di * di, di * dj, dj * dj]), d


def smooth_cells(x: np.ndarray, w: np.ndarray, cell: float, half: int = SMOOTH_HALF_WIDTH
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Weighted local quadratic regression of one plane's cell phases (2-D Savitzky-Golay).

    The phase of a flat target varies smoothly over the image, so each cell's estimate is
    replaced by the value at its centre of a weighted quadratic fitted over the
    (2h+1)^2 neighbouring cells: this keeps any quadratic variation exactly and cuts the
    noise about twofold. Its second-order terms also remove the bias of the cell's own
    plane fit, 0.5 x_uu <du^2> + 0.5 x_vv <dv^2> (the curvature of x_p(u, v)).

    Parameters
    ----------
    x : (n_v, n_u) float
        Cell-centre phases of one plane, NaN where missing [projector px].
    w : (n_v, n_u) float
        Their weights 1 / variance [1/px^2], 0 where missing.
    cell : float
        Cell size [camera px].
    half : int
        Window half-width [cells]; 0 returns the input.

    Returns
    -------
    (x_s, w_s) : (n_v, n_u) arrays
        Smoothed phases and their weights 1 / var(x_s); where the window cannot hold a
        quadratic (edges of the covered region), the input values.
    singular : int
        Cells whose window held enough samples but no quadratic (its normal matrix is
        singular: the samples lie on a line); they keep their input values [-].
    """
    from scipy.ndimage import correlate

    if half <= 0:
        return x, w, 0
    basis, _ = _window_terms(half)
    ok = (w > 0) & np.isfinite(x)
    wv, xv = np.where(ok, w, 0.0), np.where(ok, x, 0.0)
    k = basis.shape[0]
    moments, rhs = np.empty((*x.shape, k, k)), np.empty((*x.shape, k))
    wx, done = wv * xv, {}  # 15 of the 21 basis products differ (di * di = di^2 * 1)
    for a in range(k):
        rhs[..., a] = correlate(wx, basis[a], mode="constant")
        for b in range(a, k):
            key = (basis[a] * basis[b]).tobytes()
            if key not in done:
                done[key] = correlate(wv, basis[a] * basis[b], mode="constant")
            moments[..., a, b] = moments[..., b, a] = done[key]
    count = correlate(ok.astype(float), np.ones_like(basis[0]), mode="constant")
    good = ok & (count >= 3 * k)
    moments[~good] = np.eye(k)
    # windows whose samples lie on a line: singular, their cells keep their value (counted)
    flags, inv = ill_conditioned(moments, 1e12)
    singular = good & flags
    good &= ~singular
    if singular.any() or inv is None:
        moments[singular] = np.eye(k)
        inv = np.linalg.inv(moments)
    coef = np.einsum("...ab,...b->...a", inv, rhs)
    du2 = (cell * cell - 1.0) / 12.0 / (cell * cell)  # <du^2> of a cell, in cells^2
    value = coef[..., 0] - (coef[..., 3] + coef[..., 5]) * du2
    var = inv[..., 0, 0]
    good &= np.isfinite(value) & (var > 0)
    return (np.where(good, value, x), np.where(good, 1.0 / np.where(good, var, 1.0), w),
            int(singular.sum()))


def default_cell_px(config: ScannerConfig, z_mm: float, spacing_mm: float = 0.45) -> int:
    """Node spacing [camera px] that puts nodes ~``spacing_mm`` apart on the object.

    The bilinear interpolation error in (u, v) grows with the square of the node spacing
    on the object (0.1 um at 0.45 mm for the paper's scanner), so big pixels get small
    cells; at least 4 px so that each cell's quadratic fit has 16 samples.
    """
    cam = config.camera
    footprint = cam.pixel_um * 1e-3 * z_mm / (cam.principal_distance_px * cam.pixel_um * 1e-3)
    return int(np.clip(round(spacing_mm / footprint), 4, 32))


def _cell_count(n_px: int, cell: int) -> int:
    """Cells along an axis: a partial last cell only when it has >= 3 pixels; otherwise its
    pixels are extrapolated from the last full cells."""
    full, rest = divmod(n_px, cell)
    return full + (1 if rest >= 3 or full == 0 else 0)


def build_table(observations: Iterable[PlaneObservation], config: ScannerConfig,
                weights: str = "model", cell_px: int | None = None, s_step_px: float = 1.0,
                min_modulation: float = 0.0, jump_fraction: float = 0.25,
                provenance: dict | None = None, total: int | None = None
                ) -> tuple[CalibrationTable, BuildReport]:
    """Build a calibration table from decoded scans of a flat target on a stage.

    Parameters
    ----------
    observations : iterable of PlaneObservation
        Scans at three or more distinct stage positions (repeats allowed), all of the
        config's camera size. Consumed one at a time: memory holds one image.
    config : ScannerConfig
        Scanner config (intrinsics for lateral X, Y and the model weights).
    weights : {"model", "modulation", "none"}
        How samples are weighted (module notes).
    cell_px : int, optional
        Node spacing in u and v [camera px], 3 to the image's smaller side; default
        :func:`default_cell_px`.
    s_step_px : float
        Node spacing along the sheared phase axis [projector px].
    min_modulation : float
        Samples with modulation below this are rejected [DN]; 0 keeps the decoder's mask.
    jump_fraction : float
        Residuals larger than this fraction of the working period count as unwrapping
        jumps (also any beyond 6 robust std of the cell) [-].
    provenance : dict, optional
        Sweep description stored in the table.
    total : int, optional
        Number of observations, for the progress display (:mod:`scanqa.progress`);
        default ``len(observations)`` when it has one.

    Returns
    -------
    (CalibrationTable, BuildReport)
    """
    if weights not in WEIGHT_MODES:
        raise InputError(f"weights must be one of {', '.join(WEIGHT_MODES)}, got {weights!r}")
    if not (np.isfinite(min_modulation) and min_modulation >= 0):
        raise InputError(f"min_modulation must be >= 0 DN, got {min_modulation!r}")
    report = BuildReport()
    stats, shape, seen = [], None, {}
    total = total if total is not None else getattr(observations, "__len__", lambda: None)()
    with Progress("calibrate", total, "scan", log) as bar:
        for obs in observations:
            if shape is None:
                shape = check_camera_size(obs, config)
                cell_px = _cell_size(cell_px, config, obs)
                n_v, n_u = _cell_count(shape[0], cell_px), _cell_count(shape[1], cell_px)
            elif obs.xp.shape != shape:
                raise InputError(f"{obs.source or 'observation'}: image is {obs.xp.shape[1]} "
                                 f"x {obs.xp.shape[0]} px, the sweep's first is {shape[1]} x "
                                 f"{shape[0]} px: all scans must come from one camera")
            _check_not_repeated(obs, seen)
            jump = jump_fraction * config.fringes.working_period_px
            stats.append(_stage1(obs, cell_px, n_v, n_u, jump, min_modulation, report))
            bar.update(1, note=f"z = {obs.z_mm:g} mm")
    zs = sorted({s.z_mm for s in stats})
    if len(zs) < 3:
        raise InputError(f"a calibration sweep needs at least 3 distinct positions, got "
                         f"{len(zs)}")
    node_u = np.arange(n_u) * cell_px + (cell_px - 1) / 2.0
    node_v = np.arange(n_v) * cell_px + (cell_px - 1) / 2.0
    table = _stage2(stats, config, weights, node_u, node_v, s_step_px, shape, provenance,
                    report)
    return table, report


def _check_not_repeated(obs: PlaneObservation, seen: dict) -> None:
    """Refuse one scan listed at two stage positions: its phases cannot change with Z, and
    the per-node fit would be singular."""
    import hashlib

    digest = hashlib.blake2b(np.ascontiguousarray(obs.xp).data, digest_size=16).digest()
    source, z_mm = seen.setdefault(digest, (obs.source or "another scan", obs.z_mm))
    if z_mm != obs.z_mm:
        raise InputError(f"{obs.source or 'a scan'} at z = {obs.z_mm:g} mm holds exactly the "
                         f"phases of {source} at z = {z_mm:g} mm: one scan is listed at two "
                         "positions (check the sweep manifest's files)")


def check_camera_size(obs: PlaneObservation, config: ScannerConfig) -> tuple[int, int]:
    """The image size of an observation (rows, columns) [px], which must be the config's
    camera's.

    Raises
    ------
    InputError
        Naming the scan, both sizes and the fix.
    """
    shape = tuple(int(n) for n in np.shape(obs.xp))
    cam = config.camera
    if shape != (cam.height_px, cam.width_px):
        got = " x ".join(str(n) for n in shape[::-1])
        raise InputError(f"{obs.source or 'the first scan'} is {got} px but the camera of "
                         f"config {config.source or config.name} is {cam.width_px} x "
                         f"{cam.height_px} px: give the config the sweep was captured with "
                         "(a table built with another camera's intrinsics is wrong)")
    return shape


def _cell_size(cell_px: int | None, config: ScannerConfig, obs: PlaneObservation) -> int:
    """The node spacing: ``cell_px`` checked against the image, or the default [px]."""
    if cell_px is None:
        return default_cell_px(config, obs.z_mm)
    side = min(obs.xp.shape)
    if isinstance(cell_px, bool) or not float(cell_px).is_integer() or not 3 <= cell_px <= side:
        raise InputError(f"cell size must be a whole number of camera px from 3 (9 samples "
                         f"per cell) to the image's smaller side ({side} px), got {cell_px!r}")
    return int(cell_px)


def _stage2(stats: list[_CellStats], config: ScannerConfig, weights: str,
            node_u: np.ndarray, node_v: np.ndarray, s_step: float, shape: tuple,
            provenance: dict | None, report: BuildReport) -> CalibrationTable:
    """Fit the per-node ray model and sample it on the (u, v, s) grid."""
    z = np.array([s.z_mm for s in stats])
    z0, half = 0.5 * (z.min() + z.max()), 0.5 * (z.max() - z.min())
    zeta = (z - z0) / half
    cell = node_u[1] - node_u[0] if node_u.size > 1 else 1.0
    pairs = [smooth_cells(s.x, _weights(s, weights, config, node_u, node_v), cell)
             for s in stats]
    report.unsmoothed_cells = sum(p[2] for p in pairs)
    if report.unsmoothed_cells:
        log.warning(f"{report.unsmoothed_cells} cell estimates kept unsmoothed: their "
                    "neighbourhood's samples lie on a line (a narrow strip of valid pixels)")
    x = np.stack([p[0] for p in pairs], -1)                   # (n_v, n_u, M)
    w = np.stack([p[1] for p in pairs], -1)
    # centre each node's phases: the fit's columns 1, z, z^2, -x z stay well conditioned
    centre = np.nansum(np.where(w > 0, x, 0.0), -1) / np.maximum((w > 0).sum(-1), 1)
    x0 = np.where(w > 0, x - centre[..., None], 0.0)
    check_phase_changes(x, w, z)
    cols = np.stack(np.broadcast_arrays(np.ones_like(x0), zeta, zeta**2, -x0 * zeta), -1)
    theta, cov, n_obs = wls(cols, x0, w)
    position_residuals(stats, theta, zeta, x0, w, z, report)
    return _sample_grid(theta, cov, n_obs, x0, w, z0, half, centre, config, node_u, node_v,
                        s_step, shape, weights, stats, provenance, report)


def _sample_grid(theta, cov, n_obs, x, w, z0, half, centre, config, node_u, node_v, s_step,
                 shape, weights, stats, provenance, report) -> CalibrationTable:
    """Evaluate every node's model on the sheared s grid.

    ``x`` are the phases relative to each node's ``centre`` [projector px]; the s axis is
    relative to the smooth shear (:mod:`scanqa.calibration.shear`) fitted to the mid-sweep phases.
    """
    uu, vv = np.meshgrid(node_u, node_v)
    size = (int(shape[1]), int(shape[0]))
    mid = np.where(n_obs >= 5, solve_x(theta, 0.0), np.nan) + centre
    coef = fit_shear(uu, vv, mid, size)
    x_ref = eval_shear(coef, uu, vv, size) - centre  # node-centred like x
    has = w > 0
    xmin = np.where(has, x, np.inf).min(-1)
    xmax = np.where(has, x, -np.inf).max(-1)
    s_lo = np.where(n_obs >= 5, xmin - x_ref, np.nan)
    s_hi = np.where(n_obs >= 5, xmax - x_ref, np.nan)
    if not np.isfinite(s_lo).any():
        raise InputError("no table node has samples on 5 or more planes: the sweep covers "
                         "too little of the image (check masks and positions)")
    lo = np.floor(np.nanmin(s_lo) / s_step) - 1
    hi = np.ceil(np.nanmax(s_hi) / s_step) + 1
    s_nodes = np.arange(lo, hi + 1) * s_step
    xq = x_ref[..., None] + s_nodes
    zeta, dzdx = solve_zeta(theta, xq)
    zz = z0 + half * zeta
    dz = half * dzdx
    lat = lateral_rays(stats, w, z0, half, config, node_u, node_v)
    xyz = np.stack([lat[0] + lat[1] * zz, lat[2] + lat[3] * zz, lat[4] + lat[5] * zz], -1)
    dxyz = np.stack([lat[1] * dz, lat[3] * dz, lat[5] * dz], -1)
    sig = node_sigma(theta, cov, zeta, xq) * half * np.linalg.norm(
        np.stack([lat[1] + 0 * zz, lat[3] + 0 * zz, lat[5] + 0 * zz], -1), axis=-1)
    prov = dict(provenance or {})
    prov.setdefault("positions", [{"z_mm": float(s.z_mm)} for s in stats])
    prov["report"] = report.as_dict()
    prov["scanqa_version"] = __version__
    return CalibrationTable(node_u, node_v, x_ref + centre, s_nodes, xyz, dxyz, sig, s_lo,
                            s_hi, coef, int(shape[1]), int(shape[0]), weights,
                            config.to_dict(), prov)
