"""Closed loops through the simulator with known truth: acceptance of issues 5, 6 and 7.

One camera throughout: profile ``sample`` of sample_data/sample_scanner.toml (the paper's
scanner at f/11, sensor binned 8 x 8 to 306 x 256 px, 8-bit). Data:

* committed sample data: the camera and projector sweeps (characterisation), the
  27-position calibration sweep 424..476 mm (past the depth of field) and 3 gauge-block
  scans;
* simulated here, in memory, by session fixtures (~35 s on 2 cores): 9 more repeats of
  the gauge-block scan (12 in all, the same noise streams as ``scanqa simulate
  gauge-blocks --repeats 12``), 4 repeats of 9 hold-out planes between the calibrated
  positions, rendered in the central 128 x 128 px window of the sensor, and a sweep far
  past the depth of field (414..490 mm) of the central 96 x 96 px, for three noise seeds
  (the weighting comparison; seeds 1 and 2 only in the slow test).

Truth is the simulator's ray casting (:func:`scanqa.simulator.render.truth_for`): X, Y, Z
and the true projector coordinate ``xp_true`` at every pixel centre. The simulator forms
images; it never draws noise from the model's sigma.

Systematic error with R repeats: the repeat-averaged error holds the systematic error
plus noise of variance s^2 / R, so the noise floor is removed with each point's sample
covariance S: sys^2 = mean |mean error|^2 - mean(trace S) / R (unbiased). Points within
3 px of a depth step or of an unlit (shadowed) pixel are left out there: the camera blur
mixes two surfaces or light and shadow, which is a property of the scene, not of the
calibration (the gauge QA excludes them with its edge margin too).

Tests marked ``xfail(strict=True)`` state an acceptance criterion that the current code
does not meet, unweakened; the reason gives the measured numbers and the diagnosis. A
strict xfail fails the suite as soon as the criterion holds, so the marker goes with the
fix. Every measured number is printed (``pytest -s``) and stored in the pytest cache
under ``scanqa/closed_loop`` (``.pytest_cache/v/scanqa/closed_loop``).
"""

from __future__ import annotations

import functools
import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.ndimage import binary_erosion, maximum_filter, minimum_filter

from scanqa.annotation.points import annotate
from scanqa.calibration.build import PlaneObservation, build_table
from scanqa.calibration.sweep import iter_observations
from scanqa.calibration.table import load_table
from scanqa.characterization.sweep import apply_fitted_model, characterize_sweeps
from scanqa.cli import main
from scanqa.decoding.decoder import decode_images, decode_pattern_dir
from scanqa.io.manifest import read_manifest
from scanqa.io.sweep import load_sweep
from scanqa.model import optics
from scanqa.model.config import load_config
from scanqa.qa.blocks import run_qa
from scanqa.qa.layout import load_layout
from scanqa.simulator import render
from scanqa.simulator.devices import sensor_window
from scanqa.simulator.experiments import acquisition, build_positions, pattern_description

from .conftest import ROOT
from .shared_runs import sample_table
from .synth_sweep import small_camera

SAMPLE_DATA = ROOT / "sample_data"
SAMPLE_TOML = SAMPLE_DATA / "sample_scanner.toml"
SAMPLE = f"{SAMPLE_TOML}#sample"
SWEEP_DIR = SAMPLE_DATA / "calibration_sweep"
GAUGE_DIR = SAMPLE_DATA / "gauge_blocks"
CAMERA_SWEEP = SAMPLE_DATA / "camera_sweep"
PROJECTOR_SWEEP = SAMPLE_DATA / "projector_sweep"
LAYOUT = ROOT / "calib" / "gauge_blocks_paper.toml"

#: Hold-out planes for the table applied to the true phase: midway between positions.
HOLDOUT_TRUE_Z = tuple(float(z) for z in np.arange(425.0, 476.0, 2.0))
#: Hold-out planes scanned (decoded phase), spread over the calibrated range [mm].
HOLDOUT_SCAN_Z = (425.0, 431.0, 437.0, 443.0, 449.0, 455.0, 461.0, 467.0, 475.0)
HOLDOUT_REPEATS = 4
HOLDOUT_WINDOW_PX = 128
#: Noise streams of the hold-out scans: distinct from every sweep and gauge scan.
HOLDOUT_KEY = 900
GAUGE_REPEATS = 12
#: A sweep reaching far past the depth of field (camera attenuation ~0.05 at its ends),
#: of the sample camera's central 96 x 96 px [mm].
WIDE_SWEEP_Z = tuple(float(z) for z in np.arange(414.0, 491.0, 2.0))
WIDE_WINDOW_PX = 96
#: Points this close to a depth step or to an unlit pixel are left out [px].
EDGE_MARGIN_PX = 3
CACHE_KEY = "scanqa/closed_loop"


# ------------------------------------------------------------------------ helpers


def _record(request: pytest.FixtureRequest, key: str, value: dict) -> None:
    """Print a measurement and keep it in the pytest cache."""
    print(f"\n[closed loop] {key}: {json.dumps(value)}")
    cache = getattr(request.config, "cache", None)
    if cache is not None:
        data = cache.get(CACHE_KEY, {})
        data[key] = value
        cache.set(CACHE_KEY, data)


def _parallel(fn, items: list) -> list:
    """Map on both cores: rendering and decoding are numpy and Open3D, which release
    the GIL (results are identical to a sequential run)."""
    with ThreadPoolExecutor(max_workers=min(2, os.cpu_count() or 1)) as pool:
        return list(pool.map(fn, items))


def plane_truth(config, z_mm: float) -> render.Truth:
    """Truth of the flat calibration target at world Z = z_mm."""
    pos = build_positions("calibration-sweep", config, [z_mm])[0]
    return render.truth_for(config, acquisition(config, pos, 0))


def clean_pixels(valid: np.ndarray, z: np.ndarray, margin: int = EDGE_MARGIN_PX
                 ) -> np.ndarray:
    """Pixels at least ``margin`` px from a depth step (> 0.05 mm) and from unlit pixels."""
    k = 2 * margin + 1
    zz = np.where(np.isfinite(z), z, 0.0)
    flat = (maximum_filter(zz, size=k) - minimum_filter(zz, size=k)) < 0.05
    return flat & binary_erosion(valid, np.ones((k, k), bool), border_value=0)


def line_of_sight(points: np.ndarray) -> np.ndarray:
    """Unit vectors from the scanner origin to the points: (n, 3)."""
    return points / np.linalg.norm(points, axis=-1, keepdims=True)


@dataclass(frozen=True)
class Systematic:
    """Systematic error of repeat-averaged points [mm]."""

    sys: float       # RMS with the noise floor removed
    raw: float       # RMS of the repeat-averaged error
    floor: float     # RMS noise left in the average
    bias: float      # mean signed error along the line of sight
    n: int


def systematic(errors: np.ndarray, los: np.ndarray) -> Systematic:
    """(R, n, 3) errors of R repeats at n points -> :class:`Systematic` [mm]."""
    reps = errors.shape[0]
    mean = errors.mean(axis=0)
    raw2 = float(np.mean(np.sum(mean**2, axis=-1)))
    floor2 = float(np.mean(errors.var(axis=0, ddof=1).sum(axis=-1))) / reps if reps > 1 \
        else 0.0
    bias = float(np.mean(np.einsum("ni,ni->n", mean, los)))
    return Systematic(float(np.sqrt(max(raw2 - floor2, 0.0))), float(np.sqrt(raw2)),
                      float(np.sqrt(floor2)), bias, int(errors.shape[1]))


def pooled(parts: list[Systematic]) -> Systematic:
    """Point-weighted pool of several :class:`Systematic` results."""
    n = np.array([p.n for p in parts], float)

    def avg(values):
        return float(np.sum(n * np.square(values)) / n.sum())

    raw2, floor2 = avg([p.raw for p in parts]), avg([p.floor for p in parts])
    bias = float(np.sum(n * [p.bias for p in parts]) / n.sum())
    return Systematic(float(np.sqrt(max(raw2 - floor2, 0.0))), float(np.sqrt(raw2)),
                      float(np.sqrt(floor2)), bias, int(n.sum()))


def trend(z: list[float], bias: list[float]) -> float:
    """Change of the least-squares line through the biases across the z span [mm]."""
    slope = np.polyfit(np.asarray(z), np.asarray(bias), 1)[0]
    return float(abs(slope) * (max(z) - min(z)))


def table_errors(table, u, v, xp_stack: np.ndarray, truth_xyz: np.ndarray) -> np.ndarray:
    """(R, n, 3) errors of the table applied to R phase maps at pixels (u, v) [mm]."""
    return np.stack([table.apply(u, v, xp).xyz - truth_xyz for xp in xp_stack])


def um(value_mm: float) -> float:
    """mm -> um, rounded for the record."""
    return round(1e3 * float(value_mm), 3)


# ----------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def sample_config():
    return load_config(SAMPLE_TOML, profile="sample")


@pytest.fixture(scope="session")
def characterised(tmp_path_factory, sample_config):
    """``scanqa characterize`` of the committed camera and projector sweeps: (summary.json,
    config with the model they select)."""
    out = tmp_path_factory.mktemp("characterise")
    assert main(["characterize", "sweep", str(CAMERA_SWEEP), str(PROJECTOR_SWEEP),
                 "--config", SAMPLE, "--out", str(out)]) == 0
    summary = out / "summary.json"
    return summary, apply_fitted_model(sample_config, summary)


@pytest.fixture(scope="session")
def sweep_observations():
    """The committed calibration sweep, decoded."""
    return list(iter_observations(load_sweep(SWEEP_DIR)))


@pytest.fixture(scope="session")
def calibrated(tmp_path_factory, sample_config, sweep_observations):
    """(table file of ``scanqa calibrate`` with model weights, {"model", "none"} tables)."""
    # `scanqa calibrate SWEEP_DIR/sweep.toml --config SAMPLE`, run once per make test
    path = sample_table(tmp_path_factory.mktemp("calibrate"))
    unweighted, _ = build_table(sweep_observations, sample_config, weights="none")
    return path, {"model": load_table(path), "none": unweighted}


@pytest.fixture(scope="session")
def focus_sigma_mm(request, sample_config, sweep_observations, calibrated, characterised):
    """Measured single-point std at focus [mm]: the decoded phase of the calibration plane
    at the camera's focus against its true phase, times the table's slope |dQ/dx_p|.
    (The characterised model's sigma there is recorded beside it.)"""
    focus = sample_config.camera.focus_mm
    obs = min(sweep_observations, key=lambda o: abs(o.z_mm - focus))
    truth = plane_truth(sample_config, obs.z_mm)
    d = obs.xp - truth.xp
    half_period = 0.5 * sample_config.fringes.working_period_px
    ok = np.isfinite(d) & truth.valid & (np.abs(d) < half_period)
    v, u = np.nonzero(ok)
    look = calibrated[1]["model"].apply(u, v, obs.xp[ok])
    sigma = float(np.std(d[ok] * look.s_t))
    model = optics.predict(look.xyz, characterised[1], s_t=look.s_t).sigma
    _record(request, "in_focus_sigma", {"z_mm": obs.z_mm, "measured_um": um(sigma),
                                        "model_um": um(np.sqrt(np.mean(model**2)))})
    return sigma


@pytest.fixture(scope="session")
def holdout_scans(sample_config):
    """Decoded repeats of hold-out planes in the central window: [(z, u, v, xp (R, n),
    truth (n, 3))] with u, v in sensor pixels."""
    config = sample_config.replace_simulator(roi_width_px=HOLDOUT_WINDOW_PX,
                                             roi_height_px=HOLDOUT_WINDOW_PX)
    win = sensor_window(config)
    desc = pattern_description(config)
    positions = build_positions("calibration-sweep", config, HOLDOUT_SCAN_Z)
    acqs = [replace(acquisition(config, p, 0), key=(HOLDOUT_KEY + p.index, r))
            for p in positions for r in range(HOLDOUT_REPEATS)]
    maps = _parallel(lambda acq: decode_images(desc, render.render_images(config, acq, desc)).xp,
                     acqs)
    out = []
    for k, pos in enumerate(positions):
        truth = render.truth_for(config, acquisition(config, pos, 0))
        xp = np.stack(maps[k * HOLDOUT_REPEATS:(k + 1) * HOLDOUT_REPEATS])
        ok = np.isfinite(xp).all(axis=0) & clean_pixels(truth.valid, truth.z)
        v, u = np.nonzero(ok)
        xyz = np.stack([truth.x[ok], truth.y[ok], truth.z[ok]], axis=-1)
        out.append((pos.stage_mm, u + float(win.u0), v + float(win.v0), xp[:, ok], xyz))
    return out


def wide_sweep(sample_config, seed: int = 0):
    """(config, decoded observations) of a one-repeat sweep over WIDE_SWEEP_Z with the
    sample camera's central 96 x 96 px and noise seed ``seed``: a camera with that
    sensor and the same optics (its principal point is the window's centre, so the
    geometry is the window's)."""
    config = small_camera(sample_config, WIDE_WINDOW_PX, WIDE_WINDOW_PX)
    config = config.replace_simulator(seed=seed)
    desc = pattern_description(config)

    def scan(pos):
        pm = decode_images(desc, render.render_images(config, acquisition(config, pos, 0), desc))
        return PlaneObservation(pos.stage_mm, pm.xp, pm.mask, pm.modulation, pm.sigma_xp,
                                source=f"z={pos.stage_mm}")

    return config, _parallel(scan, build_positions("calibration-sweep", config,
                                                   WIDE_SWEEP_Z))


@pytest.fixture(scope="session")
def gauge_scans(sample_config):
    """(12 decoded gauge-block scans: the committed 3 + 9 rendered here, truth arrays)."""
    committed = sorted(GAUGE_DIR.glob("p000_r*"), key=lambda p: int(p.name.split("_r")[1]))
    scans = [decode_pattern_dir(p) for p in committed]
    desc = pattern_description(sample_config)
    pos = build_positions("gauge-blocks", sample_config, [0.0])[0]
    render.truth_for(sample_config, acquisition(sample_config, pos, 0))  # build the scene
    scans += _parallel(lambda rep: decode_images(desc, render.render_images(
        sample_config, acquisition(sample_config, pos, rep), desc)),
        list(range(len(scans), GAUGE_REPEATS)))
    with np.load(GAUGE_DIR / "truth" / "p000.npz", allow_pickle=False) as data:
        truth = {k: data[k] for k in data.files}
    return scans, truth


@pytest.fixture(scope="session")
def gauge_cloud(gauge_scans, calibrated, characterised):
    """Scan 0 annotated with the characterised model, the 11 other scans as repeats,
    points outside the calibrated volume kept (flagged)."""
    scans, _ = gauge_scans
    return annotate(scans[0], calibrated[1]["model"], characterised[1], repeats=scans[1:],
                    keep_invalid=True)


# ------------------------------------------------------------------ issue 5: table


def _holdout_true_phase(sample_config, table) -> tuple[list, list[float]]:
    """Per hold-out plane: Systematic of the table applied to the true phase."""
    parts = []
    for z in HOLDOUT_TRUE_Z:
        truth = plane_truth(sample_config, z)
        v, u = np.nonzero(truth.valid)
        xyz = np.stack([truth.x, truth.y, truth.z], axis=-1)[truth.valid]
        err = table_errors(table, u, v, truth.xp[truth.valid][None], xyz)
        parts.append(systematic(err, line_of_sight(xyz)))
    return parts, list(HOLDOUT_TRUE_Z)


@pytest.fixture(scope="session")
def true_phase_parts(sample_config, calibrated):
    """:func:`_holdout_true_phase` of the table of each weighting ("model", "none"),
    computed once: the model table's is asserted by two tests (~1.8 s of CPU each)."""
    return functools.cache(lambda weights: _holdout_true_phase(sample_config,
                                                               calibrated[1][weights]))


def test_characterisation_is_of_the_same_camera(sample_config, characterised):
    mine = sample_config.to_dict()["camera"]
    for folder in (CAMERA_SWEEP, PROJECTOR_SWEEP):
        cam = read_manifest(folder)["config"]["camera"]
        assert {k: cam[k] for k in mine} == mine
    summary = json.loads(characterised[0].read_text())
    assert summary["experiment"] == "camera-sweep+projector-sweep"
    assert summary["better_than_constant"]


def test_sample_camera_sweep_reports_only_what_it_identifies(request):
    """Issue 16 acceptance on the sample camera sweep alone: no parameter is reported as
    fitted that the fit did not move, every fitted one has its 95 % interval, and the
    selected model beats a constant (which the paper's readings do not)."""
    config = load_config(SAMPLE_TOML, profile="sample_roi64")
    result = characterize_sweeps([CAMERA_SWEEP], config)
    summary = result.summary()
    rows = {f["filter_floor"] + "/" + f["filter_form"] + "/" + f["noise_reading"]: f
            for f in summary["fits"]}
    _record(request, "issue16_sample_camera_sweep", {
        "verdict": summary["verdict"], "constant_cv": summary["constant"]["cv_rms_relative"],
        **{k: [round(f["cv_rms_relative"], 4),
               [(p["name"], p["status"], p["low"], p["high"]) for p in f["parameters"]]]
           for k, f in rows.items()}})
    for label, fit in rows.items():
        for p in fit["parameters"]:
            if p["status"] == "fitted":
                assert p["low"] < p["value"] < p["high"], (label, p)
            elif p["status"] == "not identifiable":
                assert p["why"] and not np.isfinite(p["low"] or np.nan), (label, p)
        if fit["filter_floor"] == "none":  # F ~ 1 / gamma: only sigma_p x gamma
            assert fit["parameters"][1]["status"] == "not identifiable", label
            assert any(c["name"] == "sigma_p_px * gamma" for c in fit["identifiable"])
        if fit["filter_form"] == "product" and fit["filter_floor"] == "one":
            # 64 um pixels: b_d = 0.03, so F = 1 everywhere and gamma has no effect
            assert "F = 1 at every position" in fit["parameters"][1]["why"], label
    assert summary["better_than_constant"]
    constant = summary["constant"]["cv_rms_relative"]
    paper = [f for k, f in rows.items() if "two_source" not in k]
    assert all(f["cv_rms_relative"] > constant for f in paper)


def test_characterisation_from_the_calibration_sweep_alone(request, sample_config,
                                                           characterised):
    """Issue 15 acceptance: a rigid scanner's calibration sweep (both devices defocus
    together) picks a reading and gives sigma_p within 20 % of the dedicated camera +
    projector sweeps of the same simulated scanner."""
    sweeps = json.loads(characterised[0].read_text())["best_variant"]
    cal = characterize_sweeps([SWEEP_DIR / "sweep.toml"], sample_config)
    label = f"{sweeps['filter_floor']}/{sweeps['filter_form']}/{sweeps['noise_reading']}"
    same = next(f for f in cal.fits if f.label == label)
    _record(request, "issue15_characterise_from_calibration_sweep", {
        "selected": cal.best.label, "sigma_p_px": cal.best.sigma_p_px,
        "sweeps_selected": label, "sweeps_sigma_p_px": sweeps["sigma_p_px"],
        "same_variant_sigma_p_px": same.sigma_p_px,
        "held_out_rms": cal.best.cv_rms_relative})
    assert cal.summary()["better_than_constant"]
    assert cal.best.label == label
    assert cal.best.sigma_p_px == pytest.approx(sweeps["sigma_p_px"], rel=0.20)


def test_sweep_extends_past_the_depth_of_field(sample_config, sweep_observations):
    zs = [o.z_mm for o in sweep_observations]
    ends = optics.predict(np.array([[0.0, 0.0, min(zs)], [0.0, 0.0, max(zs)]]),
                          sample_config)
    assert (ends.attenuation_camera < 0.49).all()


def test_table_systematic_on_holdout_planes(request, true_phase_parts, focus_sigma_mm):
    parts, zs = true_phase_parts("model")
    total = pooled(parts)
    change = trend(zs, [p.bias for p in parts])
    _record(request, "issue5_table_xp_true", {
        "rms_um": um(total.raw), "limit_um": um(0.1 * focus_sigma_mm),
        "trend_um": um(change), "per_plane_rms_um": [um(p.raw) for p in parts],
        "per_plane_bias_um": [um(p.bias) for p in parts]})
    assert total.raw <= 0.1 * focus_sigma_mm
    # No trend assertion against xp_true: the decoded phase of a simulated plane carries a
    # physical defocus bias, odd about focus (-2.3..+1.6 mpx; it vanishes with a pinhole
    # projector), which the table absorbs from the sweep. It shows here as a trend of
    # ~1.2 um and cancels in scans, whose trend is asserted on decoded data below.


@pytest.fixture(scope="session")
def holdout_scan_errors(request, calibrated, holdout_scans, focus_sigma_mm):
    """Systematic error of the hold-out scans per plane, pooled, and its trend [mm]."""
    table = calibrated[1]["model"]
    parts = [systematic(table_errors(table, u, v, xp, xyz), line_of_sight(xyz))
             for _, u, v, xp, xyz in holdout_scans]
    zs = [z for z, *_ in holdout_scans]
    total, change = pooled(parts), trend(zs, [p.bias for p in parts])
    own = np.concatenate([table.apply(u, v, xp.mean(axis=0)).sigma_table
                          for _, u, v, xp, _ in holdout_scans])
    _record(request, "issue5_holdout_scans", {
        "table_own_sigma_rms_um": um(np.sqrt(np.nanmean(own**2))),
        "repeats": HOLDOUT_REPEATS, "sys_um": um(total.sys), "raw_um": um(total.raw),
        "noise_floor_um": um(total.floor), "limit_um": um(0.1 * focus_sigma_mm),
        "trend_um": um(change), "z_mm": zs, "per_plane_sys_um": [um(p.sys) for p in parts],
        "per_plane_bias_um": [um(p.bias) for p in parts]})
    return total, change, float(np.sqrt(np.nanmean(own**2)))


def test_scan_systematic_on_holdout_planes(holdout_scan_errors, focus_sigma_mm):
    total, *_ = holdout_scan_errors
    assert total.sys <= 0.1 * focus_sigma_mm


def test_table_term_of_the_budget_against_holdout_planes(holdout_scan_errors):
    """The budget's table term is the table's own sigma (its node fits' covariance,
    scaled by their reduced chi-square). On hold-out planes that were not used to build
    the table it is measured to be 0.42 um against a systematic error of 0.47 um: about
    10 % low, which the noise terms dominate in every step; it must not be far lower."""
    total, _, own = holdout_scan_errors
    assert 0.7 * total.sys <= own <= 2.0 * total.sys


def test_scan_on_holdout_planes_has_no_trend(holdout_scan_errors, focus_sigma_mm):
    _, change, _ = holdout_scan_errors
    assert change <= 0.1 * focus_sigma_mm


@pytest.mark.slow  # ~23 s of CPU: nine gauge-block scans rendered
def test_scan_systematic_on_gauge_blocks(request, gauge_scans, calibrated, focus_sigma_mm):
    scans, truth = gauge_scans
    table = calibrated[1]["model"]
    xp = np.stack([s.xp for s in scans])
    ok = np.isfinite(xp).all(axis=0) & clean_pixels(truth["valid"], truth["Z"])
    v, u = np.nonzero(ok)
    xyz = np.stack([truth["X"][ok], truth["Y"][ok], truth["Z"][ok]], axis=-1)
    inside = table.apply(u, v, xp[:, ok].mean(axis=0)).in_volume
    err = table_errors(table, u[inside], v[inside], xp[:, ok][:, inside], xyz[inside])
    levels = np.round(xyz[inside, 2], 2)
    parts, zs = [], []
    for level in np.unique(levels):
        sel = levels == level
        if sel.sum() >= 100:  # block tops and the base plate, not side walls
            parts.append(systematic(err[:, sel], line_of_sight(xyz[inside][sel])))
            zs.append(float(level))
    total = pooled(parts)
    change = trend(zs, [p.bias for p in parts])
    _record(request, "issue5_gauge_scan", {
        "repeats": len(scans), "points": total.n, "sys_um": um(total.sys),
        "raw_um": um(total.raw), "noise_floor_um": um(total.floor),
        "limit_um": um(0.1 * focus_sigma_mm), "trend_um": um(change), "z_mm": zs,
        "per_level_sys_um": [um(p.sys) for p in parts],
        "per_level_bias_um": [um(p.bias) for p in parts]})
    assert len(zs) == 8  # blocks 2-8 and the base plate; block 1 is outside the volume
    assert total.sys <= 0.1 * focus_sigma_mm
    assert change <= 0.1 * focus_sigma_mm


@pytest.mark.xfail(strict=True, reason=(
    "on the committed 424..476 mm sweep the model-weighted table is barely better than the "
    "unweighted one (0.579 vs 0.609 um against truth on 26 hold-out planes): the "
    "simulated noise grows only 2.1x from focus to the sweep's ends (14.8 -> 30 mpx) "
    "although the fringe amplitude drops 3.5x - at focus the noise is mostly "
    "scene-side, which the camera blur filters away from focus (the W curve) - so even "
    "weights from the measured noise (oracle) gain 5.5 % on the noise part. Much of the "
    "remaining error, the defocus phase bias seen against xp_true, is common to both "
    "tables. Weighting does pay on a sweep reaching 414..490 mm (next test)."))
def test_weighting_pays_past_the_depth_of_field(request, true_phase_parts):
    rms = {w: pooled(true_phase_parts(w)[0]).raw
           for w in ("model", "none")}
    _record(request, "issue5_weighting", {"model_rms_um": um(rms["model"]),
                                          "none_rms_um": um(rms["none"]),
                                          "reduction": round(1 - rms["model"] / rms["none"],
                                                             4)})
    assert rms["model"] <= 0.8 * rms["none"]


#: Noise seeds of the weighting comparison (docs/studies/acceptance_weighting.py runs 12).
WEIGHTING_SEEDS = (0, 1, 2)


def _weighting_errors(config, observations, fitted) -> dict:
    """RMS error against truth [mm] inside the DOF (camera attenuation >= 0.49) of the
    tables of the four weighting schemes built from one sweep."""
    zs = np.arange(WIDE_SWEEP_Z[0] + 1.0, WIDE_SWEEP_Z[-1], 2.0)
    att = optics.predict(np.stack([0 * zs, 0 * zs, zs], axis=-1), config).attenuation_camera
    assert att[[0, -1]].max() < 0.1 and np.any(att >= 0.49)  # far past the DOF
    obs_att = optics.predict(np.array([[0.0, 0.0, o.z_mm] for o in observations]),
                             config).attenuation_camera
    in_dof = [o for o, a in zip(observations, obs_att, strict=True) if a >= 0.49]
    # every table is scored on the same planes: inside the DOF and inside the range of
    # the table from the DOF's planes alone
    att = np.where((zs > in_dof[0].z_mm) & (zs < in_dof[-1].z_mm), att, 0.0)
    builds = {"model": (observations, replace(config, model=fitted.model), "model"),
              "modulation": (observations, config, "modulation"),
              "none": (observations, config, "none"),
              "none, in DOF": (in_dof, config, "none")}
    truths = [plane_truth(config, float(z)) for z in zs[att >= 0.49]]
    out = {}
    for name, (obs, cfg, weights) in builds.items():
        table, _ = build_table(obs, cfg, weights=weights)
        parts = []
        for truth in truths:
            v, u = np.nonzero(truth.valid)
            xyz = np.stack([truth.x, truth.y, truth.z], axis=-1)[truth.valid]
            err = table_errors(table, u, v, truth.xp[truth.valid][None], xyz)
            parts.append(systematic(err, line_of_sight(xyz)))
        out[name] = pooled(parts).raw
    return out


@pytest.mark.slow
def test_weighting_against_every_baseline_over_seeds(request, sample_config, characterised):
    """Issue 16: the weighting comparison with the strongest fair baseline. On a sweep
    reaching far past the depth of field (the std grows 5.7x from focus to 414 mm), over
    three noise seeds, the hold-out error inside the DOF of tables weighted by the model
    the sweeps selected, by the decoder's per-pixel sigma_xp (no optics model), with
    equal weights, and with equal weights over the planes inside the DOF only. Measured
    (and asserted): the model's weights beat both unweighted tables, and the decoder's
    sigma_xp does as well as the model - the optics model is not what makes weighting
    pay here."""
    runs = [_weighting_errors(*wide_sweep(sample_config, seed), characterised[1])
            for seed in WEIGHTING_SEEDS]
    mean = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
    spread = {k: float(np.std([r[k] for r in runs], ddof=1)) for k in runs[0]}
    _record(request, "issue16_weighting_over_seeds", {
        "seeds": list(WEIGHTING_SEEDS), "mean_um": {k: um(v) for k, v in mean.items()},
        "std_um": {k: um(v) for k, v in spread.items()},
        "per_seed_um": [{k: um(v) for k, v in r.items()} for r in runs]})
    assert mean["model"] <= 0.8 * mean["none"]
    assert mean["model"] <= 0.9 * mean["none, in DOF"]
    assert abs(mean["model"] / mean["modulation"] - 1.0) <= 0.10


def test_block1_outside_the_volume_is_flagged(request, gauge_scans, gauge_cloud):
    _, truth = gauge_scans
    layout = {b.block_id: b for b in load_layout(LAYOUT).blocks}
    a = gauge_cloud.attributes
    z_true = truth["Z"][a["pixel_v"].astype(int), a["pixel_u"].astype(int)]
    flags = {}
    for bid, spec in layout.items():
        on_top = np.abs(z_true - spec.top_z_mm) < 1e-3
        flags[bid] = (int(on_top.sum()), float(np.mean(a["in_volume"][on_top])))
    _record(request, "issue5_in_volume_per_block", {str(k): v for k, v in flags.items()})
    assert flags[1][0] > 1000 and flags[1][1] == 0.0  # kept with --keep-invalid, flagged
    for bid in range(2, 9):
        assert flags[bid][1] >= 0.99, (bid, flags[bid])


# ------------------------------------------------------------ issue 6: honest sigma


def _ratio_stats(ratio: np.ndarray) -> dict:
    q = np.quantile(ratio, [0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95])
    return {"n": int(ratio.size), "q05_q10_q25_q50_q75_q90_q95": [round(float(x), 3) for x in q],
            "fraction_in_0.6_1.6": round(float(np.mean((ratio >= 0.6) & (ratio <= 1.6))), 4)}


def test_measured_std_matches_the_characterised_sigma(request, gauge_cloud):
    a = gauge_cloud.attributes
    use = (a["model_valid"] == 1) & (a["in_volume"] == 1) & (a["n_repeats"] == GAUGE_REPEATS)
    model = _ratio_stats(a["sigma_meas_um"][use] / a["sigma_model_um"][use])
    phase = _ratio_stats(a["sigma_meas_um"][use] / a["sigma_phase_um"][use])
    _record(request, "issue6_ratio_model", {**model, "model": gauge_cloud.model})
    _record(request, "issue6_ratio_phase", phase)
    assert model["n"] > 20000
    assert 0.85 <= model["q05_q10_q25_q50_q75_q90_q95"][3] <= 1.15
    assert model["fraction_in_0.6_1.6"] >= 0.90


# ------------------------------------------------------------- issue 7: gauge QA


@pytest.fixture(scope="session")
def qa_cli(tmp_path_factory, calibrated, characterised):
    """``scanqa annotate`` + ``scanqa qa`` (layout and --auto) on committed scan r0."""
    out = tmp_path_factory.mktemp("qa")
    cloud = out / "cloud.ply"
    scans = [str(GAUGE_DIR / f"p000_r{r}") for r in range(3)]
    assert main(["annotate", scans[0], "--table", str(calibrated[0]), "--config", SAMPLE,
                 "--model", str(characterised[0]), "--out", str(cloud), "--repeats",
                 *scans[1:], "--keep-invalid"]) == 0
    summaries = {}
    for name, extra in (("layout", []), ("auto", ["--auto"])):
        assert main(["qa", str(cloud), "--layout", str(LAYOUT), *extra, "--config", SAMPLE,
                     "--model", str(characterised[0]), "--out", str(out / name)]) == 0
        summaries[name] = json.loads((out / name / "summary.json").read_text())
    return summaries


def test_qa_paper_setup_acceptance(request, qa_cli):
    info = qa_cli["layout"]
    blocks = {b["block_id"]: b for b in info["blocks"]}
    _record(request, "issue7_cli_blocks", {str(k): [b["status"], b["measured_std_um"],
                                                    b["predicted_std_um"], b["ratio"]]
                                           for k, b in blocks.items()})
    _record(request, "issue7_cli_steps", {
        "within_U": info["steps_error_within_U"], "evaluated": info["steps_evaluated"],
        "steps": [[s["block_a"], s["block_b"], s["error_um"], s["U_um"]]
                  for s in info["steps"]]})
    assert blocks[1]["status"] == "outside_volume"
    for bid in range(2, 9):
        assert blocks[bid]["status"] == "ok", blocks[bid]
        assert abs(blocks[bid]["ratio"] - 1.0) <= 0.20, blocks[bid]
    assert info["steps_evaluated"] == 6 and info["steps_not_evaluated"] == 1
    assert info["decisions"]["not evaluated"] == 1  # step 1-2: block 1 is flagged
    # One scan has only 6 pairs: with an honest 95 % interval one of them lies outside U
    # in a quarter of all scans. The >= 90 % criterion is asserted over 72 pairs in
    # test_qa_over_twelve_scans; here at most one of six may miss.
    assert info["steps_error_within_U"] >= 5


def test_qa_auto_finds_the_layout_blocks(request, qa_cli):
    by_layout = {b["block_id"]: b for b in qa_cli["layout"]["blocks"]}
    by_auto = {b["block_id"]: b for b in qa_cli["auto"]["blocks"]}
    _record(request, "issue7_auto", {str(k): [b["status"], b["n_points"]]
                                     for k, b in by_auto.items()})
    assert set(by_auto) == {k for k, b in by_layout.items() if b["n_points"] > 0}
    for bid, b in by_auto.items():
        assert b["status"] == by_layout[bid]["status"]
        # the auto region is the found patch's bounding box: its points are the layout's
        assert b["n_points"] >= 0.8 * by_layout[bid]["n_points"]
        assert abs(b["measured_std_um"] / by_layout[bid]["measured_std_um"] - 1) < 0.1


def test_qa_over_twelve_scans(request, gauge_scans, calibrated, characterised):
    """Issue 16 acceptance on the sample camera (12 scans, one at a time): the model the
    sweeps selected predicts blocks 2-8 within 15 % on average over the scans and no
    block is off by more than 15 % in every scan; >= 90 % of the evaluated steps lie
    within U and RMS(error / u) is in [0.7, 1.3]; step 1-2 is never evaluated."""
    scans, _ = gauge_scans
    layout = load_layout(LAYOUT)
    ratios, within, evaluated, z_scores = {b: [] for b in range(2, 9)}, 0, 0, []
    for scan in scans:
        cloud = annotate(scan, calibrated[1]["model"], characterised[1], keep_invalid=True)
        result = run_qa(cloud, layout)
        status = {b.block_id: b.status for b in result.blocks}
        assert status[1] == "outside_volume"
        for b in result.blocks[1:]:
            assert b.status == "ok", (b.block_id, b.status)
            ratios[b.block_id].append(b.ratio)
        for s in result.steps:
            assert s.evaluated == (status[s.block_a] == status[s.block_b] == "ok")
            if s.evaluated:
                evaluated += 1
                within += s.within_u
                z_scores.append(s.error_um / s.u_um)
            else:
                assert s.decision == "not evaluated"
    rms = float(np.sqrt(np.mean(np.square(z_scores))))
    _record(request, "issue16_twelve_scans", {
        "steps_within_U": within, "steps_evaluated": evaluated,
        "rms_error_over_u": round(rms, 3),
        "ratio_mean": {str(k): round(float(np.mean(v)), 3) for k, v in ratios.items()},
        "ratio_min_max": {str(k): [round(min(v), 3), round(max(v), 3)]
                          for k, v in ratios.items()}})
    assert all(abs(np.mean(v) - 1.0) <= 0.15 for v in ratios.values())
    assert not any(all(abs(r - 1.0) > 0.15 for r in v) for v in ratios.values())
    assert evaluated == 6 * len(scans) and within / evaluated >= 0.90
    assert 0.7 <= rms <= 1.3
