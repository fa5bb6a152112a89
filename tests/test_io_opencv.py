"""OpenCV camera-projector calibration files (scanqa.io.opencv): the real SLStudio file read
against an independent XML parse, files written by OpenCV itself in every format, and one
clear error for each kind of bad file."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest
from numpy.testing import assert_array_equal

from scanqa.calibration.base import load_calibration
from scanqa.errors import InputError
from scanqa.io.opencv import is_opencv_file, read_opencv_calibration
from tests.realdata import SLSTUDIO, needs_slstudio

REAL = SLSTUDIO / "calibration" / "calibration.xml"

#: A plausible calibration (camera 640 x 480, projector 800 x 600) [px, mm].
GOOD = {
    "Kc": np.array([[900.0, 0.0, 320.0], [0.0, 905.0, 240.0], [0.0, 0.0, 1.0]]),
    "kc": np.array([[-0.1, 0.02, 0.001, -0.002, 0.003]]),
    "Kp": np.array([[1500.0, 0.0, 400.0], [0.0, 1500.0, 580.0], [0.0, 0.0, 1.0]]),
    "kp": np.array([[-0.03], [0.0], [0.0], [0.0]]),
    "Rp": cv2.Rodrigues(np.array([0.01, -0.3, 0.02]))[0],
    "Tp": np.array([[-150.0], [2.0], [40.0]]),
}
SIZES = {"frameWidth": 640, "frameHeight": 480, "screenResX": 800, "screenResY": 600}


def write_fs(path, entries: dict) -> str:
    """Write ``entries`` with OpenCV's own FileStorage writer (format by suffix)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, value)
    fs.release()
    return str(path)


@needs_slstudio
def test_real_slstudio_file_matches_an_independent_xml_parse():
    cal = read_opencv_calibration(REAL)
    root = ET.parse(REAL).getroot()

    def matrix(name):
        node = root.find(name)
        data = np.array(node.find("data").text.split(), dtype=np.float32)
        return data.reshape(int(node.find("rows").text), int(node.find("cols").text))

    for name in ("Kc", "Kp", "Rp"):
        assert_array_equal(getattr(cal, name), matrix(name))  # the file stores float32
    assert_array_equal(cal.kc, matrix("kc").ravel())
    assert_array_equal(cal.Tp, matrix("Tp").ravel())
    assert cal.sizes == {k: int(root.find(k).text) for k in SIZES}
    assert cal.errors["stereo_error"] == float(root.find("stereo_error").text)
    assert cal.Kc[0, 0] == pytest.approx(2195.12036) and cal.sizes["screenResX"] == 1824


@pytest.mark.parametrize("suffix", [".xml", ".yml", ".yaml", ".json", ".xml.gz"])
def test_every_format_opencv_writes_is_read(tmp_path, suffix):
    path = write_fs(tmp_path / f"cal{suffix}", {**GOOD, **SIZES, "stereo_error": 0.25})
    assert is_opencv_file(path)
    cal = read_opencv_calibration(path)
    assert_array_equal(cal.Kc, GOOD["Kc"])
    assert_array_equal(cal.Rp, GOOD["Rp"])
    assert_array_equal(cal.Tp, GOOD["Tp"].ravel())
    assert_array_equal(cal.kc, GOOD["kc"].ravel())
    assert_array_equal(cal.kp, [-0.03, 0, 0, 0, 0])  # 4 coefficients: k3 = 0
    assert cal.sizes == SIZES and cal.errors == {"stereo_error": 0.25}


def test_optional_keys_may_be_absent(tmp_path):
    cal = read_opencv_calibration(write_fs(tmp_path / "c.yml", GOOD))
    assert cal.sizes == {} and cal.errors == {}


def test_zero_higher_order_terms_are_accepted(tmp_path):
    kc = np.array([[-0.1, 0.02, 0.001, -0.002, 0.003, 0, 0, 0]])
    cal = read_opencv_calibration(write_fs(tmp_path / "c.yml", {**GOOD, "kc": kc}))
    assert_array_equal(cal.kc, kc.ravel()[:5])


BAD = {
    "missing matrix": ({k: v for k, v in GOOD.items() if k != "Rp"},
                       r"matrix 'Rp' or 'rotation' is missing"),
    "two names of one matrix": ({**GOOD, "cam_int": GOOD["Kc"]},
                                r"'Kc' and 'cam_int', two names of one matrix"),
    "negative stated sigma": ({**GOOD, "calibration_sigma_um": -3.0},
                              r"calibration_sigma_um must be a number >= 0 \[um\]"),
    "wrong shape": ({**GOOD, "Kc": np.eye(4)}, r"'Kc' is 4 x 4, expected 3 x 3"),
    "wrong length": ({**GOOD, "Tp": np.ones((2, 1))}, r"'Tp' is 2 x 1, expected 3 numbers"),
    "distortion length": ({**GOOD, "kp": np.ones((1, 6))},
                          r"'kp' is 1 x 6, expected a row or column of 4, 5, 8"),
    "distortion matrix": ({**GOOD, "kc": np.ones((2, 5))}, r"'kc' is 2 x 5"),
    "rational terms": ({**GOOD, "kc": np.array([[-0.1, 0, 0, 0, 0, 0.2, 0, 0]])},
                       r"rational, thin-prism or tilt terms"),
    "not finite": ({**GOOD, "Kp": np.full((3, 3), np.nan)}, r"'Kp' holds NaN"),
    "scalar": ({**GOOD, "Kc": 3.0}, r"'Kc' is not an OpenCV matrix"),
    "negative size": ({**GOOD, "frameWidth": -640}, r"frameWidth must be a positive whole"),
    "fractional size": ({**GOOD, "screenResY": 600.5}, r"screenResY must be a positive whole"),
    "text size": ({**GOOD, "frameHeight": "480"}, r"frameHeight must be .* got '480'"),
    "text error": ({**GOOD, "cam_error": "small"}, r"cam_error must be a number"),
    "negative error": ({**GOOD, "proj_error": -0.4}, r"proj_error must be a number >= 0"),
    "covariance not symmetric": ({**GOOD, "calibration_covariance": np.triu(np.ones((24, 24)))},
                                 r"'calibration_covariance' is not symmetric"),
    "covariance not positive": ({**GOOD, "calibration_covariance": np.diag(
        np.r_[np.ones(23), -1e-3])}, r"'calibration_covariance' has a negative eigenvalue"),
}


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
def test_bad_contents_give_one_clear_error(tmp_path, case, suffix):
    entries, message = BAD[case]
    path = write_fs(tmp_path / f"bad{suffix}", entries)
    with pytest.raises(InputError, match=message) as err:
        read_opencv_calibration(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize(("name", "text"), [
    ("toml.xml", "[camera]\nfocal_mm = 3\n"),
    ("empty.yml", ""),
    ("truncated.xml", '<?xml version="1.0"?>\n<opencv_storage>\n<Kc type_id="opencv-'),
    ("broken.yaml", "%YAML:1.0\nKc: !!opencv-matrix\n  rows: 3\n  cols: [\n"),
])
def test_files_that_are_not_filestorage_give_one_clear_error(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InputError, match=r"not an OpenCV FileStorage file|cannot open|is empty|"
                                         r"matrix .Kc. is missing|not a readable OpenCV matrix"):
        read_opencv_calibration(path)


def test_data_of_the_wrong_size_inside_a_matrix_is_an_error(tmp_path):
    path = tmp_path / "c.yml"
    path.write_text("%YAML:1.0\nKc: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
                    "  data: [1, 2, 3]\n")
    with pytest.raises(InputError, match=r"'Kc' is not a readable OpenCV matrix"):
        read_opencv_calibration(path)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(InputError, match=r"nope.xml does not exist"):
        read_opencv_calibration(tmp_path / "nope.xml")
    (tmp_path / "cal.txt").write_text("x")
    with pytest.raises(InputError, match=r"unknown calibration format"):
        load_calibration(tmp_path / "cal.txt")


#: The names other public projector-camera calibration tools write (io.opencv.ALIASES).
PUBLIC_NAMES = {"Kc": "cam_int", "kc": "cam_dist", "Kp": "proj_int", "kp": "proj_dist",
                "Rp": "rotation", "Tp": "translation"}


@pytest.mark.parametrize("suffix", [".xml", ".yml"])
def test_the_public_tools_names_are_read(tmp_path, suffix):
    ours = read_opencv_calibration(write_fs(tmp_path / f"ours{suffix}", {**GOOD, **SIZES}))
    other = read_opencv_calibration(write_fs(tmp_path / f"other{suffix}", {
        **{PUBLIC_NAMES[k]: v for k, v in GOOD.items()}, **SIZES}))
    for key in PUBLIC_NAMES:
        assert_array_equal(getattr(other, key), getattr(ours, key))
    assert other.stated_sigma_um is None and other.covariance is None


def test_a_stated_sigma_is_read_and_written_back(tmp_path):
    from scanqa.io.opencv import write_opencv_calibration

    cal = read_opencv_calibration(write_fs(tmp_path / "a.xml", {
        **GOOD, **SIZES, "calibration_sigma_um": 400.0}))
    assert cal.stated_sigma_um == 400.0
    back = read_opencv_calibration(write_opencv_calibration(tmp_path / "b.yml", cal))
    assert back.stated_sigma_um == 400.0
    par = load_calibration(tmp_path / "b.yml")
    assert par.calibration_term["kind"] == "stated"
    assert float(par.calibration_sigma_mm(1.0, 2.0, 3.0)) == pytest.approx(0.4)
