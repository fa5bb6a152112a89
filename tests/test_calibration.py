"""The weighted calibration table on synthetic sweeps with exact pinhole truth."""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration.build import build_table
from scanqa.calibration.table import load_table, save_table
from scanqa.errors import InputError

from .synth_sweep import plane_truth, small_camera, sweep

CAL_Z = np.arange(420.0, 480.1, 1.5)         # planes every 1.5 mm, past the DOF both sides
HOLDOUT_Z = np.arange(432.75, 468.0, 3.0)    # half-way between calibrated planes


@pytest.fixture(scope="module")
def cfg(paper_config):
    return small_camera(paper_config)


@pytest.fixture(scope="module")
def tables(cfg):
    obs = sweep(cfg, CAL_Z, seed=3)
    return {w: build_table(obs, cfg, weights=w) for w in ("model", "modulation", "none")}


def _holdout_rms_um(cfg, table) -> np.ndarray:
    """RMS of the Z error on hold-out planes, applying the table to the true phase [um]."""
    rms = []
    for z in HOLDOUT_Z:
        xp, q = plane_truth(cfg, z)
        err = table.apply_image(xp).xyz - q
        rms.append(1e3 * np.sqrt(np.nanmean(np.sum(err**2, -1))))
    return np.array(rms)


def test_noise_free_table_is_exact_between_planes(cfg):
    table, report = build_table(sweep(cfg, CAL_Z, noise=False), cfg)
    rms = _holdout_rms_um(cfg, table)
    # pinhole geometry is exactly the per-ray model: only the bilinear interpolation in
    # (u, v) remains, 0.11 um at 16-px cells (it scales with the cell size squared)
    assert rms.max() < 0.2, rms
    table8, _ = build_table(sweep(cfg, CAL_Z, noise=False), cfg, cell_px=8)
    assert _holdout_rms_um(cfg, table8).max() < 0.3 * rms.max()
    assert report.rejected["unwrap_jump"] == 0


def test_weighting_pays(tables, cfg):
    rms = {w: np.sqrt(np.mean(_holdout_rms_um(cfg, t[0]) ** 2)) for w, t in tables.items()}
    # issue 5: model weights at least 20 % better than none on a sweep past the DOF
    assert rms["model"] < 0.8 * rms["none"], rms
    assert rms["modulation"] < 0.8 * rms["none"], rms
    # and far below the in-focus single-point sigma (~10 um)
    assert rms["model"] < 1.0, rms


def test_no_trend_over_range(tables, cfg):
    table = tables["model"][0]
    mean_err = []
    for z in HOLDOUT_Z:
        xp, q = plane_truth(cfg, z)
        mean_err.append(1e3 * np.nanmean(table.apply_image(xp).xyz[..., 2] - q[..., 2]))
    slope = np.polyfit(HOLDOUT_Z, mean_err, 1)[0]
    assert abs(slope) * (HOLDOUT_Z[-1] - HOLDOUT_Z[0]) < 0.5  # < 0.5 um over the range


def test_slope_matches_finite_difference(tables, cfg):
    table = tables["model"][0]
    u, v = np.array([50.0, 120.0]), np.array([40.0, 77.0])
    xp0 = plane_truth(cfg, 450.0)[0][[40, 77], [50, 120]]
    look = table.apply(u, v, xp0)
    h = 0.01
    fd = (table.apply(u, v, xp0 + h).xyz - table.apply(u, v, xp0 - h).xyz) / (2 * h)
    np.testing.assert_allclose(look.slope, fd, rtol=1e-4, atol=1e-7)
    assert look.in_volume.all()


def test_sigma_table_reported_and_smaller_with_weights(tables):
    med = {w: np.nanmedian(t[0].sigma_node) for w, t in tables.items()}
    assert 0 < med["model"] < med["none"]


def test_out_of_range_flagged_not_extrapolated(tables, cfg):
    table = tables["model"][0]
    xp_far, _ = plane_truth(cfg, 500.0)  # beyond the last calibrated plane (480 mm)
    look = table.apply_image(xp_far)
    assert not look.in_volume.any()
    assert np.isnan(look.xyz).all()
    ext = table.apply_image(xp_far, extrapolate=True)
    assert np.isfinite(ext.xyz).all() and not ext.in_volume.any()


def test_injected_unwrapping_jumps_are_rejected_and_counted(cfg):
    clean_table, clean = build_table(sweep(cfg, CAL_Z[::2], seed=5), cfg)
    table, rep = build_table(sweep(cfg, CAL_Z[::2], seed=5, jump_fraction=0.01), cfg)
    n_pix = cfg.camera.width_px * cfg.camera.height_px * len(CAL_Z[::2])
    injected = 0.01 * n_pix
    extra = rep.rejected["unwrap_jump"] - clean.rejected["unwrap_jump"]
    assert abs(extra - injected) < 0.1 * injected, (extra, injected)
    # (the injection draws from the same generator, so the noise differs between the two
    # runs): one 5-px jump averaged into a 256-sample cell would shift it by ~9 um
    rms_jump = np.sqrt(np.mean(_holdout_rms_um(cfg, table) ** 2))
    rms_clean = np.sqrt(np.mean(_holdout_rms_um(cfg, clean_table) ** 2))
    assert rms_jump < 1.5 * rms_clean + 0.2, (rms_jump, rms_clean)


def test_file_round_trip_and_version_check(tables, tmp_path):
    table = tables["model"][0]
    path = tmp_path / "t.npz"
    save_table(path, table)
    again = load_table(path)
    np.testing.assert_array_equal(again.xyz, table.xyz)
    assert again.weights == "model" and again.config == table.config
    np.savez(tmp_path / "old.npz", meta=np.array('{"format": "scanqa-table/0"}'))
    with pytest.raises(InputError, match="table format 'scanqa-table/0' is not supported"):
        load_table(tmp_path / "old.npz")
    with pytest.raises(InputError, match="does not exist"):
        load_table(tmp_path / "none.npz")


def test_other_camera_size_is_refused(tables):
    with pytest.raises(InputError, match=r"phase map is 10 x 20 px but the table was built "
                                         r"for a 192 x 128 px camera"):
        tables["model"][0].apply_image(np.zeros((20, 10)))


def test_too_few_positions_and_mixed_sizes(cfg):
    with pytest.raises(InputError, match="at least 3 distinct positions, got 2"):
        build_table(sweep(cfg, [440.0, 450.0], repeats=2), cfg)
    obs = sweep(cfg, [440.0, 450.0, 460.0])
    small = sweep(small_camera(cfg, 64, 64), [470.0])
    with pytest.raises(InputError, match="all scans must come from one camera"):
        build_table(obs + small, cfg)
    with pytest.raises(InputError, match="weights must be one of"):
        build_table(obs, cfg, weights="magic")
