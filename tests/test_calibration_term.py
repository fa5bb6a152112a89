"""An imported calibration's term given beside it (issue 42): a covariance file
(scanqa.io.covariance) or a stated std, through load_calibration and the command line;
every cloud's sigma_source says which (covariance / stated / none). The expected
sigmas come from the covariance carried inside the calibration file itself (the path
tests/test_calibration_sigma.py checks against a Monte Carlo) and from the stated
number."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.calibration.base import load_calibration
from scanqa.cli import main
from scanqa.decoding.phasemap import save_phase_map
from scanqa.design.rig import config_toml_dict
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import read_cloud
from scanqa.io.covariance import FORMAT, read_covariance, write_covariance
from scanqa.io.opencv import COVARIANCE_PARAMETERS, OpenCVCalibration, write_opencv_calibration
from scanqa.io.tomlfile import dumps_toml
from tests.synth_parametric import (
    camera_rays,
    layout_scene,
    phase_map,
    projector_pixels,
    small_scanner,
)

#: A covariance of the 24 parameters: f_x, f_y of the camera 3 px, Tp x 0.3 mm, and a
#: correlation between the projector's c_x and the rotation about y.
COV = np.zeros((24, 24))
COV[0, 0] = COV[1, 1] = 3.0**2
COV[21, 21] = 0.3**2
COV[11, 11], COV[19, 19] = 2.0**2, 1e-3**2
COV[11, 19] = COV[19, 11] = 0.5 * 2.0 * 1e-3


@pytest.fixture(scope="module")
def files(paper_config, tmp_path_factory):
    """An OpenCV calibration without covariance, the same with one, a config and a scan."""
    cal, cfg = small_scanner(paper_config, 40, 30)
    root = tmp_path_factory.mktemp("term")
    sizes = {"frameWidth": cal.width_px, "frameHeight": cal.height_px,
             "screenResX": cal.projector.width_px, "screenResY": cal.projector.height_px}
    data = OpenCVCalibration(cal.camera.matrix, cal.camera.distortion, cal.projector.matrix,
                             cal.projector.distortion, cal.rotation, cal.translation, sizes,
                             {}, "")
    write_opencv_calibration(root / "plain.xml", data)
    write_opencv_calibration(root / "inside.xml", replace(data, covariance=COV))
    (root / "scanner.toml").write_text(dumps_toml(config_toml_dict(cfg)))
    xp = projector_pixels(cal, layout_scene(camera_rays(cal), 450.0, []))[..., 0]
    scan = phase_map(xp, np.full(xp.shape, 0.02), cfg.fringes.working_period_px,
                     cfg.projector.width_px)
    save_phase_map(root / "phase.npz", scan)
    return root, cfg, scan


def test_covariance_files_round_trip_and_are_reordered_by_name(tmp_path):
    for suffix in (".json", ".npz"):
        path = write_covariance(tmp_path / f"c{suffix}", COV)
        np.testing.assert_array_equal(read_covariance(path), COV)
    # a file listing the parameters in another order: its matrix follows that order
    order = np.random.default_rng(3).permutation(24)
    (tmp_path / "shuffled.json").write_text(json.dumps({
        "format": FORMAT, "parameters": [COVARIANCE_PARAMETERS[i] for i in order],
        "covariance": COV[np.ix_(order, order)].tolist()}))
    np.testing.assert_array_equal(read_covariance(tmp_path / "shuffled.json"), COV)


def test_a_covariance_file_gives_the_same_term_as_the_files_own(files):
    root, cfg, scan = files
    write_covariance(root / "cov.json", COV)
    given = load_calibration(root / "plain.xml", cfg, covariance=root / "cov.json")
    inside = load_calibration(root / "inside.xml", cfg)
    a, b = annotate(scan, given, cfg), annotate(scan, inside, cfg)
    assert a.sigma_source["calibration"] == b.sigma_source["calibration"] == "covariance"
    assert "cov.json" in a.sigma_source["calibration_detail"]
    assert a.attributes["sigma_calibration_um"].min() > 10  # tens of um: not negligible
    np.testing.assert_array_equal(a.attributes["sigma_calibration_um"],
                                  b.attributes["sigma_calibration_um"])


def test_a_stated_sigma_and_none_are_named(files):
    root, cfg, scan = files
    stated = annotate(scan, load_calibration(root / "plain.xml", cfg, sigma_um=120.0), cfg)
    assert stated.sigma_source["calibration"] == "stated"
    assert "stated beside the calibration" in stated.sigma_source["calibration_detail"]
    np.testing.assert_allclose(stated.attributes["sigma_calibration_um"], 120.0, rtol=1e-6)
    # a stated std replaces the covariance the file holds
    over = annotate(scan, load_calibration(root / "inside.xml", cfg, sigma_um=7.0), cfg)
    assert over.sigma_source["calibration"] == "stated"
    none = annotate(scan, load_calibration(root / "plain.xml", cfg), cfg)
    assert none.sigma_source["calibration"] == "none"
    assert np.all(none.attributes["sigma_calibration_um"] == 0)
    with pytest.raises(InputError, match="not both"):
        load_calibration(root / "plain.xml", cfg, covariance=root / "x.json", sigma_um=1.0)


def test_the_command_line_takes_either_and_the_cloud_says_which(files, tmp_path):
    root, _, _ = files
    write_covariance(root / "cov.npz", COV)
    base = ["annotate", str(root / "phase.npz"), "--calibration", str(root / "plain.xml"),
            "--config", str(root / "scanner.toml"), "-q"]
    expect = {"covariance": ["--calibration-covariance", str(root / "cov.npz")],
              "stated": ["--calibration-sigma-um", "80"], "none": []}
    for kind, extra in expect.items():
        out = tmp_path / f"{kind}.ply"
        assert main([*base, *extra, "--out", str(out)]) == 0
        cloud = read_cloud(out)
        assert cloud.sigma_source["calibration"] == kind
        if kind == "stated":
            np.testing.assert_allclose(cloud.attributes["sigma_calibration_um"], 80.0,
                                       rtol=1e-6)


BAD = {  # (what the file holds, what the one line must say)
    "no_matrix": ({"format": FORMAT, "parameters": list(COVARIANCE_PARAMETERS)},
                  r"field 'covariance' is missing"),
    "wrong_shape": ({"format": FORMAT, "parameters": list(COVARIANCE_PARAMETERS),
                     "covariance": np.eye(23).tolist()},
                    r"field 'covariance' must be a 24 x 24 matrix .* got 23 x 23"),
    "unknown_name": ({"format": FORMAT, "parameters": ["camera_f", *COVARIANCE_PARAMETERS[1:]],
                      "covariance": COV.tolist()},
                     r"field 'parameters' must name .*unknown 'camera_f'"),
    "asymmetric": ({"format": FORMAT, "parameters": list(COVARIANCE_PARAMETERS),
                    "covariance": (COV + np.triu(np.full((24, 24), 0.1), 1)).tolist()},
                   r"'covariance' is not symmetric"),
    "negative": ({"format": FORMAT, "parameters": list(COVARIANCE_PARAMETERS),
                  "covariance": (-COV).tolist()}, r"'covariance' has a negative eigenvalue"),
    "format": ({"format": "other/2", "parameters": list(COVARIANCE_PARAMETERS),
                "covariance": COV.tolist()}, r"format must be 'scanqa-calibration-covariance"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_malformed_covariance_file_is_one_line_naming_file_and_field(files, case,
                                                                      tmp_path, capsys):
    root, _, _ = files
    content, message = BAD[case]
    bad = tmp_path / f"{case}.json"
    bad.write_text(json.dumps(content))
    with pytest.raises(InputError, match=message):
        read_covariance(bad)
    out = tmp_path / "cloud.ply"
    assert main(["annotate", str(root / "phase.npz"), "--calibration",
                 str(root / "plain.xml"), "--config", str(root / "scanner.toml"),
                 "--calibration-covariance", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and str(bad) in err
    assert not out.exists()


def test_a_table_takes_neither(tmp_path):
    with pytest.raises(InputError, match="calibration table, which carries its own"):
        load_calibration(tmp_path / "table.npz", sigma_um=5.0)


# --------------------------------------------------------------------------- step budget


def _rows(step) -> dict:
    return {c.name: c for c in step.budget.components}


def test_the_step_budget_lists_the_calibration_term_by_its_source():
    """Each step's GUM budget has one row for the calibration term, named by where the
    cloud's sigma_calibration_um comes from, with its value: 0.5 um at every point of two
    blocks taken as independent shifts gives sqrt(2) x 0.5 um (x |cos| of the line of
    sight to the block's normal, >= 0.99 here); "none" is listed at 0."""
    from scanqa.io.annotated_cloud import AnnotatedCloud
    from scanqa.qa.blocks import run_qa

    from .test_gauge import synthetic_cloud

    xyz, attrs, layout = synthetic_cloud(seed=2, sigma_um=0.01)  # 0.5 um calibration term
    want = {"table": ("calibration table", "A"),
            "covariance": ("calibration term (covariance)", "A"),
            "stated": ("calibration term (stated)", "B"),
            "none": ("calibration term (none)", "B")}
    for kind, (name, gum) in want.items():
        a = dict(attrs)
        if kind == "none":  # what annotate writes for a calibration without a term
            a["sigma_calibration_um"] = np.zeros(len(xyz), np.float32)
        cloud = AnnotatedCloud(xyz, a, metadata={"sigma_source": {"calibration": kind}})
        for step in run_qa(cloud, layout).steps:
            rows = _rows(step)
            assert name in rows and rows[name].kind == gum, (kind, list(rows))
            others = [c for c in rows if c.startswith("calibration") and c != name]
            assert others == []
            value = rows[name].contribution_um
            if kind == "none":
                assert value == 0.0
            else:
                assert 0.99 * math.sqrt(2) * 0.5 < value <= math.sqrt(2) * 0.5 + 1e-6
            assert math.isclose(step.u_um**2, sum(c.contribution_um**2
                                                  for c in rows.values()), rel_tol=1e-12)


def test_a_covariance_carried_to_the_step_is_not_counted_twice():
    """With the calibration's covariance given (the "calibration geometry" line: the same
    covariance carried to the step with the blocks' correlation), a cloud whose term is
    that covariance has no per-point calibration row beside it; a table's own node
    error and a marker fit's geometry are two sources and keep both rows."""
    from scanqa.io.annotated_cloud import AnnotatedCloud
    from scanqa.qa.blocks import run_qa

    from .test_calibration_geometry_term import _depth_scale_term
    from .test_gauge import synthetic_cloud

    xyz, attrs, layout = synthetic_cloud(seed=2, sigma_um=0.01)
    term = _depth_scale_term(2e-5)
    cov = run_qa(AnnotatedCloud(xyz, attrs, metadata={"sigma_source": {
        "calibration": "covariance"}}), layout, calibration=term)
    table = run_qa(AnnotatedCloud(xyz, attrs, metadata={"sigma_source": {
        "calibration": "table"}}), layout, calibration=term)
    for s_cov, s_table in zip(cov.steps, table.steps, strict=True):
        names = [c.name for c in s_cov.budget.components if c.name.startswith("calibration")]
        assert names == ["calibration geometry"]
        rows = _rows(s_table)
        assert "calibration table" in rows and "calibration geometry" in rows
        assert math.isclose(s_table.u_um**2, s_cov.u_um**2
                            + rows["calibration table"].contribution_um**2, rel_tol=1e-9)
