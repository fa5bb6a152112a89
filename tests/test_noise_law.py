"""The per-pixel noise law from repeated captures (simulated sample data: three repeats
of the gauge-block scene), checked on image rows it was not fitted to, and against the
model the sweeps characterised - two independent characterisations of one scanner."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.characterization import board
from scanqa.characterization.sweep import apply_fitted_model
from scanqa.cli import main
from scanqa.decoding.decoder import decode
from scanqa.decoding.imagenoise import phase_sigma_px
from scanqa.errors import InputError
from scanqa.model.config import load_config
from tests.conftest import ROOT
from tests.synth_parametric import config_pinhole

SAMPLE = ROOT / "sample_data"


@pytest.fixture(scope="module")
def repeats():
    return [decode(SAMPLE / "gauge_blocks" / f"p000_r{i}") for i in range(3)]


def test_law_is_the_textbook_phase_noise():
    """sigma_phi^2 = 2 sigma_I^2 / (N B^2) for N equally spaced steps: checked here by
    Monte Carlo of a 4-step demodulation (independent of the formula's code)."""
    rng = np.random.default_rng(3)
    a_dn, b_dn, sigma_i, n = 80.0, 30.0, 2.0, 4
    delta = 2 * np.pi * np.arange(n) / n
    frames = a_dn + b_dn * np.cos(0.7 + delta)[:, None] + rng.normal(0, sigma_i, (n, 200000))
    phi = np.arctan2(-(np.sin(delta) @ frames), np.cos(delta) @ frames)
    period = 2 * np.pi  # x_p in radians
    got = phase_sigma_px(b_dn, a_dn, sigma_i**2, 0.0, period, n)
    np.testing.assert_allclose(got, np.std(phi), rtol=0.01)  # 200 000 samples: ~0.2 %
    assert np.isnan(phase_sigma_px(0.0, a_dn, 1.0, 0.0, period, n))


def test_repeats_law_holds_on_held_out_rows_and_meets_the_sweep_model(repeats, tmp_path):
    """Fitted on the even rows, the law predicts the temporal std of the odd rows (median
    measured/predicted 1.00 here, simulated); applied through annotate its median sigma is
    within 15 % of the sigma the camera and projector sweeps characterised (7.6 vs 7.2 um
    here), and the cloud says it was characterised from repeats."""
    result = board.characterize_repeats(repeats)
    assert 0.9 <= result["held_out"]["median_ratio"] <= 1.1
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(result))
    config = load_config(SAMPLE / "sample_scanner.toml", profile="sample")
    law = apply_fitted_model(config, path)
    assert law.model.has_noise_law
    assert "summary.json sha256 " in law.model.characterised_by
    assert "(scanqa characterize repeats" in law.model.characterised_by
    cal = config_pinhole(config)
    swept = annotate(repeats[0], cal, config).attributes
    lawful = annotate(repeats[0], cal, law)
    assert lawful.metadata["sigma_source"]["random"] == "law"
    a = lawful.attributes
    ok = np.isfinite(swept["sigma_model_um"]) & np.isfinite(a["sigma_random_um"])
    ratio = np.median(a["sigma_random_um"][ok]) / np.median(swept["sigma_model_um"][ok])
    assert 0.85 <= ratio <= 1.15, ratio


def test_repeats_need_two_captures_and_the_cli_writes_the_summary(repeats, tmp_path, capsys):
    with pytest.raises(InputError, match=">= 2 captures"):
        board.repeat_samples(repeats[:1])
    scans = [str(SAMPLE / "gauge_blocks" / f"p000_r{i}") for i in range(2)]
    code = main(["characterize", "repeats", *scans, "--out", str(tmp_path / "n")])
    out = capsys.readouterr().out
    assert code == 0 and "held-out rows" in out
    data = json.loads((tmp_path / "n" / "summary.json").read_text())
    assert data["kind"] == "repeats" and len(data["noise_law"]["data_sha256"]) == 64


def test_a_characterisation_that_does_not_fit_the_scan_warns_with_both_numbers(repeats,
                                                                               tmp_path):
    """The law the repeats gave: its median random sigma over the scan within [0.5, 2] of
    the images' own (no warning). The same law with 400x the intensity variance (20x the
    sigma, as a datasheet for another camera might give): a warning naming both medians."""
    result = board.characterize_repeats(repeats)
    config = load_config(SAMPLE / "sample_scanner.toml", profile="sample")
    cal = config_pinhole(config)
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(result))
    fits = annotate(repeats[0], cal, apply_fitted_model(config, path))
    assert 0.5 <= fits.sigma_source["ratio_to_images"] <= 2.0
    assert fits.sigma_source["warning"] == ""  # the random term: no word against the images
    assert "carries no covariance" in fits.sigma_warning  # the config's pinhole: none
    law = result["noise_law"]
    law["read_var_dn2"], law["shot_dn"] = 400 * law["read_var_dn2"], 400 * law["shot_dn"]
    path.write_text(json.dumps(result))
    cloud = annotate(repeats[0], cal, apply_fitted_model(config, path))
    a = cloud.attributes
    ok = np.isfinite(a["sigma_random_um"]) & np.isfinite(a["sigma_phase_um"])
    char, images = (float(np.median(a[k][ok])) for k in ("sigma_random_um", "sigma_phase_um"))
    assert char / images == pytest.approx(20 * fits.sigma_source["ratio_to_images"], rel=0.05)
    warning = cloud.sigma_source["warning"]
    assert f"median of {char:.3g} um" in warning and f"give {images:.3g} um" in warning
    assert "does not fit this scan" in warning and "\n" not in warning
