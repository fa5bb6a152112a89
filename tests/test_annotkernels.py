"""The compiled annotate loop against the numpy expressions it replaces (annotkernels)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import j1

from scanqa.annotation import kernels, points
from scanqa.annotation.points import ATTRIBUTES, REPEAT_ATTRIBUTES, annotate
from scanqa.calibration.build import build_table
from scanqa.decoding.phasemap import PhaseMap
from scanqa.io import ply
from scanqa.io.annotated_cloud import AnnotatedCloud, read_cloud
from scanqa.model import optics
from scanqa.model.config import FILTER_FLOORS, FILTER_FORMS, NOISE_READINGS

from .synth_sweep import plane_truth, small_camera, sweep

# every test here compares the compiled loop with numpy or scipy (tests/cpu_targets.py):
# rerun on numba's generic CPU target by tests/test_generic_cpu.py
pytestmark = pytest.mark.compiled_vs_numpy

W, H = 96, 64
#: One float32 rounding step: the compiled and numpy paths round the same float64
#: values, which may differ in the last bits (J1, the shear's sum order) [-].
F32_STEP = 2.0**-23
#: A(r) of the loop (J1 as a series) against optics' (scipy's J1) on the main lobe [-].
ATTENUATION_RTOL = 2e-14
#: The loop's model against predict: both call the same equations
#: (scanqa.model.equations), so they differ by A's agreement, twice (A_c A_p in the power
#: reading), and by half an ulp for each of the ~40 roundings from a point to sigma, which
#: compiled code may do otherwise than numpy (on another CPU: tests/cpu_targets.py) [-].
CHAIN_RTOL = 2 * ATTENUATION_RTOL + 40 * np.finfo(float).eps / 2


@pytest.fixture(scope="module")
def cfg(paper_config):
    return small_camera(paper_config, W, H)


@pytest.fixture(scope="module")
def table(cfg):
    return build_table(sweep(cfg, np.arange(430.0, 470.1, 2.0), seed=2), cfg)[0]


def test_bessel_j1_matches_scipy_over_the_range():
    # the main lobe and its side lobes, both sides of the series/asymptotic switch at 12
    x = np.concatenate([np.linspace(0.0, 12.0, 4001), np.linspace(12.0, 200.0, 4001),
                        -np.linspace(0.0, 30.0, 301), [1e-300, 1e-9]])
    got = np.array([kernels.bessel_j1(v) for v in x])
    lobe = np.abs(x) < 4.0  # the attenuation's main lobe: to scipy's own accuracy
    np.testing.assert_allclose(got[lobe], j1(x[lobe]), rtol=0, atol=5e-16)
    # the series' cancellation below 12, the asymptotic series' smallest term above
    np.testing.assert_allclose(got, j1(x), rtol=0, atol=2e-12)
    assert np.isnan(kernels.bessel_j1(np.nan))


def test_attenuation_matches_optics_to_its_last_bits():
    r = np.concatenate([np.linspace(0.0, 1.25, 5001), np.linspace(1.25, 40.0, 2001),
                        -np.linspace(0.0, 2.0, 51), [1e-12, 1e-9, np.nan, np.inf]])
    want = optics.attenuation(r)
    got = np.empty_like(r)
    kernels.attenuations(r, got)
    scalar = np.array([kernels.attenuation(v) for v in r])
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    main_lobe = np.abs(r) < 1.2  # A > 1e-3: relative agreement to ~1e-14
    np.testing.assert_allclose(got[main_lobe], want[main_lobe], rtol=ATTENUATION_RTOL,
                               atol=0)
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-15)
    np.testing.assert_allclose(scalar, want, rtol=1e-11, atol=1e-15)
    assert optics.attenuation(0.5) == pytest.approx(got[2000], rel=1e-15)


@pytest.mark.parametrize("form,floor,reading",
                         list(itertools.product(FILTER_FORMS, FILTER_FLOORS, NOISE_READINGS)))
def test_point_model_matches_predict(cfg, form, floor, reading):
    config = cfg.replace_model(filter_form=form, filter_floor=floor, noise_reading=reading,
                               sensor_sigma_p_px=0.01 if reading == "two_source" else 0.0)
    rng = np.random.default_rng(7)
    n = 4000  # in and past focus, inside and outside the model's validity
    pts = np.stack([rng.uniform(-60, 60, n), rng.uniform(-50, 50, n),
                    rng.uniform(420.0, 490.0, n)], -1)
    pts[:5] = np.nan
    s_t = rng.uniform(0.02, 0.2, n)
    got = kernels.model_points(pts, s_t, *kernels.model_parameters(config))
    want = optics.predict(pts, config, s_t=s_t)
    assert (~want.valid).sum() > 500 and want.valid.sum() > 500
    np.testing.assert_array_equal(got[:, 7].astype(bool), want.valid)
    for k, values in enumerate((want.attenuation_camera, want.attenuation_projector,
                                want.filter_factor, want.s_o, want.sigma, want.sigma_scene,
                                want.sigma_sensor)):
        np.testing.assert_array_equal(np.isnan(got[:, k]), np.isnan(values))
        # the main lobe (A > 1e-3), in and outside the validity; past it s_O is NaN
        ok = (want.ratio_camera < 1.2) & (want.ratio_projector < 1.2)
        np.testing.assert_allclose(got[ok, k], values[ok], rtol=CHAIN_RTOL, atol=0)


def phase_map(cfg, sigma=0.02, seed=0, masked_rows=0, far_rows=0):
    xp, _ = plane_truth(cfg, 447.0)
    rng = np.random.default_rng(seed)
    shape = xp.shape
    xp = xp + rng.normal(0, sigma, shape)
    xp[:masked_rows] = np.nan
    xp[masked_rows:masked_rows + far_rows] += 60.0  # outside the calibrated volume
    mask = np.zeros(shape, np.uint8)
    mask[:masked_rows] = 2  # low modulation
    return PhaseMap(xp=xp, modulation=rng.uniform(100, 500, shape),
                    offset=rng.uniform(300, 1500, shape), mask=mask,
                    sigma_xp=np.full(shape, sigma), period_px=5.0, projector_width_px=1280)


def numpy_path(monkeypatch, *args, **kwargs):
    """annotate through the numpy lookup, model and attributes: the path of an install
    without numba (the ``fast`` extra), taken by the same switch."""
    with monkeypatch.context() as m:
        m.setattr(points, "HAVE_NUMBA", False)
        return annotate(*args, **kwargs)


def raw_records(path):
    """The vertex records of a binary PLY written by annotate, as they are."""
    data = path.read_bytes()
    start = data.index(b"end_header\n") + len(b"end_header\n")
    names = ATTRIBUTES + REPEAT_ATTRIBUTES
    return np.frombuffer(data[start:], dtype=ply.vertex_dtype(names))


def assert_same_cloud(got, want):
    assert got.counts == want.counts
    np.testing.assert_allclose(got.xyz, want.xyz, rtol=0, atol=1e-9)  # [mm]: 1 pm
    assert list(got.attributes) == list(want.attributes)
    for name, values in want.attributes.items():
        mine = got.attributes[name]
        np.testing.assert_array_equal(np.isnan(mine), np.isnan(values), err_msg=name)
        np.testing.assert_allclose(mine, values, rtol=F32_STEP, atol=0, err_msg=name)


@pytest.mark.parametrize("keep_invalid", [False, True])
def test_records_match_the_numpy_path(cfg, table, monkeypatch, keep_invalid, tmp_path):
    pm = phase_map(cfg, masked_rows=3, far_rows=4)
    repeats = [phase_map(cfg, seed=s) for s in (1, 2)]
    want = numpy_path(monkeypatch, pm, table, cfg, repeats=repeats,
                      keep_invalid=keep_invalid)
    got = annotate(pm, table, cfg, repeats=repeats, keep_invalid=keep_invalid)
    assert want.counts["out_of_volume"] == 4 * W
    assert_same_cloud(got, want)
    out = tmp_path / "cloud.ply"
    annotate(pm, table, cfg, repeats=repeats, keep_invalid=keep_invalid, out=out)
    wanted = tmp_path / "numpy.ply"
    numpy_path(monkeypatch, pm, table, cfg, repeats=repeats, keep_invalid=keep_invalid,
               out=wanted)
    assert out.stat().st_size == wanted.stat().st_size
    mine, theirs = raw_records(out), raw_records(wanted)
    for name in ("intensity", "red", "green", "blue", "alpha"):  # the display fields
        np.testing.assert_array_equal(mine[name], theirs[name], err_msg=name)
    assert len(np.unique(mine["red"])) > 50  # the offsets span the grey scale
    mine, theirs = read_cloud(out), read_cloud(wanted)
    assert_same_cloud(AnnotatedCloud(mine.xyz, mine.attributes, want.counts),
                      AnnotatedCloud(theirs.xyz, theirs.attributes, want.counts))


@pytest.mark.parametrize("noise", ["model", "law", "images"])
def test_every_sigma_source_matches_the_numpy_path(cfg, table, monkeypatch, noise):
    config = cfg.replace_model(characterised_by="")
    if noise == "model":
        config = cfg.replace_model(characterised_by="test board")
    elif noise == "law":
        config = cfg.replace_model(noise_read_var_dn2=4.0, noise_shot_dn=0.5,
                                   characterised_by="test law")
    pm = replace(phase_map(cfg, seed=3), provenance={  # a 4-step working set
        "decode": {"chain": ["p5"]}, "patterns": {"set": [{"name": "p5", "steps": 4}]}})
    assert points.sigma_source(config, pm)["random"] == noise
    assert_same_cloud(annotate(pm, table, config), numpy_path(monkeypatch, pm, table,
                                                              config))


def test_one_compiled_signature_for_every_output(cfg, table, tmp_path):
    # load() gives the types annotate gives, whatever the PLY header's length: no second
    # compilation (8-9 s of CPU) for another offset of the file's mapping
    kernels.load()
    pm = phase_map(cfg, masked_rows=2)
    for k, name in enumerate(("a.ply", "bb.ply", "ccc.ply", "dddd.ply")):
        annotate(pm, table, cfg, out=tmp_path / name, source="s" * k)
    annotate(pm, table, cfg, repeats=[phase_map(cfg, seed=1)], keep_invalid=True)
    other = replace(pm, xp=np.asfortranarray(pm.xp, dtype=np.float32),
                    modulation=np.asfortranarray(pm.modulation, dtype=np.float32))
    annotate(other, table, cfg)
    assert len(kernels.annotate_band.signatures) == 1


def test_attribute_columns_are_annotates_order():
    # the loop writes record columns by position: they must be annotate's names in order
    assert kernels.ATTRIBUTE_COLUMNS == ATTRIBUTES + REPEAT_ATTRIBUTES
