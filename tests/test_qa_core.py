"""The QA core function by function: the ISO 14253-1 decision and the verdict
(qa/verdict.py), the GUM budget (qa/budget.py) and the VDI/VDE 2634-2 quantities
(qa/vdi2634.py), each against a hand-computed value, and each public numeric function
with NaN, inf and 0 in (colour's habit). Fast (no closed loops): the mutation run
(docs/mutation.rst) leans on these."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from scanqa.errors import InputError
from scanqa.io.budget import WELCH_SATTERTHWAITE, BudgetInputs
from scanqa.io.spec import BallBarCertificate, Mpe, Spec, SphereCertificate
from scanqa.qa import budget as bud
from scanqa.qa import vdi2634 as vdi
from scanqa.qa.verdict import DECISIONS, EXIT_STATUS, VERDICTS, decide, verdict

NAN, INF = math.nan, math.inf


def _sphere(centre, radius, n=400, seed=0):
    """n points spread over the camera-facing half of a sphere, exactly on it [mm]."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u[:, 2] = -np.abs(u[:, 2])  # facing the camera at the origin (z < 0 side)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return np.asarray(centre, float) + radius * u


# ---- the decision (ISO 14253-1) and the verdict -----------------------------------------

@pytest.mark.parametrize("value, expanded, limit, expected", [
    (0.0, 0.0, 0.0, "pass"),             # 0 in: |0| <= 0 - 0
    (0.0, 0.0, 0.5, "pass"),
    (-0.5, 0.0, 0.5, "pass"),            # U = 0: the limit itself conforms
    (-0.5000001, 0.0, 0.5, "fail"),      # ... and just past it does not
    (0.3, 0.25, 0.5, "undecided"),       # |E| > T - U = 0.25
    (-0.75, 0.25, 0.5, "undecided"),     # |E| = T + U: not yet proven non-conforming
    (-0.7500001, 0.25, 0.5, "fail"),
    (0.1, 1.0, 0.5, "undecided"),        # U > T: nothing can pass, only fail beyond T + U
    (INF, 0.1, 0.5, "not evaluated"),
    (-INF, 0.1, 0.5, "not evaluated"),
    (0.1, INF, 0.5, "not evaluated"),
    (0.1, 0.1, INF, "not evaluated"),
    (0.1, 0.1, -INF, "not evaluated"),
])
def test_decide_by_hand_with_zero_and_inf(value, expanded, limit, expected):
    assert decide(value, expanded, limit) == expected


@pytest.mark.parametrize("decisions, expected", [
    ([], "NOT EVALUATED"),
    (["not evaluated"], "NOT EVALUATED"),
    (["pass"], "PASS"),
    (["pass", "pass"], "PASS"),
    (["pass", "not evaluated"], "INCOMPLETE"),
    (["pass", "undecided"], "UNDECIDED"),
    (["undecided", "not evaluated"], "UNDECIDED"),
    (["pass", "undecided", "fail"], "FAIL"),  # a fail outranks everything
    (["fail", "not evaluated"], "FAIL"),
])
def test_verdict_of_each_mix(decisions, expected):
    out = verdict(iter(decisions))
    assert out["verdict"] == expected
    assert {d: out[d] for d in DECISIONS} == {d: decisions.count(d) for d in DECISIONS}
    assert expected in VERDICTS


def test_verdict_refuses_an_unknown_decision():
    with pytest.raises(ValueError, match=r"unknown decision 'maybe' \(known: pass, fail, "
                                         r"undecided, not evaluated\)"):
        verdict(["pass", "maybe"])


def test_exit_status_of_each_verdict():
    # docs/cli.rst: 0 PASS, 1 FAIL, 3 anything not decided (2 stays a bad input)
    assert EXIT_STATUS == {"PASS": 0, "FAIL": 1, "UNDECIDED": 3, "INCOMPLETE": 3,
                           "NOT EVALUATED": 3}
    assert set(EXIT_STATUS) == set(VERDICTS)


# ---- the budget (GUM) ---------------------------------------------------------------------

def test_component_contribution_and_row():
    c = bud.Component("temperature", "B", "file", 0.2, "K", -0.5)
    assert c.contribution_um == pytest.approx(0.1)  # |c| u, the sign does not count
    row = c.row()
    assert row["dof"] is None and row["contribution_um"] == pytest.approx(0.1)
    assert row["c_um_per_unit"] == -0.5 and row["unit"] == "K" and row["type"] == "B"
    assert bud.Component("noise", "A", "fit", 1.0, "um", 1.0, 7.0).row()["dof"] == 7.0


def test_welch_satterthwaite_by_hand():
    # GUM G.4.1: nu = u^4 / sum(u_i^4 / nu_i); u = 5 (3, 4), nu_i = 4 and 9
    assert bud.welch_satterthwaite([(3.0, 4.0), (4.0, 9.0)]) == pytest.approx(
        625.0 / (81.0 / 4.0 + 256.0 / 9.0))
    assert bud.welch_satterthwaite([(3.0, INF), (4.0, INF)]) == INF  # all Type B
    assert bud.welch_satterthwaite([(3.0, INF), (0.0, 5.0)]) == INF  # zero finite parts
    assert bud.welch_satterthwaite([(3.0, 0.0), (4.0, 9.0)]) == pytest.approx(
        625.0 / (256.0 / 9.0))  # nu = 0 is not a degree of freedom: left out
    assert bud.welch_satterthwaite([]) == INF


def test_coverage_factor_from_the_t_table():
    # Student's t, two-sided 95 %: 12.706 (1), 2.228 (10), 1.960 (inf) (GUM Table G.2)
    assert bud.coverage_factor(1.0) == pytest.approx(12.706, abs=1e-3)
    assert bud.coverage_factor(10.0) == pytest.approx(2.228, abs=1e-3)
    assert bud.coverage_factor(INF) == pytest.approx(1.960, abs=1e-3)
    assert bud.coverage_factor(INF, 0.9545) == pytest.approx(2.0, abs=1e-3)
    # unknown (NaN) degrees of freedom give an unknown k, not the optimistic normal k;
    # an empty budget has infinite ones (Welch-Satterthwaite over no finite dof)
    assert math.isnan(bud.coverage_factor(NAN))
    assert bud.welch_satterthwaite([]) == INF


def test_budget_combines_in_quadrature_and_picks_k():
    parts = (bud.Component("a", "A", "", 3.0, "um", 1.0, 4.0),
             bud.Component("b", "B", "", 2.0, "um", 2.0, 9.0))
    stated = bud.Budget(parts, 2.0, True, 0.5)
    assert stated.u_um == pytest.approx(5.0) and stated.k == 2.0
    assert stated.expanded_um == pytest.approx(10.0)
    nu = 625.0 / (81.0 / 4.0 + 256.0 / 9.0)
    assert stated.nu_eff == pytest.approx(nu)
    ws = bud.Budget(parts, WELCH_SATTERTHWAITE)
    assert ws.k == pytest.approx(bud.coverage_factor(nu))
    assert ws.expanded_um == pytest.approx(5.0 * bud.coverage_factor(nu))
    s, w = stated.summary(), ws.summary()
    assert s["k_rule"] == "stated" and w["k_rule"] == "welch-satterthwaite"
    assert s["U_um"] == pytest.approx(10.0) and s["u_um"] == pytest.approx(5.0)
    assert s["type_b_included"] is True and s["reference_correction_um"] == 0.5
    assert s["nu_eff"] == pytest.approx(nu) and len(s["components"]) == 2
    type_b_only = bud.Budget((bud.Component("b", "B", "", 2.0, "um", 2.0),))
    assert type_b_only.summary()["nu_eff"] is None  # inf degrees of freedom: JSON null
    empty = bud.Budget(())
    assert empty.u_um == 0.0 and empty.expanded_um == 0.0


def test_type_b_by_hand():
    assert bud.type_b(None, 10.0, 2.0) == ([], 0.0)
    inputs = BudgetInputs("b.toml", certificate_U_um=0.1, certificate_U_per_mm_um=0.001,
                          certificate_k=2.0, deviation_K=0.5, uncertainty_K=0.2,
                          expansion_per_K=11.5e-6, expansion_uncertainty_per_K=1e-6,
                          scale_uncertainty_ppm=2.0, flatness_um=1.2)
    parts, correction = bud.type_b(inputs, 10.0, 2.0)
    d = 8.0  # mm
    assert correction == pytest.approx(1e3 * d * 11.5e-6 * 0.5)  # 0.046 um
    got = {p.name: p for p in parts}
    cert = got["gauge-block certificates (both blocks)"]
    assert cert.u == pytest.approx(math.hypot((0.1 + 0.01) / 2, (0.1 + 0.002) / 2))
    assert cert.c == 1.0 and cert.unit == "um"
    temp = got["temperature of the blocks"]
    assert (temp.u, temp.unit) == (0.2, "K") and temp.c == pytest.approx(1e3 * 11.5e-6 * d)
    alpha = got["expansion coefficient"]
    assert alpha.u == 1e-6 and alpha.c == pytest.approx(1e3 * d * 0.5)
    scale = got["calibration stage scale"]
    assert scale.u == 2.0 and scale.c == pytest.approx(1e-3 * d)
    flat = got["flatness of the calibration flat"]
    assert flat.u == pytest.approx(1.2 / math.sqrt(6.0)) and flat.c == 1.0
    assert all(p.kind == "B" and p.dof == INF for p in parts)
    # only the per-mm certificate term, no temperature deviation: no correction
    only = BudgetInputs("b.toml", certificate_U_per_mm_um=0.002, certificate_k=1.0,
                        expansion_per_K=11.5e-6)
    parts, correction = bud.type_b(only, 3.0, 1.0)
    assert correction == 0.0
    assert parts[0].u == pytest.approx(math.hypot(0.006, 0.002))
    assert [p.u for p in parts[1:]] == [0.0, 0.0]  # neither uncertainty given


# ---- VDI/VDE 2634-2 quantities ------------------------------------------------------------

def test_quantity_picks_the_uncertainty_of_the_decision():
    # U_test = k u_artefact = 0.1; U = k u + |b| = 0.5 + 0.05
    q = vdi.quantity("PS", 0.35, 0.25, 0.5, 2.0, bias=-0.05, u_artefact=0.05)
    assert q.decision == "pass" and q.decided_with == "test"
    assert q.expanded == pytest.approx(0.55) and q.expanded_test == pytest.approx(0.1)
    assert q.u_points == pytest.approx(math.sqrt(0.25**2 - 0.05**2))
    t = vdi.quantity("PS", 0.35, 0.25, 0.5, 2.0, bias=-0.05, u_artefact=0.05,
                     decide_with="total")
    assert t.decision == "undecided"  # 0.35 > 0.5 - 0.55
    assert vdi.quantity("PS", 1.2, 0.25, 0.5, 2.0, decide_with="total").decision == "fail"
    assert vdi.quantity("PS", 0.1, NAN, 0.5).decision == "not evaluated"  # u unknown
    assert vdi.quantity("PS", 0.1, INF, 0.5).decision == "not evaluated"
    assert vdi.quantity("PS", 0.0, 0.0, 0.0).decision == "pass"
    with pytest.raises(InputError, match="decide_with must be one of test, total, got 'x'"):
        vdi.quantity("PS", 0.1, 0.1, 0.5, decide_with="x")


def test_quantity_row_in_micrometres():
    q = vdi.quantity("F", 0.0123456, 0.002, 0.05, 2.0, u_artefact=0.001, length=7.0,
                     n_points=40, n_dropped=1)
    row = q.row()
    assert row["value_um"] == 12.346 and row["U_um"] == 4.0 and row["U_test_um"] == 2.0
    assert row["u_points_um"] == pytest.approx(round(1e3 * math.sqrt(3e-6), 3))
    assert row["mpe_um"] == 50.0 and row["length_mm"] == 7.0 and row["k"] == 2.0
    assert (row["n_points"], row["n_dropped"]) == (40, 1)
    assert row["name"] == "flatness measurement error" and row["decision"] == "pass"
    nan_row = vdi.quantity("F", NAN, NAN, NAN).row()
    assert math.isnan(nan_row["value_um"]) and math.isnan(nan_row["mpe_um"])
    assert vdi.quantity("F", 0.01, 0.001, 0.05).u_points == pytest.approx(0.001)
    assert vdi.quantity("F", 0.01, 0.001, 0.05, u_artefact=0.002).u_points == 0.0


@pytest.mark.parametrize("sigma, n_dropped", [
    ([0.01, NAN, 0.01], 0), ([0.01, INF, 0.01], 0), ([0.01, 0.0, 0.01], 0),
    ([0.01, -0.01, 0.01], 0), ([0.01], 0), ([], 0),
    ([0.01, 0.01, 0.01], 2), ([0.01, 0.01, 0.01], -1),
])
def test_predicted_range_is_nan_without_a_prediction(sigma, n_dropped):
    pred, u = vdi.predicted_range(sigma, n_dropped)
    assert math.isnan(pred) and math.isnan(u)


def test_predicted_range_of_two_points():
    # n = 2, nothing dropped: the range of two N(0, s^2) is |X - Y|, mean 2 s / sqrt(pi)
    # (the tail model's Poisson arrivals are exact only for large n: within 15 %)
    pred, u = vdi.predicted_range([0.01, 0.01], 0)
    assert 0 < pred and 0 < u
    assert pred == pytest.approx(2 * 0.01 / math.sqrt(math.pi), rel=0.5)
    big, _ = vdi.predicted_range([0.02, 0.02], 0)
    assert big == pytest.approx(2 * pred)  # scales with sigma


def test_normal_sigma_nan_inf_zero():
    pts = np.array([[0.0, 0.0, 100.0], [0.0, 100.0, 100.0], [0.0, 0.0, 50.0]])
    n = np.array([0.0, 0.0, -1.0])
    out = vdi.normal_sigma(pts, [NAN, INF, 0.0], n)
    assert math.isnan(out[0]) and out[1] == INF and out[2] == 0.0
    assert_allclose(vdi.normal_sigma(pts, 0.02, n), [0.02, 0.02 / math.sqrt(2), 0.02])
    assert_allclose(vdi.normal_sigma(pts, 0.02, n, view_origin=None), [0.02] * 3)
    # lines of sight from another origin: (0, 100, 0) sees point 2 along -y
    assert_allclose(vdi.normal_sigma(pts[1:2], 0.02, n, view_origin=(0, 100, 0)), [0.02])


def test_drop_rule_refuses_fractions_outside_its_range():
    pts = _sphere([0, 0, 300], 10.0, 200)
    for bad in (-0.1, 0.5, NAN, INF):
        with pytest.raises(InputError, match=r"drop_fraction must be in \[0, 0.5\)"):
            vdi.probing_errors(pts, drop_fraction=bad)


def test_probing_errors_of_an_exact_sphere():
    pts = _sphere([5.0, -3.0, 300.0], 12.5, 1000)
    spec = Spec("s", {"PF": Mpe(10.0), "PS": Mpe(5.0)},
                sphere=SphereCertificate(25.0, 2.0, 2.0, form_um=3.0))
    t = vdi.probing_errors(pts, None, spec, drop_fraction=0.003)
    assert t.pf.n_dropped == 3 and t.pf.n_points == 1000 and t.kept.sum() == 997
    assert t.ps.value == pytest.approx(0.0, abs=1e-9)  # diameter 25.0, certified 25.0
    assert t.ps.u == pytest.approx(1e-3, rel=1e-6)      # only the certificate: 2 um / 2
    assert t.ps.length == 25.0
    assert t.pf.value == pytest.approx(0.0, abs=1e-9)   # no form
    assert t.pf.u == pytest.approx(3e-3 / math.sqrt(3.0), rel=1e-6)  # form f / sqrt(3)
    assert t.pf.mpe == pytest.approx(0.01) and t.ps.mpe == pytest.approx(0.005)
    assert t.pf.decision == "pass" and t.ps.decision == "pass"
    # shared errors of the points (the calibration table's) enter u(R) twice over: 2 u(R)
    shared = vdi.probing_errors(pts, None, spec, drop_fraction=0.003, u_table=0.004)
    assert shared.ps.u == pytest.approx(math.hypot(2 * 0.004, 1e-3), rel=1e-6)


def test_ball_bar_sd_counts_the_table_term_of_each_ball():
    """The hand mutant of issue 28: each ball's centre carries the table's shared error
    u_table independently, so the centre distance carries it twice:
    u(L)^2 = u_fit^2 + 2 u_table^2 + u_cert^2 (VDI/VDE 2634-2, SD; module notes)."""
    pa = _sphere([-150.0, 0.0, 500.0], 12.7, 800, seed=1)
    pb = _sphere([150.0, 0.0, 500.0], 12.7, 800, seed=2)
    spec = Spec("s", {"SD": Mpe(20.0, 1000.0)}, ball_bar=BallBarCertificate(300.0, 3.0, 3.0))
    t = vdi.sphere_spacing_error(pa, pb, None, None, spec, u_table=0.005)
    # exact spheres, u from the residuals' scatter: the fits add nothing, u_cert = 3 um / 3 = 1 um
    assert t.bar.u_distance == pytest.approx(0.0, abs=1e-9)
    assert t.sd.u == pytest.approx(math.sqrt(2 * 0.005**2 + 0.001**2), rel=1e-6)
    assert t.sd.value == pytest.approx(0.0, abs=1e-9)
    assert t.sd.mpe == pytest.approx(0.0203) and t.sd.length == 300.0
    assert t.sd.n_points == 1600 and t.sd.u_artefact == pytest.approx(0.001)
    assert t.sd.decision == "pass"
    none = vdi.sphere_spacing_error(pa, pb, None, None, spec)
    assert none.sd.u == pytest.approx(0.001, rel=1e-6)


def test_flatness_error_of_an_exact_plane():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-20, 20, (500, 2))
    pts = np.column_stack([xy, 400.0 + 0.01 * xy[:, 0]])
    t = vdi.flatness_error(pts, 0.0, drop_fraction=0.0)
    assert t.f.value == pytest.approx(0.0, abs=1e-9) and t.f.n_dropped == 0
    assert math.isnan(t.f.mpe) and t.f.decision == "not evaluated"
    assert t.f.note == "u from the per-point sigmas"
    assert vdi.flatness_error(pts, drop_fraction=0.0).f.note.startswith("no per-point sigma")
    for bad in (0.0, -1.0, NAN, INF):
        with pytest.raises(InputError, match="noise-correlation factor must be > 0"):
            vdi.flatness_error(pts, 0.01, correlation=bad)


FULL = Spec("full", {"PF": Mpe(11.0), "PS": Mpe(7.0), "SD": Mpe(20.0, 1000.0), "F": Mpe(13.0)},
            sphere=SphereCertificate(25.0, 2.0, 2.0, form_um=3.0),
            ball_bar=BallBarCertificate(300.0, 3.0, 3.0))
NO_CERT = Spec("mpe only", {"PF": Mpe(11.0), "PS": Mpe(7.0), "SD": Mpe(20.0, 1000.0),
                            "F": Mpe(13.0)})


def test_each_quantity_carries_its_name_mpe_and_defaults():
    """Names, the MPE each reads from the spec (PF 11, PS 7, SD 20 + L / 1000, F 13 um),
    the default k = 2 and the point counts, with and without certificates."""
    pts = _sphere([5.0, -3.0, 300.0], 12.5, 1000)
    t = vdi.probing_errors(pts, None, FULL)
    assert (t.pf.name, t.ps.name) == ("PF", "PS") and t.pf.k == t.ps.k == 2.0
    assert (t.pf.mpe, t.ps.mpe) == pytest.approx((0.011, 0.007))
    assert t.ps.n_points == 1000 and t.ps.n_dropped == 3 and t.ps.decided_with == "test"
    assert t.kept.shape == (1000,) and t.zone.width >= 0.0
    bare = vdi.probing_errors(pts, None, NO_CERT)
    assert (bare.ps.name, bare.ps.k, bare.ps.n_points) == ("PS", 2.0, 1000)
    assert bare.ps.mpe == pytest.approx(0.007) and math.isnan(bare.ps.u)
    assert "no sphere certificate" in bare.ps.note and bare.ps.decision == "not evaluated"
    pa = _sphere([-150.0, 0.0, 500.0], 12.7, 600, seed=1)
    pb = _sphere([150.0, 0.0, 500.0], 12.7, 600, seed=2)
    for first, second in ((pa, pb), (pb, pa)):  # ball a is the one of smaller x either way
        bar = vdi.sphere_spacing_error(first, second, spec=FULL)
        assert bar.bar.sphere_a.centre[0] == pytest.approx(-150.0)
        assert bar.sd.k == 2.0 and bar.sd.name == "SD"
    sd = vdi.sphere_spacing_error(pa, pb, spec=NO_CERT).sd
    assert (sd.name, sd.k, sd.n_points) == ("SD", 2.0, 1200)
    assert sd.mpe == pytest.approx(0.020) and sd.decision == "not evaluated"
    rng = np.random.default_rng(3)
    xy = rng.uniform(-20, 20, (500, 2))
    flat = np.column_stack([xy, 400.0 + 0.01 * xy[:, 0]])
    f = vdi.flatness_error(flat, 0.002, FULL)
    assert f.f.name == "F" and f.f.k == 2.0 and f.f.mpe == pytest.approx(0.013)
    assert f.f.n_dropped == 1 and f.kept.sum() == 499 and f.plane is not None
    assert f.f.u == pytest.approx(math.sqrt(vdi.predicted_range(
        vdi.normal_sigma(flat, 0.002, f.plane.normal), 1)[1] ** 2))  # no flat certificate


def test_messages_name_the_artefact():
    with pytest.raises(InputError, match=r"^flat: 9 points, a fit needs at least 10"):
        vdi.flatness_error(np.random.default_rng(0).normal(size=(9, 3)))
    line = np.column_stack([np.arange(20.0), np.zeros(20), np.full(20, 400.0)])
    with pytest.raises(InputError, match=r"^flat: the points are collinear"):
        vdi.flatness_error(line)
    with pytest.raises(InputError, match=r"^sphere: 4 points"):
        vdi.probing_errors(_sphere([0, 0, 300], 10.0, 4))
    good = _sphere([150.0, 0.0, 500.0], 12.7, 300)
    with pytest.raises(InputError, match=r"^ball bar, ball a: 4 points"):
        vdi.sphere_spacing_error(_sphere([-150.0, 0.0, 500.0], 12.7, 4), good)
    with pytest.raises(InputError, match=r"^bar 7, ball b: 4 points"):
        vdi.sphere_spacing_error(good, _sphere([160.0, 0.0, 500.0], 12.7, 4), where="bar 7")


def test_sigmas_and_correlation_reach_the_sphere_fits():
    """The per-point sigmas along the radial normals and the correlation factor enter
    u(R) (u grows as sqrt(kappa)); with sigmas along the line of sight, a bias is
    predicted (view_origin None: none)."""
    pts = _sphere([0.0, 0.0, 300.0], 12.5, 1500, seed=4)
    spec = Spec("s", {"PS": Mpe(7.0)}, sphere=SphereCertificate(25.0, 0.0, 2.0))
    one = vdi.probing_errors(pts, 0.01, spec, drop_fraction=0.0)
    four = vdi.probing_errors(pts, 0.01, spec, drop_fraction=0.0, correlation=4.0)
    assert four.ps.u == pytest.approx(2.0 * one.ps.u, rel=1e-9)
    assert one.ps.u > 0 and one.ps.bias != 0.0
    flat_out = vdi.probing_errors(pts, 0.01, spec, drop_fraction=0.0, view_origin=None)
    assert flat_out.ps.bias == 0.0 and flat_out.ps.u > one.ps.u  # sigma along the normal
    a = _sphere([-150.0, 0.0, 500.0], 12.7, 800, seed=5)
    b = _sphere([150.0, 0.0, 500.0], 12.7, 800, seed=6)
    bar_spec = Spec("s", {"SD": Mpe(20.0, 1000.0)}, ball_bar=BallBarCertificate(300.0, 0.0, 2.0))
    s1 = vdi.sphere_spacing_error(a, b, 0.01, 0.01, bar_spec)
    s4 = vdi.sphere_spacing_error(a, b, 0.01, 0.01, bar_spec, correlation=4.0)
    assert s4.sd.u == pytest.approx(2.0 * s1.sd.u, rel=1e-9) and s1.sd.u > 0
    s_none = vdi.sphere_spacing_error(a, b, 0.01, 0.01, bar_spec, view_origin=None)
    assert s_none.sd.bias == 0.0 and s_none.sd.u != s1.sd.u
    only_b = vdi.sphere_spacing_error(a, b, None, 0.01, bar_spec)
    assert 0 < only_b.sd.u < s1.sd.u  # ball a without sigmas: its exact fit adds nothing
