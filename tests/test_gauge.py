"""Gauge-block QA on synthetic clouds with known planes and noise."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.io.cloud import read_cloud, write_cloud
from scanqa.qa.blocks import run_qa
from scanqa.qa.detect import detect_blocks
from scanqa.qa.layout import load_layout
from scanqa.qa.planes import fit_plane
from scanqa.report.qa import step_verdict

from .conftest import ROOT

LAYOUT = ROOT / "calib" / "gauge_blocks_paper.toml"
SIGMA_UM = 10.0


def synthetic_cloud(seed=0, step=0.25, sigma_um=SIGMA_UM, drop_block=None, tilt=0.0,
                    patch_mm=None):
    """Points on the block tops and the base, with Gaussian noise along Z (one draw per
    square patch of ``patch_mm`` when given: noise correlated over the patch)."""
    layout = load_layout(LAYOUT)
    rng = np.random.default_rng(seed)
    pts = []
    for b in layout.blocks:
        if b.block_id == drop_block:
            continue
        x0, x1, y0, y1 = b.region_mm
        x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
        z = b.top_z_mm + tilt * x
        pts.append(np.stack([x.ravel(), y.ravel(), z.ravel()], -1))
    x, y = np.meshgrid(np.arange(-44, 44, 0.5), np.arange(-36, 36, 0.5))
    base = np.stack([x.ravel(), y.ravel(), np.full(x.size, 469.05)], -1)
    inside = np.zeros(len(base), bool)
    for b in layout.blocks:
        x0, x1, y0, y1 = b.region_mm
        inside |= (base[:, 0] >= x0 - 1) & (base[:, 0] <= x1 + 1) & (base[:, 1] >= y0 - 1) \
            & (base[:, 1] <= y1 + 1)
    pts.append(base[~inside])
    xyz = np.concatenate(pts)
    if patch_mm is None:
        xyz[:, 2] += rng.normal(0, sigma_um * 1e-3, len(xyz))
    else:
        key = np.floor(xyz[:, :2] / patch_mm + 1e-9).astype(np.int64)
        _, patch = np.unique(key, axis=0, return_inverse=True)
        xyz[:, 2] += rng.normal(0, sigma_um * 1e-3, patch.max() + 1)[patch.ravel()]
    n = len(xyz)
    attrs = {"sigma_model_um": np.full(n, sigma_um, np.float32),
             "sigma_calibration_um": np.full(n, 0.5, np.float32),
             "att_camera": np.full(n, 0.9, np.float32), "att_projector": np.ones(n, np.float32),
             "in_volume": np.ones(n, np.float32), "model_valid": np.ones(n, np.float32)}
    return xyz, attrs, layout


def test_fit_plane_exact_and_errors():
    rng = np.random.default_rng(1)
    normal = np.array([0.1, -0.2, -1.0]) / np.linalg.norm([0.1, -0.2, -1.0])
    pts = rng.normal(size=(200, 3)) * [10, 10, 0]
    pts = pts - np.outer(pts @ normal, normal) + [1, 2, 450]
    fit = fit_plane(pts)
    np.testing.assert_allclose(abs(fit.normal @ normal), 1.0, atol=1e-12)
    assert fit.normal[2] < 0  # towards the camera
    np.testing.assert_allclose(fit.residuals, 0.0, atol=1e-9)
    with pytest.raises(InputError, match="at least 3 points, got 2"):
        fit_plane(pts[:2])
    line = np.outer(np.arange(10.0), [1, 0, 0]) + np.array([0.0, 0.0, 450.0])
    with pytest.raises(InputError, match="collinear"):
        fit_plane(line, "block 9")


def test_blocks_and_steps_recover_truth():
    xyz, attrs, layout = synthetic_cloud()
    res = run_qa(AnnotatedCloud(xyz, attrs), layout, margin_mm=1.0)
    assert [b.status for b in res.blocks] == ["ok"] * 8
    for b in res.blocks:
        # measured std of Gaussian noise along Z: within 5 % with > 2000 points per block
        assert b.n_points > 2000
        assert b.measured_std_um == pytest.approx(SIGMA_UM, rel=0.05)
        # predicted = RMS of sigma along the normal; the normal is ~ the line of sight
        assert b.predicted_std_um == pytest.approx(SIGMA_UM, rel=0.01)
        assert b.mean_attenuation == pytest.approx(0.9)
    errors = np.array([s.error_um for s in res.steps])
    big_u = np.array([s.expanded_um for s in res.steps])
    assert len(res.steps) == 7
    # the noise of a block mean is ~0.2 um; U includes the 0.5 um table sigma per block
    assert np.all(np.abs(errors) <= big_u), (errors, big_u)
    assert all(s.decision == "pass" for s in res.steps)
    # the normal's tilt uncertainty times the ~55 mm lever between rows dominates u here
    np.testing.assert_allclose([s.measured_diff_mm for s in res.steps],
                               [s.nominal_diff_mm for s in res.steps], atol=5e-3)
    in_block = res.block_id >= 0
    assert np.nanstd(res.residual_um[in_block]) == pytest.approx(SIGMA_UM, rel=0.05)
    assert np.nanmedian(res.local_std_um[in_block]) == pytest.approx(SIGMA_UM, rel=0.15)


def test_step_uncertainty_is_honest_over_seeds():
    """Errors / u over many seeds is ~N(0, 1): the propagated u is not too small."""
    z = []
    for seed in range(12):
        xyz, attrs, layout = synthetic_cloud(seed=seed, step=0.5)
        attrs["sigma_calibration_um"][:] = 0.0
        res = run_qa(AnnotatedCloud(xyz, attrs), layout)
        z += [s.error_um / s.u_um for s in res.steps]
    assert 0.7 < np.std(z) < 1.3, np.std(z)


def test_noise_correlation_factor_counts_the_points_sharing_one_noise_draw():
    xyz, attrs, layout = synthetic_cloud(patch_mm=0.75)  # 3 x 3 points of 0.25 mm
    res = run_qa(AnnotatedCloud(xyz, attrs), layout)
    # 9 points per draw; 2 mm tiles split a 0.75 mm patch now and then, which keeps a
    # fraction (1 - 0.75 / (3 * 2))^2 = 0.77 of the correlated pairs: kappa ~ 6.9
    kappa = np.array([b.noise_corr for b in res.blocks])
    assert all(b.n_tiles >= 8 for b in res.blocks)
    assert np.mean(kappa[:, 0]) == pytest.approx(6.9, rel=0.2), kappa
    assert np.all((kappa > 3.5) & (kappa < 12)), kappa
    xyz, attrs, layout = synthetic_cloud()
    res = run_qa(AnnotatedCloud(xyz, attrs), layout)
    assert all(b.noise_corr[0] < 1.4 for b in res.blocks), [b.noise_corr for b in res.blocks]
    info = json.loads(json.dumps(res.blocks[0].row()))
    assert info["n_tiles"] == res.blocks[0].n_tiles and "noise_corr_factor" in info


def test_step_uncertainty_is_honest_with_correlated_noise():
    """With noise shared by 2 x 2 points (patches of 0.5 mm, a quarter of a tile), errors / u
    stay ~N(0, 1) because the plane's covariance is scaled by the measured correlation
    factor; taking the points as independent (tiles smaller than the point spacing) makes
    u ~2x too small."""
    z, z_indep = [], []
    for seed in range(12):
        xyz, attrs, layout = synthetic_cloud(seed=seed, patch_mm=0.5)
        attrs["sigma_calibration_um"][:] = 0.0
        z += [s.error_um / s.u_um for s in run_qa(AnnotatedCloud(xyz, attrs), layout).steps]
        res = run_qa(AnnotatedCloud(xyz, attrs), layout, tile_mm=0.1)
        assert any("too few to measure the noise correlation" in n for n in res.notes)
        z_indep += [s.error_um / s.u_um for s in res.steps]
    assert 0.7 < np.std(z) < 1.3, np.std(z)
    assert np.std(z_indep) > 1.6, np.std(z_indep)


def test_missing_block_degenerate_region_and_no_sigma():
    xyz, attrs, layout = synthetic_cloud(drop_block=5)
    res = run_qa(AnnotatedCloud(xyz, attrs), layout)
    b5 = next(b for b in res.blocks if b.block_id == 5)
    assert b5.status == "no_points" and "block 5: no points" in res.notes[0]
    assert len(res.steps) == 7  # 4-5 and 5-6 need block 5's plane: kept, not evaluated
    unmeasured = [(s.block_a, s.block_b) for s in res.steps if not s.evaluated]
    assert unmeasured == [(4, 5), (5, 6)], unmeasured
    assert all(math.isnan(s.measured_diff_mm) and "block 5 has no plane" in s.note
               for s in res.steps if not s.evaluated)
    assert res.summary()["verdict"] == "INCOMPLETE", res.summary()["verdict"]
    assert step_verdict(res)["not evaluated"] == 2
    bare = {k: v for k, v in attrs.items() if not k.startswith("sigma")}
    res = run_qa(AnnotatedCloud(xyz, bare), layout)
    assert not res.has_prediction and "predicted-std column is missing" in res.notes[0]
    assert np.isnan(res.blocks[0].predicted_std_um)
    assert all(np.isfinite(s.u_um) for s in res.steps if s.evaluated)


def test_outside_volume_block_is_flagged():
    xyz, attrs, layout = synthetic_cloud()
    b1 = layout.blocks[0]
    x0, x1, y0, y1 = b1.region_mm
    sel = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    attrs["in_volume"][sel] = 0
    res = run_qa(AnnotatedCloud(xyz, attrs), layout)
    assert res.blocks[0].status == "outside_volume"
    assert res.blocks[0].in_volume_fraction == 0.0


def test_auto_finds_the_layout_blocks():
    xyz, _attrs, layout = synthetic_cloud(step=0.3)
    found = detect_blocks(xyz, {b.block_id: b.nominal_height_mm for b in layout.blocks})
    assert [b.block_id for b in found.blocks] == [b.block_id for b in layout.blocks]
    for f, b in zip(found.blocks, layout.blocks, strict=True):
        centre_f = np.array([f.region_mm[0] + f.region_mm[1], f.region_mm[2] + f.region_mm[3]])
        centre_b = np.array([b.region_mm[0] + b.region_mm[1], b.region_mm[2] + b.region_mm[3]])
        np.testing.assert_allclose(centre_f / 2, centre_b / 2, atol=1.0)


def test_auto_prefers_block_tops_over_wall_slivers():
    """A side wall seen obliquely leaves thin ribbons of points at every height; one lying
    exactly at a nominal height must not be taken for that block's top (the full-
    resolution demo lost block 8 to such a ribbon of block 7's wall)."""
    xyz, _attrs, layout = synthetic_cloud(step=0.3)
    top8 = (np.abs(xyz[:, 2] - 466.51) < 0.1) & (xyz[:, 0] > 17) & (xyz[:, 0] < 31)
    xyz[top8, 2] -= 0.05  # block 8 stands 50 um proud of nominal: the ribbon is nearer
    y = np.arange(3.0, 21.0, 0.1)
    ribbon = np.stack([np.full_like(y, 14.2), y, np.full_like(y, 469.05 - 2.54)], -1)
    ribbon = np.concatenate([ribbon + np.array([dx, 0.0, 0.0]) for dx in (-0.1, 0.0, 0.1)])
    found = detect_blocks(np.concatenate([xyz, ribbon]),
                          {b.block_id: b.nominal_height_mm for b in layout.blocks})
    block8 = next(b for b in found.blocks if b.block_id == 8)
    assert block8.region_mm[1] - block8.region_mm[0] > 10.0, block8.region_mm


def test_bad_layouts(tmp_path):
    text = LAYOUT.read_text()
    cases = [
        (text.replace('format = "scanqa-gauge-layout/1"', 'format = "x"'), "format must be"),
        (text.replace("id = 2\n", "id = 1\n"), "block ids must be unique"),
        (text.replace("region_mm = [-14.000, -2.000, -21.000, -3.000]",
                      "region_mm = [-2.0, -14.0, -21.0, -3.0]"), "min < max"),
        (text.replace("nominal_height_mm = 25.40", "nominal_height_mm = -1"),
         r"nominal_height_mm must be a finite number in \(0, 1000\] \[mm\]"),
        (text + "\n[extra]\n", "unknown key 'extra'"),
    ]
    for body, message in cases:
        path = tmp_path / "l.toml"
        path.write_text(body)
        with pytest.raises(InputError, match=message):
            load_layout(path)


def test_qa_cli_writes_every_output(tmp_path, capsys):
    xyz, attrs, _ = synthetic_cloud(step=0.5)
    cloud = write_cloud(tmp_path / "c.ply", xyz, attrs)
    out = tmp_path / "qa"
    code = main(["qa", str(cloud), "--layout", str(LAYOUT), "--out", str(out), "--config",
                 str(ROOT / "calib" / "paper_scanner.toml")])
    printed = capsys.readouterr().out
    assert code == 0 and "report:" in printed
    header = (out / "blocks.csv").read_text().splitlines()[0]
    assert header == ("block_id,nominal_height_mm,n_points,measured_std_um,measured_std_u_um,"
                      "predicted_std_um,ratio,flatness_um,mean_attenuation,in_volume_fraction,"
                      "model_valid_fraction,status")
    header = (out / "steps.csv").read_text().splitlines()[0]
    assert header == ("block_a,block_b,nominal_diff_mm,measured_diff_mm,error_um,u_um,nu_eff,"
                      "U_um,k,tolerance_um,decision,within_U")
    info = json.loads((out / "summary.json").read_text())
    assert info["steps_evaluated"] == 7 and info["fraction_within_U"] == 1.0
    assert len((out / "budget.csv").read_text().splitlines()) == 1 + 7 * 3
    assert not info["type_b_included"] and "Type B is not included" in \
        (out / "report.html").read_text()
    html = (out / "report.html").read_text()
    assert html.count("<img") == 4
    _, qattrs, _ = read_cloud(out / "cloud_qa.ply")
    assert {"qa_block_id", "qa_residual_um", "qa_local_std_um"} <= set(qattrs)
    code = main(["qa", str(cloud), "--auto", "--layout", str(LAYOUT), "--out",
                 str(tmp_path / "qa2")])
    assert code == 0


def test_qa_cli_bad_input(tmp_path, capsys):
    code = main(["qa", str(tmp_path / "none.ply"), "--layout", str(LAYOUT), "--out",
                 str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "does not exist" in err and "Traceback" not in err
    code = main(["qa", str(tmp_path / "none.ply"), "--out", str(tmp_path / "o")])
    assert code == 2 and "--layout" in capsys.readouterr().err
