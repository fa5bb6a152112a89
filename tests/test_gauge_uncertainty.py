"""The gauge-block QA's numbers against independent computations (the notes of
:mod:`scanqa.qa.blocks`).

* The table term of a step's u: a Monte Carlo of the calibration table's error field
  (node errors bilinearly interpolated, as the table's lookup does, on a grid of the
  correlation length with a random origin) through the whole QA, and hand values of the
  formula in :func:`scanqa.qa.blocks._table_variance` for its other branches.
* Per-block statistics, the plane covariance and the noise-correlation factor: explicit
  sums and a loop-per-tile sandwich estimator instead of the code's matrix algebra.
* The ISO 14253-1 decision at its boundaries.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.qa import blocks
from scanqa.qa.blocks import BlockResult, StepResult, analyse_block, run_qa, step_between
from scanqa.qa.correlation import noise_correlation
from scanqa.qa.layout import BlockSpec, Layout
from scanqa.qa.planes import PlaneFit, fit_plane, plane_design

# two blocks of the paper's artefact (calib/gauge_blocks_paper.toml, blocks 2 and 3)
BLOCK_A = BlockSpec(2, 25.40, (-14.0, -2.0, -21.0, -3.0), 443.65)
BLOCK_B = BlockSpec(3, 12.70, (2.0, 14.0, -21.0, -3.0), 456.35)
TWO = Layout("two blocks", (BLOCK_A, BLOCK_B))


def _grid(spec: BlockSpec, step: float) -> np.ndarray:
    x0, x1, y0, y1 = spec.region_mm
    x, y = np.meshgrid(np.arange(x0, x1, step) + step / 2, np.arange(y0, y1, step) + step / 2)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, spec.top_z_mm)], -1)


def _bilinear_field(rng, xy: np.ndarray, spacing: float, sigma: float) -> np.ndarray:
    """Independent N(0, sigma) errors on a node grid of ``spacing`` with a random origin,
    interpolated bilinearly at ``xy`` [mm]."""
    g = (xy - xy.min(axis=0) + rng.uniform(0.0, spacing, 2)) / spacing
    i = np.floor(g).astype(int)
    t = g - i
    nodes = rng.normal(0.0, sigma, tuple(i.max(axis=0) + 2))
    out = np.zeros(len(xy))
    for di in (0, 1):
        for dj in (0, 1):
            w = (t[:, 0] if di else 1 - t[:, 0]) * (t[:, 1] if dj else 1 - t[:, 1])
            out += w * nodes[i[:, 0] + di, i[:, 1] + dj]
    return out


def _table_error_cloud(rng, corr_mm: float | None, sigma_tab_um: float, noise_um: float):
    """The two blocks at 0.5 mm spacing: table errors (a field correlated over corr_mm, or
    one offset per block when corr_mm is None) plus independent point noise along Z."""
    xyz = np.concatenate([_grid(BLOCK_A, 0.5), _grid(BLOCK_B, 0.5)])
    if corr_mm is None:
        tab = np.where(xyz[:, 0] < 0, *rng.normal(0.0, sigma_tab_um * 1e-3, 2))
    else:
        tab = _bilinear_field(rng, xyz[:, :2], corr_mm, sigma_tab_um * 1e-3)
    xyz[:, 2] += tab + rng.normal(0.0, noise_um * 1e-3, len(xyz))
    attrs = {"sigma_model_um": np.full(len(xyz), noise_um),
             "sigma_calibration_um": np.full(len(xyz), sigma_tab_um)}
    if corr_mm is not None:
        attrs["table_corr_mm"] = np.full(len(xyz), corr_mm)
    return xyz, attrs


def _monte_carlo(corr_mm: float | None, trials: int, seed: int) -> tuple[float, float]:
    """RMS of the step error over ``trials`` draws of the table and the noise, and the mean
    u the QA propagated [um] (blocks with a 1 mm edge margin, as run_qa's default)."""
    rng = np.random.default_rng(seed)
    errors, us = [], []
    for _ in range(trials):
        xyz, attrs = _table_error_cloud(rng, corr_mm, sigma_tab_um=5.0, noise_um=1.0)
        a, b = (analyse_block(xyz, attrs, spec, 1.0, None) for spec in (BLOCK_A, BLOCK_B))
        step = step_between(a, b, 2.0, 20.0)  # what run_qa does, without the per-point fields
        errors.append(step.error_um)
        us.append(step.u_um)
    return float(np.sqrt(np.mean(np.square(errors)))), float(np.mean(us))


def test_table_term_of_u_matches_a_monte_carlo_of_the_table_field():
    """Table errors of 5 um correlated over 2 mm, point noise 1 um: the step error's RMS
    over 200 simulated tables is the propagated u. Without the table term u would be
    ~0.1 um; without the tilt it carries over the 16 mm lever, ~1.2 um; the simulated RMS is
    ~3.9 um. The formula counts a block as area / corr^2 independent patches, which
    overstates the error of a bilinear field by ~15 % here (conservative): the band is
    0.75 .. 1.1 (the Monte Carlo's own scatter is ~5 %)."""
    rms, u = _monte_carlo(2.0, trials=200, seed=7)
    assert 3.0 < rms < 5.0, rms
    assert 0.75 < rms / u < 1.1, (rms, u)


def test_table_term_without_correlation_length_is_a_shift_per_block():
    """Without table_corr_mm the table error is one offset per block: the step's error is
    the difference of two N(0, 5 um) offsets, sqrt(2) * 5 = 7.07 um, plus ~0.1 um of noise."""
    rms, u = _monte_carlo(None, trials=150, seed=11)
    np.testing.assert_allclose(u, math.hypot(5.0, 5.0), rtol=0.01)
    assert 0.88 < rms / u < 1.12, (rms, u)  # 150 trials: ~6 % scatter of an RMS


def _block(block_id, centroid, spread, corr, sigma_tab_um, u_plane=None, height=10.0):
    """A BlockResult with a horizontal plane facing the camera (axes X and Y)."""
    fit = PlaneFit(np.asarray(centroid, float), np.array([0.0, 0.0, -1.0]), np.zeros(3),
                   np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    return BlockResult(block_id, height, fit=fit, spread_mm=spread, table_corr_mm=corr,
                       table_sigma_um=sigma_tab_um,
                       u_plane=np.zeros((3, 3)) if u_plane is None else u_plane)


def test_step_uncertainty_hand_values():
    """The step's u (scanqa.qa.blocks notes): block a (spread 3 x 4 mm, corr 2 mm,
    sigma_tab 5 um) is 12 * 3 * 4 / 2^2 = 36 patches, block b (2 x 5 mm, 1 mm, 3 um)
    12 * 2 * 5 / 1 = 120; b's centroid is 16 mm along a's first axis and -2 mm along its
    second. Variance [um^2]: 25 / 36 (a's shift) + 9 / 120 (b's shift)
    + 25 / 36 * ((16 / 3)^2 + (2 / 4)^2) (a's tilt)."""
    a = _block(2, (-8.0, -12.0, 443.65), (3.0, 4.0), 2.0, 5.0, height=25.4)
    b = _block(3, (8.0, -14.0, 456.35), (2.0, 5.0), 1.0, 3.0, height=12.7)
    step = step_between(a, b, 2.0, 20.0)
    want = math.sqrt(25 / 36 + 9 / 120 + 25 / 36 * ((16 / 3) ** 2 + (2 / 4) ** 2))
    np.testing.assert_allclose(step.u_um, want, rtol=1e-12)
    # the measured difference: b's centroid below a's plane along a's normal
    np.testing.assert_allclose(step.measured_diff_mm, 12.7, rtol=1e-12)
    assert step.nominal_diff_mm == pytest.approx(12.7, rel=1e-12)
    assert (step.block_a, step.block_b, step.k, step.tolerance_um) == (2, 3, 2.0, 20.0)
    np.testing.assert_allclose(step.expanded_um, 2 * want, rtol=1e-12)
    # the lever's sign does not matter, its size does (16 -> 8 mm along a's first axis)
    b_near = _block(3, (0.0, -10.0, 456.35), (2.0, 5.0), 1.0, 3.0)
    want_near = math.sqrt(25 / 36 + 9 / 120 + 25 / 36 * ((8 / 3) ** 2 + (2 / 4) ** 2))
    np.testing.assert_allclose(step_between(a, b_near, 2.0, 20.0).u_um, want_near, rtol=1e-12)


def test_step_uncertainty_plane_terms_by_hand():
    """The plane's variance at b's centroid, g^T U_a g with g = (1, 16, -2), plus the
    variance of b's offset U_b[0, 0]; the table term absent (sigma_tab 0)."""
    u_a = np.array([[1.0e-6, 2.0e-8, 0.0], [2.0e-8, 1.0e-8, 0.0], [0.0, 0.0, 4.0e-8]])
    u_b = np.diag([3.0e-6, 9.0, 9.0])  # b's slopes do not enter
    a = _block(2, (-8.0, -12.0, 443.65), (3.0, 4.0), 2.0, 0.0, u_a)
    b = _block(3, (8.0, -14.0, 456.35), (2.0, 5.0), 1.0, 0.0, u_b)
    var = 1.0e-6 + 2 * 16 * 2.0e-8 + 16**2 * 1.0e-8 + 2**2 * 4.0e-8 + 3.0e-6  # [mm^2]
    np.testing.assert_allclose(step_between(a, b, 2.0, 20.0).u_um, 1e3 * math.sqrt(var),
                               rtol=1e-12)


def test_small_blocks_count_at_least_one_patch():
    """A block smaller than the correlation area is one patch (not a fraction of one):
    12 * 0.1 * 0.1 / 2^2 = 0.03 -> 1 for both; tilt (16 / 0.1)^2."""
    a = _block(2, (-8.0, -12.0, 443.65), (0.1, 0.1), 2.0, 5.0)
    b = _block(3, (8.0, -12.0, 456.35), (0.1, 0.1), 2.0, 3.0)
    want = math.sqrt(25 + 9 + 25 * (16 / 0.1) ** 2)
    np.testing.assert_allclose(step_between(a, b, 2.0, 20.0).u_um, want, rtol=1e-12)


@pytest.mark.parametrize("which", ["a", "b", "both"])
def test_missing_correlation_length_takes_each_block_as_one_patch(which):
    """Without the correlation length of either block: u^2 = sigma_a^2 + sigma_b^2."""
    a = _block(2, (-8.0, -12.0, 443.65), (3.0, 4.0), 2.0, 5.0)
    b = _block(3, (8.0, -12.0, 456.35), (2.0, 5.0), 1.0, 3.0)
    if which in ("a", "both"):
        a = dataclasses.replace(a, table_corr_mm=math.nan)
    if which in ("b", "both"):
        b = dataclasses.replace(b, table_corr_mm=math.nan)
    np.testing.assert_allclose(step_between(a, b, 2.0, 20.0).u_um, math.hypot(5.0, 3.0),
                               rtol=1e-12)


def _checkerboard_block(step: float = 0.5, delta_um: float = 3.0):
    """Block A's grid with residuals +-delta in a checkerboard (orthogonal to 1, x, y on a
    symmetric grid), per-point sigma, attenuation, flags and table attributes."""
    pts = _grid(BLOCK_A, step)
    ix = np.round((pts[:, 0] - pts[:, 0].min()) / step).astype(int)
    iy = np.round((pts[:, 1] - pts[:, 1].min()) / step).astype(int)
    sign = np.where((ix + iy) % 2 == 0, 1.0, -1.0)
    pts[:, 2] -= sign * delta_um * 1e-3  # towards the camera: a positive residual
    n = len(pts)
    rng = np.random.default_rng(5)
    attrs = {"sigma_model_um": rng.uniform(2.0, 6.0, n),
             "sigma_calibration_um": rng.uniform(0.5, 1.5, n),
             "table_corr_mm": rng.choice([0.4, 0.5, 0.9], n),
             "att_camera": rng.uniform(0.5, 1.0, n), "att_projector": rng.uniform(0.6, 1.0, n),
             "in_volume": (rng.uniform(size=n) < 0.8).astype(float),
             "model_valid": (rng.uniform(size=n) < 0.6).astype(float)}
    return pts, attrs, sign


def test_block_statistics_by_explicit_sums():
    """Every per-block number of a block with known residuals, from explicit sums; the
    normal is -Z, so the cosine of each point's line of sight is Z / |Q|."""
    pts, attrs, sign = _checkerboard_block()
    res = analyse_block(pts, attrs, BLOCK_A, margin=0.0, outlier_k=None)
    n = len(pts)
    assert res.n_points == n and res.outliers == 0
    # ~20 % of the points outside the volume (> 5 %): flagged, though it has a plane
    outside = 100 * (1 - sum(attrs["in_volume"]) / n)
    assert 15 < outside < 25
    assert (res.status, res.message) == (
        "outside_volume", f"block 2: {outside:.0f} % of its points lie outside the calibrated "
        "volume (more than 5 %): flagged, its steps are not evaluated")
    np.testing.assert_allclose(res.fit.residuals, sign * 3e-3, atol=1e-12)
    np.testing.assert_allclose(res.measured_std_um, 3.0 * math.sqrt(n / (n - 3)), rtol=1e-9)
    np.testing.assert_allclose(res.flatness_um, 6.0, rtol=1e-9)
    cos = pts[:, 2] / np.linalg.norm(pts, axis=1)
    np.testing.assert_allclose(res.predicted_std_um,
                               math.sqrt(sum((attrs["sigma_model_um"] * cos) ** 2) / n),
                               rtol=1e-9)
    np.testing.assert_allclose(res.table_sigma_um,
                               math.sqrt(sum((attrs["sigma_calibration_um"] * cos) ** 2) / n),
                               rtol=1e-9)
    assert res.table_corr_mm == float(np.median(attrs["table_corr_mm"]))
    np.testing.assert_allclose(res.mean_attenuation,
                               np.mean(attrs["att_camera"] * attrs["att_projector"]), rtol=1e-12)
    np.testing.assert_allclose(res.in_volume_fraction, np.mean(attrs["in_volume"]), rtol=1e-12)
    np.testing.assert_allclose(res.model_valid_fraction, np.mean(attrs["model_valid"]),
                               rtol=1e-12)
    np.testing.assert_allclose(res.mean_z_mm, BLOCK_A.top_z_mm, atol=1e-6)
    # the grid is 24 x 36 points at 0.5 mm: axis stds sqrt((m^2 - 1) / 12) * 0.5
    spreads = sorted(res.spread_mm)
    np.testing.assert_allclose(spreads, [0.5 * math.sqrt((24**2 - 1) / 12),
                                         0.5 * math.sqrt((36**2 - 1) / 12)], rtol=1e-9)
    np.testing.assert_allclose(res.sigma_n, attrs["sigma_model_um"] * 1e-3 * cos, rtol=1e-12)
    assert res.row()["n_points"] == n and res.ratio == res.measured_std_um / res.predicted_std_um


def test_plane_covariance_by_explicit_sums():
    """Offset and slope covariance of a least-squares plane with per-point sigma_i, by the
    sums of the normal equations on a symmetric grid (sum s = 0, sum s_1 s_2 = 0):
    var(offset) = sum sigma^2 / n^2, var(slope_k) = sum sigma^2 s_k^2 / (sum s_k^2)^2,
    cov(offset, slope_k) = sum sigma^2 s_k / (n sum s_k^2). The checkerboard residuals
    cancel in every tile, so the noise-correlation factor is 1."""
    pts, attrs, _ = _checkerboard_block()
    res = analyse_block(pts, attrs, BLOCK_A, margin=0.0, outlier_k=None)
    np.testing.assert_allclose(res.noise_corr, 1.0)
    assert res.n_tiles == 6 * 9  # 12 x 18 mm in 2 mm tiles
    d = pts - pts.mean(axis=0)
    s = np.stack([d @ res.fit.axes[0], d @ res.fit.axes[1]])
    v = res.sigma_n**2
    n = len(pts)
    want = np.empty((3, 3))
    want[0, 0] = v.sum() / n**2
    for k in range(2):
        ssk = (s[k] ** 2).sum()
        want[0, k + 1] = want[k + 1, 0] = (v * s[k]).sum() / (n * ssk)
        for j in range(2):
            want[k + 1, j + 1] = (v * s[k] * s[j]).sum() / (ssk * (s[j] ** 2).sum())
    np.testing.assert_allclose(res.u_plane, want, rtol=1e-9, atol=1e-20)
    # tiles too large to count 8 of them: no factor measured (NaN), none applied
    res = analyse_block(pts, attrs, BLOCK_A, margin=0.0, outlier_k=None, tile_mm=10.0)
    assert np.isnan(res.noise_corr).all() and res.n_tiles == 4
    np.testing.assert_allclose(res.u_plane, want, rtol=1e-9, atol=1e-20)


def _sandwich_by_tiles(pts: np.ndarray, residuals: np.ndarray, tile: float | None):
    """Cluster-robust variances of (offset, slope_1, slope_2) of the plane, one tile (or one
    point, tile None) per cluster, with K / (K - 3) for K clusters; loops over a dict."""
    fit = fit_plane(pts)
    d = pts - fit.centroid
    rows = [(1.0, p @ fit.axes[0], p @ fit.axes[1]) for p in d]
    a = np.array(rows)
    bread = np.linalg.inv(a.T @ a)
    lo = a[:, 1:].min(axis=0)
    clusters: dict = {}
    for i, (row, r) in enumerate(zip(rows, residuals, strict=True)):
        key = i if tile is None else (math.floor((row[1] - lo[0]) / tile),
                                      math.floor((row[2] - lo[1]) / tile))
        acc = clusters.setdefault(key, np.zeros(3))
        acc += np.array(row) * r
    meat = sum(np.outer(g, g) for g in clusters.values())
    if tile is not None:
        meat *= len(clusters) / (len(clusters) - 3)
    return np.diag(bread @ meat @ bread), clusters


def test_noise_correlation_matches_a_loop_per_tile_sandwich():
    """kappa = (tile-clustered sandwich variance) / (per-point sandwich variance), >= 1, on
    noise shared by 3 x 3 points (0.75 mm patches): by a loop over a dict of tiles."""
    rng = np.random.default_rng(3)
    pts = _grid(BLOCK_A, 0.25)
    patch = np.floor((pts[:, :2] - pts[:, :2].min(axis=0)) / 0.75 + 1e-9).astype(int)
    _, pid = np.unique(patch, axis=0, return_inverse=True)
    pts[:, 2] += rng.normal(0.0, 5e-3, pid.max() + 1)[pid.ravel()]
    fit = fit_plane(pts)
    a = plane_design(pts, fit)
    kappa, n_tiles = noise_correlation(a, fit.residuals, a[:, 1:], 2.0)
    v_tiles, tiles = _sandwich_by_tiles(pts, fit.residuals, 2.0)
    v_points, _ = _sandwich_by_tiles(pts, fit.residuals, None)
    np.testing.assert_allclose(kappa, np.maximum(1.0, v_tiles / v_points), rtol=1e-9)
    assert n_tiles == len(tiles) == 6 * 9
    assert np.all(kappa > 3.0)  # 9 points share a draw
    # a factor below 1 is clipped: alternating residuals cancel within every tile
    alt = np.where(np.arange(len(pts)) % 2 == 0, 1e-3, -1e-3)
    kappa, _ = noise_correlation(a, alt, a[:, 1:], 2.0)
    np.testing.assert_array_equal(kappa, 1.0)


def test_noise_correlation_needs_eight_tiles_of_three_points():
    """MIN_TILES = 8 tiles holding >= 3 points: 4 x 2 tiles of 3 points give a number; with
    one point fewer in one tile (7 usable) or 2 points per tile (0 usable), NaN."""
    # 3 points inside each 2 mm tile; tiles 2.137 x 2.173 mm apart, so that no point falls
    # on a tile edge whichever corner the tiling starts from
    pattern = [(0.5, 0.6), (0.9, 1.0), (1.3, 0.6)]

    def run(per_tile: int, short_tiles: int):
        pts = []
        for t, (i, j) in enumerate((i, j) for i in range(4) for j in range(2)):
            n = per_tile - (t < short_tiles)
            pts += [[2.137 * i + x, 2.173 * j + y, 450.0 + 1e-3 * (k - 1) * (-1) ** t]
                    for k, (x, y) in enumerate(pattern[:n])]
        pts = np.array(pts)
        fit = fit_plane(pts)
        a = plane_design(pts, fit)
        return noise_correlation(a, fit.residuals, a[:, 1:], 2.0)

    kappa, n = run(3, 0)
    assert n == 8 and np.isfinite(kappa).all()
    kappa, n = run(3, 1)
    assert n == 7 and np.isnan(kappa).all()
    kappa, n = run(2, 0)
    assert n == 0 and np.isnan(kappa).all()


# T = 19.53125 um, U = 3.90625 um: T - U = 15.625 and T + U = 23.4375 um; errors of
# 1000 x (a binary fraction of a mm) are exact in float64, so the boundaries are hit exactly
@pytest.mark.parametrize(("measured_mm", "expanded_um", "decision"), [
    (0.0, 0.0, "pass"), (1 / 64, 3.90625, "pass"), (-1 / 64, 3.90625, "pass"),
    (1 / 64 + 2**-20, 3.90625, "undecided"), (3 / 128, 3.90625, "undecided"),
    (3 / 128 + 2**-20, 3.90625, "fail"), (-3 / 128 - 2**-20, 3.90625, "fail"),
    (math.nan, 3.90625, "not evaluated"), (1e-3, math.inf, "not evaluated"),
])
def test_iso_14253_decision_at_its_boundaries(measured_mm, expanded_um, decision):
    """ISO 14253-1 with k = 2 (U = 2 u): pass when |e| <= T - U, fail when |e| > T + U."""
    step = StepResult(1, 2, 0.0, measured_mm, expanded_um / 2, 2.0, 19.53125)
    assert step.decision == decision
    np.testing.assert_allclose(step.error_um, 1e3 * measured_mm)
    assert step.expanded_um == expanded_um
    assert step.row()["decision"] == decision


def test_summary_counts_evaluated_steps():
    """A block outside the calibrated volume is flagged: its step stays in the table, "not
    evaluated" (no decision), and out of the counts of steps within U."""
    xyz = np.concatenate([_grid(BLOCK_A, 0.5), _grid(BLOCK_B, 0.5)])
    n = len(xyz)
    attrs = {"sigma_model_um": np.full(n, 1.0), "in_volume": np.ones(n)}
    res = run_qa(AnnotatedCloud(xyz, attrs), TWO)
    info = res.summary()
    assert (info["steps_evaluated"], info["steps_not_evaluated"]) == (1, 0)
    assert info["steps_error_within_U"] == 1 and info["fraction_within_U"] == 1.0
    assert (info["blocks_ok"], info["blocks_flagged"]) == (2, 0)
    # a perfect cloud: error 0 <= T - U, so "pass"
    assert info["decisions"] == {"pass": 1, "fail": 0, "undecided": 0, "not evaluated": 0}
    attrs["in_volume"][xyz[:, 0] > 0] = 0.0
    res = run_qa(AnnotatedCloud(xyz, attrs), TWO)
    assert [b.status for b in res.blocks] == ["ok", "outside_volume"]
    (step,) = res.steps
    assert (step.evaluated, step.decision, step.note) == (False, "not evaluated",
                                                          "not evaluated: block 3 flagged")
    assert step.within_u  # |error| <= U, but not counted: the step is not evaluated
    assert res.steps_evaluated() == []
    info = res.summary()
    assert (info["steps_evaluated"], info["steps_not_evaluated"]) == (0, 1)
    assert info["steps_error_within_U"] == 0 and info["fraction_within_U"] is None
    assert (info["blocks_ok"], info["blocks_flagged"]) == (1, 1)
    assert info["decisions"] == {"pass": 0, "fail": 0, "undecided": 0, "not evaluated": 1}
    step = info["steps"][0]
    assert step["decision"] == "not evaluated" and step["evaluated"] is False


def test_robust_std_hand_values():
    """1.4826 x the median absolute deviation; the plain std when the MAD is 0; 1e-12 mm
    when both are 0 (a perfectly flat block)."""
    r = np.array([1.0, 2.0, 3.0, 4.0, 100.0])  # median 3, |r - 3| = 2 1 0 1 97: MAD 1
    assert blocks._spread(r) == pytest.approx(1.4826, rel=1e-15)
    r = np.array([0.0, 0.0, 0.0, 0.0, 5.0])  # MAD 0: std = sqrt(mean((r - 1)^2)) = 2
    assert blocks._spread(r) == pytest.approx(2.0, rel=1e-15)
    assert blocks._spread(np.zeros(6)) == 1e-12


def test_outliers_beyond_k_robust_std_are_dropped():
    """Five spikes of 1 mm on a block with 2 um noise: with outlier_k = 5 exactly the
    spikes go and the refit has the noise's std; without, they stay."""
    rng = np.random.default_rng(12)
    pts = _grid(BLOCK_A, 0.5)
    pts[:, 2] += rng.normal(0.0, 2e-3, len(pts))
    spikes = np.array([10, 200, 400, 600, 800])
    pts[spikes, 2] -= 1.0
    res = analyse_block(pts, {}, BLOCK_A, margin=0.0, outlier_k=5.0)
    assert res.outliers == 5 and res.n_points == len(pts) - 5
    assert not np.isin(spikes, res.index).any()
    assert res.measured_std_um == pytest.approx(2.0, rel=0.1)
    kept = analyse_block(pts, {}, BLOCK_A, margin=0.0, outlier_k=None)
    assert kept.outliers == 0 and kept.measured_std_um > 50.0
    # without predicted sigmas the per-point sigma is the measured std
    np.testing.assert_allclose(res.sigma_n, res.measured_std_um * 1e-3)
    assert math.isnan(res.predicted_std_um) and res.table_sigma_um == 0.0
    assert math.isnan(res.table_corr_mm)


def test_plane_covariance_is_scaled_by_the_noise_correlation():
    """With noise shared by 3 x 3 points the covariance is the explicit-sums one times
    sqrt(kappa_i kappa_j), kappa from the loop-per-tile sandwich."""
    rng = np.random.default_rng(21)
    pts = _grid(BLOCK_A, 0.25)
    patch = np.floor((pts[:, :2] - pts[:, :2].min(axis=0)) / 0.75 + 1e-9).astype(int)
    _, pid = np.unique(patch, axis=0, return_inverse=True)
    pts[:, 2] += rng.normal(0.0, 4e-3, pid.max() + 1)[pid.ravel()]
    attrs = {"sigma_model_um": rng.uniform(3.0, 5.0, len(pts))}
    res = analyse_block(pts, attrs, BLOCK_A, margin=0.0, outlier_k=None)
    v_tiles, _ = _sandwich_by_tiles(pts, res.fit.residuals, 2.0)
    v_points, _ = _sandwich_by_tiles(pts, res.fit.residuals, None)
    kappa = np.maximum(1.0, v_tiles / v_points)
    assert np.all(kappa > 2.0)
    np.testing.assert_allclose(res.noise_corr, kappa, rtol=1e-9)
    d = pts - pts.mean(axis=0)
    a = np.column_stack([np.ones(len(pts)), d @ res.fit.axes[0], d @ res.fit.axes[1]])
    bread = np.linalg.inv(a.T @ a)
    base = bread @ (a.T * res.sigma_n**2) @ a @ bread
    np.testing.assert_allclose(res.u_plane, base * np.sqrt(np.outer(kappa, kappa)), rtol=1e-9)


# -- the GUM budget of a step (docs/uncertainty_budget.rst) ------------------------------

def _budget_blocks(n_tiles_a: int = 13, n_tiles_b: int = 23):
    """Block a: noise 2 um at b's centroid, block b: 3 um mean height, table sigmas 1.2 and
    1.6 um without a correlation length (2 um for the step); noise factors measured on
    n_tiles_a and n_tiles_b tiles."""
    u_a = np.diag([4.0e-6, 0.0, 0.0])
    u_b = np.diag([9.0e-6, 1.0, 1.0])
    a = _block(2, (-8.0, -12.0, 443.65), (3.0, 4.0), math.nan, 1.2, u_a, height=25.4)
    b = _block(3, (8.0, -14.0, 456.35), (2.0, 5.0), math.nan, 1.6, u_b, height=12.7)
    return tuple(dataclasses.replace(blk, n_tiles=tiles, noise_corr=(1.5, 1, 1), n_points=500,
                                     status="ok")
                 for blk, tiles in ((a, n_tiles_a), (b, n_tiles_b)))


def test_budget_type_a_terms_and_their_degrees_of_freedom():
    """Three Type A lines, 2, 3 and 2 um, with K - 3 = 10 and 20 dof for the noise terms
    and M - 4 = 10 for the table from 14 planes: u = sqrt(17) um and
    nu_eff = 17^2 / (2^4 / 10 + 3^4 / 20 + 2^4 / 10) = 289 / 7.25."""
    a, b = _budget_blocks()
    step = step_between(a, b, 2.0, 20.0, None, 14)
    rows = [c.row() for c in step.budget.components]
    assert [(r["component"], r["type"], r["unit"], r["c_um_per_unit"], r["dof"])
            for r in rows] == [("noise, plane of block 2 at block 3", "A", "um", 1.0, 10.0),
                               ("noise, mean height of block 3", "A", "um", 1.0, 20.0),
                               ("calibration table", "A", "um", 1.0, 10.0)]
    assert rows[0]["source"] == "model sigma x measured correlation (13 tiles)"
    assert rows[1]["source"] == "model sigma x measured correlation (23 tiles)"
    assert rows[2]["source"] == ("node fits over the calibration planes, scaled by their "
                                 "reduced chi-square")
    np.testing.assert_allclose([r["u"] for r in rows], [2.0, 3.0, 2.0], rtol=1e-12)
    np.testing.assert_allclose(step.u_um, math.sqrt(17.0), rtol=1e-12)
    np.testing.assert_allclose(step.budget.nu_eff, 289 / 7.25, rtol=1e-12)
    assert step.k == 2.0 and step.row()["nu_eff"] == pytest.approx(289 / 7.25, rel=1e-12)
    assert step.evaluated and step.note == "" and not step.budget.type_b_included
    # the table's dof: none known (no plane count, or too few planes for a node's 4
    # parameters) is infinite; 5 planes leave 1
    for n_planes, dof in ((None, None), (4, None), (5, 1.0), (0, None)):
        comp = step_between(a, b, 2.0, 20.0, None, n_planes).budget.components[2]
        assert comp.row()["dof"] == dof, n_planes


def test_budget_dof_of_unmeasured_noise_correlation_and_std_u():
    """Without a measured noise factor a block's points count as independent: the noise
    term has n - 3 dof, and the measured std's u is s / sqrt(2 (n - 3)); with a factor
    kappa, n / kappa - 3 (at least 1 either way)."""
    a, b = _budget_blocks(n_tiles_a=8, n_tiles_b=4)
    b = dataclasses.replace(b, noise_corr=(math.nan,) * 3)
    step = step_between(a, b, 2.0, 20.0)
    assert [c.dof for c in step.budget.components] == [5.0, 497.0, math.inf]
    a, b = (dataclasses.replace(x, measured_std_um=6.0) for x in (a, b))
    np.testing.assert_allclose(a.std_u_um, 6.0 / math.sqrt(2 * (500 / 1.5 - 3)), rtol=1e-12)
    np.testing.assert_allclose(b.std_u_um, 6.0 / math.sqrt(2 * 497), rtol=1e-12)
    a = dataclasses.replace(a, n_tiles=2, n_points=2)
    assert a.noise_dof == 1.0 and a.std_u_um == 6.0 / math.sqrt(2.0)
    b = dataclasses.replace(b, n_points=3)
    assert b.noise_dof == 1.0


def test_welch_satterthwaite_coverage_factor():
    """k = t_0.975(nu_eff): one term with 10 dof (the others zero) gives nu_eff = 10 and
    Student's table value 2.228; two equal terms of 10 dof give 20 and 2.086."""
    a, b = _budget_blocks()
    a = dataclasses.replace(a, table_sigma_um=0.0)
    b = dataclasses.replace(b, table_sigma_um=0.0, u_plane=np.zeros((3, 3)))
    step = step_between(a, b, "welch-satterthwaite", 20.0)
    np.testing.assert_allclose(step.budget.nu_eff, 10.0, rtol=1e-12)
    np.testing.assert_allclose(step.k, 2.228139, rtol=1e-6)
    np.testing.assert_allclose(step.expanded_um, 2.228139 * 2.0, rtol=1e-6)
    b = dataclasses.replace(b, u_plane=np.diag([4.0e-6, 0.0, 0.0]), n_tiles=13)
    step = step_between(a, b, "welch-satterthwaite", 20.0)
    np.testing.assert_allclose(step.budget.nu_eff, 20.0, rtol=1e-12)
    np.testing.assert_allclose(step.k, 2.085963, rtol=1e-6)
    assert step.budget.summary()["k_rule"] == "welch-satterthwaite"


def test_budget_type_b_terms_from_the_inputs():
    """A budget file's inputs for blocks of 25.4 and 12.7 mm (d = 12.7 mm): certificates
    (0.1 + 0.001 L) / 2 per block, temperature 0.2 K x 1e3 alpha d, alpha's 1e-6 /K x
    1e3 d dT, stage 20 ppm x 1e-3 d, flatness 0.5 / sqrt(6); the reference is corrected
    by 1e3 d alpha dT = 0.073025 um; the budget's k applies when none is stated."""
    from scanqa.io.budget import BudgetInputs

    inputs = BudgetInputs("b.toml", 0.1, 0.001, 2.0, 0.5, 0.2, 11.5e-6, 1.0e-6, 20.0, 0.5,
                          3.0)
    a, b = _budget_blocks()
    step = step_between(a, b, None, 20.0, inputs)
    extra = [0.5 * math.hypot(0.1 + 0.0254, 0.1 + 0.0127), 0.2 * 11.5e-3 * 12.7,
             1.0e-6 * 1e3 * 12.7 * 0.5, 20.0 * 12.7e-3, 0.5 / math.sqrt(6.0)]
    got = [c.contribution_um for c in step.budget.components]
    np.testing.assert_allclose(got, [2.0, 3.0, 2.0, *extra], rtol=1e-12)
    assert [c.kind for c in step.budget.components] == ["A"] * 3 + ["B"] * 5
    np.testing.assert_allclose(step.u_um, math.sqrt(17.0 + sum(x * x for x in extra)),
                               rtol=1e-12)
    assert step.k == 3.0 and step.budget.type_b_included
    step_b = dataclasses.replace(step, measured_diff_mm=12.7 + 0.001)
    np.testing.assert_allclose(step_b.error_um, 1.0 - 1e3 * 12.7 * 11.5e-6 * 0.5, rtol=1e-9)
    # a stated k wins over the budget's
    assert step_between(a, b, 2.5, 20.0, inputs).k == 2.5


def test_coverage_rule_and_bad_k():
    """k given: used; not given: the budget file's [coverage] k, else 2; anything but a
    number > 0 or "welch-satterthwaite" is refused with one message."""
    from scanqa.errors import InputError
    from scanqa.io.budget import BudgetInputs

    assert blocks.coverage_rule(None, None) == 2.0
    assert blocks.coverage_rule(None, BudgetInputs()) == 2.0
    assert blocks.coverage_rule(None, BudgetInputs(coverage_k=2.6)) == 2.6
    assert blocks.coverage_rule(None, BudgetInputs(coverage_k="welch-satterthwaite")) == \
        "welch-satterthwaite"
    assert blocks.coverage_rule(1.5, BudgetInputs(coverage_k=2.6)) == 1.5
    assert blocks.coverage_rule(3, None) == 3
    assert blocks.coverage_rule("welch-satterthwaite", None) == "welch-satterthwaite"
    for bad in (0.0, -1.0, True, math.nan, math.inf, "student", [2.0]):
        with pytest.raises(InputError, match=r"^k must be a number > 0 or "
                                             r"'welch-satterthwaite', got "):
            blocks.coverage_rule(bad, None)


def test_flagged_blocks_name_themselves_in_the_step_note():
    a, b = _budget_blocks()
    a = dataclasses.replace(a, status="model_invalid")
    step = step_between(a, b, 2.0, 20.0)
    assert (step.evaluated, step.note) == (False, "not evaluated: block 2 flagged")
    b = dataclasses.replace(b, status="outside_volume")
    step = step_between(a, b, 2.0, 20.0)
    assert step.note == "not evaluated: block 2 and 3 flagged"
    assert step.decision == "not evaluated" and step.row()["evaluated"] is False
    a = dataclasses.replace(a, status="ok")
    assert step_between(a, b, 2.0, 20.0).note == "not evaluated: block 3 flagged"


def test_run_qa_with_a_budget_file_and_the_table_planes():
    """run_qa hands the budget's inputs and the cloud's table plane count to every step:
    the Type B lines are in, the note about their absence is not, the settings name the
    file, and the table term has M - 4 dof."""
    from scanqa.io.budget import BudgetInputs

    xyz = np.concatenate([_grid(BLOCK_A, 0.5), _grid(BLOCK_B, 0.5)])
    n = len(xyz)
    attrs = {"sigma_model_um": np.full(n, 1.0), "sigma_calibration_um": np.full(n, 0.5)}
    cloud = AnnotatedCloud(xyz, attrs, metadata={"table": {"n_planes": 12}})
    inputs = BudgetInputs("budget.toml", flatness_um=0.6, coverage_k="welch-satterthwaite")
    res = run_qa(cloud, TWO, budget=inputs)
    (step,) = res.steps
    names = [c.name for c in step.budget.components]
    assert names[3:] == ["flatness of the calibration flat"] and len(names) == 4
    assert step.budget.components[2].dof == 8.0
    assert res.settings["budget"] == "budget.toml" and res.settings["k"] == "welch-satterthwaite"
    assert not any("Type B" in note for note in res.notes)
    assert res.type_b_included and res.summary()["type_b_included"] is True
    # the flatness term alone is 0.6 / sqrt(6) = 0.245 um: u is above it
    assert step.u_um > 0.6 / math.sqrt(6.0)
    assert math.isfinite(step.k) and step.k > 1.96
    res = run_qa(AnnotatedCloud(xyz, attrs), TWO)
    assert res.steps[0].budget.components[2].dof == math.inf and not res.type_b_included
