"""Annotated point clouds: values, names that survive CloudCompare, round trips, errors."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import numpy as np
import pytest

from scanqa.annotation.points import ATTRIBUTES, NORMAL_ATTRIBUTES, REPEAT_ATTRIBUTES, annotate
from scanqa.calibration.build import build_table
from scanqa.calibration.table import save_table
from scanqa.cli import main
from scanqa.decoding.phasemap import PhaseMap, save_phase_map
from scanqa.errors import InputError
from scanqa.io.cloud import read_cloud
from scanqa.io.ply import RESERVED_SUBSTRINGS, check_attribute_name
from scanqa.model import optics

from .conftest import paper_config_text
from .synth_sweep import plane_truth, small_camera, sweep

W, H = 96, 64
REQUIRE_CLIENTS = os.environ.get("SCANQA_REQUIRE_CLIENTS") == "1"


@pytest.fixture(scope="module")
def cfg(paper_config):
    return small_camera(paper_config, W, H)


@pytest.fixture(scope="module")
def table(cfg):
    return build_table(sweep(cfg, np.arange(430.0, 470.1, 2.0), seed=2), cfg)[0]


def scan(cfg, z=447.0, sigma=0.02, seed=0, nan_rows=0):
    xp, q = plane_truth(cfg, z)
    rng = np.random.default_rng(seed)
    shape = xp.shape
    xp = xp + rng.normal(0, sigma, shape)
    xp[:nan_rows] = np.nan
    mask = np.zeros(shape, np.uint8)
    mask[:nan_rows] = 2  # low modulation
    pm = PhaseMap(xp=xp, modulation=np.full(shape, 400.0),
                  offset=np.full(shape, 900.0), mask=mask,
                  sigma_xp=np.full(shape, sigma), period_px=5.0, projector_width_px=1280)
    return pm, q


def test_points_and_sigmas_are_consistent(cfg, table):
    pm, q = scan(cfg, sigma=0.0)
    cloud = annotate(pm, table, cfg)
    assert cloud.counts["written"] == W * H
    err = cloud.xyz - q.reshape(-1, 3)
    # the table was built from a noisy sweep: sub-um RMS, a few um at extrapolated corners
    assert np.sqrt(np.mean(err**2)) < 1e-3 and np.abs(err).max() < 5e-3
    a = cloud.attributes
    # sigma_model is Eq. 18 with the table's slope as s_T
    pred = optics.predict(cloud.xyz, cfg, s_t=a["s_t_um_px"].astype(float) * 1e-3)
    np.testing.assert_allclose(a["sigma_model_um"], 1e3 * pred.sigma, rtol=1e-5)
    # components along the line of sight add up to the total
    comp = np.sqrt(a["sx_um"] ** 2 + a["sy_um"] ** 2 + a["sz_um"] ** 2)
    np.testing.assert_allclose(comp, a["sigma_model_um"], rtol=1e-5)
    np.testing.assert_allclose(a["sigma_total_um"], np.hypot(a["sigma_model_um"],
                                                             a["sigma_calibration_um"]), rtol=1e-5)
    assert set(a) == set(ATTRIBUTES + NORMAL_ATTRIBUTES)


def test_repeats_give_measured_std(cfg, table):
    sigma_xp = 0.03
    scans = [scan(cfg, sigma=sigma_xp, seed=s)[0] for s in range(12)]
    cloud = annotate(scans[0], table, cfg, repeats=scans[1:])
    a = cloud.attributes
    assert set(REPEAT_ATTRIBUTES) <= set(a) and (a["n_repeats"] == 12).all()
    expected = a["s_t_um_px"] * sigma_xp  # s_T x phase noise, along the ray [um]
    ratio = a["sigma_meas_um"] / expected
    # 12 repeats: the std of one estimate is ~21 %; the median over 6144 pixels is tight
    assert abs(np.median(ratio) - 1.0) < 0.03
    np.testing.assert_allclose(np.median(a["sigma_phase_um"] / expected), 1.0, rtol=1e-5)


def test_attribute_names_survive_cloudcompare():
    for name in ATTRIBUTES + REPEAT_ATTRIBUTES:
        check_attribute_name(name)
        low = name.lower()
        assert not any(bad in f"scalar_{low}" for bad in RESERVED_SUBSTRINGS)
        # M3C2 precision maps pick fields containing sx/sy/sz: only the three components do
        assert (("sx" in low) + ("sy" in low) + ("sz" in low)) == (low in ("sx_um", "sy_um",
                                                                           "sz_um"))
    with pytest.raises(InputError, match="'sigma_pred_um' contains 'red'"):
        check_attribute_name("sigma_pred_um")


@pytest.mark.parametrize("suffix", [".ply", ".csv", ".las"])
def test_round_trip_through_our_readers(cfg, table, tmp_path, suffix):
    cloud = annotate(scan(cfg)[0], table, cfg)
    path = cloud.write(tmp_path / f"c{suffix}")
    xyz, attrs, meta = read_cloud(path)
    assert meta == json.loads(json.dumps(cloud.metadata))  # the model travels with the file
    atol = 1e-4 if suffix == ".las" else 1e-9  # LAS stores 0.1 um integers
    np.testing.assert_allclose(xyz, cloud.xyz, atol=atol)
    for name, values in cloud.attributes.items():
        np.testing.assert_allclose(attrs[name], values, rtol=1e-6, err_msg=name)


def test_open3d_tensor_reader_round_trip(cfg, table, tmp_path):
    o3d = pytest.importorskip("open3d")
    cloud = annotate(scan(cfg)[0], table, cfg)
    path = cloud.write(tmp_path / "c.ply")
    pcd = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(pcd.point["positions"].numpy(), cloud.xyz)
    for name, values in cloud.attributes.items():
        if name not in NORMAL_ATTRIBUTES:
            np.testing.assert_array_equal(pcd.point[f"scalar_{name}"].numpy().ravel(), values)
    normals = np.stack([cloud.attributes[n] for n in NORMAL_ATTRIBUTES], -1)
    np.testing.assert_array_equal(pcd.point["normals"].numpy(), normals)
    legacy = o3d.io.read_point_cloud(str(path))  # the reader most Open3D code uses
    assert legacy.has_normals()
    np.testing.assert_allclose(np.asarray(legacy.normals), normals, rtol=1e-6)


def _clean_qt_env() -> dict:
    """The environment without Qt variables: importing cv2 (pulled in by the fringes test)
    points QT_QPA_PLATFORM_PLUGIN_PATH at its own plugins, which aborts CloudCompare."""
    return {k: v for k, v in os.environ.items() if not k.startswith("QT_")}


def _cloudcompare_asc(path, tmp_path):
    """Load a cloud with CloudCompare's command line and export it as ASC with header."""
    exe = shutil.which("CloudCompare")
    xvfb = shutil.which("xvfb-run")
    if not (exe and xvfb):
        if REQUIRE_CLIENTS:
            pytest.fail("CloudCompare/xvfb-run missing although make test installs them")
        pytest.skip("CloudCompare not installed (make test installs it)")
    run = subprocess.run([xvfb, "-a", exe, "-SILENT", "-NO_TIMESTAMP", "-O", str(path),
                          "-C_EXPORT_FMT", "ASC", "-ADD_HEADER", "-SAVE_CLOUDS"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         stdin=subprocess.DEVNULL, env=_clean_qt_env())
    assert run.returncode == 0, f"CloudCompare failed ({run.returncode}): {run.stderr[-2000:]}"
    asc = path.with_suffix(".asc")
    header = asc.read_text().splitlines()[0].lstrip("/").split()
    return header, np.loadtxt(asc, comments="//", ndmin=2)


def test_cloudcompare_reads_every_attribute(cfg, table, tmp_path):
    scans = [scan(cfg, seed=s)[0] for s in range(3)]
    cloud = annotate(scans[0], table, cfg, repeats=scans[1:])
    path = cloud.write(tmp_path / "cloud.ply")
    header, data = _cloudcompare_asc(path, tmp_path)
    # the grey colour and intensity of the fringe offset (tests/test_cloud_display.py)
    assert header[:6] == ["X", "Y", "Z", "R", "G", "B"] and header[-4:] == [
        "intensity", "Nx", "Ny", "Nz"]  # the normals as CloudCompare's own normals
    scalars = [n for n in cloud.attributes if n not in NORMAL_ATTRIBUTES]
    assert header[6:-4] == scalars  # every attribute, under its own name
    # the first scalar field, the one CloudCompare shows a cloud by: sigma_total
    assert header[6] == "sigma_total_um"
    # CloudCompare keeps coordinates in float32: 0.03 um resolution at 450 mm
    np.testing.assert_allclose(data[:, :3], cloud.xyz, atol=1e-4)
    # and normals compressed to one of ~2 million directions (about 1e-3 apart)
    normals = np.stack([cloud.attributes[n] for n in NORMAL_ATTRIBUTES], -1)
    np.testing.assert_allclose(data[:, -3:], normals, atol=3e-3)
    for i, name in enumerate(header[6:-4], start=6):
        np.testing.assert_allclose(data[:, i], cloud.attributes[name], rtol=1e-6,
                                   equal_nan=True, err_msg=name)


def test_cloudcompare_loads_the_csv_with_every_point(cfg, table, tmp_path):
    """The cloud CSV is a plain table (metadata in its sidecar): CloudCompare loads every
    point and every column (it names the columns Scalar_field..., its CSV reader ignores
    header names in silent mode)."""
    cloud = annotate(scan(cfg)[0], table, cfg)
    path = cloud.write(tmp_path / "cloud.csv")
    header, data = _cloudcompare_asc(path, tmp_path)
    assert header[:3] == ["X", "Y", "Z"] and len(header) == 3 + len(cloud.attributes)
    assert data.shape == (len(cloud), 3 + len(cloud.attributes))
    np.testing.assert_allclose(data[:, :3], cloud.xyz, atol=1e-4)  # float32 in CloudCompare


def _read_las_by_spec(path):
    """Independent LAS 1.4 reader (point format 7 + float extra bytes), from the spec.

    Debian 12's CloudCompare is built without LAS support and PDAL is not packaged, so
    the LAS export is checked against the ASPRS LAS 1.4 R15 layout directly, not through
    laspy (which wrote it).
    """
    import struct

    raw = path.read_bytes()
    assert raw[:4] == b"LASF" and raw[24:26] == bytes([1, 4])
    header_size, = struct.unpack_from("<H", raw, 94)
    offset_points, n_vlr = struct.unpack_from("<II", raw, 96)
    fmt, rec_len = struct.unpack_from("<BH", raw, 104)
    scale = struct.unpack_from("<3d", raw, 131)
    origin = struct.unpack_from("<3d", raw, 155)
    n_points, = struct.unpack_from("<Q", raw, 247)
    global_encoding, = struct.unpack_from("<H", raw, 6)
    assert fmt == 7 and global_encoding & 16  # bit 4: the CRS is OGC WKT
    names, descriptions, pos, wkt = [], {}, header_size, b""
    for _ in range(n_vlr):
        user = raw[pos + 2:pos + 18].rstrip(b"\0")
        rec_id, length = struct.unpack_from("<HH", raw, pos + 18)
        if user == b"LASF_Spec" and rec_id == 4:
            for d in range(length // 192):
                base = pos + 54 + 192 * d
                assert raw[base + 2] == 9  # data type 9: float
                names.append(raw[base + 4:base + 36].rstrip(b"\0").decode())
                # the description: 32 bytes after 4 + 32 + 4 + 5 x 24 bytes of the record
                descriptions[names[-1]] = raw[base + 160:base + 192].rstrip(b"\0").decode()
        if user == b"LASF_Projection" and rec_id == 2112:
            wkt = raw[pos + 54:pos + 54 + length].rstrip(b"\0")
        pos += 54 + length
    # format 7: X Y Z (3 x i4), intensity (u2), 16 bytes to the RGB (3 x u2)
    dtype = np.dtype([("xyz", "<i4", 3), ("intensity", "<u2"), ("base", "V16"),
                      ("rgb", "<u2", 3)] + [(n, "<f4") for n in names])
    assert dtype.itemsize == rec_len
    pts = np.frombuffer(raw, dtype=dtype, count=n_points, offset=offset_points)
    xyz = pts["xyz"] * np.array(scale) + np.array(origin)
    extra = {"intensity": pts["intensity"], "rgb": pts["rgb"], "descriptions": descriptions}
    return xyz, {n: pts[n] for n in names}, wkt.decode(), extra


def test_las_extra_bytes_follow_the_spec(cfg, table, tmp_path):
    cloud = annotate(scan(cfg)[0], table, cfg)
    path = cloud.write(tmp_path / "cloud.las")
    xyz, attrs, wkt, extra = _read_las_by_spec(path)
    # LAS holds metres (GIS tools assume it), on a 0.1 um integer grid
    np.testing.assert_allclose(xyz * 1e3, cloud.xyz, atol=1e-4)
    assert 'UNIT["metre",1]' in wkt and wkt.startswith("LOCAL_CS[")
    assert list(attrs) == list(cloud.attributes)
    for name, values in cloud.attributes.items():
        np.testing.assert_array_equal(attrs[name], values, err_msg=name)
    # every dimension says its unit; intensity and grey RGB follow the fringe offset
    desc = extra["descriptions"]
    assert desc["sigma_total_um"] == "sigma_total [um]" and desc["s_o"] == "s_o [-]"
    assert desc["offset_dn"] == "offset [DN]" and desc["s_t_um_px"] == "s_t [um/px]"
    off = cloud.attributes["offset_dn"].astype(float)
    np.testing.assert_allclose(extra["intensity"], np.clip(np.rint(
        off * 65535 / np.percentile(off, 99.9)), 0, 65535))
    assert (extra["rgb"] == extra["intensity"][:, None]).all()
    import laspy  # and the library most LAS users read with sees the same descriptions

    dims = laspy.read(str(path)).point_format.extra_dimensions
    described = {d.name: d.description for d in dims}
    assert described["sigma_random_um"] == "sigma_random [um]"
    assert [described[n] for n in NORMAL_ATTRIBUTES] == ["normal x [-]", "normal y [-]",
                                                          "normal z [-]"]  # extra bytes


def test_keep_invalid_and_counts(cfg, table):
    pm, _ = scan(cfg, z=480.0, nan_rows=10)  # beyond the calibrated range (430-470 mm)
    with_invalid = annotate(pm, table, cfg, keep_invalid=True)
    assert with_invalid.counts == {"written": W * H - 10 * W, "decoder_masked": 10 * W,
                                   "out_of_volume": W * H - 10 * W,
                                   "model_invalid": with_invalid.counts["model_invalid"],
                                   "kept_invalid": True}
    assert (with_invalid.attributes["in_volume"] == 0).all()
    assert annotate(pm, table, cfg).counts["written"] == 0


def test_bad_inputs(cfg, table, tmp_path, capsys):
    other = small_camera(cfg, 48, 64)
    with pytest.raises(InputError, match="is 48 x 64 px but the calibration table was built "
                                         "for a 96 x 64 px camera"):
        annotate(scan(other)[0], table, cfg)
    moved = cfg.replace_model()  # same model; change the projector pose instead
    from dataclasses import replace

    from scanqa.model.config import ScannerConfig

    proj = replace(moved.projector, position_mm=(150.0, 0.0, 0.0))
    wrong = ScannerConfig(cfg.camera, proj, cfg.fringes, cfg.model, source="wrong.toml")
    with pytest.raises(InputError, match=r"does not match the table.s: projector\.position_mm"):
        annotate(scan(cfg)[0], table, wrong)
    pm, _ = scan(cfg, nan_rows=H)
    with pytest.raises(InputError, match="no valid phase at all"):
        annotate(pm, table, cfg)
    # CLI: output in a missing folder, no half file, one line
    save_table(tmp_path / "t.npz", table)
    save_phase_map(tmp_path / "s.npz", scan(cfg)[0])
    cfg_file = tmp_path / "small.toml"
    cfg_file.write_text(paper_config_text().replace("width_px = 2448", f"width_px = {W}")
                        .replace("height_px = 2048", f"height_px = {H}"))
    code = main(["annotate", str(tmp_path / "s.npz"), "--table", str(tmp_path / "t.npz"),
                 "--config", str(cfg_file), "--out", str(tmp_path / "no" / "c.ply")])
    err = capsys.readouterr().err
    assert code == 2 and "does not exist" in err and err.count("\n") == 1
    code = main(["annotate", str(tmp_path / "s.npz"), "--table", str(tmp_path / "t.npz"),
                 "--config", str(cfg_file), "--out", str(tmp_path / "c.ply")])
    out = capsys.readouterr().out
    assert code == 0 and f"{W * H} points written" in out
    xyz, attrs, _ = read_cloud(tmp_path / "c.ply")
    assert xyz.shape == (W * H, 3) and "sigma_model_um" in attrs
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def _slope_by_differences(table, xp, h=0.01):
    """|dQ/dx_p| from central differences of the calibration [mm / projector px]."""
    up, down = table.apply_image(xp + h).xyz, table.apply_image(xp - h).xyz
    return np.linalg.norm(up - down, axis=-1).ravel() / (2 * h)


def test_sigma_source_picks_the_random_sigma(cfg, table):
    """Characterised model -> sigma_random is the model's; an assumed sigma_p -> the
    decoder's image estimate s_T sigma_xp (and a warning); a board noise law -> the law on
    each pixel's own A and B, worked out here by hand (docs/noise_model.rst)."""
    pm, _ = scan(cfg, sigma=0.03)
    s_t = _slope_by_differences(table, pm.xp)
    model = annotate(pm, table, cfg)
    a = model.attributes
    assert model.sigma_source["kind"] == "characterised"
    # this scan's own sigma_xp (0.03 px) is ~4x what the characterised model gives: the
    # cloud warns with both medians; at 0.008 px the two agree within [0.5, 2], no warning
    ratio = model.sigma_source["ratio_to_images"]
    assert ratio == pytest.approx(np.median(a["sigma_model_um"]) / np.median(
        1e3 * s_t * 0.03), rel=2e-3) and ratio < 0.5
    assert "does not fit this scan" in model.sigma_warning
    assert annotate(scan(cfg, sigma=0.008)[0], table, cfg).sigma_warning == ""
    np.testing.assert_allclose(a["sigma_random_um"], a["sigma_model_um"], rtol=1e-6)

    images = annotate(pm, table, cfg.replace_model(characterised_by=""))
    a = images.attributes
    source = images.metadata["sigma_source"]
    assert source["kind"] == "images" and "assumed" in source["warning"]
    # s_T x 0.03 px, the slope from differences of the table (rtol: float32, differences)
    np.testing.assert_allclose(a["sigma_random_um"], 1e3 * s_t * 0.03, rtol=2e-3)
    np.testing.assert_allclose(a["sigma_total_um"], np.hypot(a["sigma_random_um"],
                                                             a["sigma_calibration_um"]), rtol=1e-5)

    lawful = replace_prov(pm)
    law = cfg.replace_model(characterised_by="board test", noise_read_var_dn2=4.0,
                            noise_shot_dn=0.25, systematic_sigma_mm=0.002)
    a = annotate(lawful, table, law).attributes
    # 4 steps of period 5 px, A = 900 DN, B = 400 DN: sigma_xp = 5 / 2pi sqrt(2 (4 + 225)
    # / 4) / 400 = 0.021288 px
    sigma_xp = 5 / (2 * np.pi) * np.sqrt(2 * (4.0 + 0.25 * 900) / 4) / 400
    np.testing.assert_allclose(sigma_xp, 0.021288, rtol=1e-4)
    np.testing.assert_allclose(a["sigma_random_um"], 1e3 * s_t * sigma_xp, rtol=2e-3)
    np.testing.assert_allclose(a["sigma_total_um"], np.sqrt(
        a["sigma_random_um"].astype(float) ** 2 + a["sigma_calibration_um"].astype(float) ** 2
        + 2.0**2), rtol=1e-5)
    with pytest.raises(InputError, match="how many phase steps"):
        annotate(pm, table, law)


def replace_prov(pm):
    """The phase map with a decode provenance naming a 4-step working set."""
    from dataclasses import replace

    return replace(pm, provenance={"decode": {"chain": ["p5"]},
                                   "patterns": {"set": [{"name": "p5", "steps": 4}]}})


def test_cli_warns_when_sigma_p_is_assumed(cfg, table, tmp_path, capsys):
    """An assumed sigma_p is never silent: a warning on the console and the source in the
    cloud's header; a characterised config gives neither."""
    save_table(tmp_path / "t.npz", table)
    save_phase_map(tmp_path / "s.npz", scan(cfg, sigma=0.008)[0])  # as characterised
    text = paper_config_text().replace("width_px = 2448", f"width_px = {W}") \
        .replace("height_px = 2048", f"height_px = {H}")
    for name, body in (("char.toml", text), ("assumed.toml", "\n".join(
            line for line in text.splitlines() if not line.startswith("characterised_by")))):
        (tmp_path / name).write_text(body)
        code = main(["annotate", str(tmp_path / "s.npz"), "--table", str(tmp_path / "t.npz"),
                     "--config", str(tmp_path / name), "--out", str(tmp_path / f"{name}.ply")])
        err = capsys.readouterr().err
        header = (tmp_path / f"{name}.ply").read_bytes().split(b"end_header")[0].decode()
        assert code == 0
        if name == "char.toml":
            assert err == "" and '"kind":"characterised"' in header
        else:
            assert err.startswith("scanqa: warning: sigma_p_px = 0.006487 px in ")
            assert "is assumed" in err and err.count("\n") == 1
            assert '"kind":"images"' in header and "is assumed" in header
