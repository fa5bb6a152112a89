"""``scanqa decode``: the command writes phase.npz and prints a one-line summary."""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.patternset import synthesize_images, write_pattern_set
from scanqa.decoding.phasemap import load_phase_map


def _scan(folder, fmt="png"):
    sets = (PhaseSet("p800", 800.0, 4), PhaseSet("p40", 40.0, 4))
    desc = PatternDescription(800, sets, sensor=SensorModel(bit_depth=12))
    xp = np.broadcast_to(np.linspace(1.0, 798.0, 50), (20, 50))
    offset = np.full((20, 50), 1500.0)
    offset[:, :5] = 3800.0  # saturated
    images = [np.clip(np.rint(im), 0, 4095).astype(np.uint16)
              for im in synthesize_images(desc, xp, offset, 1000.0)]
    write_pattern_set(folder, desc, images, image_format=fmt)
    return xp


def test_decode_writes_the_map_and_prints_a_summary(tmp_path, capsys):
    xp = _scan(tmp_path / "scan")
    out = tmp_path / "phase.npz"
    assert main(["decode", str(tmp_path / "scan"), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert lines[0].startswith("900 of 1000 pixels valid (90.0 %); masked: saturated 100, "
                               "low_modulation 0, inconsistent 0, out_of_range 0 -> ")
    # the sensor gives no gain and read noise: the summary says where the noise came from
    assert lines[1].startswith("noise: estimated from the images: residuals of the N-step "
                               "fits (p800, p40)")
    assert lines[2].startswith("x_p: finest set 'p40' alone (period 40 px)")
    assert lines[3].startswith("period disagreement: 'p800' - x_p median")
    assert "scanqa decode: read 8 images of 50 x 20 px (uint16)" in captured.err
    pm = load_phase_map(out)
    np.testing.assert_allclose(pm.xp[:, 5:], xp[:, 5:], atol=0.01)
    assert pm.provenance["patterns"]["set"][1]["period_px"] == 40.0
    assert pm.provenance["version"]


def test_quiet_and_toml_path(tmp_path, capsys):
    _scan(tmp_path / "scan", fmt="npz")
    out = tmp_path / "phase.npz"
    toml = tmp_path / "scan" / "patterns.toml"
    assert main(["decode", str(toml), "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert out.exists()


@pytest.mark.parametrize("breakage,match", [
    ("unknown_key", "patterns.toml: [[set]] 1: unknown key 'colour'"),
    ("missing_image", "scanqa: image file"),
    ("no_folder", "scanqa: no pattern description"),
])
def test_errors_exit_2_without_traceback_or_output(tmp_path, capsys, breakage, match):
    folder = tmp_path / "scan"
    _scan(folder)
    if breakage == "unknown_key":
        toml = folder / "patterns.toml"
        toml.write_text(toml.read_text().replace('kind = "phase"', 'kind = "phase"\ncolour = 1',
                                                 1))
    elif breakage == "missing_image":
        (folder / "p40_02.png").unlink()
    else:
        folder = tmp_path / "nowhere"
    out = tmp_path / "phase.npz"
    assert main(["decode", str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not out.exists()


def test_a_missing_response_names_the_flag_that_measures_one(tmp_path, capsys):
    """The library says how to get a response; the CLI names its own flag for it."""
    folder = tmp_path / "scan"
    _scan(folder)
    assert main(["decode", str(folder), "--response", str(tmp_path / "none.toml"),
                 "--out", str(tmp_path / "phase.npz")]) == 2
    err = capsys.readouterr().err
    assert "no projector response file" in err and "none.toml" in err
    assert "'scanqa decode SCAN --measure-response FILE' on a flat" in err
    assert "Traceback" not in err and not (tmp_path / "phase.npz").exists()


def test_help_has_an_example(capsys):
    with pytest.raises(SystemExit):
        main(["decode", "--help"])
    assert "scanqa decode scans/plane_010 --out" in capsys.readouterr().out


def test_measure_response_then_name_it_in_patterns_toml(tmp_path, capsys):
    # a projector with gamma 2.2 on a flat: the response measured on one scan corrects
    # the next one, named from patterns.toml
    sets = (PhaseSet("p800", 800.0, 4), PhaseSet("p40", 40.0, 4))
    desc = PatternDescription(800, sets, sensor=SensorModel(bit_depth=12, gain_e_per_dn=4.0,
                                                            read_noise_e=8.0))
    v, u = np.mgrid[0:40, 0:200]
    for name, x in (("flat", 3.0 + 3.9 * u + 0.05 * v), ("scan", 9.0 + 3.8 * u + 0.1 * v)):
        images = [np.clip(np.rint(im), 0, 4095).astype(np.uint16)
                  for im in synthesize_images(desc, x, 1500.0, 1000.0, gamma=2.2)]
        write_pattern_set(tmp_path / name, desc, images)
    response = tmp_path / "projector.toml"
    assert main(["decode", str(tmp_path / "flat"), "--out", str(tmp_path / "flat.npz"),
                 "--measure-response", str(response), "--quiet"]) == 0
    assert "response: 40 px x 4 steps: phase error rms" in capsys.readouterr().out
    plain = tmp_path / "plain.npz"
    assert main(["decode", str(tmp_path / "scan"), "--out", str(plain), "--quiet"]) == 0
    toml = tmp_path / "scan" / "patterns.toml"
    toml.write_text(toml.read_text().replace('response = ""', 'response = "../projector.toml"'))
    fixed = tmp_path / "fixed.npz"
    assert main(["decode", str(tmp_path / "scan"), "--out", str(fixed), "--quiet"]) == 0
    assert "projector response" in capsys.readouterr().out
    x = 9.0 + 3.8 * u + 0.1 * v
    err_plain = np.abs(load_phase_map(plain).xp - x).max()
    err_fixed = np.abs(load_phase_map(fixed).xp - x).max()
    assert err_fixed < 0.1 * err_plain, (err_fixed, err_plain)
