"""VDI/VDE 2634-2 tests on annotated clouds: point selection counted independently,
closed loops on synthetic artefacts with known truth, finding artefacts without a
layout, and one clear message (exit 2, one line from the CLI) for each bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.io.cloud import write_cloud
from scanqa.io.spec import BallBarCertificate, FlatCertificate, Mpe, Spec, SphereCertificate
from scanqa.qa.artefacts import (
    ArtefactLayout,
    ArtefactSpec,
    Options,
    auto_layout,
    oblique_factor,
    run_artefact_qa,
    tile_correlation,
)

from .qa_artefacts import along_sight, flat_patch, sight_cosine, visible_cap

SIGMA_MM = 0.006
D = 12.0
CENTRE = np.array([2.0, -1.0, 450.0])
BAR_A, BAR_B = np.array([-14.0, -12.0, 441.5]), np.array([14.0, 12.0, 458.5])
SPEC = Spec("test spec", {"PF": Mpe(60.0), "PS": Mpe(10.0), "SD": Mpe(15.0, 1000.0),
                          "F": Mpe(60.0)},
            sphere=SphereCertificate(D, 0.5), flat=FlatCertificate(0.0),
            ball_bar=BallBarCertificate(float(np.linalg.norm(BAR_B - BAR_A)), 1.0,
                                        diameter_mm=D))


def attributes(points, normals, sigma_mm=SIGMA_MM):
    """The attributes annotate writes that the QA reads: a constant model sigma, and a
    decoder sigma that grows as 1 / cos of the incidence (a foreshortened fringe)."""
    cos = sight_cosine(points, normals)
    n = len(points)
    return {"sigma_model_um": np.full(n, 1e3 * sigma_mm, np.float32),
            "sigma_phase_um": (500.0 * 0.008 / cos).astype(np.float32),
            "s_t_um_px": np.full(n, 500.0, np.float32),
            "att_camera": np.ones(n, np.float32), "att_projector": np.ones(n, np.float32),
            "modulation_dn": (60.0 * cos).astype(np.float32),
            "sigma_calibration_um": np.full(n, 0.25, np.float32),
            "table_corr_mm": np.full(n, 4.4, np.float32)}


def image_sampled_cap(rng, centre, n, max_incidence_deg):
    """Points of the visible cap as an image samples them: surface density prop. to the
    cosine of the incidence (uniform over the pixels)."""
    exact, normals = visible_cap(rng, centre, D / 2, 4 * n, max_incidence_deg)
    keep = rng.random(len(exact)) < sight_cosine(exact, normals)
    return exact[keep][:n], normals[keep][:n]


def ball(rng, centre, n=3000, grazing_junk_mm=0.05):
    """A ball as a scanner sees it up to 85 deg incidence; the points beyond 70 deg are
    pushed out by ``grazing_junk_mm`` (mixed pixels at the silhouette)."""
    exact, normals = image_sampled_cap(rng, centre, n, 85.0)
    pts = along_sight(rng, exact, SIGMA_MM)
    grazing = sight_cosine(exact, normals) < math.cos(math.radians(70.0))
    pts[grazing] += grazing_junk_mm * normals[grazing]
    return pts, normals, grazing


def cloud_of(parts) -> AnnotatedCloud:
    pts = np.vstack([p for p, _ in parts])
    attrs = [attributes(p, nrm) for p, nrm in parts]
    return AnnotatedCloud(pts, {k: np.concatenate([a[k] for a in attrs]) for k in attrs[0]})


def sphere_layout(centre=CENTRE, ident="S1"):
    return ArtefactLayout("t", (ArtefactSpec("sphere", ident, D, centre_mm=tuple(centre)),))


def bar_layout(a=BAR_A, b=BAR_B):
    return ArtefactLayout("t", (ArtefactSpec("ball_bar", "P1", D, float(np.linalg.norm(b - a)),
                                             tuple(np.round(a)), tuple(np.round(b)),
                                             bar_diameter_mm=4.0),))


def bar_cloud(rng):
    """Two balls and the visible part of the bar between them (4 mm diameter)."""
    pa, na, _ = ball(rng, BAR_A)
    pb, nb, _ = ball(rng, BAR_B)
    axis = (BAR_B - BAR_A) / np.linalg.norm(BAR_B - BAR_A)
    t = rng.uniform(0, np.linalg.norm(BAR_B - BAR_A), 4000)
    ang = rng.uniform(0, 2 * np.pi, t.size)
    e1 = np.cross(axis, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    radial = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
    rod = BAR_A + t[:, None] * axis + 2.0 * radial
    outside = (np.linalg.norm(rod - BAR_A, axis=1) > D / 2) & \
        (np.linalg.norm(rod - BAR_B, axis=1) > D / 2) & (radial[:, 2] < 0)  # seen side
    return cloud_of([(pa, na), (pb, nb), (rod[outside], radial[outside])]), (pa, pb), axis


def test_sphere_selection_counts_and_closed_loop():
    rng = np.random.default_rng(1)
    pts, normals, grazing = ball(rng, CENTRE)
    res = run_artefact_qa([("scan", cloud_of([(pts, normals)]))], sphere_layout(), SPEC)
    (r,) = res.results
    counts = r.selections[0].counts
    # the grazing points are found from the fitted sphere, so a point right at 70 deg may
    # fall on either side: the count agrees with the exact normals within a few points
    assert abs(counts["grazing_removed"] - int(grazing.sum())) <= 5
    assert counts["used"] == len(pts) - counts["grazing_removed"]
    pf, ps = r.quantities
    assert abs(ps.value) <= ps.expanded  # the true diameter is the certificate's
    assert abs(pf.predicted / pf.value - 1) <= 0.2, (pf.predicted, pf.value)
    assert pf.n_dropped == math.floor(0.003 * counts["used"])
    assert ps.decision == "pass" and pf.decision == "pass"


def test_keeping_grazing_points_shows_in_pf():
    """With every point kept (90 deg), the silhouette's mixed points widen PF by about
    their offset (50 um) and PF no longer matches its prediction."""
    pts, normals, _ = ball(np.random.default_rng(1), CENTRE)
    cloud = cloud_of([(pts, normals)])
    kept = run_artefact_qa([("s", cloud)], sphere_layout(), SPEC,
                           Options(max_incidence_deg=90.0)).results[0].quantities[0]
    cut = run_artefact_qa([("s", cloud)], sphere_layout(), SPEC).results[0].quantities[0]
    assert kept.value > cut.value + 0.02
    assert kept.value > 1.3 * kept.predicted


def test_ball_bar_mounting_cone_and_distance():
    rng = np.random.default_rng(2)
    cloud, (pa, pb), axis = bar_cloud(rng)
    res = run_artefact_qa([("p000_r0", cloud)], bar_layout(), SPEC)
    (r,) = res.results
    sa, sb = r.selections
    # ball b's mounting region faces ball a; the cone is asin(4/12) + 10 deg = 29.5 deg:
    # no point of the bar and no point of ball b within 29 deg of the bar's axis is used,
    # every point of ball b beyond 30 deg (seen at less than 69 deg) is
    first_b, first_rod = len(pa), len(pa) + len(pb)
    used = sb.index
    assert used.min() >= first_b and used.max() < first_rod
    ub = (pb - BAR_B) / np.linalg.norm(pb - BAR_B, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(ub @ -axis, -1, 1)))
    seen = sight_cosine(pb, ub) >= math.cos(math.radians(69.0))
    assert not np.any(angle[used - first_b] < 29.0)
    assert set(np.flatnonzero((angle > 30.0) & seen)) <= set(used - first_b)
    assert sb.counts["mount_removed"] > 0.05 * len(pb)
    assert sa.index.max() < first_b  # ball a's mounting side faces away: only the bar's
    assert sa.counts["mount_removed"] < 0.01 * len(pa)  # edge there, no ball point
    (sd,) = r.quantities
    assert abs(sd.value) <= sd.expanded
    assert sd.length == pytest.approx(np.linalg.norm(BAR_B - BAR_A))


def test_flat_edge_margin_and_prediction():
    rng = np.random.default_rng(3)
    normal = np.array([0.0, 0.17, -0.985])
    normal /= np.linalg.norm(normal)
    exact, st = flat_patch(rng, [0.0, 0.0, 450.0], normal, 40.0, 20000)
    pts = along_sight(rng, exact, SIGMA_MM)
    cloud = cloud_of([(pts, np.broadcast_to(normal, pts.shape))])
    layout = ArtefactLayout("t", (ArtefactSpec("flat", "F1", centre_mm=(0.0, 0.0, 450.0),
                                               normal=tuple(normal)),))
    (r,) = run_artefact_qa([("s", cloud)], layout, SPEC).results
    counts = r.selections[0].counts
    # points within 1 mm of the square's edge (its convex hull) are removed
    inner = np.all(np.abs(st) <= 20.0 - 1.0, axis=1)
    assert abs(counts["edge_removed"] - int(np.sum(~inner))) <= 0.002 * len(pts)
    (f,) = r.quantities
    assert abs(f.predicted / f.value - 1) <= 0.2
    assert f.decision == "pass"


def test_found_without_a_layout_as_with_one():
    rng = np.random.default_rng(4)
    pts, normals, _ = ball(rng, CENTRE)
    cloud = cloud_of([(pts, normals)])
    auto = run_artefact_qa([("s", cloud)], auto_layout("sphere", SPEC), SPEC).results[0]
    given = run_artefact_qa([("s", cloud)], sphere_layout(), SPEC).results[0]
    assert_allclose(auto.quantities[1].value, given.quantities[1].value, atol=1e-9)
    bar, _, _ = bar_cloud(rng)
    (r,) = run_artefact_qa([("s", bar)], auto_layout("ball-bar", SPEC), SPEC).results
    assert abs(r.quantities[0].value) <= r.quantities[0].expanded


def test_oblique_factor_follows_the_decoder():
    """Its reference is the median of the points within 20 deg of their normal; the
    synthetic decoder sigma grows as 1 / cos, so the factor is cos_ref / cos."""
    rng = np.random.default_rng(5)
    exact, normals = visible_cap(rng, CENTRE, D / 2, 4000, max_incidence_deg=70.0)
    cloud = cloud_of([(exact, normals)])
    f = oblique_factor(cloud, np.arange(len(exact)), normals)
    cos = sight_cosine(exact, normals)
    ref = np.median(1.0 / cos[cos >= math.cos(math.radians(20.0))])
    assert_allclose(f, (1.0 / cos) / ref, rtol=1e-5)
    g = oblique_factor(cloud, np.arange(len(exact)), normals, "modulation")
    assert_allclose(g, (1.0 / cos) / ref, rtol=1e-5)  # modulation = 60 cos here


def test_oblique_factor_two_part():
    """With the model's two parts and the fringe offset, the sensor part follows the
    decoder's sigma and the scene part the inverse contrast A / B: here A / B goes as
    sqrt(cos) and the decoder sigma as 1 / cos, the scene part carries
    80 % of the variance, so the factor is sqrt(0.8 c^2 + 0.2 d^2) with c, d each over
    its median within 20 deg of the normal."""
    rng = np.random.default_rng(7)
    exact, normals = visible_cap(rng, CENTRE, D / 2, 4000, max_incidence_deg=70.0)
    cloud = cloud_of([(exact, normals)])
    cos = sight_cosine(exact, normals)
    n = len(exact)
    cloud.attributes["offset_dn"] = (120.0 * cos ** 1.5).astype(np.float32)  # A / B ~ sqrt(cos)
    cloud.attributes["sigma_scene_um"] = np.full(n, 4.0, np.float32)
    cloud.attributes["sigma_sensor_um"] = np.full(n, 2.0, np.float32)
    f = oblique_factor(cloud, np.arange(n), normals)
    front = cos >= math.cos(math.radians(20.0))
    c = np.sqrt(cos) / np.median(np.sqrt(cos[front]))
    d = (1.0 / cos) / np.median(1.0 / cos[front])
    assert_allclose(f, np.sqrt(0.8 * c**2 + 0.2 * d**2), rtol=1e-5)
    # a one-source reading (no sensor part) keeps the decoder's sigma alone
    cloud.attributes["sigma_sensor_um"] = np.zeros(n, np.float32)
    assert_allclose(oblique_factor(cloud, np.arange(n), normals), d, rtol=1e-5)


def test_tile_correlation_counts_shared_noise():
    """Noise drawn once per 1 mm cube and shared by its points: kappa of the radius is
    about the number of points per cube; independent noise gives about 1."""
    rng = np.random.default_rng(6)
    exact, normals = visible_cap(rng, CENTRE, D / 2, 6000, max_incidence_deg=70.0)
    cell = np.floor(exact / 1.0).astype(int)
    _, tile, per = np.unique(cell, axis=0, return_inverse=True, return_counts=True)
    shared = rng.normal(0, SIGMA_MM, per.size)[tile.ravel()]
    kappa = tile_correlation(2.0)
    for noise, low, high in ((rng.normal(0, SIGMA_MM, len(exact)), 0.7, 1.5),
                             (shared, 0.5 * per.mean(), 2.0 * per.mean())):
        pts = exact + normals * noise[:, None]
        d = pts - CENTRE
        dist = np.linalg.norm(d, axis=1)
        jac = np.column_stack([-d / dist[:, None], -np.ones(len(d))])
        k = kappa(pts, jac, dist - D / 2)
        assert low <= k[3] <= high, (k, per.mean())


# ------------------------------------------------------------------------ bad input

def test_too_few_points_small_cap_and_a_missing_ball():
    rng = np.random.default_rng(7)
    pts, normals, _ = ball(rng, CENTRE, n=12)
    with pytest.raises(InputError, match=r"sphere 'S1': \d+ points within 12 mm of its "
                                         r"approximate centre .* needs at least 20"):
        run_artefact_qa([("s", cloud_of([(pts, normals)]))], sphere_layout(), SPEC)
    exact, nrm = visible_cap(rng, CENTRE, D / 2, 3000, max_incidence_deg=25.0)
    with pytest.raises(InputError, match=r"sphere 'S1': the points cover \d+% of a "
                                         r"hemisphere .* at least 50%"):
        run_artefact_qa([("s", cloud_of([(along_sight(rng, exact, SIGMA_MM), nrm)]))],
                        sphere_layout(), SPEC)
    pa, na, _ = ball(rng, BAR_A)
    with pytest.raises(InputError, match=r"ball bar 'P1', ball b: 0 points within 12 mm"):
        run_artefact_qa([("s", cloud_of([(pa, na)]))], bar_layout(), SPEC)
    with pytest.raises(InputError, match="ball bar: found 1 of 2 spheres of radius 6 mm"):
        run_artefact_qa([("s", cloud_of([(pa, na)]))], auto_layout("ball_bar", SPEC), SPEC)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A sphere cloud, a one-ball 'bar', a tiny cap, layouts and specs as files."""
    d = tmp_path_factory.mktemp("artefact_cli")
    rng = np.random.default_rng(8)
    pts, normals, _ = ball(rng, CENTRE)
    c = cloud_of([(pts, normals)])
    write_cloud(d / "sphere.ply", c.xyz, c.attributes)
    few = cloud_of([ball(rng, CENTRE, n=12)[:2]])
    write_cloud(d / "few.ply", few.xyz, few.attributes)
    exact, nrm = visible_cap(rng, CENTRE, D / 2, 3000, max_incidence_deg=25.0)
    cap = cloud_of([(exact, nrm)])
    write_cloud(d / "cap.ply", cap.xyz, cap.attributes)
    one = cloud_of([ball(rng, BAR_A)[:2]])
    write_cloud(d / "oneball.ply", one.xyz, one.attributes)
    (d / "sphere.toml").write_text(
        'format = "scanqa-artefact-layout/1"\n[[sphere]]\nid = "S1"\ndiameter_mm = 12.0\n'
        f"centre_mm = [{CENTRE[0]}, {CENTRE[1]}, {CENTRE[2]}]\n")
    (d / "bar.toml").write_text(
        'format = "scanqa-artefact-layout/1"\n[[ball_bar]]\nid = "P1"\ndiameter_mm = 12.0\n'
        "distance_mm = 40.0\ncentre_a_mm = [-14.0, -12.0, 442.0]\n"
        "centre_b_mm = [14.0, 12.0, 458.0]\n")
    (d / "spec.toml").write_text(
        'format = "scanqa-spec/1"\nmpe_pf_um = 60.0\nmpe_ps_um = 10.0\n'
        "[sphere]\ndiameter_mm = 12.0\ndiameter_uncertainty_um = 0.5\n")
    (d / "nompe.toml").write_text(
        'format = "scanqa-spec/1"\n[sphere]\ndiameter_mm = 12.0\n'
        "diameter_uncertainty_um = 0.5\n")
    return d


def test_cli_writes_the_artefact_report(files, capsys):
    out = files / "qa"
    assert main(["qa", str(files / "sphere.ply"), "--layout", str(files / "sphere.toml"),
                 "--spec", str(files / "spec.toml"), "--operator", "A. Tester",
                 "--notes", "bench 3", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "verdict: PASS (2 pass, 0 fail, 0 undecided, 0 not evaluated)" in printed
    info = json.loads((out / "summary.json").read_text())
    assert info["header"]["Operator"] == "A. Tester" and info["header"]["Notes"] == "bench 3"
    assert [r["quantity"] for r in info["quantities"]] == ["PF", "PS"]
    for name in ("report.html", "quantities.csv", "budget.csv", "selection.csv"):
        assert (out / name).stat().st_size > 0
    html = (out / "report.html").read_text()
    assert html.index('id="verdict"') < html.index('id="header"') < html.index("Results")


@pytest.mark.parametrize("args, message", [
    (["few.ply", "--layout", "sphere.toml"], "sphere 'S1': .* points within 12 mm of its "
                                             "approximate centre"),
    (["cap.ply", "--layout", "sphere.toml"], "sphere 'S1': the points cover .* of a "
                                             "hemisphere"),
    (["oneball.ply", "--layout", "bar.toml"], "ball bar 'P1', ball b: 0 points within"),
    (["oneball.ply", "--auto", "--artefact", "ball-bar", "--diameter", "12", "--distance",
      "40"], "ball bar: found 1 of 2 spheres"),
    (["sphere.ply", "--layout", "sphere.toml", "--spec", "nompe.toml"],
     "nompe.toml: no MPE given: set at least one of mpe_pf_um"),
    (["sphere.ply", "--auto", "--artefact", "sphere"], "needs its nominal diameter"),
    (["sphere.ply", "--artefact", "sphere"], "--artefact finds the artefact by RANSAC: add "
                                             "--auto"),
])
def test_cli_bad_inputs_get_one_line(files, capsys, args, message):
    argv = ["qa", *[str(files / a) if a.endswith((".ply", ".toml")) else a for a in args],
            "--out", str(files / "bad")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("scanqa: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    import re

    assert re.search(message, err), err


def test_cli_without_a_spec_prints_the_fitted_diameter_not_nan(files, capsys):
    """Issue 45: a sphere without a spec printed 'PS: E +nan um' and no diameter."""
    out = files / "qa-nospec"
    assert main(["qa", str(files / "sphere.ply"), "--layout", str(files / "sphere.toml"),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "nan" not in printed.lower()
    import re

    found = re.search(r"S1 PS: fitted diameter (\d+\.\d+) mm; no spec: not evaluated", printed)
    assert found, printed
    assert float(found.group(1)) == pytest.approx(D, abs=0.005)  # the simulated ball's
    assert "S1 PF: E +" in printed and "PF: E" in printed.split("no spec")[0]
    rows = json.loads((out / "summary.json").read_text())["quantities"]
    ps = next(r for r in rows if r["quantity"] == "PS")
    assert ps["measured_mm"] == pytest.approx(float(found.group(1)), abs=1e-4)
    assert ps["value_um"] is None and ps["note"] == "no spec: not evaluated"
    html = (out / "report.html").read_text()
    assert f">{ps['measured_mm']:.4f}<" in html and "fitted size [mm]" in html
