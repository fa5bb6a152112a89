"""Scanner configs: loading, profiles and one clear error per invalid value."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from scanqa.errors import ConfigError
from scanqa.model.config import ScannerConfig, config_from_dict, load_config

from .conftest import PAPER_CONFIG, paper_config_text


def _base() -> str:
    return paper_config_text()


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "x.toml"
    path.write_text(text)
    return path


def test_paper_config_values(paper_config: ScannerConfig):
    assert paper_config.camera.focal_mm == 100.0
    assert paper_config.camera.f_number == 8.0
    assert paper_config.camera.aperture_mm == 12.5
    assert paper_config.fringes.periods_px == (5.0, 7.0, 10.0)
    assert paper_config.model.gamma == 3.0
    assert paper_config.model.filter_floor == "none"
    assert paper_config.model.noise_reading == "power"


@pytest.mark.parametrize(("profile", "f_number", "gamma"), [("f11", 11.0, 5.0),
                                                            ("f16", 16.0, 6.0)])
def test_profiles_reach_fig3_settings(profile, f_number, gamma):
    cfg = load_config(PAPER_CONFIG, profile=profile)
    assert (cfg.camera.f_number, cfg.model.gamma) == (f_number, gamma)
    same = load_config(f"{PAPER_CONFIG}#{profile}")
    assert same.camera == cfg.camera and same.profile == profile


def test_config_is_frozen(paper_config):
    with pytest.raises(AttributeError):
        paper_config.camera.focal_mm = 50.0  # type: ignore[misc]


BAD_VALUES = [
    ("focal_mm = 100.0", "focal_mm = -25.0",
     r"camera\.focal_mm must be >= 0\.5 mm and <= 5000 mm, got -25\.0"),
    ("focal_mm = 100.0", "focal_mm = 0.0",
     r"camera\.focal_mm must be >= 0\.5 mm and <= 5000 mm, got 0\.0"),
    ("f_number = 8.0", "f_number = 0", r"camera\.f_number must be >= 0\.5 and <= 256, got 0"),
    ("pixel_um = 8.0", "pixel_um = -8.0",
     r"camera\.pixel_um must be >= 0\.1 um and <= 1000 um, got -8\.0"),
    ("focus_mm = 450.0", "focus_mm = 90.0",
     r"camera\.focus_mm must be > camera\.focal_mm = 100 mm .*got 90\.0"),
    ("pitch_um = 8.8507", "pitch_um = 0.0",
     r"projector\.pitch_um must be >= 0\.1 um and <= 1000 um, got 0\.0"),
    ("periods_px = [5.0, 7.0, 10.0]", "periods_px = [5.0, -7.0]",
     r"fringes\.periods_px\[1\] must be >= 2 px and <= 1e\+07 px, got -7\.0"),
    # physical ranges (issue 45): a period of 1e-9 px made every sigma NaN, gamma = 1e9 a
    # sigma of 3.3e9 um, both with exit 0
    ("periods_px = [5.0, 7.0, 10.0]", "periods_px = [1e-9]",
     r"fringes\.periods_px\[0\] must be >= 2 px and <= 1e\+07 px, got 1e-09"),
    ("gamma = 3.0", "gamma = 1e9", r"model\.gamma must be >= 1 and <= 1000, got 1000000000\.0"),
    ("gamma = 3.0", "gamma = 0.5", r"model\.gamma must be >= 1 and <= 1000, got 0\.5"),
    ("width_px = 2448", "width_px = 24.5", r"camera\.width_px must be a whole number"),
    ("focal_mm = 100.0", 'focal_mm = "100"', r"camera\.focal_mm must be a number"),
    ('filter_floor = "none"', 'filter_floor = "half"',
     r"model\.filter_floor must be one of 'none', 'one', 'smooth', got 'half'"),
    ("position_mm = [140.0, 0.0, 0.0]", "position_mm = [140.0, 0.0]",
     r"projector\.position_mm must be a list of 3 numbers"),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD_VALUES)
def test_each_bad_value_names_key_value_and_file(tmp_path, old, new, message):
    text = _base()
    assert old in text
    path = _write(tmp_path, text.replace(old, new, 1))
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_unknown_key(tmp_path):
    path = _write(tmp_path, _base().replace("f_number = 8.0", "f_number = 8.0\nfnumber = 8", 1))
    with pytest.raises(ConfigError, match=r"unknown key camera\.fnumber .*x\.toml"):
        load_config(path)


def test_unknown_table(tmp_path):
    path = _write(tmp_path, _base() + "\n[lens]\nfocal_mm = 1.0\n")
    with pytest.raises(ConfigError, match=r"unknown table or key 'lens'"):
        load_config(path)


def test_missing_key(tmp_path):
    path = _write(tmp_path, _base().replace("pixel_um = 8.0\n", "", 1))
    with pytest.raises(ConfigError, match=r"missing key camera\.pixel_um \(expected >= 0\.1 "
                       r"um and <= 1000 um\)"):
        load_config(path)


def test_missing_table():
    with pytest.raises(ConfigError, match=r"missing table \[camera\] \(in mem\)"):
        config_from_dict({"projector": {}}, source="mem")


def test_unknown_profile_and_bad_profile_key(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown profile 'f22' .*f11, f16"):
        load_config(PAPER_CONFIG, profile="f22")
    path = _write(tmp_path, _base() + "\n[profiles.bad]\ncamera.fnumber = 2.0\n")
    with pytest.raises(ConfigError, match=re.escape("unknown key camera.fnumber in "
                                                    "[profiles.bad]")):
        load_config(path)


def test_invalid_profile_value_is_caught(tmp_path):
    path = _write(tmp_path, _base() + "\n[profiles.neg]\ncamera.f_number = -1.0\n")
    with pytest.raises(ConfigError,
                       match=r"camera\.f_number must be >= 0\.5 and <= 256, got -1\.0"):
        load_config(path, profile="neg")


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match=r"cannot read scanner config .*nope\.toml"):
        load_config(tmp_path / "nope.toml")
    path = _write(tmp_path, "[camera\nfocal_mm = 1")
    with pytest.raises(ConfigError, match=r"x\.toml is not valid TOML"):
        load_config(path)


def test_to_dict_round_trip(paper_config):
    data = paper_config.to_dict()
    again = config_from_dict(data, source="roundtrip")
    assert again.camera == paper_config.camera
    assert again.projector == paper_config.projector
    assert again.model == paper_config.model


def test_projector_rotation_is_orthonormal_and_aims_at_look_at(paper_config):
    import numpy as np

    rot = paper_config.projector.rotation
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, rtol=1e-14)
    target = np.subtract(paper_config.projector.look_at_mm, paper_config.projector.position_mm)
    np.testing.assert_allclose(rot @ target, [0, 0, np.linalg.norm(target)], atol=1e-12)
