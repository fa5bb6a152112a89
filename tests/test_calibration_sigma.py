"""A parametric calibration's own uncertainty in every point's sigma_calibration_um / sigma_total:
annotate against a Monte Carlo over parameters drawn from the covariance (independent of
the sigma-point propagation in scanqa.calibration.uncertainty)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from scanqa.annotation.points import annotate
from scanqa.calibration.uncertainty import pack, unpack
from tests.synth_parametric import (
    camera_rays,
    layout_scene,
    phase_map,
    projector_pixels,
    small_scanner,
)


def test_calibration_covariance_reaches_every_point(paper_config):
    cal, cfg = small_scanner(paper_config, 80, 60)
    rays = camera_rays(cal)
    points = layout_scene(rays, 450.0, [])
    xp = projector_pixels(cal, points)[..., 0]
    scan = phase_map(xp, np.full(xp.shape, 0.02), cfg.fringes.working_period_px,
                     cfg.projector.width_px)
    cov = np.zeros((24, 24))
    cov[0, 0] = cov[1, 1] = 3.0**2   # camera f_x, f_y: 3 px
    cov[21, 21] = 0.3**2             # Tp x: 0.3 mm
    cal_cov = replace(cal, covariance=cov)
    cloud = annotate(scan, cal_cov, cfg)
    plain = annotate(scan, cal, cfg)
    a = cloud.attributes
    assert np.all(plain.attributes["sigma_calibration_um"] == 0)
    # Monte Carlo: 400 calibrations drawn from the covariance, the same pixels and phases
    rng = np.random.default_rng(5)
    idx = rng.choice(len(cloud), 30, replace=False)
    u, v = a["pixel_u"][idx].astype(float), a["pixel_v"][idx].astype(float)
    x = xp[v.astype(int), u.astype(int)]
    theta = pack(cal)
    ray = cloud.xyz[idx] / np.linalg.norm(cloud.xyz[idx], axis=1, keepdims=True)
    along = [np.sum(unpack(cal, theta + rng.multivariate_normal(np.zeros(24), cov))
                    .apply(u, v, x).xyz * ray, axis=1) for _ in range(400)]
    mc = np.std(along, axis=0, ddof=1)
    # 400 draws: the std is known to ~3.5 %; the propagation is linear to within that
    assert 1e3 * mc.min() > 10  # tens of um: the term is not negligible here
    np.testing.assert_allclose(a["sigma_calibration_um"][idx], 1e3 * mc, rtol=0.12)
    np.testing.assert_allclose(a["sigma_total_um"], np.sqrt(
        a["sigma_random_um"].astype(float) ** 2 + a["sigma_calibration_um"].astype(float) ** 2),
        rtol=1e-5)


def test_a_covariance_too_wide_for_its_calibration_is_named(paper_config):
    """A covariance whose one-std step makes the camera's focal length negative is not this
    calibration's: one clear error naming the covariance, not the camera matrix alone."""
    import pytest

    from scanqa.errors import InputError

    cal, _ = small_scanner(paper_config, 40, 30)
    cov = np.zeros((24, 24))
    cov[0, 0] = (2 * cal.camera.matrix[0, 0]) ** 2   # f_x's std twice f_x itself
    xp = np.full((30, 40), cal.projector.width_px / 2.0)
    with pytest.raises(InputError, match=r"calibration_covariance: one std along a principal "
                                         r"axis .* moves the calibration to an impossible one"):
        replace(cal, covariance=cov).calibration_sigma_mm(
            np.arange(40.0), np.zeros(40), xp[0])


def test_a_calibration_without_covariance_says_so_and_a_stated_sigma_is_used(paper_config):
    """Issue 42: an imported calibration with no covariance has no calibration term, and
    every cloud of it says so (sigma_source); a stated std enters every point instead."""
    cal, cfg = small_scanner(paper_config, 40, 30)
    rays = camera_rays(cal)
    xp = projector_pixels(cal, layout_scene(rays, 450.0, []))[..., 0]
    scan = phase_map(xp, np.full(xp.shape, 0.02), cfg.fringes.working_period_px,
                     cfg.projector.width_px)
    plain = annotate(scan, cal, cfg)
    source = plain.sigma_source
    assert source["calibration"] == "none"
    assert "carries no covariance" in source["calibration_warning"]
    assert "carries no covariance" in plain.sigma_warning  # what the CLI logs
    stated = annotate(scan, replace(cal, stated_sigma_mm=0.25), cfg)
    a = stated.attributes
    assert stated.sigma_source["calibration"] == "stated"
    assert stated.sigma_source["calibration_warning"] == ""
    np.testing.assert_allclose(a["sigma_calibration_um"], 250.0, rtol=1e-6)
    np.testing.assert_allclose(a["sigma_total_um"], np.sqrt(
        a["sigma_random_um"].astype(float) ** 2 + 250.0**2), rtol=1e-5)
    cov = replace(cal, covariance=np.diag(np.r_[np.ones(18) * 1e-6, np.zeros(6)]))
    assert annotate(scan, cov, cfg).sigma_source["calibration"] == "covariance"


def test_the_documented_sigma_total_formula_holds_in_a_written_cloud(paper_config, tmp_path):
    """docs/formats.rst's sigma_total_um formula, parsed term by term, recomputed from the
    attributes of a cloud written to PLY and read back, the systematic term from the
    config the cloud's metadata carries."""
    import re
    from pathlib import Path

    from scanqa.io.annotated_cloud import read_cloud

    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.rst").read_text()
    row = text[text.index("* - ``sigma_total_um``"):]
    formula = re.search(r"``sqrt\(([^`]*)\)``", row).group(1)
    terms = [t.strip() for t in formula.split("+")]
    names = [re.fullmatch(r"(\w+)\^2", t).group(1) for t in terms]
    assert names == ["sigma_random_um", "sigma_calibration_um", "systematic_um"]
    cal, cfg = small_scanner(paper_config, 40, 30)
    cfg = cfg.replace_model(systematic_sigma_mm=0.05)
    xp = projector_pixels(cal, layout_scene(camera_rays(cal), 450.0, []))[..., 0]
    scan = phase_map(xp, np.full(xp.shape, 0.02), cfg.fringes.working_period_px,
                     cfg.projector.width_px)
    path = tmp_path / "cloud.ply"
    annotate(scan, replace(cal, stated_sigma_mm=0.1), cfg).write(path)
    back = read_cloud(path)
    values = {n: back.attributes[n].astype(float) for n in names[:2]}
    values["systematic_um"] = 1e3 * back.metadata["config"]["model"]["systematic_sigma_mm"]
    expect = np.sqrt(sum(values[n] ** 2 for n in names))
    np.testing.assert_allclose(back.attributes["sigma_total_um"], expect, rtol=1e-5)
    assert values["systematic_um"] == 50.0 and np.all(values["sigma_calibration_um"] > 99)


def test_a_cloud_with_the_old_name_sigma_table_um_is_read_under_the_new_one(tmp_path):
    """Clouds written before the rename carry the calibration term as sigma_table_um:
    every reader gives it back as sigma_calibration_um, in its place and with its values;
    a file holding both names keeps the new one's values."""
    import importlib.util

    from scanqa.io.annotated_cloud import read_cloud
    from scanqa.io.cloud import write_cloud

    n = 50
    xyz = np.c_[np.arange(n, dtype=float), np.zeros(n), np.full(n, 400.0)]
    old = {"sigma_total_um": np.full(n, 30.0, np.float32),
           "sigma_table_um": np.linspace(1.0, 20.0, n).astype(np.float32),
           "sigma_random_um": np.full(n, 10.0, np.float32)}
    suffixes = [".ply", ".csv"] + [".las"] * (importlib.util.find_spec("laspy") is not None) \
        + [".e57"] * (importlib.util.find_spec("pye57") is not None)
    for suffix in suffixes:
        path = write_cloud(tmp_path / f"old{suffix}", xyz, old)
        back = read_cloud(path).attributes
        assert list(back)[:3] == ["sigma_total_um", "sigma_calibration_um",
                                  "sigma_random_um"], suffix
        np.testing.assert_allclose(back["sigma_calibration_um"], old["sigma_table_um"],
                                   rtol=1e-6)
    both = write_cloud(tmp_path / "both.ply", xyz,
                       {**old, "sigma_calibration_um": np.full(n, 7.0, np.float32)})
    back = read_cloud(both).attributes
    assert "sigma_table_um" not in back and np.all(back["sigma_calibration_um"] == 7.0)
