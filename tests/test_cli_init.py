"""``scanqa init`` (a commented scanner config, optionally from an OpenCV calibration) and
the command line taking an OpenCV calibration where it takes a table."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from scanqa.calibration.parametric import check_config, load_opencv_calibration
from scanqa.cli import main
from scanqa.decoding.phasemap import save_phase_map
from scanqa.errors import ConfigError
from scanqa.io.annotated_cloud import read_cloud
from scanqa.model.config import load_config
from scanqa.qa.layout import load_layout
from tests.conftest import ROOT
from tests.synth_parametric import (
    camera_rays,
    layout_scene,
    phase_map,
    projector_pixels,
    small_scanner,
)

LAYOUT = ROOT / "calib" / "gauge_blocks_paper.toml"


@pytest.fixture(scope="module")
def rig(paper_config, tmp_path_factory):
    """The synthetic scanner's calibration written by OpenCV (YAML, with sizes)."""
    cal, cfg = small_scanner(paper_config)
    path = tmp_path_factory.mktemp("rig") / "calibration.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in {"Kc": cal.camera.matrix, "kc": cal.camera.distortion,
                       "Kp": cal.projector.matrix, "kp": cal.projector.distortion,
                       "Rp": cal.rotation, "Tp": cal.translation,
                       "frameWidth": cal.width_px, "frameHeight": cal.height_px,
                       "screenResX": cal.projector.width_px,
                       "screenResY": cal.projector.height_px}.items():
        fs.write(key, value)
    fs.release()
    return cal, cfg, path


def fill(path, **values) -> None:
    """Replace the "MEASURE" placeholders of the given keys in a config file."""
    text = path.read_text()
    for key, value in values.items():
        text, n = re.subn(rf'^{key} = "MEASURE"$', f"{key} = {value}", text, flags=re.M)
        assert n >= 1, key
    path.write_text(text)


def test_init_without_calibration_writes_placeholders(tmp_path, capsys):
    out = tmp_path / "scanner.toml"
    assert main(["init", str(out)]) == 0
    text = out.read_text()
    n = len(re.findall(r'^\w+ = "MEASURE"$', text, flags=re.M))
    assert n == 15 and f'replace the {n} "MEASURE" placeholders' in capsys.readouterr().out
    for key in ("focal_mm", "f_number", "pixel_um", "aperture_mm", "pitch_um",
                "position_mm", "look_at_mm", "periods_px"):
        assert re.search(rf'^# .*\n{key} = "MEASURE"$', text, flags=re.M), key
    assert all(line.startswith("#") or "=" in line or line.startswith("[") or not line
               for line in text.splitlines())
    with pytest.raises(ConfigError, match=r"camera.focal_mm is still the placeholder "
                                          r"'MEASURE'.*>= 0.5 mm and <= 5000 mm"):
        load_config(out)


def test_init_from_a_calibration_agrees_with_it(rig, tmp_path):
    cal, _, path = rig
    out = tmp_path / "scanner.toml"
    assert main(["init", str(out), "--calibration", str(path), "--pixel-um", "6.5",
                 "--pitch-um", "8.8507", "--periods", "20,80"]) == 0
    fill(out, f_number="8.0", aperture_mm="8.0")
    config = load_config(out)
    check_config(load_opencv_calibration(path), config)  # sizes and pose agree
    assert (config.camera.width_px, config.projector.height_px) == (400, 800)
    # focal lengths: the config's principal distances are the calibrated f_x
    assert_allclose(config.camera.principal_distance_px, cal.camera.matrix[0, 0], rtol=1e-6)
    assert_allclose(config.projector.principal_distance_px, cal.projector.matrix[0, 0],
                    rtol=1e-6)
    # position -R^T T; look-at on the projector axis, at the axes' common perpendicular
    pos, look = np.array(config.projector.position_mm), np.array(config.projector.look_at_mm)
    assert_allclose(pos, -cal.rotation.T @ cal.translation, atol=1e-5)
    axis = cal.rotation[2]
    assert np.linalg.norm(np.cross(look - pos, axis)) < 1e-4
    foot = np.array([0.0, 0.0, config.camera.focus_mm])  # camera-axis point nearest it
    assert abs((look - foot) @ axis) < 1e-4 and abs(look[2] - foot[2]) < 1e-4
    assert_allclose(config.projector.focus_mm, np.linalg.norm(look - pos), rtol=1e-6)


def test_init_writes_the_mode_the_umask_gives(tmp_path):
    import os

    mask = os.umask(0o027)
    try:
        assert main(["init", str(tmp_path / "s.toml")]) == 0
    finally:
        os.umask(mask)
    assert (tmp_path / "s.toml").stat().st_mode & 0o777 == 0o640


def test_init_refuses_to_overwrite_and_checks_its_inputs(rig, tmp_path, capsys):
    _, _, path = rig
    out = tmp_path / "s.toml"
    out.write_text("mine")
    assert main(["init", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "mine"
    assert main(["init", str(out), "--force"]) == 0
    assert main(["init", str(tmp_path / "t.toml"), "--calibration", str(path),
                 "--pitch-um", "5000"]) == 2
    assert "check --pitch-um" in capsys.readouterr().err
    assert main(["init", str(tmp_path / "u.toml"), "--pixel-um", "-1"]) == 2
    assert "pixel_um must be > 0" in capsys.readouterr().err
    assert not (tmp_path / "t.toml").exists() and not (tmp_path / "u.toml").exists()


@pytest.fixture(scope="module")
def cli_files(rig, tmp_path_factory):
    """A config from 'scanqa init' and a noisy scan of the gauge artefact."""
    cal, _, path = rig
    folder = tmp_path_factory.mktemp("cli")
    config = folder / "scanner.toml"
    assert main(["init", str(config), "--calibration", str(path), "--pixel-um", "6.5",
                 "--pitch-um", "8.8507", "--periods", "20,80"]) == 0
    fill(config, f_number="8.0", aperture_mm="8.0")
    q = layout_scene(camera_rays(cal), 469.05, load_layout(LAYOUT).blocks)
    xp = projector_pixels(cal, q)[..., 0] + np.random.default_rng(1).normal(0, 0.02,
                                                                             q.shape[:2])
    save_phase_map(folder / "scan.npz", phase_map(xp, np.full(xp.shape, 0.02), 20.0, 1280))
    return folder, config, path


@pytest.mark.parametrize("spelling", ["--calibration", "--table"])
def test_annotate_takes_an_opencv_calibration(cli_files, spelling, capsys):
    folder, config, path = cli_files
    out = folder / f"cloud{spelling}.ply"
    assert main(["annotate", str(folder / "scan.npz"), spelling, str(path), "--config",
                 str(config), "--out", str(out)]) == 0, capsys.readouterr().err
    cloud = read_cloud(out)
    assert cloud.xyz.shape == (400 * 300, 3)
    assert np.all(cloud.attributes["sigma_calibration_um"] == 0)
    table = cloud.metadata["table"]
    assert table["kind"] == "parametric" and table["calibration"] == str(path)
    assert np.median(cloud.xyz[:, 2]) == pytest.approx(469.05, abs=0.01)  # the base plane


def test_qa_takes_an_opencv_calibration(cli_files, capsys, tmp_path):
    folder, config, path = cli_files
    assert main(["qa", str(folder / "scan.npz"), "--calibration", str(path), "--config",
                 str(config), "--layout", str(LAYOUT), "--out", str(tmp_path / "qa"),
                 "--depth-range-mm", "400,500"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert out.count(", ok") == 8 and out.count(": pass") >= 5 and ": fail" not in out


def test_cli_mismatch_is_one_line(cli_files, capsys, tmp_path):
    folder, config, path = cli_files
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(config.read_text().replace("height_px = 800", "height_px = 768"))
    assert main(["annotate", str(folder / "scan.npz"), "--calibration", str(path),
                 "--config", str(wrong), "--out", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("scanqa: ") and err.count("\n") == 1
    assert "screenResX x screenResY is 1280 x 800 but the projector is 1280 x 768" in err
    assert main(["annotate", str(folder / "scan.npz"), "--calibration", str(path),
                 "--config", str(config), "--out", str(tmp_path / "c.ply"),
                 "--depth-range-mm", "500"]) == 2
    assert "NEAR,FAR" in capsys.readouterr().err
