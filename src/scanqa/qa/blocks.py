"""Gauge-block QA (Sect. 4.3, Tables 3 and 4 of the paper; docs/qa.rst).

Vocabulary follows VDI/VDE 2634-2 and the GUM: per block a least-squares plane
(orthogonal distances), its residuals, the measured standard deviation, the flatness
(max - min residual) and the predicted standard deviation (RMS of the points' predicted
sigma along the plane normal); per pair of successive blocks the measured height
difference, its standard uncertainty u propagated from the points, the expanded
uncertainty U = k u (k = 2) and an ISO 14253-1 decision against a tolerance T.

Height difference between blocks a and b (a the reference, normally the taller):
d = n_a . (c_a - c_b), the distance from block b's centroid c_b to the plane of block a,
along block a's normal n_a (oriented towards the camera). Its uncertainty combines the
plane's height uncertainty at c_b (from the per-point sigmas through the fit), the
uncertainty of c_b along n_a, and the calibration table's own errors: correlated over
``table_corr_mm`` (the cell smoothing of the table), they shift each block and tilt
block a's plane, and the tilt reaches c_b through the lever between the blocks.

Neighbouring points are not independent: blur spreads one noise event over several
pixels, and at fine pixels the noise of a block is correlated over ~0.5-1 mm. The plane's
covariance from the per-point sigmas (which assumes independence) is therefore scaled by
a noise-correlation factor kappa >= 1 per parameter, measured on the block itself: the
ratio of the cluster-robust (sandwich) covariance of the fit, with square tiles of
``tile_mm`` as clusters, to the same estimate with every point its own cluster. kappa is
the number of pixels that share one noise event (1 for independent points); it also takes
up any residual structure of the block (flatness, table errors) below the tile size.

The step's standard uncertainty u and expanded uncertainty U come from a GUM budget
(:mod:`scanqa.qa.budget`): the Type A terms above and, from a budget file, the Type B
terms (certificates, temperature, stage scale, flatness of the calibration flat); k is
stated or follows from the effective degrees of freedom. Given the calibration's
parameter covariance (:func:`scanqa.calibration.sweep.geometry_covariance`), a
"calibration geometry" line carries it to the step: the calibration's depth-scale error
times the height, its depth-axis tilt error times the lateral separation.

Statuses: a block is flagged "outside_volume" or "model_invalid" when more than
:data:`MAX_FLAGGED_FRACTION` of its points lie outside the calibrated volume or outside
the model's validity (a blur ratio > 1/2). A step involving a flagged block is "not
evaluated": it gets no decision. A block without a plane (no points, too few) keeps its
steps to the blocks before and after it in the table, "not evaluated" with NaN numbers, and
the notes name the block: a missed block makes the verdict INCOMPLETE, never PASS.

Decision (ISO 14253-1): conformance is proven when |error| <= T - U ("pass"),
non-conformance when |error| > T + U ("fail"), otherwise "undecided".
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import numbers

import numpy as np

from scanqa.design import tools
from scanqa.errors import ConfigError, InputError
from scanqa.io.annotated_cloud import AnnotatedCloud, random_sigma_name
from scanqa.io.budget import WELCH_SATTERTHWAITE, BudgetInputs
from scanqa.model.config import ScannerConfig, config_from_dict
from scanqa.numeric import robust_std
from scanqa.qa import budget as gum
from scanqa.qa.budget import Budget, Component, StepGeometry, coverage_factor, type_b
from scanqa.qa.correlation import MIN_TILES, TILE_MM, noise_correlation
from scanqa.qa.layout import BlockSpec, Layout
from scanqa.qa.planes import PlaneFit, fit_plane, plane_design
from scanqa.qa.results import BlockResult, QAResult, StepResult

__all__ = ["MIN_TILES", "TILE_MM", "BlockResult", "QAResult", "StepResult",
           "analyse_block", "check_sigmas", "cloud_config", "coverage_notes",
           "coverage_rule", "geometry_component", "local_std", "model_curve",
           "noise_correlation", "refuse_bad_sigmas", "run_qa", "step_between"]
#: Fewest points of a block whose steps are decided: below, the plane is fitted and shown
#: but the block is flagged "too_few_points" and its steps are not evaluated (the
#: relative uncertainty of its std, 1/sqrt(2(n - 3)), exceeds 14 %, and MIN_TILES tiles
#: of 3 points cannot be had).
MIN_POINTS = 30
#: Block status values, in the order they are checked.
STATUSES = ("no_points", "too_few_points", "degenerate", "outside_volume", "model_invalid",
            "ok")
#: A block is flagged when more than this fraction of its points lie outside the
#: calibrated volume or the model's validity [-].
MAX_FLAGGED_FRACTION = 0.05
#: Tolerance T on a height difference when none is given [um]; the verdict says so.
DEFAULT_TOLERANCE_UM = 20.0


def _attr(attrs: dict, name: str, idx: np.ndarray, default: float = math.nan) -> np.ndarray:
    """Attribute ``name`` at the points ``idx`` as float64 (``default`` when missing)."""
    v = attrs.get(name)
    return np.full(idx.size, default) if v is None else np.asarray(v[idx], dtype=float)


def _select(xyz: np.ndarray, spec: BlockSpec, margin: float, z_window: float) -> np.ndarray:
    x0, x1, y0, y1 = spec.region_mm
    sel = (np.isfinite(xyz).all(axis=1) & (xyz[:, 0] >= x0 + margin) & (xyz[:, 0] <= x1 - margin)
           & (xyz[:, 1] >= y0 + margin) & (xyz[:, 1] <= y1 - margin))
    if spec.top_z_mm is not None:
        sel &= np.abs(xyz[:, 2] - spec.top_z_mm) <= z_window
    return np.flatnonzero(sel)


def analyse_block(xyz: np.ndarray, attrs: dict, spec: BlockSpec, margin: float,
                  outlier_k: float | None, z_window: float = 3.0,
                  tile_mm: float = TILE_MM) -> BlockResult:
    """Plane fit and statistics of one block (see module notes).

    Parameters
    ----------
    xyz : (n, 3) float
        The cloud [mm]; NaN or infinite points are left out.
    attrs : dict
        Its per-point attributes (``sigma_model_um`` [um] and the like).
    spec : BlockSpec
        The block's id, nominal height [mm] and region [mm].
    margin : float
        Edge margin inside the region, finite and >= 0 [mm].
    outlier_k : float or None
        Reject residuals beyond K robust std, finite and > 0 [-]; None: no rejection.
    z_window : float
        Accepted |z - top_z_mm| when the layout gives the top [mm].
    tile_mm : float
        Tile of the noise-correlation factor [mm].

    Returns
    -------
    BlockResult
        With a status; a block without points or plane carries NaN statistics. A
        predicted sigma that is 0, negative, NaN or infinite predicts nothing (NaN).

    Raises
    ------
    InputError
        A margin, window or outlier K that is NaN, infinite or out of range.

    Notes
    -----
    Per block (Sect. 4.3 and Table 3 of the paper; docs/qa.rst): the least-squares plane
    (:func:`scanqa.qa.planes.fit_plane`), the measured std s = sqrt(sum r_i^2 / (n - 3)),
    the flatness max r_i - min r_i, the predicted std sqrt(mean sigma_n,i^2) with
    sigma_n,i = sigma_i |l_i . n| (Eq. 18 of the paper along the normal), the plane's
    covariance B J^T diag(sigma_n^2) J B scaled by the noise-correlation factor
    (GUM 5.2.2, Eq. 13), and u(s) = s / sqrt(2 nu) (GUM E.4.3, Table E.1).
    """
    _check_block_settings(margin, outlier_k, z_window)
    res = BlockResult(spec.block_id, spec.nominal_height_mm)
    idx = _select(xyz, spec, margin, z_window)
    if idx.size == 0:
        return dataclasses.replace(res, message=(
            f"block {spec.block_id}: no points inside its region after the {margin:g} mm "
            "edge margin (occluded, outside the calibrated volume or a wrong layout?)"))
    if idx.size < 3:
        return dataclasses.replace(res, n_points=int(idx.size), status="too_few_points",
                                   message=f"block {spec.block_id}: only {idx.size} points, "
                                   "a plane needs 3")
    outliers, n_selected = 0, int(idx.size)
    try:
        fit = fit_plane(xyz[idx], f"block {spec.block_id}")
        if outlier_k:
            keep = np.abs(fit.residuals) <= outlier_k * _spread(fit.residuals)
            outliers = int((~keep).sum())
            idx = idx[keep]
            fit = fit_plane(xyz[idx], f"block {spec.block_id}")
    except InputError as err:
        return dataclasses.replace(res, n_points=n_selected, outliers=outliers,
                                   status="degenerate", message=str(err))
    res = dataclasses.replace(res, outliers=outliers,
                              **_block_fields(spec.block_id, fit, idx, xyz, attrs, tile_mm))
    if res.status == "ok" and res.n_points < MIN_POINTS:
        res = dataclasses.replace(res, status="too_few_points", message=(
            f"block {spec.block_id}: only {res.n_points} points (fewer than {MIN_POINTS}): "
            "flagged, its steps are not evaluated"))
    return res


def _check_block_settings(margin: float, outlier_k: float | None, z_window: float) -> None:
    if not (math.isfinite(margin) and margin >= 0):
        raise InputError(f"edge margin must be >= 0 mm, got {margin!r}")
    if not (math.isfinite(z_window) and z_window > 0):
        raise InputError(f"height window must be > 0 mm, got {z_window!r}")
    if outlier_k is not None and not (math.isfinite(outlier_k) and outlier_k > 0):
        raise InputError(f"outlier rejection K must be > 0 robust std (or not given), got "
                         f"{outlier_k!r}")


def check_sigmas(attrs: dict) -> None:
    """A predicted sigma is > 0 and finite, or NaN (no prediction): 0, negative or
    infinite values are refused, not read as "no prediction"."""
    name = random_sigma_name(attrs)
    if name is not None:
        refuse_bad_sigmas(attrs[name], name)


def refuse_bad_sigmas(values: np.ndarray, name: str) -> None:
    """Refuse a per-point sigma attribute ``name`` holding 0, negative or infinite
    values [um]; NaN (no prediction) passes."""
    sig = np.asarray(values, dtype=float)
    bad = np.flatnonzero(np.isinf(sig) | (sig <= 0))
    if bad.size:
        raise InputError(f"the cloud's {name} holds {bad.size} values that are 0, "
                         f"negative or infinite (first: point {bad[0]}, {sig[bad[0]]!r} um); "
                         "a sigma must be > 0, or NaN where there is none "
                         "(annotate the scan again)")


def _spread(r: np.ndarray) -> float:
    return robust_std(r) or float(np.std(r)) or 1e-12


def _block_fields(block_id: int, fit: PlaneFit, idx: np.ndarray, xyz: np.ndarray,
                  attrs: dict, tile_mm: float) -> dict:
    """The :class:`BlockResult` fields of a block with a plane (module notes)."""
    n = idx.size
    pts = xyz[idx]
    los = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    cos = np.abs(los @ fit.normal)
    sig = _attr(attrs, random_sigma_name(attrs) or "sigma_model_um", idx) * 1e-3 * cos
    sig[~((sig > 0) & np.isfinite(sig))] = np.nan  # 0, negative, NaN, inf predict nothing
    out = {"n_points": n, "fit": fit, "index": idx}
    out["measured_std_um"] = 1e3 * float(np.sqrt(np.sum(fit.residuals**2) / max(n - 3, 1)))
    out["flatness_um"] = 1e3 * float(np.ptp(fit.residuals))
    out["predicted_std_um"] = 1e3 * float(np.sqrt(np.nanmean(sig**2))) \
        if np.isfinite(sig).any() else math.nan
    att = _attr(attrs, "att_camera", idx) * _attr(attrs, "att_projector", idx)
    out["mean_attenuation"] = float(np.nanmean(att)) if np.isfinite(att).any() else math.nan
    out["in_volume_fraction"] = float(np.mean(_attr(attrs, "in_volume", idx, 1.0)))
    out["model_valid_fraction"] = float(np.mean(_attr(attrs, "model_valid", idx, 1.0)))
    out["mean_z_mm"] = float(pts[:, 2].mean())
    tab = _attr(attrs, "sigma_calibration_um", idx, 0.0) * cos
    out["table_sigma_um"] = float(np.sqrt(np.nanmean(tab**2))) if np.isfinite(tab).any() \
        else 0.0
    corr = _attr(attrs, "table_corr_mm", idx)
    out["table_corr_mm"] = float(np.nanmedian(corr)) if np.isfinite(corr).any() else math.nan
    d = pts - fit.centroid
    out["spread_mm"] = (float(np.std(d @ fit.axes[0])), float(np.std(d @ fit.axes[1])))
    # per-point sigma along the normal: predicted where available, else measured
    out["sigma_n"] = np.where(np.isfinite(sig), sig, out["measured_std_um"] * 1e-3)
    a = plane_design(pts, fit)
    bread = np.linalg.inv(a.T @ a)
    kappa, out["n_tiles"] = noise_correlation(a, fit.residuals, a[:, 1:], tile_mm, bread)
    out["noise_corr"] = tuple(float(v) for v in kappa)
    scale = np.sqrt(np.where(np.isfinite(kappa), kappa, 1.0))
    # plane covariance from the per-point sigmas, scaled by the noise correlation
    out["u_plane"] = bread @ (a.T * out["sigma_n"]**2) @ a @ bread * np.outer(scale, scale)
    return {**out, **_block_status(block_id, out["in_volume_fraction"],
                                   out["model_valid_fraction"])}


def _block_status(block_id: int, in_volume: float, model_valid: float) -> dict:
    """``status`` and ``message`` of a block from its in-volume and model-valid fractions."""
    if in_volume < 1.0 - MAX_FLAGGED_FRACTION:
        status, what, frac = "outside_volume", "the calibrated volume", in_volume
    elif model_valid < 1.0 - MAX_FLAGGED_FRACTION:
        status, what, frac = ("model_invalid", "the model's validity (a blur ratio > 1/2)",
                              model_valid)
    else:
        return {"status": "ok"}
    return {"status": status,
            "message": (f"block {block_id}: {100 * (1 - frac):.0f} % of its points lie "
                        f"outside {what} (more than {100 * MAX_FLAGGED_FRACTION:g} %): "
                        "flagged, its steps are not evaluated")}


def step_between(a: BlockResult, b: BlockResult, k: float | str | None, tolerance_um: float,
                 inputs: BudgetInputs | None = None, n_planes: int | None = None,
                 geometry: Component | None = None, calibration: str | None = "table"
                 ) -> StepResult:
    """Height difference of block b relative to block a with its budget (module notes).

    ``k`` is a stated coverage factor or "welch-satterthwaite" (None: the budget file's
    ``[coverage] k``, else 2); ``inputs`` the budget file's Type B inputs; ``n_planes``
    the number of planes the calibration table was built from (its degrees of freedom);
    ``geometry`` the calibration-geometry line (:func:`geometry_component`), if known;
    ``calibration`` the cloud's ``sigma_source`` "calibration"
    (:func:`scanqa.qa.budget.calibration_rows`).

    Notes
    -----
    d = n_a . (c_a - c_b) (Table 4 of the paper); u from the budget's contributions in
    quadrature (GUM 5.1.2, Eq. 10): the plane of a at c_b, sqrt(g^T U_a g) with
    g = (1, s_1, s_2) the lever; the mean height of b, sqrt(U_b[0, 0]); the calibration
    table; the calibration geometry; and the Type B terms. U = k u (GUM 6.2.1), k stated
    or t_95(nu_eff) (GUM G.4.1); the decision is ISO 14253-1 against T.
    """
    fa, fb = a.fit, b.fit
    measured = float(fa.normal @ (fa.centroid - fb.centroid))
    off = fb.centroid - fa.centroid
    g = np.array([1.0, off @ fa.axes[0], off @ fa.axes[1]])
    table_dof = float(n_planes - 4) if n_planes and n_planes > 4 else math.inf
    components = [
        Component(f"noise, plane of block {a.block_id} at block {b.block_id}", "A",
                  f"model sigma x measured correlation ({a.n_tiles} tiles)",
                  1e3 * math.sqrt(float(g @ a.u_plane @ g)), "um", 1.0, a.noise_dof),
        Component(f"noise, mean height of block {b.block_id}", "A",
                  f"model sigma x measured correlation ({b.n_tiles} tiles)",
                  1e3 * math.sqrt(float(b.u_plane[0, 0])), "um", 1.0, b.noise_dof),
        *gum.calibration_rows(calibration, 1e3 * math.sqrt(_table_variance(a, b, g[1:])),
                              table_dof, geometry)]
    extra, correction = type_b(inputs, a.nominal_height_mm, b.nominal_height_mm)
    budget = Budget(tuple(components + extra), coverage_rule(k, inputs), inputs is not None,
                    correction)
    evaluated = a.status == "ok" and b.status == "ok"
    flagged = [x.block_id for x in (a, b) if x.status != "ok"]
    note = "" if evaluated else (f"not evaluated: block {' and '.join(map(str, flagged))} "
                                 "flagged")
    return StepResult(a.block_id, b.block_id, a.nominal_height_mm - b.nominal_height_mm,
                      measured, budget.u_um, budget.k, tolerance_um, budget, evaluated, note)


def unmeasured_step(a: BlockResult, b: BlockResult, tolerance_um: float) -> StepResult:
    """The step between two blocks when one has no plane (no points, too few, degenerate):
    kept in the table as "not evaluated" with NaN numbers, so that the verdict counts it
    (a layout block the cloud misses makes the verdict INCOMPLETE, never PASS)."""
    missing = [x.block_id for x in (a, b) if x.fit is None]
    return StepResult(a.block_id, b.block_id, a.nominal_height_mm - b.nominal_height_mm,
                      math.nan, math.nan, math.nan, tolerance_um, None, False,
                      f"not evaluated: block {' and '.join(map(str, missing))} has no plane "
                      "(see its status)")


def geometry_component(term: StepGeometry, xyz: np.ndarray, a: BlockResult,
                       b: BlockResult) -> Component:
    """The calibration-geometry line of a step's budget: the calibration's parameter
    covariance carried to the height difference of blocks a and b
    (:func:`scanqa.calibration.uncertainty.step_sigma_mm`, Eq. 3 there).

    Notes
    -----
    u_geo^2 = sum_j (d_j(+) - d_j(-))^2 / 4 over the principal axes j of the parameter
    covariance: the step d refitted with the blocks' points moved by +- one standard
    deviation along axis j (GUM 5.1.3, sensitivity by finite differences;
    docs/uncertainty_budget.rst, "The calibration geometry").
    """
    sigma = term.step_sigma_mm(xyz[a.index], xyz[b.index])
    return Component("calibration geometry", "A", f"{term.name}: covariance carried to the "
                     "step (depth scale x h, depth-axis tilt x lateral separation)",
                     1e3 * sigma, "um", 1.0, term.dof)


def _independent_patches(block: BlockResult) -> float:
    """How many independent table errors a block's plane averages over [-]: its area
    (12 s_1 s_2 for a rectangle of axis stds s_1, s_2) over the correlation area."""
    s1, s2 = block.spread_mm
    return max(1.0, 12.0 * s1 * s2 / block.table_corr_mm**2)


def _table_variance(a: BlockResult, b: BlockResult, lever: np.ndarray) -> float:
    """Variance of a step from the calibration table's own errors [mm^2].

    The table's error field has std sigma_tab and is correlated over ``table_corr_mm``;
    a block averages n_eff independent patches of it. It shifts each block by
    sigma_tab^2 / n_eff and tilts block a's plane by sigma_tab^2 / (n_eff s_i^2) per
    axis, which the lever from a's centroid to b's carries into the step. Without the
    correlation length (a cloud from elsewhere) the table error is taken as fully
    correlated within each block: no tilt, the whole sigma_tab as a shift.
    """
    sa, sb = a.table_sigma_um * 1e-3, b.table_sigma_um * 1e-3
    if not (a.table_corr_mm > 0 and b.table_corr_mm > 0
            and math.isfinite(a.table_corr_mm) and math.isfinite(b.table_corr_mm)):
        return sa**2 + sb**2
    na, nb = _independent_patches(a), _independent_patches(b)
    tilt = sum((lv / s) ** 2 for lv, s in zip(lever, a.spread_mm, strict=True))
    return sa**2 / na + sb**2 / nb + sa**2 * tilt / na


def model_curve(blocks: list[BlockResult], config: ScannerConfig) -> dict | None:
    """The model's uncertainty curve on the camera axis over the blocks' depths, +- 5 mm
    (:func:`scanqa.design.tools.axis_curve`), or None when no block has points.

    Notes
    -----
    sigma(Z) on the camera axis from Eqs. 18-19 of the paper
    (:func:`scanqa.design.tools.axis_curve`), every 0.25 mm over the blocks' depths +- 5 mm.
    """
    zs = [b.mean_z_mm for b in blocks if math.isfinite(b.mean_z_mm)]
    return tools.axis_curve(config, min(zs) - 5, max(zs) + 5, 0.25) if zs else None


def cloud_config(cloud: AnnotatedCloud, config: ScannerConfig | None, notes: list[str]
                 ) -> ScannerConfig | None:
    """The config whose model gave the cloud's sigmas: the one in the cloud's metadata
    (written by :func:`scanqa.annotation.points.annotate`), else ``config``."""
    stored = cloud.metadata.get("config")
    if not stored:
        return config
    try:
        carried = config_from_dict(stored, source="the cloud's metadata")
    except ConfigError as err:
        notes.append(f"the cloud's metadata holds an unreadable config ({err}); "
                     "its model curve is not drawn")
        return config
    if config is not None and config.model != carried.model:
        notes.append(f"the cloud's sigmas come from the model in its metadata "
                     f"({carried.model.filter_floor}/{carried.model.noise_reading}, sigma_p "
                     f"{carried.model.sigma_p_px:.4g} px, gamma {carried.model.gamma:.3g}); "
                     "the model of the config given to the QA was not used")
    return carried


def local_std(xyz: np.ndarray, residual_mm: np.ndarray, block_id: np.ndarray, k: int = 16
              ) -> np.ndarray:
    """Std of the residuals of each point's k nearest neighbours in its block [mm].

    Notes
    -----
    s_i = sqrt(sum_j (r_j - mean r)^2 / (k - 1)) over the k nearest neighbours j of point i
    in its block (in X, Y): the experimental standard deviation of GUM 4.2.2, Eq. 4, per
    neighbourhood.
    """
    from scipy.spatial import cKDTree

    out = np.full(len(xyz), np.nan)
    for bid in np.unique(block_id[block_id >= 0]):
        idx = np.flatnonzero(block_id == bid)
        kk = min(k, idx.size)
        if kk < 3:
            continue
        _, nn = cKDTree(xyz[idx, :2]).query(xyz[idx, :2], k=kk, workers=-1)
        out[idx] = np.std(residual_mm[idx][nn], axis=1, ddof=1)
    return out


def _check_settings(margin_mm: float, outlier_k: float | None, tolerance_um: float,
                    knn: int, tile_mm: float) -> None:
    """Refuse settings that would give meaningless numbers (k: :func:`coverage_rule`)."""
    checks = (("edge margin", margin_mm, 0.0, "mm", True), ("tolerance", tolerance_um, 0.0,
              "um", True), ("tile size", tile_mm, 0.0, "mm", False),
              ("neighbour count", knn, 2, "", False))
    for name, value, bound, unit, inclusive in checks:
        ok = isinstance(value, numbers.Real) and math.isfinite(value) and (
            value >= bound if inclusive else value > bound)
        if not ok:
            raise InputError(f"{name} must be {'>=' if inclusive else '>'} {bound:g} {unit}"
                             f", got {value!r}".replace(" ,", ","))
    if outlier_k is not None and not (math.isfinite(outlier_k) and outlier_k > 0):
        raise InputError(f"outlier rejection K must be > 0 robust std (or not given), got "
                         f"{outlier_k!r}")


def _no_block_message(xyz: np.ndarray, layout: Layout, margin_mm: float) -> str:
    """Why no block holds a point: the extents of the cloud and of the layout [mm]."""
    pts = xyz[np.isfinite(xyz).all(axis=1)]
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    regions = np.array([b.region_mm for b in layout.blocks])
    span_cloud = float(np.max(hi - lo))
    span_layout = float(max(np.ptp(regions[:, :2]), np.ptp(regions[:, 2:])))
    hint = (" The cloud is about 1000 times smaller than the layout: is it in metres? "
            "scanqa reads millimetres." if 0 < span_cloud < span_layout / 100 else
            " Check that cloud and layout share the scanner frame.")
    return (f"no block of the layout holds a point of the cloud (after the {margin_mm:g} mm "
            f"edge margin): the cloud spans X {lo[0]:.4g} to {hi[0]:.4g}, Y {lo[1]:.4g} to "
            f"{hi[1]:.4g} mm; the blocks X {regions[:, 0].min():.4g} to "
            f"{regions[:, 1].max():.4g}, Y {regions[:, 2].min():.4g} to "
            f"{regions[:, 3].max():.4g} mm.{hint}")


def coverage_notes(steps: list[StepResult]) -> list[str]:
    """A note per evaluated step whose stated k covers clearly less than 95.45 % at its
    effective degrees of freedom (the t-distribution's k is > 5 % larger)."""
    notes = []
    for s in steps:
        if s.budget is None or not s.evaluated or s.budget.k_rule == WELCH_SATTERTHWAITE:
            continue
        k_t = coverage_factor(s.budget.nu_eff)
        if math.isfinite(k_t) and k_t > 1.05 * s.k:
            notes.append(f"step {s.block_a}-{s.block_b}: nu_eff = {s.budget.nu_eff:.3g}, for "
                         f"which k = {s.k:g} covers less than 95 % (the t-distribution gives "
                         f"k = {k_t:.3g}); give --k welch-satterthwaite to use it")
    return notes


def coverage_rule(k: float | str | None, budget: BudgetInputs | None) -> float | str:
    """The coverage factor to use: ``k`` when given (a number > 0 or
    "welch-satterthwaite"), else the budget file's, else 2.

    Notes
    -----
    The coverage factor of U = k u (GUM 6.2.1): a stated k, or "welch-satterthwaite" for
    t_95(nu_eff) (GUM G.4.1), else the budget file's k, else 2 (GUM 6.3.3).
    """
    if k is None:
        return budget.coverage_k if budget is not None and budget.coverage_k is not None \
            else 2.0
    if k != WELCH_SATTERTHWAITE and (isinstance(k, bool) or not isinstance(k, (int, float))
                                     or not math.isfinite(k) or not k > 0):
        raise InputError(f"k must be a number > 0 or {WELCH_SATTERTHWAITE!r}, got {k!r}")
    return k


def run_qa(cloud: AnnotatedCloud, layout: Layout, *, config: ScannerConfig | None = None,
           margin_mm: float = 1.0, outlier_k: float | None = None,
           tolerance_um: float | None = None, k: float | str | None = None, knn: int = 16,
           tile_mm: float = TILE_MM, budget: BudgetInputs | None = None,
           calibration: StepGeometry | None = None) -> QAResult:
    """Gauge-block QA of an annotated cloud.

    Parameters
    ----------
    cloud : AnnotatedCloud
        Points in the scanner frame [mm] with the attributes of
        :func:`scanqa.annotation.points.annotate` (any may be missing).
    layout : Layout
        Blocks with nominal heights and regions.
    config : ScannerConfig, optional
        For the model curve when the cloud does not carry the config its sigmas came
        from (clouds written by scanqa carry it).
    margin_mm : float
        Edge margin removed from every region [mm].
    outlier_k : float, optional
        Reject points beyond this many robust std from the first plane fit [-].
    tolerance_um : float, optional
        Tolerance T on each height difference [um]; default :data:`DEFAULT_TOLERANCE_UM`,
        and then the settings, the summary and the verdict line say it was the default.
    k : float or "welch-satterthwaite", optional
        Coverage factor of the expanded uncertainty [-], stated, or from each step's
        effective degrees of freedom; default the budget file's ``[coverage] k``, else 2.
    knn : int
        Neighbours for the per-point local std [-].
    tile_mm : float
        Tile size of the noise-correlation estimate [mm] (module notes).
    budget : BudgetInputs, optional
        Type B inputs of a budget file (:func:`scanqa.qa.budget.load_budget`); without
        one the budgets hold the Type A terms only, and the notes say so.
    calibration : StepGeometry, optional
        The calibration's geometric parameters and covariance
        (:func:`scanqa.calibration.uncertainty.marker_covariance` for a marker table,
        :func:`~scanqa.calibration.uncertainty.parametric_covariance`); each step's
        budget then has a "calibration geometry" line.

    Returns
    -------
    QAResult

    Notes
    -----
    Every block by :func:`analyse_block` and every pair of successive blocks by
    :func:`step_between` (Sect. 4.3, Tables 3 and 4 of the paper; GUM budget and
    ISO 14253-1 decision, docs/qa.rst).
    """
    tolerance_source = "given" if tolerance_um is not None else "default"
    tolerance_um = DEFAULT_TOLERANCE_UM if tolerance_um is None else tolerance_um
    _check_settings(margin_mm, outlier_k, tolerance_um, knn, tile_mm)
    k = coverage_rule(k, budget)
    xyz, attrs = np.asarray(cloud.xyz, dtype=float), cloud.attributes
    if not np.isfinite(xyz).all(axis=1).any():
        raise InputError(f"the cloud has no points with finite coordinates ({len(xyz)} "
                         "points): nothing to measure")
    notes = []
    check_sigmas(attrs)
    has_pred = random_sigma_name(attrs) is not None
    if not has_pred:
        notes.append("the cloud has no sigma attributes: the predicted-std column is missing "
                     "and step uncertainties use the measured residual std instead")
    blocks = [analyse_block(xyz, attrs, spec, margin_mm, outlier_k, tile_mm=tile_mm)
              for spec in layout.blocks]
    if not any(b.n_points for b in blocks):
        raise InputError(_no_block_message(xyz, layout, margin_mm))
    notes += [b.message for b in blocks if b.message]
    notes += [f"block {b.block_id}: only {b.n_tiles} tiles of {tile_mm:g} mm, too few to "
              "measure the noise correlation; its points are taken as independent"
              for b in blocks if b.fit is not None and not np.isfinite(b.noise_corr[0])]
    ordered = sorted((b for b in blocks), key=lambda b: -b.nominal_height_mm)
    n_planes = (cloud.metadata.get("table") or {}).get("n_planes")
    pairs = [(a, b) for a, b in itertools.pairwise(ordered)
             if a.fit is not None and b.fit is not None]
    lines = [None if calibration is None else geometry_component(calibration, xyz, a, b)
             for a, b in pairs]
    notes += [f"step {a.block_id}-{b.block_id}: the calibration-geometry term could not be "
              "computed (the blocks' points do not map through the calibration); left out"
              for (a, b), line in zip(pairs, lines, strict=True)
              if line is not None and not math.isfinite(line.u)]
    term = (cloud.metadata.get("sigma_source") or {}).get("calibration")
    fitted = {(a.block_id, b.block_id): step_between(
        a, b, k, tolerance_um, budget, n_planes,
        line if line is not None and math.isfinite(line.u) else None, term)
        for (a, b), line in zip(pairs, lines, strict=True)}
    steps = [fitted.get((a.block_id, b.block_id)) or unmeasured_step(a, b, tolerance_um)
             for a, b in itertools.pairwise(ordered)]
    notes += coverage_notes(steps)
    if budget is None:
        notes.append("Type B inputs (gauge-block certificates, temperature, stage scale, "
                     "flatness of the calibration flat) are not included: no budget file "
                     "was given; U holds the noise and calibration-table terms only")
    block_id = np.full(len(xyz), -1)
    residual = np.full(len(xyz), np.nan)
    for b in blocks:
        if b.fit is not None:
            block_id[b.index] = b.block_id
            residual[b.index] = b.fit.residuals
    settings = {"margin_mm": margin_mm, "outlier_k": outlier_k, "tolerance_um": tolerance_um,
                "tolerance_source": tolerance_source,
                "k": k, "budget": budget.source if budget is not None else None,
                "max_flagged_fraction": MAX_FLAGGED_FRACTION, "knn": knn, "tile_mm": tile_mm,
                "calibration_geometry": None if calibration is None else calibration.name,
                "layout": layout.source, "paper_comparison": layout.paper_comparison}
    model_config = cloud_config(cloud, config, notes)
    curve = model_curve(blocks, model_config) if model_config is not None else None
    return QAResult(blocks, steps, block_id, 1e3 * residual,
                    1e3 * local_std(xyz, residual, block_id, knn), has_pred, notes, settings,
                    cloud, curve)
