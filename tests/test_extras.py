"""A command that needs an optional extra refuses at once, naming the pip command.

Each is given inputs that do not exist: refused for the missing extra, not for the
inputs, shows the check comes before any work (nothing read, no output folder made).
"""

from __future__ import annotations

import sys

import pytest

from scanqa.cli import main

from .conftest import PAPER_CONFIG


@pytest.mark.parametrize(("modules", "argv", "extra"), [
    (["weasyprint"], ["qa", "nope.ply", "--layout", "nope.toml", "--pdf", "--out", "OUT"],
     "pdf"),
    (["pyarrow", "fastparquet"], ["annotate", "nope.npz", "--table", "nope.npz", "--config",
                                   str(PAPER_CONFIG), "--out", "OUT.parquet"], "parquet"),
    (["plotly"], ["design", "page", "--config", "nope.toml", "--no-browser"], "design"),
    (["distributed"], ["batch", "nope*", "--calibration", "nope.npz", "--config", "nope.toml",
                       "--out", "OUT", "--scheduler", "tcp://127.0.0.1:1"], "cluster"),
])
def test_a_missing_extra_is_named_before_any_work(modules, argv, extra, monkeypatch,
                                                   tmp_path, capsys):
    for name in modules:
        monkeypatch.setitem(sys.modules, name, None)  # as if not installed
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"pip install 'scanqa[{extra}]'" in err and "nope" not in err, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # no output started


CALIB_COMMANDS = [
    ["annotate", "nope.npz", "--calibration", "nope.xml", "--config", str(PAPER_CONFIG),
     "--out", "OUT.ply"],
    ["calibrate", "nope1", "nope2", "--board", "9x13", "--square-mm", "10", "--patterns",
     "nope_c.toml", "nope_r.toml", "--out", "OUT.xml"],
    ["characterize", "board", "nope1", "nope2", "--calibration", "nope.yml", "--config",
     "nope.toml", "--board", "9x13", "--out", "OUT"],
    ["init", "--calibration", "nope.json", "OUT.toml"],
]


@pytest.mark.parametrize("argv", CALIB_COMMANDS, ids=lambda a: a[0])
def test_opencv_paths_name_the_calib_extra_before_any_work(argv, monkeypatch, tmp_path,
                                                           capsys):
    """OpenCV is the calib extra: what needs it (FileStorage files, the board's corner
    detector and solvers) refuses at once without it, like the extras above."""
    monkeypatch.setitem(sys.modules, "cv2", None)  # as if not installed
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "pip install 'scanqa[calib]'" in err and "nope" not in err, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_opencv_api_paths_name_the_calib_extra(monkeypatch, tmp_path):
    import numpy as np

    import scanqa
    from scanqa.calibration.sweep import marker_geometry
    from scanqa.errors import InputError
    from scanqa.io.opencv import (
        OpenCVCalibration,
        read_opencv_calibration,
        write_opencv_calibration,
    )

    monkeypatch.setitem(sys.modules, "cv2", None)
    monkeypatch.chdir(tmp_path)
    eye = np.eye(3)
    calls = [lambda: read_opencv_calibration("nope.xml"),
             lambda: write_opencv_calibration("out.xml", OpenCVCalibration(
                 eye, np.zeros(5), eye, np.zeros(5), eye, np.zeros(3))),
             lambda: scanqa.calibrate_board(["nope1", "nope2"], ("a.toml", "b.toml"), 10.0),
             lambda: scanqa.characterize_board(["nope1"], "nope.xml", "nope.toml", (9, 13)),
             lambda: marker_geometry(None, None)]
    for call in calls:
        with pytest.raises(InputError, match=r"pip install 'scanqa\[calib\]'"):
            call()
    assert list(tmp_path.iterdir()) == []
