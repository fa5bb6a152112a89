"""What the gauge-block QA hands on: column names, notes, statuses at their thresholds,
the model curve and the per-point fields, each against a value worked out here."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.numeric import json_ready
from scanqa.qa import blocks
from scanqa.qa.blocks import StepResult, analyse_block, run_qa
from scanqa.qa.layout import BlockSpec, Layout

from .model_reference import reference_point

BLOCK_A = BlockSpec(2, 25.40, (-14.0, -2.0, -21.0, -3.0), 443.65)
BLOCK_B = BlockSpec(3, 12.70, (2.0, 14.0, -21.0, -3.0), 456.35)
BLOCK_C = BlockSpec(4, 7.62, (18.0, 30.0, -21.0, -3.0), 461.43)
THREE = Layout("three blocks", (BLOCK_B, BLOCK_C, BLOCK_A), source="three.toml")

BLOCK_COLUMNS = ["block_id", "nominal_height_mm", "n_points", "measured_std_um",
                 "measured_std_u_um", "predicted_std_um", "ratio", "flatness_um",
                 "mean_attenuation", "in_volume_fraction", "model_valid_fraction", "status",
                 "noise_corr_factor", "n_tiles"]
STEP_COLUMNS = ["block_a", "block_b", "nominal_diff_mm", "measured_diff_mm", "error_um",
                "u_um", "nu_eff", "U_um", "k", "tolerance_um", "decision", "within_U",
                "evaluated"]
SUMMARY_KEYS = ["format", "verdict", "tolerance_um", "tolerance_source", "settings", "model",
                "sigma_source", "has_prediction", "blocks", "blocks_ok",
                "blocks_flagged", "steps", "budgets", "type_b_included", "steps_evaluated",
                "steps_not_evaluated", "steps_error_within_U", "fraction_within_U",
                "decisions", "max_abs_ratio_deviation", "notes"]
#: the note of every run without a budget file
NO_TYPE_B = ("Type B inputs (gauge-block certificates, temperature, stage scale, flatness of "
             "the calibration flat) are not included: no budget file was given; U holds the "
             "noise and calibration-table terms only")


def _cloud(seed: int = 0, specs=(BLOCK_A, BLOCK_B, BLOCK_C), sigma_um: float = 2.0,
           step: float = 0.5):
    rng = np.random.default_rng(seed)
    pts = []
    for b in specs:
        x0, x1, y0, y1 = b.region_mm
        x, y = np.meshgrid(np.arange(x0, x1, step) + step / 2, np.arange(y0, y1, step) + step / 2)
        pts.append(np.stack([x.ravel(), y.ravel(), np.full(x.size, b.top_z_mm)], -1))
    xyz = np.concatenate(pts)
    xyz[:, 2] += rng.normal(0.0, sigma_um * 1e-3, len(xyz))
    attrs = {"sigma_model_um": np.full(len(xyz), sigma_um)}
    return xyz, attrs


def test_rows_and_summary_have_their_documented_names():
    """blocks.csv, steps.csv and summary.json columns; the steps go from the tallest block
    down, whatever the layout's order; the summary's fractions worked out here."""
    xyz, attrs = _cloud()
    res = run_qa(AnnotatedCloud(xyz, attrs), THREE, margin_mm=0.5, tolerance_um=15.0, k=3.0,
                 knn=9, tile_mm=2.5)
    assert [b.block_id for b in res.blocks] == [3, 4, 2]  # layout order
    assert [(s.block_a, s.block_b) for s in res.steps] == [(2, 3), (3, 4)]
    rows = [b.row() for b in res.blocks]
    assert all(list(r) == BLOCK_COLUMNS for r in rows)
    b = res.blocks[0]
    assert rows[0]["noise_corr_factor"] == b.noise_corr[0] and rows[0]["n_tiles"] == b.n_tiles
    assert rows[0]["ratio"] == b.measured_std_um / b.predicted_std_um
    assert rows[0]["model_valid_fraction"] == 1.0 and rows[0]["status"] == "ok"
    # s / sqrt(2 nu), nu = n / kappa - 3
    nu = b.n_points / b.noise_corr[0] - 3
    assert rows[0]["measured_std_u_um"] == pytest.approx(b.measured_std_um / math.sqrt(2 * nu),
                                                         rel=1e-12)
    steps = [s.row() for s in res.steps]
    assert all(list(r) == STEP_COLUMNS for r in steps)
    s = res.steps[0]
    assert steps[0]["U_um"] == 3.0 * s.u_um and steps[0]["tolerance_um"] == 15.0
    assert steps[0]["nominal_diff_mm"] == pytest.approx(25.40 - 12.70)
    assert steps[0]["evaluated"] is True and steps[0]["k"] == 3.0
    # nu_eff of the two noise terms (K - 3 dof each; no table term) by Welch-Satterthwaite
    terms = [c.contribution_um for c in s.budget.components]
    assert terms[2] == 0.0 and len(terms) == 3  # no table sigma, no Type B
    a_, b_ = res.blocks[2], res.blocks[0]  # block 2 (tallest), then block 3
    want = (terms[0]**2 + terms[1]**2) ** 2 / (terms[0]**4 / (a_.n_tiles - 3)
                                             + terms[1]**4 / (b_.n_tiles - 3))
    assert steps[0]["nu_eff"] == pytest.approx(want, rel=1e-12)
    info = res.summary()
    assert list(info) == SUMMARY_KEYS
    assert info["format"] == "scanqa-qa-summary/3" and info["model"] == {}
    assert info["settings"] == {"margin_mm": 0.5, "outlier_k": None, "tolerance_um": 15.0,
                                "tolerance_source": "given", "k": 3.0, "budget": None,
                                "max_flagged_fraction": 0.05,
                                "knn": 9, "tile_mm": 2.5, "calibration_geometry": None,
                                "layout": "three.toml",
                                "paper_comparison": False}
    assert info["has_prediction"] is True and info["notes"] == res.notes == [NO_TYPE_B]
    assert info["type_b_included"] is False
    assert (info["blocks_ok"], info["blocks_flagged"]) == (3, 0)
    within = sum(abs(s.error_um) <= s.expanded_um for s in res.steps)
    assert (info["steps_evaluated"], info["steps_not_evaluated"]) == (2, 0)
    assert info["steps_error_within_U"] == within and info["fraction_within_U"] == within / 2
    want = {"pass": 0, "fail": 0, "undecided": 0, "not evaluated": 0}
    for s in res.steps:  # ISO 14253-1 with T = 15 um
        e, big_u = abs(s.error_um), 3.0 * s.u_um
        want["pass" if e <= 15 - big_u else "fail" if e > 15 + big_u else "undecided"] += 1
    assert info["decisions"] == want
    assert [(x["block_a"], x["block_b"], x["u_um"], x["k"], x["k_rule"])
            for x in info["budgets"]] == [(2, 3, res.steps[0].u_um, 3.0, "stated"),
                                          (3, 4, res.steps[1].u_um, 3.0, "stated")]
    assert [c["component"] for c in info["budgets"][0]["components"]] == [
        "noise, plane of block 2 at block 3", "noise, mean height of block 3",
        "calibration table"]
    ratios = [b.measured_std_um / b.predicted_std_um for b in res.blocks]
    assert info["max_abs_ratio_deviation"] == max(abs(r - 1) for r in ratios)
    assert info["blocks"][0]["block_id"] == 3 and info["steps"][1]["block_b"] == 4


def test_nan_becomes_null_in_the_summary():
    step = StepResult(1, 2, 1.0, math.nan, math.inf, 2.0, 20.0)
    assert json_ready(math.nan) is None and json_ready(math.inf) is None
    assert json_ready(1.5) == 1.5 and json_ready("ok") == "ok"
    assert step.row()["decision"] == "not evaluated"  # a NaN decides nothing (issue 27)


def test_notes_name_what_is_missing():
    xyz, _ = _cloud(specs=(BLOCK_A, BLOCK_B))
    res = run_qa(AnnotatedCloud(xyz, {}), THREE)
    assert res.notes[0] == ("the cloud has no sigma attributes: the predicted-std column is "
                            "missing and step uncertainties use the measured residual std "
                            "instead")
    assert res.notes[1] == ("block 4: no points inside its region after the 1 mm edge margin "
                            "(occluded, outside the calibrated volume or a wrong layout?)")
    assert not res.has_prediction and res.summary()["has_prediction"] is False
    res = run_qa(AnnotatedCloud(xyz, {}), THREE, tile_mm=20.0)
    assert ("block 2: only 1 tiles of 20 mm, too few to measure the noise correlation; its "
            "points are taken as independent") in res.notes
    assert run_qa(AnnotatedCloud(xyz, {}), THREE, tile_mm=0.5).settings["tile_mm"] == 0.5
    with pytest.raises(InputError, match=r"^tile size must be > 0 mm, got 0.0$"):
        run_qa(AnnotatedCloud(xyz, {}), THREE, tile_mm=0.0)


def test_status_of_a_block_at_each_threshold():
    """outside_volume when more than 5 % of the points lie outside the volume, model_invalid
    when more than 5 % are outside the model's validity (exactly 5 % is still ok; the
    volume is checked first), too_few_points under 3, degenerate for a line."""
    xyz, attrs = _cloud(specs=(BLOCK_A,))
    xyz = xyz[:860]  # 43 points are exactly 5 %
    attrs = {"sigma_model_um": attrs["sigma_model_um"][:860]}
    inside = (np.arange(860) >= 43).astype(np.float32)
    for name, status, what in (("in_volume", "outside_volume", "the calibrated volume"),
                               ("model_valid", "model_invalid",
                                "the model's validity (a blur ratio > 1/2)")):
        at = {**attrs, name: inside.copy()}
        res = analyse_block(xyz, at, BLOCK_A, margin=0.0, outlier_k=None)
        assert (res.status, res.message) == ("ok", "")
        at[name][43] = 0.0  # 44 of 860 outside: 5.1 %
        res = analyse_block(xyz, at, BLOCK_A, margin=0.0, outlier_k=None)
        assert (res.status, res.message) == (
            status, f"block 2: 5 % of its points lie outside {what} (more than 5 %): flagged, "
            "its steps are not evaluated")
    both = {**attrs, "in_volume": np.zeros(860), "model_valid": np.zeros(860)}
    res = analyse_block(xyz, both, BLOCK_A, margin=0.0, outlier_k=None)
    assert res.status == "outside_volume" and res.message.startswith("block 2: 100 % of")
    two = analyse_block(xyz[:2], attrs, BLOCK_A, margin=0.0, outlier_k=None)
    assert (two.status, two.message) == ("too_few_points",
                                         "block 2: only 2 points, a plane needs 3")
    line = xyz[:40].copy()
    line[:, 1:] = [-10.0, 443.65]
    bad = analyse_block(line, attrs, BLOCK_A, margin=0.0, outlier_k=None)
    assert bad.status == "degenerate" and bad.message == ("block 2: the points are collinear, "
                                                         "no plane is defined")
    empty = analyse_block(xyz, attrs, BlockSpec(9, 1.0, (100.0, 110.0, 0.0, 5.0)), 1.0, None)
    assert empty.status == "no_points" and empty.n_points == 0 and empty.fit is None


def test_region_margin_and_height_window_are_inclusive():
    """Points exactly at region minus margin, and exactly 3 mm from the top, are in."""
    spec = BlockSpec(1, 10.0, (0.0, 10.0, 0.0, 8.0), 450.0)
    pts = np.array([[1.0, 1.0, 450.0], [9.0, 7.0, 450.0], [0.75, 4.0, 450.0],
                    [9.25, 4.0, 450.0], [5.0, 0.75, 450.0], [5.0, 7.25, 450.0],
                    [5.0, 4.0, 453.0], [5.0, 4.0, 447.0], [5.0, 4.0, 453.125],
                    [5.0, 4.0, 446.875]])
    np.testing.assert_array_equal(blocks._select(pts, spec, 1.0, 3.0), [0, 1, 6, 7])
    open_spec = BlockSpec(1, 10.0, (0.0, 10.0, 0.0, 8.0))  # no top height: no window
    np.testing.assert_array_equal(blocks._select(pts, open_spec, 1.0, 3.0), [0, 1, 6, 7, 8, 9])


def test_missing_attributes_default_to_inside_and_valid():
    xyz, attrs = _cloud(specs=(BLOCK_A,))
    res = analyse_block(xyz, attrs, BLOCK_A, margin=0.0, outlier_k=None)
    assert res.in_volume_fraction == 1.0 and res.model_valid_fraction == 1.0
    assert math.isnan(res.mean_attenuation) and res.status == "ok"
    idx = np.arange(5)
    np.testing.assert_array_equal(blocks._attr({}, "x", idx, 2.5), np.full(5, 2.5))
    got = blocks._attr({"x": np.arange(10, dtype=np.float32)}, "x", idx)
    assert got.dtype == np.float64 and list(got) == [0, 1, 2, 3, 4]


def test_local_std_by_brute_force():
    """Std (ddof 1) of the residuals of each point's k nearest neighbours in XY within its
    block, by sorting all distances; NaN outside blocks and in blocks of < 3 points."""
    rng = np.random.default_rng(4)
    xyz = rng.uniform(0, 10, (60, 3))
    resid = rng.normal(0, 1, 60)
    block = np.repeat([0, 1, -1, 2], [30, 22, 6, 2])
    got = blocks.local_std(xyz, resid, block, k=7)
    for i in range(60):
        if block[i] < 0 or (block == block[i]).sum() < 3:
            assert np.isnan(got[i])
            continue
        same = np.flatnonzero(block == block[i])
        d = np.linalg.norm(xyz[same, :2] - xyz[i, :2], axis=1)
        nearest = same[np.argsort(d, kind="stable")[:7]]
        np.testing.assert_allclose(got[i], np.std(resid[nearest], ddof=1), rtol=1e-12)
    small = blocks.local_std(xyz[:5], resid[:5], np.zeros(5, int), k=16)  # k > block: all 5
    np.testing.assert_allclose(small, np.std(resid[:5], ddof=1), rtol=1e-12)


def test_model_curve_and_cloud_config(paper_config):
    """The model's curve spans the blocks' depths +- 5 mm in 0.25 mm steps, from the model
    in the cloud's metadata when it has one; unreadable or different models are noted."""
    xyz, attrs = _cloud()
    meta = {"config": paper_config.to_dict()}
    res = run_qa(AnnotatedCloud(xyz, attrs, metadata=meta), THREE)
    z = res.curve["z_mm"]
    assert z[0] == pytest.approx(443.65 - 5, abs=1e-3) and z[-1] == pytest.approx(461.43 + 5,
                                                                                  abs=0.25)
    np.testing.assert_allclose(np.diff(z), 0.25)
    want = [1e3 * reference_point((0.0, 0.0, zz), paper_config, "power", "none")["sigma"]
            for zz in z[::8]]
    np.testing.assert_allclose(res.curve["sigma_um"][::8], want, rtol=1e-9)
    assert res.notes == [NO_TYPE_B]
    assert run_qa(AnnotatedCloud(xyz, attrs), THREE).curve is None
    # a different model in the config given: the cloud's wins, and the notes say so
    other = paper_config.replace_model(gamma=5.0)
    res = run_qa(AnnotatedCloud(xyz, attrs, metadata=meta), THREE, config=other)
    assert res.notes == [NO_TYPE_B,
                         "the cloud's sigmas come from the model in its metadata (none/power, "
                         "sigma_p 0.006487 px, gamma 3); the model of the config given to "
                         "the QA was not used"]
    np.testing.assert_allclose(res.curve["sigma_um"][::8], want, rtol=1e-9)
    res = run_qa(AnnotatedCloud(xyz, attrs, metadata={"config": {"camera": {}}}), THREE,
                 config=other)
    assert res.notes == [NO_TYPE_B,
                         "the cloud's metadata holds an unreadable config (missing table "
                         "[projector] (in the cloud's metadata)); its model curve is not drawn"]
    assert res.curve["sigma_um"][0] > 0  # from the config given
    assert blocks.model_curve([blocks.BlockResult(1, 1.0)], paper_config) is None


def test_annotated_cloud_carries_the_per_point_fields():
    xyz, attrs = _cloud()
    cloud = AnnotatedCloud(xyz, attrs, metadata={"source": "x"})
    res = run_qa(cloud, THREE)
    out = res.annotated_cloud()
    assert set(out.attributes) == {"sigma_model_um", "qa_block_id", "qa_residual_um",
                                   "qa_local_std_um"}
    np.testing.assert_array_equal(out.attributes["qa_block_id"], res.block_id)
    np.testing.assert_array_equal(out.attributes["qa_residual_um"], res.residual_um)
    np.testing.assert_array_equal(out.attributes["qa_local_std_um"], res.local_std_um)
    assert out.metadata == {"source": "x"}
    # the per-point fields are the fits' own residuals, in um, and -1 / NaN elsewhere
    b = res.blocks[0]
    np.testing.assert_allclose(res.residual_um[b.index], 1e3 * b.fit.residuals)
    assert set(np.unique(res.block_id)) == {-1, 2, 3, 4}  # -1: in the 1 mm edge margins
    outside = res.block_id < 0
    assert np.isnan(res.residual_um[outside]).all() and np.isnan(res.local_std_um[outside]).all()
    assert np.isfinite(res.residual_um[~outside]).all()
    assert dataclasses.replace(res, cloud=None).annotated_cloud() is None


def _result(blocks_, steps, cloud=None):
    return blocks.QAResult(blocks_, steps, np.zeros(0, int), np.zeros(0), np.zeros(0), True,
                           [], {}, cloud)


def test_summary_counts_at_the_boundaries():
    """An error of exactly U is within U (and, with T - U above it, a pass); a step that is
    not evaluated counts only as such; ratios come from "ok" blocks only; the model is the
    cloud's."""
    ok1, ok2, out = (blocks.BlockResult(i, 10.0 - i, measured_std_um=measured,
                                        predicted_std_um=2.0, status=status)
                     for i, measured, status in ((1, 3.0, "ok"), (2, 2.5, "ok"),
                                                 (3, 9.0, "model_invalid")))
    steps = [StepResult(1, 2, 0.0, 2**-8, 1000 * 2**-9, 2.0, 20.0),   # |e| = U = 3.90625 um
             StepResult(2, 3, 0.0, 2**-8, 1.0, 2.0, 20.0, evaluated=False)]  # block 3 flagged
    cloud = AnnotatedCloud(np.zeros((1, 3)), {}, metadata={"model": {"gamma": 3.0}})
    info = _result([ok1, ok2, out], steps, cloud).summary()
    assert (info["steps_evaluated"], info["steps_not_evaluated"]) == (1, 1)
    assert info["steps_error_within_U"] == 1 and info["fraction_within_U"] == 1.0
    assert info["decisions"] == {"pass": 1, "fail": 0, "undecided": 0, "not evaluated": 1}
    assert (info["blocks_ok"], info["blocks_flagged"]) == (2, 1)
    assert info["budgets"] == [] and info["type_b_included"] is False
    assert info["max_abs_ratio_deviation"] == 0.5  # 3.0 / 2.0 (not the 4.5 of block 3)
    assert info["model"] == {"gamma": 3.0}
    ok1 = dataclasses.replace(ok1, predicted_std_um=math.nan)  # no prediction, no ratio
    assert _result([ok1, ok2], steps).summary()["max_abs_ratio_deviation"] == 0.25


def test_few_points_and_the_height_window():
    """Exactly 3 points make a plane (no residuals); with 4, the std has n - 3 = 1 degree of
    freedom; points 3.5 mm off the top face are outside the default 3 mm window."""
    spec = BlockSpec(7, 5.0, (0.0, 10.0, 0.0, 10.0), 450.0)
    tri = np.array([[2.0, 2.0, 450.0], [8.0, 2.0, 450.0], [5.0, 8.0, 450.0]])
    res = analyse_block(tri, {}, spec, margin=0.0, outlier_k=None)
    # fitted, but fewer than MIN_POINTS points: flagged, its steps are not decided
    assert res.status == "too_few_points" and res.n_points == 3 and res.measured_std_um == 0.0
    quad = np.array([[2.0, 2.0, 450.0], [8.0, 2.0, 450.0], [8.0, 8.0, 450.0],
                     [2.0, 8.0, 450.004]])  # residuals +-1 um: sum of squares 4 um^2
    res = analyse_block(quad, {}, spec, margin=0.0, outlier_k=None)
    np.testing.assert_allclose(np.abs(res.fit.residuals), 1e-3, rtol=1e-6)
    np.testing.assert_allclose(res.measured_std_um, 2.0, rtol=1e-6)
    far = np.vstack([quad, [[5.0, 5.0, 453.5], [5.0, 5.0, 446.5]]])
    assert analyse_block(far, {}, spec, margin=0.0, outlier_k=None).n_points == 4
    assert analyse_block(far, {}, spec, margin=0.0, outlier_k=None, z_window=4.0).n_points == 6


def test_a_block_left_degenerate_by_outlier_rejection_is_named():
    """A line of points plus a few far off it: rejecting those leaves a line."""
    spec = BlockSpec(5, 5.0, (0.0, 20.0, 0.0, 20.0), 450.0)
    line = np.column_stack([np.linspace(1, 19, 60), np.full(60, 10.0), np.full(60, 450.0)])
    off = np.array([[5.0, 4.0, 449.0], [15.0, 16.0, 449.0]])
    res = analyse_block(np.vstack([line, off]), {}, spec, margin=0.0, outlier_k=3.0)
    assert res.status == "degenerate"
    assert res.message == "block 5: the points are collinear, no plane is defined"


def test_missing_or_nan_attributes_are_silent(recwarn):
    """No sigma, attenuation or correlation attribute, or a table sigma that is all NaN: the
    block's numbers fall back (NaN, measured std, table sigma 0) without RuntimeWarnings."""
    xyz, _ = _cloud(specs=(BLOCK_A,))
    res = analyse_block(xyz, {}, BLOCK_A, margin=0.0, outlier_k=None)
    assert math.isnan(res.predicted_std_um) and math.isnan(res.mean_attenuation)
    assert math.isnan(res.table_corr_mm) and res.table_sigma_um == 0.0
    nan = np.full(len(xyz), np.nan)
    res = analyse_block(xyz, {"sigma_calibration_um": nan, "table_corr_mm": nan}, BLOCK_A,
                        margin=0.0, outlier_k=None)
    assert res.table_sigma_um == 0.0 and math.isnan(res.table_corr_mm)
    assert [str(w.message) for w in recwarn] == []


def test_run_qa_defaults_and_what_it_passes_on():
    """Defaults T = 20 um, k = 2, 16 neighbours, no outlier rejection; outlier_k and knn
    reach the blocks and the local std; the local std is in um."""
    xyz, attrs = _cloud()
    res = run_qa(AnnotatedCloud(xyz, attrs), THREE)
    assert res.settings == {"margin_mm": 1.0, "outlier_k": None, "tolerance_um": 20.0,
                            "tolerance_source": "default", "k": 2.0, "budget": None,
                            "max_flagged_fraction": 0.05, "knn": 16,
                            "tile_mm": 2.0, "calibration_geometry": None,
                            "layout": "three.toml", "paper_comparison": False}
    assert all(s.k == 2.0 and s.tolerance_um == 20.0 for s in res.steps)
    resid = np.where(res.block_id >= 0, res.residual_um * 1e-3, np.nan)
    np.testing.assert_allclose(res.local_std_um,
                               1e3 * blocks.local_std(xyz, resid, res.block_id, k=16),
                               rtol=1e-12, equal_nan=True)
    centres = [np.argmin(np.linalg.norm(xyz[:, :2] - [(b.region_mm[0] + b.region_mm[1]) / 2,
                                                      (b.region_mm[2] + b.region_mm[3]) / 2],
                                        axis=1)) for b in THREE.blocks]
    xyz[centres, 2] -= 0.5  # a spike of 0.5 mm in the middle of each block
    res = run_qa(AnnotatedCloud(xyz, attrs), THREE, outlier_k=5.0, knn=5)
    assert sum(b.outliers for b in res.blocks) == 3
    resid = np.where(res.block_id >= 0, res.residual_um * 1e-3, np.nan)
    np.testing.assert_allclose(res.local_std_um,
                               1e3 * blocks.local_std(xyz, resid, res.block_id, k=5),
                               rtol=1e-12, equal_nan=True)


def test_local_std_small_blocks_and_default_k():
    """Blocks of 2 points get NaN, of 3 points the std of all 3, whatever comes after them;
    the default is 16 neighbours."""
    rng = np.random.default_rng(6)
    xyz = rng.uniform(0, 10, (45, 3))
    resid = rng.normal(0, 1, 45)
    block = np.repeat([1, 3, 5], [2, 3, 40])  # the small blocks first (ids ascending)
    got = blocks.local_std(xyz, resid, block)
    assert np.isnan(got[:2]).all()
    np.testing.assert_allclose(got[2:5], np.std(resid[2:5], ddof=1), rtol=1e-12)
    for i in range(5, 45):
        d = np.linalg.norm(xyz[5:, :2] - xyz[i, :2], axis=1)
        nearest = 5 + np.argsort(d, kind="stable")[:16]
        np.testing.assert_allclose(got[i], np.std(resid[nearest], ddof=1), rtol=1e-12)


def test_settings_are_refused_with_one_message():
    """Each setting at its bound: margin and tolerance may be 0, the tile size and the
    outlier K must be > 0, the neighbour count > 2; the message names the setting, the
    bound, the unit and the value."""
    ok = {"margin_mm": 0.0, "outlier_k": None, "tolerance_um": 0.0, "knn": 3, "tile_mm": 0.01}
    blocks._check_settings(**ok)
    blocks._check_settings(**{**ok, "outlier_k": 0.01})
    for change, message in (
            ({"margin_mm": -0.5}, "edge margin must be >= 0 mm, got -0.5"),
            ({"margin_mm": math.nan}, "edge margin must be >= 0 mm, got nan"),
            ({"margin_mm": "1"}, "edge margin must be >= 0 mm, got '1'"),
            ({"tolerance_um": -1.0}, "tolerance must be >= 0 um, got -1.0"),
            ({"tolerance_um": math.inf}, "tolerance must be >= 0 um, got inf"),
            ({"tile_mm": 0.0}, "tile size must be > 0 mm, got 0.0"),
            ({"knn": 2}, "neighbour count must be > 2, got 2"),
            ({"outlier_k": 0.0},
             "outlier rejection K must be > 0 robust std (or not given), got 0.0"),
            ({"outlier_k": math.inf},
             "outlier rejection K must be > 0 robust std (or not given), got inf"),
            ({"outlier_k": -2.0},
             "outlier rejection K must be > 0 robust std (or not given), got -2.0")):
        with pytest.raises(InputError) as err:
            blocks._check_settings(**{**ok, **change})
        assert str(err.value) == message
    xyz, attrs = _cloud(specs=(BLOCK_A,))
    cloud = AnnotatedCloud(xyz, attrs)
    with pytest.raises(InputError, match=r"^outlier rejection K must be > 0"):
        run_qa(cloud, THREE, outlier_k=0.0)
    with pytest.raises(InputError, match=r"^k must be a number > 0"):
        run_qa(cloud, THREE, k=0.0)
    # one block measured: its two steps kept but not evaluated, and k accepted
    assert [s.evaluated for s in run_qa(cloud, THREE, k=0.5).steps] == [False, False]


def test_clouds_without_finite_points_or_outside_every_block():
    """No finite point: one message with the count. No point in any block: the extents of
    cloud and layout, and a hint - metres when the cloud is over 100 times smaller than
    the layout (here 1000: the blocks in metres), else the frame."""
    with pytest.raises(InputError) as err:
        run_qa(AnnotatedCloud(np.full((3, 3), np.nan), {}), THREE)
    assert str(err.value) == ("the cloud has no points with finite coordinates (3 points): "
                              "nothing to measure")
    xyz, _ = _cloud()
    metres = np.vstack([xyz * 1e-3, [[np.nan, 0.0, 0.0]]])
    lo, hi = xyz[:, :2].min(axis=0) * 1e-3, xyz[:, :2].max(axis=0) * 1e-3
    with pytest.raises(InputError) as err:
        run_qa(AnnotatedCloud(metres, {}), THREE, margin_mm=0.5)
    assert str(err.value) == (
        "no block of the layout holds a point of the cloud (after the 0.5 mm edge margin): "
        f"the cloud spans X {lo[0]:.4g} to {hi[0]:.4g}, Y {lo[1]:.4g} to {hi[1]:.4g} mm; "
        "the blocks X -14 to 30, Y -21 to -3 mm. The cloud is about 1000 times smaller "
        "than the layout: is it in metres? scanqa reads millimetres.")
    assert f"{lo[0]:.4g}" == "-0.01375" and f"{hi[1]:.4g}" == "-0.00325"
    shifted = xyz + np.array([500.0, 250.0, 0.0])
    with pytest.raises(InputError) as err:
        run_qa(AnnotatedCloud(shifted, {}), THREE)
    assert str(err.value) == (
        "no block of the layout holds a point of the cloud (after the 1 mm edge margin): "
        "the cloud spans X 486.2 to 529.8, Y 229.2 to 246.8 mm; the blocks X -14 to 30, "
        "Y -21 to -3 mm. Check that cloud and layout share the scanner frame.")
    # the layout's span is the larger of its X and Y spans (44 mm here): a cloud of 0.4 mm
    # is under 1/100 of it, a single point (span 0) is not
    tiny = np.array([[100.0, 100.0, 400.0], [100.4, 100.0, 400.0]])
    with pytest.raises(InputError, match="is it in metres"):
        run_qa(AnnotatedCloud(tiny, {}), THREE)
    with pytest.raises(InputError, match="share the scanner frame"):
        run_qa(AnnotatedCloud(tiny[:1], {}), THREE)
    # 0.47 mm is over 44 / 100 (the spans are X and Y: X0, X1 and Y0 together span 51 mm);
    # exactly 0.44 mm is not under it; 0.438 mm is
    for span, hint in ((0.47, "share the scanner frame"), (0.44, "share the scanner frame"),
                       (0.438, "is it in metres")):
        edge = np.array([[0.0, 100.0, 400.0], [span, 100.0, 400.0]])
        with pytest.raises(InputError, match=hint):
            run_qa(AnnotatedCloud(edge, {}), THREE)
    wide = np.array([[100.0, 100.0, 400.0], [100.0, 100.43, 400.0]])
    with pytest.raises(InputError, match="is it in metres"):
        run_qa(AnnotatedCloud(wide, {}), Layout("tall", (BlockSpec(1, 1.0, (0, 1, 0, 44)),)))
    wide[1, 1] = 100.45
    with pytest.raises(InputError, match="share the scanner frame"):
        run_qa(AnnotatedCloud(wide, {}), Layout("tall", (BlockSpec(1, 1.0, (0, 1, 0, 44)),)))


def test_nan_points_float32_and_zero_sigmas():
    """A NaN point is skipped (the blocks keep theirs); float32 coordinates give the
    numbers of their float64 values; a zero sigma predicts nothing (the block's predicted
    std is the RMS over the others, and that point's plane weight is the measured std)."""
    xyz, attrs = _cloud()
    xyz32 = xyz.astype(np.float32)
    with_nan = np.vstack([xyz32, [[np.nan, -10.0, 450.0]]]).astype(np.float32)
    attrs_nan = {"sigma_model_um": np.append(attrs["sigma_model_um"], 2.0)}
    a = run_qa(AnnotatedCloud(with_nan, attrs_nan), THREE)
    b = run_qa(AnnotatedCloud(xyz32.astype(np.float64), attrs), THREE)
    assert [s.measured_diff_mm for s in a.steps] == [s.measured_diff_mm for s in b.steps]
    for name in ("measured_std_um", "predicted_std_um", "mean_z_mm"):
        assert [getattr(x, name) for x in a.blocks] == [getattr(x, name) for x in b.blocks]
    assert a.block_id[-1] == -1
    sig = attrs["sigma_model_um"].copy()
    sig[::2] = 0.0
    spec = BLOCK_A
    res = analyse_block(xyz, {"sigma_model_um": sig}, spec, margin=0.0, outlier_k=None)
    inside = blocks._select(xyz, spec, 0.0, 3.0)
    pos = sig[inside] > 0
    los = xyz[inside] / np.linalg.norm(xyz[inside], axis=1)[:, None]
    cos = np.abs(los @ res.fit.normal)  # the fitted normal, not quite -Z (noise)
    want = math.sqrt(np.mean((2.0 * cos[pos]) ** 2))
    assert 0 < pos.sum() < len(inside)
    np.testing.assert_allclose(res.predicted_std_um, want, rtol=1e-12)
    np.testing.assert_allclose(res.sigma_n[~pos], res.measured_std_um * 1e-3, rtol=1e-12)


def test_table_variance_needs_a_positive_correlation_length_on_both_blocks():
    """A correlation length of 0 (or NaN) on either block: one shift per block,
    sigma_a^2 + sigma_b^2; lengths under 1 mm are used as given."""
    from scanqa.qa.planes import PlaneFit

    def block(bid, centroid, corr, sig):
        fit = PlaneFit(np.asarray(centroid, float), np.array([0.0, 0.0, -1.0]),
                       np.zeros(3), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
        return blocks.BlockResult(bid, 10.0, fit=fit, spread_mm=(3.0, 4.0),
                                  table_corr_mm=corr, table_sigma_um=sig,
                                  u_plane=np.zeros((3, 3)))

    for ca, cb in ((0.0, 1.0), (1.0, 0.0), (-1.0, 1.0)):
        a, b = block(2, (-8.0, -12.0, 443.65), ca, 5.0), block(3, (8.0, -12.0, 456.35), cb, 3.0)
        np.testing.assert_allclose(blocks.step_between(a, b, 2.0, 20.0).u_um,
                                   math.hypot(5.0, 3.0), rtol=1e-12)
    # 0.5 mm: 12 * 3 * 4 / 0.25 = 576 patches each; tilt (16 / 3)^2 (lever along X only)
    a, b = block(2, (-8.0, -12.0, 443.65), 0.5, 5.0), block(3, (8.0, -12.0, 456.35), 0.5, 3.0)
    want = math.sqrt(25 / 576 + 9 / 576 + 25 / 576 * (16 / 3) ** 2)
    np.testing.assert_allclose(blocks.step_between(a, b, 2.0, 20.0).u_um, want, rtol=1e-12)


def test_report_first_screen_says_where_the_sigmas_come_from():
    """An assumed sigma_p shows as a warning right under the verdict and in summary.json;
    a cloud that does not say is 'unknown'; the random sigma attribute is preferred to the
    model's."""
    from scanqa.report.qa import render

    xyz, attrs = _cloud(sigma_um=2.0)
    attrs["sigma_random_um"] = np.full(len(xyz), 3.0)
    source = {"kind": "images", "random": "images", "detail": "estimated from the images",
              "warning": "sigma_p_px = 0.05 px in x.toml is assumed"}
    res = run_qa(AnnotatedCloud(xyz, attrs, metadata={"sigma_source": source}), THREE)
    assert res.summary()["sigma_source"] == source
    page = render(res)
    first = page[:page.index('id="sigma-source"') + 400]
    assert page.index('id="verdict"') < page.index('id="sigma-source"') < page.index("<h2")
    assert "WARNING: sigma_p_px = 0.05 px in x.toml is assumed" in first
    ok = [b for b in res.blocks if b.status == "ok"]
    # the predicted std is sigma_random (3 um, not the model's 2 um) times the cosine of
    # the line of sight to the block's normal (>= 0.99 for these blocks near the axis)
    np.testing.assert_allclose([b.predicted_std_um for b in ok], 3.0, rtol=1e-2)
    page = render(run_qa(AnnotatedCloud(xyz, attrs), THREE))
    assert "Per-point sigma: unknown" in page
