"""Characterisations refuse what fits nothing (:mod:`scanqa.characterization.checks`): board
poses named by their folder, a pose or repeat given twice, a calibration whose scale
disagrees with the config, and repeats that are not one static scene - each refused in
one line that names the pose, the repeat or the frame. Repeats are the simulated sample
data's three captures of the gauge-block scene, altered on disk here."""

from __future__ import annotations

import shutil
import types

import cv2
import numpy as np
import pytest

from scanqa.characterization.checks import check_scale, pose_keys
from scanqa.cli import main
from scanqa.cli.characterize import board_notice
from scanqa.errors import InputError
from scanqa.model.config import load_config
from tests.conftest import ROOT
from tests.realdata import SLSTUDIO

REPEATS = ROOT / "sample_data" / "gauge_blocks"


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return str(path)


def test_poses_are_named_by_their_folder(tmp_path):
    """pose1/phase.npz pose3/phase.npz calseq4.npz are three poses (main fitted two: the
    first two were both "phase.npz"); five poseN/phase.npz are five."""
    given = [_touch(tmp_path / "pose1" / "phase.npz"), _touch(tmp_path / "pose3" / "phase.npz"),
             _touch(tmp_path / "calseq4.npz")]
    assert list(pose_keys(given)) == ["pose1", "pose3", "calseq4"]
    five = [_touch(tmp_path / f"pose{k}" / "phase.npz") for k in range(1, 6)]
    assert list(pose_keys(five)) == [f"pose{k}" for k in range(1, 6)]
    (tmp_path / "folder").mkdir()
    assert list(pose_keys([str(tmp_path / "folder") + "/", given[0]])) == ["folder", "pose1"]


def test_a_pose_given_twice_or_two_poses_of_one_name_are_refused(tmp_path):
    one = _touch(tmp_path / "pose1" / "phase.npz")
    with pytest.raises(InputError, match="is given twice"):
        pose_keys([one, str(tmp_path / "pose1" / ".." / "pose1" / "phase.npz")])
    other = _touch(tmp_path / "b" / "pose1" / "phase.npz")
    with pytest.raises(InputError, match="both named 'pose1'"):
        pose_keys([one, other])


def test_board_rows_by_columns_like_calibrate():
    assert board_notice(9, 13) == ""
    note = board_notice(13, 9)
    assert "ROWSxCOLS" in note and "COLSxROWS before" in note and "\n" not in note


def test_a_calibration_ten_times_too_small_is_refused():
    """A calibration made with --square-mm 1 for a 10 mm board: its baseline is 10x short of
    the config's projector position (164.5 mm in calib/slstudio_example.toml)."""
    config = load_config(ROOT / "calib" / "slstudio_example.toml")
    true = np.array(config.projector.position_mm)
    check_scale(types.SimpleNamespace(translation=true * 1.05), config)
    with pytest.raises(InputError, match=r"0\.1x .*wrong square size") as err:
        check_scale(types.SimpleNamespace(translation=true / 10), config, "cal.xml")
    assert str(err.value).startswith("cal.xml: its baseline is 16.45 mm")
    if (SLSTUDIO / "calibration" / "calibration.xml").is_file():
        from scanqa.calibration.parametric import load_opencv_calibration

        check_scale(load_opencv_calibration(SLSTUDIO / "calibration" / "calibration.xml"),
                    config)  # the scanner's own calibration agrees with its config


def _copy(tmp_path, name, change=None, files=None):
    """A copy of repeat p000_r1 with ``change`` applied to each image (or to ``files``)."""
    folder = tmp_path / name
    shutil.copytree(REPEATS / "p000_r1", folder)
    for png in sorted(folder.glob("*.png")):
        if change is not None and (files is None or png.name in files):
            img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(png), change(img).astype(img.dtype))
    return str(folder)


def _refused(capsys, tmp_path, scans) -> str:
    code = main(["characterize", "repeats", *scans, "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.strip().splitlines()
    # the decoder's own warnings (a black frame in a set) may precede the one refusal
    errors = [line for line in lines if not line.startswith("scanqa: warning:")]
    assert code == 2 and "Traceback" not in "\n".join(lines) and len(errors) == 1, lines
    assert not (tmp_path / "out").exists()
    return errors[0]


def test_the_same_folder_twice_is_refused(tmp_path, capsys):
    first = str(REPEATS / "p000_r0")
    assert "is given twice" in _refused(capsys, tmp_path, [first, first])
    copy = _copy(tmp_path, "copy_of_r0")  # a copy of r1 under another name
    err = _refused(capsys, tmp_path, [str(REPEATS / "p000_r1"), copy])
    assert "hold the same images" in err


def test_a_shifted_or_other_scene_is_refused_naming_the_repeat(tmp_path, capsys):
    shifted = _copy(tmp_path, "shifted", lambda im: np.roll(im, 1, axis=1))
    err = _refused(capsys, tmp_path, [str(REPEATS / "p000_r0"), shifted])
    assert "repeat " + shifted + " is not the same scene" in err
    assert "(dy, dx) = (0, 1) px" in err
    other = _copy(tmp_path, "flipped", lambda im: im[::-1].copy())
    assert "not the same scene" in _refused(capsys, tmp_path,
                                            [str(REPEATS / "p000_r0"), other])


def test_black_frames_are_refused_naming_the_frame(tmp_path, capsys):
    dark = _copy(tmp_path, "one_dark", lambda im: 0 * im, files={"p80_01.png"})
    err = _refused(capsys, tmp_path, [str(REPEATS / "p000_r0"), dark])
    assert err.split(": ")[1].endswith("one_dark/p80_01.png") and "black or missing" in err
    black = _copy(tmp_path, "black", lambda im: 0 * im)
    err = _refused(capsys, tmp_path, [str(REPEATS / "p000_r0"), black,
                                      str(REPEATS / "p000_r2")])
    assert "/black/" in err and "black or missing frame" in err
