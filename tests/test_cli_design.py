"""The design-tool CLI: output formats, plots and one-line errors."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from scanqa.cli import main

from .conftest import PAPER_CONFIG, paper_config_text

CFG = str(PAPER_CONFIG)


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_dof_json_rows(capsys):
    code, out, _ = run(capsys, "design", "dof", "--config", CFG, "--json")
    rows = json.loads(out)
    assert code == 0 and len(rows) == 60  # default: ten levels x three periods x two devices
    assert {"device", "level", "period_px", "dof_mm"} <= set(rows[0])
    cam = {(r["period_px"], r["level"]): r["dof_mm"] for r in rows if r["device"] == "camera"}
    np.testing.assert_allclose(cam[(5.0, 0.49)], 27.9, rtol=1e-3)  # Table 1


def test_dof_csv_and_plot(capsys, tmp_path):
    png = tmp_path / "dof.png"
    code, out, _ = run(capsys, "design", "dof", "--config", CFG, "--levels", "0.49",
                       "--periods", "5", "--csv", "--plot", str(png))
    rows = list(csv.DictReader(io.StringIO(out)))
    assert code == 0 and [r["device"] for r in rows] == ["camera", "projector"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_curve_json_keys_and_f11_profile(capsys):
    code, out, _ = run(capsys, "design", "curve", "--config", CFG, "--z-min", "440",
                       "--z-max", "460", "--step", "5", "--json")
    rows = json.loads(out)
    assert code == 0 and [r["z_mm"] for r in rows] == [440, 445, 450, 455, 460]
    keys = {"z_mm", "attenuation_camera", "attenuation_projector", "filter_factor", "sigma_um"}
    assert keys <= set(rows[0])
    _, out11, _ = run(capsys, "design", "curve", "--config", CFG, "--profile", "f11",
                      "--z-min", "440", "--z-max", "460", "--step", "5", "--json")
    # a smaller aperture attenuates less at the same defocus
    assert json.loads(out11)[0]["attenuation_camera"] > rows[0]["attenuation_camera"]


def test_volume_and_flatten(capsys, tmp_path):
    code, out, _ = run(capsys, "design", "volume", "--config", CFG, "--step", "4", "--json",
                       "--plot", str(tmp_path / "v.png"))
    vol = json.loads(out)
    assert code == 0 and 0 < vol["fraction"] < 1
    code, out, _ = run(capsys, "design", "flatten", "--config", CFG, "--z-min", "440",
                       "--z-max", "460", "--json", "--plot", str(tmp_path / "f.png"))
    rows = json.loads(out)
    assert code == 0 and "filter_diameter_px" in rows[0]
    assert (tmp_path / "v.png").exists() and (tmp_path / "f.png").exists()


@pytest.mark.parametrize(("argv", "message"), [
    (["design", "dof", "--config", "missing.toml"], "cannot read scanner config missing.toml"),
    (["design", "dof", "--config", CFG, "--levels", "1.5"], "attenuation level must be in (0, 1)"),
    (["design", "curve", "--config", CFG, "--z-min", "460", "--z-max", "440"],
     "z_max must be > z_min"),
    (["design", "curve", "--config", CFG, "--plot", "/nonexistent/dir/x.png"], "does not exist"),
    (["design", "dof", "--config", CFG, "--profile", "f99"], "unknown profile 'f99'"),
])
def test_bad_input_is_one_line_and_nonzero(capsys, argv, message):
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert err.startswith("scanqa: ") and message in err
    assert "Traceback" not in err and err.count("\n") == 1


def test_argparse_errors_are_short(capsys):
    with pytest.raises(SystemExit) as info:
        main(["design", "dof", "--levels", "abc", "--config", CFG])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "expected comma-separated numbers" in err and "Traceback" not in err


def test_every_subcommand_has_help_with_example(capsys):
    from scanqa.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        assert "example" in (p.epilog or ""), name


def _config_with(tmp_path, section: str, **values) -> str:
    from scanqa.io.tomlfile import dumps_toml, tomllib

    doc = tomllib.loads(paper_config_text())
    doc[section].update(values)
    path = tmp_path / "scanner.toml"
    path.write_text(dumps_toml(doc))
    return str(path)


def test_projector_focus_under_four_focal_lengths_is_one_error(capsys, tmp_path):
    # Eq. 3's square root sqrt(Z (Z - 4 f)) is undefined below 4 f: dof had ended in a
    # scipy traceback ("function value at x=471.2749 is NaN") for f_p = 450 mm
    cfg = _config_with(tmp_path, "projector", focal_mm=450.0)
    code, out, err = run(capsys, "design", "dof", "--config", cfg, "--json")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "projector.focus_mm must be >= 4 x projector.focal_mm" in err


def test_curve_default_step_follows_a_long_range(capsys, tmp_path):
    # focus at 450 m: +-10 % at 0.5 mm would be 180 001 samples (it ran past 20 s)
    cfg = _config_with(tmp_path, "camera", focus_mm=450_000.0)
    code, out, _ = run(capsys, "design", "curve", "--config", cfg, "--json")
    z = [row["z_mm"] for row in json.loads(out)]
    assert code == 0 and len(z) == 2001 and z[0] == 405_000.0
    np.testing.assert_allclose(np.diff(z), 45.0)


def test_curve_step_too_fine_names_the_option(capsys):
    code, out, err = run(capsys, "design", "curve", "--config", CFG, "--z-min", "400",
                         "--z-max", "500", "--step", "0.0001", "--json")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "1e+06 samples (at most 100001)" in err and "a step of at least 0.001 mm" in err


def test_volume_without_overlap_is_one_error_not_nan(capsys, tmp_path):
    # the projector at x = 140 aimed at (0, 0, 140) looks across the camera's axis in
    # front of the range: no voxel in both fields, and the fraction was printed as NaN
    cfg = _config_with(tmp_path, "projector", look_at_mm=[0.0, 0.0, 140.0])
    code, out, err = run(capsys, "design", "volume", "--config", cfg, "--json")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "fields do not overlap from z = 337.5 to 562.5 mm" in err
