"""The geometry checks at annotation (scanqa.calibration.scan_checks) on simulated rigs.

The class a second scanner showed (issue 45), rebuilt here with the parametric model and
OpenCV's projection (tests/synth_parametric.py), the truth being the rig the scan was
projected through:

* fringes along the epipolar lines: a projector above/below the camera (a mostly
  vertical baseline) with column fringes - refused, naming s_T of both directions; a
  baseline at 70 deg from the fringe normal - warned;
* a calibration whose projector rows are in half-row units (Kp's f_y and c_y doubled,
  the panel's row count kept, as a diamond-pixel DMD's addressing): with column fringes
  most decoded pixels fall out of volume, with row fringes the depths are implausible;

and the checks stay quiet on the normal synthetic rigs (projector beside the camera with
column fringes, below it with row fringes). SLStudio's skull with its calibration.xml is
checked quiet in tests/test_realdata_parametric.py.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.calibration import scan_checks
from scanqa.calibration.parametric import Lens
from scanqa.errors import InputError
from tests.synth_parametric import camera_rays, phase_map, projector_pixels, small_scanner

Z_MM = 450.0  # the paper scanner's working distance (camera.focus_mm)


def rig(config, position_mm, orientation):
    """(calibration, config) of the paper scanner's projector moved to ``position_mm``."""
    proj = replace(config.projector, position_mm=tuple(position_mm))
    return small_scanner(replace(config, projector=proj), orientation=orientation)


def scan_of(cal, tilt: float = 0.15):
    """The decoded scan of a tilted plane through Z = 450 mm, projected by OpenCV
    through ``cal`` (the true rig); pixels whose point misses the panel are masked."""
    x, y = camera_rays(cal)
    z = Z_MM / (1.0 - tilt * x)  # the plane Z = 450 + tilt X
    uv = projector_pixels(cal, np.stack([x * z, y * z, z], -1))
    p = 0 if cal.orientation == "vertical" else 1
    sizes = (cal.projector.width_px, cal.projector.height_px)
    inside = ((uv[..., 0] >= 0) & (uv[..., 0] <= sizes[0] - 1) & (uv[..., 1] >= 0)
              & (uv[..., 1] <= sizes[1] - 1))
    xp = np.where(inside, uv[..., p], np.nan)
    return phase_map(xp, np.full(xp.shape, 0.05), 16.0, sizes[p], cal.orientation)


def half_rows(cal):
    """The same calibration with the projector's rows in half-row units (K_p's second
    row doubled), the panel's row count (screenResY) kept."""
    k = cal.projector.matrix.copy()
    k[1] *= 2.0
    return replace(cal, projector=Lens(k, cal.projector.distortion, cal.projector.width_px,
                                       cal.projector.height_px), source="half_rows.xml")


def geometry_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING
            and r.name == "scanqa.annotation.points"]


@pytest.mark.parametrize(("position", "orientation"), [
    ((140.0, 0.0, 0.0), "vertical"),     # beside the camera, column fringes
    ((0.0, 140.0, 0.0), "horizontal"),   # below it, row fringes
    ((140 * math.cos(math.radians(40)), 140 * math.sin(math.radians(40)), 0.0),
     "vertical"),                        # 40 deg off: still within the warned angle
])
def test_normal_rigs_are_quiet(paper_config, caplog, position, orientation):
    cal, cfg = rig(paper_config, position, orientation)
    scan = scan_of(cal)
    cloud = annotate(scan, cal, cfg, source="plane")
    assert geometry_warnings(caplog) == []
    assert cloud.counts["out_of_volume"] == 0
    z = cloud.xyz[:, 2]
    assert np.abs(z - Z_MM).max() < 40.0  # the simulated plane's depths


def test_fringes_along_the_epipolar_lines_are_refused(paper_config):
    """Column fringes with the projector below the camera: s_T along x_p is the
    adversary's ~20 mm/px and beyond; refused, naming both directions' s_T."""
    cal, cfg = rig(paper_config, (3.0, 140.0, 0.0), "vertical")
    s = scan_checks.fringe_sensitivity(cal, Z_MM)
    # the baseline's direction in the projector image: atan(140 / 3) from the rows
    assert s["angle_deg"] == pytest.approx(math.degrees(math.atan2(140.0, 3.0)), abs=1.0)
    assert s["s_t_mm_px"] > 10.0 and s["s_t_other_mm_px"] < 1.0
    with pytest.raises(InputError, match=r"plane: its vertical fringes run .* off the "
                       r"epipolar lines .* s_T = \d+(\.\d+)? mm of depth where horizontal "
                       r"fringes would give 0\.\d+ mm/px; scan with horizontal fringes"):
        annotate(scan_of(cal), cal, cfg, source="plane")


def test_fringes_at_70_deg_to_the_baseline_are_warned(paper_config, caplog):
    theta = math.radians(70.0)
    cal, cfg = rig(paper_config, (140 * math.cos(theta), 140 * math.sin(theta), 0.0),
                   "vertical")
    s = scan_checks.fringe_sensitivity(cal, Z_MM)
    assert 65.0 < s["angle_deg"] < 75.0
    annotate(scan_of(cal), cal, cfg, source="plane")
    (text,) = geometry_warnings(caplog)
    assert "scan with horizontal fringes" in text and f"s_T = {s['s_t_mm_px']:.3g} mm" in text


def test_projector_rows_in_half_row_units_column_fringes(paper_config, caplog):
    """x_p is right, the secondary y_p lands at twice its row: about half the decoded
    pixels are out of the panel, which the share check names with units as a cause;
    K_p's rows against the config's square pixels name the axis and the factor."""
    cal, cfg = rig(paper_config, (140.0, 0.0, 0.0), "vertical")
    scan = scan_of(cal)
    cloud = annotate(scan, half_rows(cal), cfg, source="plane")
    decoded = np.isfinite(scan.xp).sum()
    share = cloud.counts["out_of_volume"] / decoded
    assert share > 0.25
    units, volume = geometry_warnings(caplog)
    assert "projector's rows at x2.00 the config's" in units
    assert "dropped as out of volume" in units
    assert f"{100 * share:.0f} % of the decoded pixels" in volume
    assert "other units than the panel's (half or double pixels" in volume


def test_projector_rows_in_half_row_units_row_fringes(paper_config, caplog):
    """Row fringes (projector below): the coded y_p is read in the wrong units, every
    point moves (no point leaves the volume); the units check names the rows."""
    cal, cfg = rig(paper_config, (0.0, 140.0, 0.0), "horizontal")
    scan = scan_of(cal)
    cloud = annotate(scan, half_rows(cal), cfg, source="plane")
    assert np.median(cloud.xyz[:, 2]) < Z_MM - 50  # the simulated plane is at 450 mm
    (text,) = geometry_warnings(caplog)
    assert "projector's rows at x2.00" in text
    assert "decoded y_p is read in other units: every depth is off" in text


def test_depths_far_from_the_working_distance_are_warned(paper_config, caplog):
    """The scene at 450 mm, the config's camera focused at 150 mm (a config of another
    scanner's working distance): the depth check gives the share and the range."""
    cal, cfg = rig(paper_config, (140.0, 0.0, 0.0), "vertical")
    near = replace(cfg, camera=replace(cfg.camera, focus_mm=150.0))
    annotate(scan_of(cal), cal, near, source="plane")
    (text,) = geometry_warnings(caplog)
    assert "plane: 100 % of the points lie outside [75, 300] mm" in text
    assert "median 449.8 mm" in text and "camera.focus_mm = 150" in text


def test_cli_refuses_fringes_along_the_epipolar_lines_in_one_line(paper_config, tmp_path,
                                                                  capsys):
    """Through the command line, from files: exit 2, one line, no cloud written."""
    from scanqa.cli import main
    from scanqa.decoding.phasemap import save_phase_map
    from scanqa.design.rig import config_toml_dict
    from scanqa.io.opencv import OpenCVCalibration, write_opencv_calibration
    from scanqa.io.tomlfile import dumps_toml

    cal, cfg = rig(paper_config, (3.0, 140.0, 0.0), "vertical")
    sizes = {"frameWidth": cal.width_px, "frameHeight": cal.height_px,
             "screenResX": cal.projector.width_px, "screenResY": cal.projector.height_px}
    write_opencv_calibration(tmp_path / "cal.xml", OpenCVCalibration(
        cal.camera.matrix, cal.camera.distortion, cal.projector.matrix,
        cal.projector.distortion, cal.rotation, cal.translation, sizes, {}, ""))
    (tmp_path / "scanner.toml").write_text(dumps_toml(config_toml_dict(cfg)))
    save_phase_map(tmp_path / "phase.npz", scan_of(cal))
    out = tmp_path / "cloud.ply"
    assert main(["annotate", str(tmp_path / "phase.npz"), "--calibration",
                 str(tmp_path / "cal.xml"), "--config", str(tmp_path / "scanner.toml"),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("scanqa: ") and err.count("\n") == 1 and "Traceback" not in err
    assert "scan with horizontal fringes" in err and "refused" in err
    assert not out.exists()
