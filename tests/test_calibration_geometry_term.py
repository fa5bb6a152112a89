"""The calibration-geometry term of a gauge-block step (issue 25): the calibration's
parameter covariance carried to a height difference (Eq. 3 of
:mod:`scanqa.calibration.uncertainty`), checked against closed forms on synthetic cases,
and its line in the GUM budget, the JSON summary and the report."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from scanqa.calibration.parametric import Lens
from scanqa.calibration.sweep import geometry_covariance
from scanqa.calibration.sweep_fit import SweepGeometry, geometry_from_summary
from scanqa.calibration.uncertainty import (
    GeometryCovariance,
    marker_covariance,
    parametric_covariance,
    step_sigma_mm,
)
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.qa.blocks import run_qa
from scanqa.report import qa as qa_report
from scanqa.report.html import Page

from .test_gauge import synthetic_cloud

BETA = math.radians(1.0)  # the stage axis' tilt against the camera axis [rad]
SIGMA_BETA = 1e-4  # its standard uncertainty [rad]


def _geometry(cov_diag: dict[int, float], beta: float = BETA) -> SweepGeometry:
    """A marker fit's geometry: an undistorted camera (f 2000 px), the target facing the
    camera at 450 mm, the stage axis tilted by ``beta`` in X-Z; covariance diagonal."""
    theta = np.array([2000.0, 152.5, 127.5, 0, 0, 0, 0, 0, 0, 0, 0, 0, 450.0, beta, 0.0])
    cov = np.zeros((15, 15))
    for i, var in cov_diag.items():
        cov[i, i] = var
    start = SweepGeometry(Lens(np.eye(3), np.zeros(5), 306, 256), np.eye(3), np.zeros(3),
                          np.array([0.0, 0.0, 1.0]), 450.0, 0.02)
    return SweepGeometry(**{**start.with_parameters(theta).__dict__, "covariance": cov,
                            "std": {"focal_px": math.sqrt(cov[0, 0])}})


def _block(rng, z_mm: float, x_mm: float, y_mm: float) -> np.ndarray:
    """300 points of an 8 x 8 mm block top facing the camera at depth z [mm]."""
    xy = rng.uniform(-4, 4, (300, 2)) + np.array([x_mm, y_mm])
    return np.column_stack([xy, np.full(300, z_mm)])


def test_stage_axis_tilt_gives_a_depth_scale_error_times_h():
    """Closed form: with the target facing the camera and the stage axis tilted by beta,
    a point at depth Z comes from stage reading (Z - Z_0) / cos(beta); an axis angle
    beta + delta puts it at Z_0 + (Z - Z_0) cos(beta + delta) / cos(beta), a depth scale
    error e = -tan(beta) delta. A step of h then reads h (1 + e):
    u = |h| tan(beta) u_beta, whatever the blocks' lateral positions."""
    rng = np.random.default_rng(1)
    term = marker_covariance(_geometry({13: SIGMA_BETA**2}))
    for h, (xa, xb) in ((10.0, (-10.0, 12.0)), (2.5, (20.0, -25.0)), (25.0, (0.0, 0.0))):
        a, b = _block(rng, 440.0, xa, 0.0), _block(rng, 440.0 + h, xb, 5.0)
        want = h * math.tan(BETA) * math.sin(SIGMA_BETA)  # sigma points: exact in delta
        # the stage readings are recovered by the plane model to ~1e-13 mm
        np.testing.assert_allclose(step_sigma_mm(term, a, b), want, rtol=1e-6)


def test_focal_length_alone_moves_points_sideways_only():
    """The focal length scales X and Y of a target facing the camera (Z = the plane's
    depth): block tops facing the camera keep their height difference, u = 0."""
    rng = np.random.default_rng(2)
    term = marker_covariance(_geometry({0: 4.0**2}, beta=0.0))
    a, b = _block(rng, 440.0, -10.0, 0.0), _block(rng, 450.0, 12.0, 5.0)
    assert step_sigma_mm(term, a, b) < 1e-9  # mm; the term of a 10 mm step: ~0


def test_covariance_survives_the_table_provenance():
    """A table carries its marker fit's summary: parameters and covariance come back."""
    geo = _geometry({13: SIGMA_BETA**2, 0: 0.2**2})
    back = geometry_from_summary(json.loads(json.dumps(geo.summary())))
    np.testing.assert_array_equal(back.parameters, geo.parameters)
    np.testing.assert_array_equal(back.covariance, geo.covariance)
    np.testing.assert_allclose(back.axis, geo.axis, atol=1e-15)
    assert back.std == geo.std and back.stage_ref_mm == geo.stage_ref_mm
    with pytest.raises(InputError, match=r"no parameter vector.*calibrate it again"):
        geometry_from_summary({"rms_px": 0.02})
    # a table finds its term through its provenance; one built before the vector was
    # kept, or without markers, has none
    table = SimpleNamespace(provenance={"target_geometry": json.loads(json.dumps(
        geo.summary()))})
    np.testing.assert_array_equal(geometry_covariance(table).covariance, geo.covariance)
    assert geometry_covariance(SimpleNamespace(provenance={"kind": "table"})) is None


def _depth_scale_term(sigma_e: float, z0: float = 450.0) -> GeometryCovariance:
    """A calibration whose one parameter is a relative depth-scale error e about z0."""

    def move(points, theta):
        out = np.array(points, float)
        out[:, 2] = z0 + (out[:, 2] - z0) * (1.0 + theta[0])
        return out

    return GeometryCovariance("synthetic depth scale", np.zeros(1),
                              np.array([[sigma_e**2]]), move, dof=40.0)


def test_budget_has_its_own_line(tmp_path):
    """In run_qa: each step's budget gets a "calibration geometry" line of |h| u_e (the
    closed form of a depth-scale error), u grows by it in quadrature, and the JSON
    summary, budget.csv and the report show it."""
    # 0.01 um of noise: the term moves 400 of each block's points, whose plane is then
    # within ~2e-7 rad of the whole block's: ~4 nm over the lever, 3e-6 of the 0.64 mm step
    xyz, attrs, layout = synthetic_cloud(seed=3, sigma_um=0.01)
    cloud = AnnotatedCloud(xyz, attrs)
    sigma_e = 2e-5
    plain = run_qa(cloud, layout)
    res = run_qa(cloud, layout, calibration=_depth_scale_term(sigma_e))
    assert res.settings["calibration_geometry"] == "synthetic depth scale"
    for s0, s in zip(plain.steps, res.steps, strict=True):
        line = [c for c in s.budget.components if c.name == "calibration geometry"]
        assert len(line) == 1 and line[0].unit == "um" and line[0].kind == "A"
        assert line[0].source.startswith("synthetic depth scale: covariance carried")
        h_um = 1e3 * abs(s.measured_diff_mm)
        np.testing.assert_allclose(line[0].contribution_um, h_um * sigma_e, rtol=1e-5)
        np.testing.assert_allclose(s.u_um**2, s0.u_um**2 + line[0].contribution_um**2,
                                   rtol=1e-12)
        assert line[0].dof == 40.0
    rows = json.loads(json.dumps(res.summary()))["budgets"][0]["components"]
    assert any(r["component"] == "calibration geometry" for r in rows)
    qa_report.write_outputs(res, tmp_path, html=False)  # the plots take ~10 s: not drawn
    assert "calibration geometry" in (tmp_path / "budget.csv").read_text()
    for result, text in ((res, "Calibration geometry: the covariance of the synthetic depth "
                          "scale, carried to each step."),
                         (plain, "Calibration geometry: not included (no calibration "
                          "covariance was given).")):
        page = Page("budget")
        qa_report._budget_section(page, result, {"type_b_included": False})
        assert text in page.render()


def test_parametric_baseline_length_scales_the_whole_scan(paper_config):
    """Closed form: the baseline T scaled by s moves every point P (same camera pixel,
    same projector pixel) to s P, since R (s P) + s T = s (R P + T) projects where R P + T
    does. A baseline length with std u_T along T is a scale error u_T / |T| of every
    length: u = |h| u_T / |T|."""
    from .synth_parametric import small_scanner

    cal, _ = small_scanner(paper_config)
    t = np.asarray(cal.translation, float)
    sigma_t = 0.05  # [mm]
    cov = np.zeros((24, 24))
    cov[21:, 21:] = sigma_t**2 * np.outer(t, t) / (t @ t)
    term = geometry_covariance(dataclasses.replace(cal, covariance=cov))
    assert term.name == parametric_covariance(cal, cov).name
    rng = np.random.default_rng(4)
    z_c = float(np.asarray(paper_config.camera.focus_mm))  # the camera's focus [mm]
    a, b = _block(rng, z_c - 6.0, -6.0, 2.0), _block(rng, z_c + 4.0, 7.0, -3.0)
    want = 10.0 * sigma_t / np.linalg.norm(t)
    np.testing.assert_allclose(step_sigma_mm(term, a, b), want, rtol=1e-6)


def test_a_term_that_cannot_be_computed_is_left_out_and_said():
    """Points that do not map through the calibration (NaN) give no line, never a NaN
    U, and a note per step."""
    xyz, attrs, layout = synthetic_cloud(seed=5, sigma_um=0.01)
    nowhere = GeometryCovariance("nowhere", np.zeros(1), np.eye(1),
                                 lambda points, theta: np.full_like(points, np.nan))
    res = run_qa(AnnotatedCloud(xyz, attrs), layout, calibration=nowhere)
    assert all(math.isfinite(s.u_um) for s in res.steps)
    assert not any(c.name == "calibration geometry" for s in res.steps
                   for c in s.budget.components)
    left_out = [n for n in res.notes if "calibration-geometry term could not be computed" in n]
    assert len(left_out) == len(res.steps) == 7


def test_a_singular_fit_gives_nan_and_an_empty_covariance_zero():
    """A covariance with inf (the fit's Jacobian was singular) gives NaN, which run_qa
    leaves out with a note; an empty one moves nothing."""
    rng = np.random.default_rng(6)
    a, b = _block(rng, 440.0, -10.0, 0.0), _block(rng, 450.0, 12.0, 5.0)
    assert math.isnan(step_sigma_mm(marker_covariance(_geometry({13: math.inf})), a, b))
    empty = GeometryCovariance("empty", np.zeros(0), np.zeros((0, 0)),
                               lambda points, theta: points)
    assert step_sigma_mm(empty, a, b) == 0.0
