"""Flattening (paper Sect. 5.2, Fig. 7) checked against simulator truth.

The scanner is the paper's f/11 camera at full resolution (8 um pixels), its central
96 x 96 px rendered, with the smooth two-source sum-form model (its gamma following the
range) and the filter's exact second-order gain on the scene noise
(filterbank.scene_gain), chosen on the derivation stream "derive39a"
(docs/studies/derive_flatten_model.py, docs/flattening.rst: gamma = 2.10 at focus,
sigma_p = 0.0341 px fitted, sigma_s = 0.00514 px held at the decoder's image-based
estimate; never fitted on the streams
below). A
parametric calibration is the config's exact pinhole (the simulator's geometry), a table
is built from an exact synthetic sweep: both are independent of the simulator's noise.

What the test measures is the simulator's own scatter: two scans of one flat with
independent noise, the std of their range difference over sqrt(2). The scene-noise
reduction form (Gaussian, filterbank.reduction) was chosen on the "flat" noise stream at
445 and 450 mm; every number asserted here is on another stream ("flat_heldout") and
other positions.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from scipy.optimize import curve_fit
from scipy.special import erf, j1

from scanqa.annotation.filterbank import (
    FilterBank,
    default_bank,
    disc_kernel,
    filter_phase,
    reduction,
)
from scanqa.annotation.flattening import flatten, pixel_noise, plan
from scanqa.calibration.build import build_table
from scanqa.decoding.decoder import decode_images
from scanqa.design import tools
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig, load_config
from tests.conftest import ROOT
from tests.synth_parametric import config_pinhole
from tests.synth_sweep import sweep

W = 96
#: The held-out positions [mm] and the sweep's flattest target's range.
HELD_OUT_Z = (441.0, 447.0, 452.0, 458.0, 463.0)
STREAM = "flat_heldout"


def _config() -> ScannerConfig:
    base = load_config(ROOT / "calib" / "paper_scanner.toml", profile="f11")
    cfg = ScannerConfig(replace(base.camera, width_px=W, height_px=W), base.projector,
                        base.fringes, base.model, base.simulator, base.name, base.source)
    return cfg.replace_model(gamma=2.10, sigma_p_px=0.0341, sensor_sigma_p_px=0.00514,
                             filter_floor="smooth", filter_form="sum",
                             noise_reading="two_source",
                             characterised_by="simulated sweeps (docs/noise_model.rst)")


@pytest.fixture(scope="module")
def rig():
    cfg = _config()
    from scanqa.simulator import experiments

    return cfg, config_pinhole(cfg, "config pinhole"), experiments.pattern_description(cfg)


def _render(rig, scene, index: int, repeat: int):
    from scanqa.simulator import experiments, render

    cfg, _, desc = rig
    pos = experiments.Position(index, 0.0, 0.0, 0.0, scene)
    acq = experiments.acquisition(cfg, pos, repeat, STREAM)
    return render.render_images(cfg, acq, desc), render.truth_for(cfg, acq)


def _range_std_um(cal, a, b) -> float:
    """Std of one scan's range from the difference of two [um]."""
    ra = np.linalg.norm(cal.apply_image(a).xyz, axis=-1)
    rb = np.linalg.norm(cal.apply_image(b).xyz, axis=-1)
    d = (ra - rb)[np.isfinite(ra - rb)]
    return 1e3 * float(np.std(d)) / math.sqrt(2)


def _target_um(cfg) -> float:
    """The flattest sigma the volume allows: the lowest valid sigma of the model's own
    on-axis curve (design.axis_curve) between the positions' ends [um]."""
    curve = tools.axis_curve(cfg, 438.0, 466.0, 0.5)
    return float(np.min(curve["sigma_um"][curve["model_valid"]]))


@pytest.fixture(scope="module")
def flat_sweep(rig):
    """Per held-out position: measured std before and after, predicted after, filter."""
    from scanqa.simulator import scene

    cfg, cal, desc = rig
    target = _target_um(cfg)
    rows = []
    for i, z in enumerate(HELD_OUT_Z):
        scans = [_render(rig, scene.plane_scene(z), i, rep)[0] for rep in (0, 1)]
        maps = [decode_images(desc, s) for s in scans]
        flats = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps,
                                                                       strict=True)]
        rows.append({"z": z, "before": _range_std_um(cal, maps[0].xp, maps[1].xp),
                     "after": _range_std_um(cal, flats[0].phase_map.xp,
                                            flats[1].phase_map.xp),
                     "predicted": float(np.median(flats[0].curve.sigma_flat_um)),
                     "reachable": bool(flats[0].curve.reachable.all()),
                     "filter_px": float(np.median(flats[0].curve.filter_diameter_px))})
    return target, rows


# --------------------------------------------------------------------- filter bank


def test_disc_kernel_areas_and_transfer_follow_eq_11():
    """The identity has NEA 1; a disc's NEA is the variance reduction of white noise
    (measured on 512 x 512 px of it) and about its area pi d^2 / 4 (+11 % for the pixel
    grid's anti-aliased edge at 8 px); the amplitude transfer is 2 J1(pi r) / (pi r),
    r = d / P (Eq. 11 of the paper)."""
    from scipy.signal import fftconvolve

    bank = FilterBank.build((0.0, 4.0, 8.0))
    assert bank.nea_px2(0.0) == pytest.approx(1.0)
    noise = np.random.default_rng(5).normal(size=(512, 512))
    filtered = fftconvolve(noise, disc_kernel(8.0), mode="valid")
    # tolerance: ~250k samples correlated over ~50 px^2, std of the variance ~1.5 %
    assert 1 / filtered.var() == pytest.approx(bank.nea_px2(2.0), rel=0.05)
    assert bank.nea_px2(2.0) == pytest.approx(math.pi * 8.0**2 / 4, rel=0.15)
    for period in (20.0, 40.0):
        r = 8.0 / period
        eq11 = 2 * j1(math.pi * r) / (math.pi * r)
        assert bank.transfer(2.0, period) == pytest.approx(eq11, abs=0.01)
    assert disc_kernel(5.0).sum() == pytest.approx(1.0)
    # a blend sits between its two discs (NaN-free and monotonic)
    nea = bank.nea_px2(np.linspace(0.0, 2.0, 21))
    assert np.all(np.diff(nea) > 0)


def test_bad_target_and_gray_only_scans_are_refused(rig):
    cfg, cal, _ = rig
    from scanqa.decoding.phasemap import PhaseMap

    xp = np.full((W, W), 600.0)
    pm = PhaseMap(xp=xp, modulation=np.full((W, W), 100.0), offset=np.full((W, W), 200.0),
                  mask=np.zeros((W, W), np.uint8), sigma_xp=np.full((W, W), 0.01),
                  period_px=5.0, projector_width_px=1280)
    noise = pixel_noise(pm, cal, cfg)
    with pytest.raises(InputError, match="target must be a sigma > 0"):
        plan(noise, cfg, -1.0)
    gray_only = SimpleNamespace(phase_sets=(), source="gray/patterns.toml")
    with pytest.raises(InputError, match="has no phase set"):
        flatten(gray_only, [], pm, cal, cfg)


# --------------------------------------------------------------------- simulated


@pytest.mark.slow
def test_flattened_flat_has_the_target_std_at_every_reachable_depth(flat_sweep):
    """Simulated, held out: before flattening the measured std spreads over the positions
    (the W curve, 1.9x here); after, the acceptance's +-10 % of the target holds at 4 of
    the 5 positions at least and +-15 % at all, and at every position near focus
    (441-452 mm, where the floored model was 8-10 % off and the flat missed by 10-12 %),
    and the spread falls below 1.3x. Measured here with the session-39 model (exact
    scene gain, gamma 2.10): 0.991, 1.046, 1.040, 0.974, 0.954 (printed); with the
    session-38 model: 0.98, 1.06,
    1.05, 0.99, 0.94 (session 37's: 0.98, 1.04, 1.02, 0.95, 0.90; the floored one: 1.06,
    0.92, 0.94, 1.04, 0.98); docs/flattening.rst: 9 of 9 within +-10 % on four other
    streams, 8 of 9 on a fifth (463 mm at 0.896); session 39: 36 of 36 on four fresh
    streams (130-168, 96 and 192 px) with each model."""
    target, rows = flat_sweep
    before = [r["before"] for r in rows]
    after = [r["after"] for r in rows]
    assert max(before) / min(before) > 1.5, rows  # today's spread
    assert max(after) / min(after) < 1.3, rows
    assert all(r["reachable"] for r in rows), rows
    errors = [abs(r["after"] / target - 1) for r in rows]
    print("after / target:", ", ".join(f"{r['z']:.0f} mm {r['after'] / target:.3f}"
                                        for r in rows))
    assert max(errors) <= 0.15, (target, rows)  # worst on any stream now: 10.4 % (463 mm)
    assert sum(e <= 0.10 for e in errors) >= 4, (target, rows)
    near_focus = [e for r, e in zip(rows, errors, strict=True) if 441.0 <= r["z"] <= 452.0]
    assert len(near_focus) == 3 and max(near_focus) <= 0.10, (target, rows)


def _step_scene(z: float, height: float):
    """A flat at z with its left half raised by ``height`` towards the camera (a step
    whose edge runs along image columns) [mm]."""
    from scanqa.simulator.scene import Scene

    base = trimesh.creation.box(extents=[200.0, 170.0, 10.0])
    base.apply_translation([0.0, 0.0, z + 5.0])
    raised = trimesh.creation.box(extents=[100.0, 170.0, 10.0])
    raised.apply_translation([-50.0, 0.0, z - height + 5.0])
    return Scene(trimesh.util.concatenate([base, raised]), "step")


def _edge_spread_px(z_map: np.ndarray) -> float:
    """4 s of the erf fitted to the mean row profile of a step [camera px]."""
    profile = np.nanmean(z_map[10:-10], axis=0)
    u = np.arange(profile.size, dtype=float)
    ok = np.isfinite(profile)

    def model(x, a, b, x0, s):
        return a + b * 0.5 * (1 + erf((x - x0) / (math.sqrt(2) * s)))

    p0 = (profile[ok][0], profile[ok][-1] - profile[ok][0], profile.size / 2, 2.0)
    popt, _ = curve_fit(model, u[ok], profile[ok], p0=p0)
    return 4 * abs(popt[3])


@pytest.mark.slow
def test_lateral_resolution_matches_the_edge_spread_of_a_step(rig):
    """Simulated: a 0.2 mm step at focus, flattened to the volume's target; the edge
    spread 4 s of the range profile (erf fit) against the reported lateral resolution
    (camera kernel + digital filter, a disc diameter on the object): within 20 %."""
    cfg, cal, desc = rig
    images, _ = _render(rig, _step_scene(450.0, 0.2), 90, 0)
    pm = decode_images(desc, images)
    flat = flatten(desc, images, pm, cal, cfg, _target_um(cfg))
    foot = 450.0 / cfg.camera.principal_distance_px  # mm per camera px on the flat
    z = cal.apply_image(flat.phase_map.xp).xyz[..., 2]
    measured = _edge_spread_px(z) * foot
    reported = float(np.nanmedian(flat.lateral_resolution_mm))
    print(f"lateral resolution: measured {measured:.3f} mm, reported {reported:.3f} mm, "
          f"filter {float(np.nanmedian(flat.curve.filter_diameter_px)):.1f} px")
    assert abs(measured / reported - 1) <= 0.20, (measured, reported)
    assert float(np.nanmedian(flat.curve.filter_diameter_px)) > 3.0  # a real cost here


@pytest.mark.slow
def test_table_and_parametric_calibrations_flatten_alike(rig):
    """Simulated: the same two scans (at focus) flattened through a table built from an
    exact synthetic sweep and through the parametric pinhole: the same filter within
    10 % and the same measured std within 5 %."""
    from scanqa.simulator import scene

    cfg, cal, desc = rig
    table = build_table(sweep(cfg, np.arange(436.0, 464.1, 2.0), seed=3), cfg)[0]
    target = _target_um(cfg)
    scans = [_render(rig, scene.plane_scene(450.0), 91, rep)[0] for rep in (0, 1)]
    maps = [decode_images(desc, s) for s in scans]
    by_table = [flatten(desc, s, m, table, cfg, target) for s, m in zip(scans, maps,
                                                                        strict=True)]
    by_cal = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps,
                                                                    strict=True)]
    d_table = float(np.median(by_table[0].curve.filter_diameter_px))
    d_cal = float(np.median(by_cal[0].curve.filter_diameter_px))
    assert d_table == pytest.approx(d_cal, rel=0.10)
    after_table = _range_std_um(cal, by_table[0].phase_map.xp, by_table[1].phase_map.xp)
    after_cal = _range_std_um(cal, by_cal[0].phase_map.xp, by_cal[1].phase_map.xp)
    assert after_table == pytest.approx(after_cal, rel=0.05)
    before = _range_std_um(cal, maps[0].xp, maps[1].xp)
    assert after_table < 0.6 * before  # the filter did act


def _two_tops(z_left: float, z_right: float):
    """Two block tops side by side (the edge along image columns), as on the gauge
    artefact: the left half at z_left, the right at z_right [mm]."""
    from scanqa.simulator.scene import Scene

    parts = []
    for x0, z in ((-50.0, z_left), (50.0, z_right)):
        box = trimesh.creation.box(extents=[100.0, 170.0, 10.0])
        box.apply_translation([x0, 0.0, z + 5.0])
        parts.append(box)
    return Scene(trimesh.util.concatenate(parts), "two_tops")


@pytest.mark.slow
def test_one_scan_of_two_block_tops_gets_a_filter_per_range(rig):
    """Simulated, held out: one scan holding two block tops 6 mm apart (447 and 453 mm,
    both near focus); flattened, each top's measured std is within +-10 % of the target,
    with its own filter (measured here: 0.92 and 0.92 of the target, from 11.9 and
    11.7 um, with filters of 7.8 and 8.2 px)."""
    cfg, cal, desc = rig
    target = _target_um(cfg)
    scans = [_render(rig, _two_tops(447.0, 453.0), 92, rep)[0] for rep in (0, 1)]
    maps = [decode_images(desc, s) for s in scans]
    flats = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps, strict=True)]
    half = W // 2
    for cols in (slice(8, half - 12), slice(half + 12, W - 8)):  # away from the edge
        def cut(pm, cols=cols):
            xp = np.full_like(pm.xp, np.nan)
            xp[8:-8, cols] = pm.xp[8:-8, cols]
            return xp

        before = _range_std_um(cal, cut(maps[0]), cut(maps[1]))
        after = _range_std_um(cal, cut(flats[0].phase_map), cut(flats[1].phase_map))
        assert before > 1.5 * target
        assert abs(after / target - 1) <= 0.10, (cols, before, after, target)
    levels = flats[0].level[W // 2, [half // 2, half + half // 2]]
    assert levels[0] != pytest.approx(levels[1], abs=0.05)  # two ranges, two filters


def _fringe_stack(seed: int, size: int = 64, period_cam_px: float = 28.0):
    """A 4-step fringe of ``period_cam_px`` along image columns with white noise, its
    phase map (x_p from the stack's own wrapped phase, period 5 projector px) and the
    quadrature components C, S [DN]."""
    from scanqa.decoding.demodulate import ShiftFit
    from scanqa.decoding.phasemap import PhaseMap

    shifts = [k * math.pi / 2 for k in range(4)]
    u = np.arange(size)[None, :] * np.ones((size, 1))
    phi = 2 * math.pi * u / period_cam_px
    rng = np.random.default_rng(seed)
    stack = np.stack([1000 + 600 * np.cos(phi + d) + rng.normal(0, 20, phi.shape)
                      for d in shifts])
    rows = ShiftFit.from_shifts(shifts).rows[1:]
    c, s = (rows @ stack.reshape(4, -1)).reshape(2, size, size)
    xp = 5.0 * np.mod(np.arctan2(-s, c) / (2 * math.pi), 1.0) + 100.0
    pm = PhaseMap(xp=xp, modulation=np.hypot(c, s), offset=np.full(xp.shape, 1000.0),
                  mask=np.zeros(xp.shape, np.uint8), sigma_xp=np.full(xp.shape, 0.01),
                  period_px=5.0, projector_width_px=1280)
    return stack, shifts, pm, c, s


def test_pixels_masked_for_their_fringe_order_still_take_part_in_the_filter():
    """A pixel the decode masks as inconsistent (its sets disagree: a fringe-order
    question) has a good fringe; filtering must use it. Reference: the plain convolution
    of C and S (scipy, independent of the bank's code) with the 7 px disc, no pixel left
    out. With 2 % of pixels masked inconsistent the filtered x_p of the valid pixels is
    the reference's to float32 rounding; left out, a masked pixel off the kernel's
    centre turns the sum's phase (the fringe turns across the kernel) by ~0.01 px."""
    from scipy.signal import fftconvolve

    from scanqa.decoding.phasemap import MASK_INCONSISTENT, MASK_LOW_MODULATION

    stack, shifts, pm, c, s = _fringe_stack(11)
    bank = default_bank()
    level = np.full(pm.xp.shape, float(bank.diameters_px.index(7.0)))
    kern = disc_kernel(7.0)
    ref_c, ref_s = (fftconvolve(x, kern, mode="same") for x in (c, s))
    shift = (np.arctan2(-ref_s, ref_c) - np.arctan2(-s, c)) / (2 * math.pi)
    reference = pm.xp + (shift - np.rint(shift)) * 5.0
    holes = np.random.default_rng(12).random(pm.xp.shape) < 0.02
    inner = np.zeros(pm.xp.shape, bool)
    inner[8:-8, 8:-8] = True  # away from the image border (reflected there)
    for reason, same in ((MASK_INCONSISTENT, True), (MASK_LOW_MODULATION, False)):
        mask = np.where(holes, reason, 0).astype(np.uint8)
        masked = replace(pm, xp=np.where(holes, np.nan, pm.xp), mask=mask,
                         sigma_xp=np.where(holes, np.nan, pm.sigma_xp))
        xp, _ = filter_phase(stack, shifts, masked, level, bank)
        err = np.abs(xp - reference)[inner & ~holes]
        if same:
            # tolerance: float32 C, S (~1e-7 relative) on a 5 px period
            assert err.max() < 1e-4, err.max()
        else:  # a low-modulation pixel's fringe is not trusted: it stays out
            assert err.max() > 1e-3, err.max()


def _focus_pair(index: int, size: int = 160):
    """Two scans of a flat at focus (450 mm) by the camera's central ``size`` px, a noise
    stream of its own; the config, calibration and coding."""
    from scanqa.simulator import experiments, render, scene

    base = _config()
    cfg = ScannerConfig(replace(base.camera, width_px=size, height_px=size), base.projector,
                        base.fringes, base.model, base.simulator, base.name, base.source)
    desc = experiments.pattern_description(cfg)
    pos = experiments.Position(index, 0.0, 0.0, 0.0, scene.plane_scene(450.0))
    scans = [render.render_images(cfg, experiments.acquisition(cfg, pos, rep, "focus_kernel"),
                                  desc) for rep in (0, 1)]
    cal = config_pinhole(cfg, "config pinhole")
    return scans, [decode_images(desc, s) for s in scans], (cfg, cal, desc)


# slow: two 160 x 160 px renders (~15 s on the shared cores): 96 px leaves 64 x 64 px
# inside the border, whose std after a 7 px filter has a ~7 % sampling error
@pytest.mark.slow
def test_a_known_kernel_at_focus_reduces_the_std_as_predicted():
    """Simulated, at focus (450 mm), where the scene noise masks ~1 % of the pixels as
    inconsistent: two scans' x_p difference, filtered by a 7 px and a 10 px disc at
    every pixel, against filterbank.reduction of the model's scene and sensor parts.
    Measured on another stream ("probe30", 160 px, floored model): 0.419 / 0.438 and
    0.334 / 0.349 (before masked pixels took part: 0.519 and 0.467, +18 % and +34 %);
    here, smooth model: 0.401 / 0.435 and 0.317 / 0.346 (session 38: / 0.424 and
    / 0.336: measured / predicted 0.95 and 0.94; session 39, exact gain, see the
    printed line). Tolerance 12 %: three times the
    ~4 % sampling error of the filtered std on 128 x 128 px."""
    scans, maps, (cfg, cal, desc) = _focus_pair(93)
    inner = (slice(16, -16),) * 2
    diff = lambda a, b: (a - b)[inner]  # noqa: E731
    before = np.nanstd(diff(maps[0].xp, maps[1].xp))
    noise = pixel_noise(maps[0], cal, cfg)
    bank = default_bank()
    for diameter in (7.0, 10.0):
        t = float(bank.diameters_px.index(diameter))
        level = np.full(maps[0].xp.shape, t)
        xps = [filter_phase(s[-1], desc.phase_sets[-1].shifts_rad, m, level, bank)[0]
               for s, m in zip(scans, maps, strict=True)]
        measured = np.nanstd(diff(*xps)) / before
        g_scene, g_sensor = reduction(noise.noise_area_px2, noise.period_cam_px,
                                      np.full(noise.z_mm.shape, t), cfg, bank,
                                      z_mm=noise.z_mm)
        predicted = np.nanmedian(np.hypot(noise.scene_mm * g_scene,
                                          noise.sensor_mm * g_sensor)) / np.nanmedian(
                                              noise.sigma_mm)
        print(f"known {diameter:g} px disc at focus: measured {measured:.3f}, "
              f"predicted {predicted:.3f}")
        assert measured == pytest.approx(predicted, rel=0.12), (diameter, measured,
                                                                predicted)


def test_default_bank_is_built_once():
    assert default_bank() is default_bank()
