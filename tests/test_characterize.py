"""Tests of scanqa.characterization.sweep on small simulated sweeps (closed loop with known
optics)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scanqa.characterization.noisefit import JOINT_VARIANTS, SINGLE_SWEEP_VARIANTS
from scanqa.characterization.sweep import (
    JointCharacterization,
    apply_fitted_model,
    characterize_sweep,
    characterize_sweeps,
    measured_dof,
)
from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.model import optics
from scanqa.report.characterization import write_characterization
from scanqa.simulator.experiments import run_experiment


def _sweep(tmp_path_factory, paper_config, experiment: str):
    """A 48 x 48 px sweep of the paper scanner, -27..27 mm in 3 mm steps."""
    out = tmp_path_factory.mktemp(experiment)
    config = paper_config.replace_simulator(roi_width_px=48, roi_height_px=48)
    positions = [float(p) for p in np.arange(-27.0, 27.1, 3.0)]
    run_experiment(experiment, config, out, positions=positions)
    return out, config


@pytest.fixture(scope="module")
def camera_sweep(tmp_path_factory, paper_config):
    return _sweep(tmp_path_factory, paper_config, "camera-sweep")


@pytest.fixture(scope="module")
def projector_sweep(tmp_path_factory, paper_config):
    return _sweep(tmp_path_factory, paper_config, "projector-sweep")


@pytest.fixture(scope="module")
def results(camera_sweep, projector_sweep):
    """Characterisations of each sweep alone and of both together (computed once)."""
    (cam, config), (proj, _) = camera_sweep, projector_sweep
    return {"camera": characterize_sweep(cam, config),
            "projector": characterize_sweep(proj, config),
            "joint": characterize_sweeps([cam, proj], config)}


def test_characterize_fits_w_curve_within_15_percent(results):
    result = results["camera"]
    assert result.w_shape
    # issue acceptance: the selected model predicts held-out positions within 15 % RMS
    # where A >= 0.49, far better than a constant (the W is real)
    summary = result.summary()
    assert result.best.cv_rms_relative < 0.15 and summary["better_than_constant"]
    assert result.best.cv_rms_relative < 0.3 * summary["constant"]["cv_rms_relative"]
    # attenuation within 0.02 of A(r) for r <= 0.5 (noise of a 48 x 48 window included)
    assert result.attenuation_max_abs_error < 0.02
    assert {(f.filter_floor, f.filter_form, f.noise_reading) for f in result.fits} == \
        set(SINGLE_SWEEP_VARIANTS)


def _rms_with(config, result, fit, **change):
    """RMS of log(model / measured) over the fitted positions of a one-sweep result,
    with some parameters changed and sigma_p re-fitted (its log-mean closed form)."""
    pos = [p for p in result.positions if p.attenuation_model >= result.min_attenuation]
    z_c, z_p = np.array([p.z_c_mm for p in pos]), np.array([p.z_p_mm for p in pos])
    std = np.array([p.residual_std_px for p in pos])
    values = {"gamma": fit.gamma, "sensor": fit.sensor_sigma_p_px, **change}
    t = optics.optical_terms(z_c, z_p, config, result.period_px, values["gamma"],
                             fit.filter_floor, fit.noise_reading, fit.filter_form,
                             sensor_ratio=values["sensor"] / fit.sigma_p_px)
    r = np.log(fit.sigma_p_px * t.s_o / std)
    return float(np.sqrt(np.mean((r - r.mean()) ** 2)))


def test_no_parameter_is_reported_fitted_that_the_data_do_not_move(camera_sweep, results):
    config = camera_sweep[1]
    for result in (results["camera"], results["projector"]):
        for fit in result.fits:
            gamma = fit.parameter("gamma")
            if fit.filter_floor == "none":
                # Eq. 17 as printed: F ~ 1 / gamma, only sigma_p x gamma is identifiable
                assert gamma.status == "not identifiable" and "sigma_p x gamma" in gamma.why
                combo = {c["name"]: c for c in fit.identifiable}["sigma_p_px * gamma"]
                assert combo["value"] == pytest.approx(fit.sigma_p_px * fit.gamma)
                base = _rms_with(config, result, fit)
                assert _rms_with(config, result, fit, gamma=3 * fit.gamma) == \
                    pytest.approx(base, abs=1e-9)
            for p in fit.parameters:
                assert p.status in ("fitted", "bounded", "not identifiable")
                if p.status == "fitted":
                    assert p.low < p.value < p.high
                if p.status == "not identifiable":
                    assert p.why and np.isnan(p.low)
            if fit.filter_floor in ("one", "smooth") and gamma.status == "fitted":
                # a gamma the fit reports as fitted does move the model: half or twice it
                # fits worse even with sigma_p re-fitted
                base = _rms_with(config, result, fit)
                assert _rms_with(config, result, fit, gamma=max(1.0, fit.gamma / 2)) > base
                assert _rms_with(config, result, fit, gamma=2 * fit.gamma) > base
    # a projector sweep keeps the camera in focus: F is the same at every position (1 with
    # Eq. 17's product, sqrt(1 + b_d) / gamma with the sum), so gamma only rescales the
    # noise and is not identifiable there, and the sensor and scene-side terms trade off
    proj_result = results["projector"]
    for fit in proj_result.fits:
        if fit.filter_floor != "none":
            gamma = fit.parameter("gamma")
            assert gamma.status == "not identifiable" and "at every position" in gamma.why
            assert _rms_with(config, proj_result, fit, gamma=1.0) == pytest.approx(
                _rms_with(config, proj_result, fit, gamma=50.0), abs=1e-6)
        if fit.noise_reading == "two_source":
            sensor = fit.parameter("sensor_sigma_p_px")
            assert sensor.status == "not identifiable" and "decoder" in sensor.why


def test_joint_characterization_selects_the_two_source_model(camera_sweep, results,
                                                              tmp_path):
    config = camera_sweep[1]
    joint = results["joint"]
    assert isinstance(joint, JointCharacterization)
    assert {(f.filter_floor, f.filter_form, f.noise_reading) for f in joint.fits} == \
        set(JOINT_VARIANTS)
    # the simulator adds scene-side noise before the camera blur and sensor noise after
    # it: the two-source model, selected on held-out positions, fits both sweeps with one
    # set of parameters, better than every reading of the paper (mixed included)
    by = {f.label: f.cv_rms_relative for f in joint.fits}
    assert joint.best.noise_reading == "two_source", by
    assert joint.best.cv_rms_relative < 0.08, by
    assert by["one/product/mixed"] > 1.5 * joint.best.cv_rms_relative, by
    assert all(p.status == "fitted" for p in joint.best.parameters), joint.best.parameters
    # the fitted sensor part agrees with the decoder's own sensor model (read, shot and
    # quantisation noise through the phase fit) at focus within 35 %
    decoder = min(p.sensor_std_px for c in joint.sweeps for p in c.positions)
    assert joint.best.sensor_sigma_p_px == pytest.approx(decoder, rel=0.35)
    summary = json.loads(write_characterization(joint, tmp_path, config).read_text())
    assert summary["experiment"] == "camera-sweep+projector-sweep"
    assert summary["best_variant"]["noise_reading"] == "two_source"
    assert summary["better_than_constant"]
    assert [s["experiment"] for s in summary["sweeps"]] == ["camera-sweep", "projector-sweep"]
    assert (tmp_path / "std_projector-sweep.png").stat().st_size > 1000


def test_the_smooth_floor_is_offered_and_selected_where_it_fits(camera_sweep, results,
                                                                tmp_path):
    """Simulated closed loop: characterisation fits the smooth floor (F^2 = 1 + N /
    gamma^2, gamma following the range) beside the paper's forms and selects it on
    held-out positions because it predicts them best here, not by default. The
    simulator filters its scene noise (cells fixed on the object) by the camera's blur
    and adds the sensor's after it; held out, the smooth form predicts the camera sweep to
    4.1 % and both sweeps to 3.3 % RMS against 5.4 % and 3.9 % for the floored sum
    form (session 38), every parameter fitted, and its sensor part is the decoder's own
    image-based estimate (which the fit never sees) within 10 % (measured 0.1 %). The
    summary and the fitted model a user applies carry the form."""
    config = camera_sweep[1]
    joint = results["joint"]
    for result, positions in ((results["camera"], results["camera"].positions),
                              (joint, [p for c in joint.sweeps for p in c.positions])):
        by = {f.label: f for f in result.fits}
        smooth = by["smooth/sum/two_source"]
        assert result.best.label == smooth.label, {k: f.cv_rms_relative for k, f in by.items()}
        assert smooth.cv_rms_relative < by["one/sum/two_source"].cv_rms_relative
        assert all(p.status == "fitted" for p in smooth.parameters), smooth.parameters
        decoder = min(p.sensor_std_px for p in positions)
        assert smooth.sensor_sigma_p_px == pytest.approx(decoder, rel=0.10)
    path = write_characterization(results["camera"], tmp_path, config)
    summary = json.loads(path.read_text())
    assert summary["best_variant"]["filter_floor"] == "smooth"
    assert "smooth" in {f["filter_floor"] for f in summary["fits"]}
    fitted = apply_fitted_model(config, path).model
    assert (fitted.filter_floor, fitted.filter_form, fitted.noise_reading) == \
        ("smooth", "sum", "two_source")
    assert fitted.gamma == pytest.approx(results["camera"].best.gamma)


def test_joint_characterization_refuses_different_periods(camera_sweep, tmp_path):
    cam, config = camera_sweep
    small = config.replace_simulator(roi_width_px=24, roi_height_px=24)
    run_experiment("projector-sweep", small, tmp_path, positions=[-3.0, 0.0, 3.0, 6.0],
                   periods=[7.0])
    with pytest.raises(InputError, match="different working periods"):
        characterize_sweeps([cam, tmp_path], config)


def test_characterize_dof_close_to_model(results):
    rows = {r["level"]: r for r in results["camera"].dof}
    for level in (0.25, 0.36, 0.49, 0.64):
        # 3 mm steps and a 48 x 48 px window: 4 % here (3 % with the full sweep)
        assert abs(rows[level]["deviation_pct"]) < 4.0, rows[level]


def test_characterize_cli_writes_summary_and_plots(camera_sweep, tmp_path):
    folder, _ = camera_sweep
    cfg = tmp_path / "cfg.toml"
    base = (folder / "manifest.toml").read_text()
    assert "camera-sweep" in base
    from scanqa.io.tomlfile import dumps_toml as dump_toml
    from scanqa.io.tomlfile import read_toml

    data = read_toml(folder / "manifest.toml", "manifest")["config"]
    data.pop("name")
    cfg.write_text(dump_toml(data))
    code = main(["characterize", "sweep", str(folder), "--config", str(cfg), "--out",
                 str(tmp_path / "out")])
    assert code == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["best_variant"]["cv_rms_relative"] < 0.15
    assert (tmp_path / "out" / "std.png").stat().st_size > 1000


def test_measured_dof_interpolates():
    z = np.arange(-5.0, 6.0)
    att = 1.0 - (z / 5.0) ** 2
    # 1 - (z/5)^2 >= 0.64 for |z| <= 3: length 6 mm
    assert measured_dof(z, att, 0.64) == pytest.approx(6.0)
    assert np.isnan(measured_dof(z, att, -1.0))


def test_characterize_rejects_other_experiments(paper_config, tmp_path):
    config = paper_config.replace_simulator(roi_width_px=16, roi_height_px=16)
    run_experiment("gauge-blocks", config, tmp_path / "g", repeats=1)
    with pytest.raises(InputError, match="needs a camera-sweep, a projector-sweep or a "
                       "calibration sweep"):
        characterize_sweep(tmp_path / "g", config)
    run_experiment("calibration-sweep", config, tmp_path / "c", positions=[450.0], repeats=1)
    with pytest.raises(InputError, match="at least 3"):
        characterize_sweep(tmp_path / "c", config)
    with pytest.raises(InputError, match="does not exist"):
        characterize_sweep(tmp_path / "nowhere", config)


def test_write_characterization_without_config(results, tmp_path):
    path = write_characterization(results["camera"], tmp_path)
    assert json.loads(path.read_text())["experiment"] == "camera-sweep"
