"""The real-scanner path in the Python API (scanqa.api): exported from ``scanqa``, with
the command line's options as parameters, and the board calibration on SLStudio's real
poses writing what the command writes (the README's describe and compare examples run in
tests/test_readme.py)."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

import scanqa
from scanqa.cli import build_parser

from .realdata import SLSTUDIO, needs_slstudio

#: API function -> (command, its options the function takes under another name or not
#: at all, with why)
COMMANDS = {
    "describe": ("describe", {"folder": "folder", "force": "force"}),
    "calibrate_board": ("calibrate", {"sweep": "poses"}),
    "characterize_board": ("characterize board", {}),
    "compare": ("compare", {}),
}


def _options(command: str) -> set[str]:
    """The options of a command; of ``calibrate``, the board calibration's group and
    the poses and output (the rest is the sweep calibration's)."""
    name, *action = command.split()
    parser = build_parser(name)
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    if action:  # a command's action (characterize board)
        sub = next(a for a in sub._actions if a.dest == "action").choices[action[0]]
    actions = sub._actions
    if command == "calibrate":
        group = next(g for g in sub._action_groups if g.title.startswith("board"))
        actions = [*group._group_actions, *(a for a in sub._actions
                                           if a.dest in ("sweep", "out"))]
    return {a.dest for a in actions
            if a.dest not in ("help", "verbose", "quiet", "func", "action")}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_the_api_takes_the_commands_options(name):
    function = getattr(scanqa, name)
    params = set(inspect.signature(function).parameters)
    command, renamed = COMMANDS[name]
    for option in _options(command):
        assert renamed.get(option, option) in params, (name, option)


def test_the_path_is_exported_and_listed():
    for name in ("describe", "calibrate_board", "characterize_board",
                 "apply_characterization", "compare"):
        assert name in scanqa.__all__ and callable(getattr(scanqa, name))


@needs_slstudio
@pytest.mark.slow
def test_calibrate_board_writes_what_the_command_writes(tmp_path, monkeypatch):
    from .realdata import slstudio_board_patterns
    from .shared_runs import share_board_calibration

    # the decode and calibration the command's test runs (test_board_real), computed once
    share_board_calibration(monkeypatch)

    patterns = slstudio_board_patterns(tmp_path)
    poses = [SLSTUDIO / "calibration" / f"calseq{k}" for k in (1, 3, 6)]
    result = scanqa.calibrate_board(poses, patterns, square_mm=10, out=tmp_path / "board.xml")
    assert result.data.errors["cam_error"] < 0.4  # as the command's test (test_board_real)
    report = json.loads((tmp_path / "board_report.json").read_text())
    assert [p["pose"] for p in report["poses"]] == ["calseq1", "calseq3", "calseq6"]
    assert (tmp_path / "board_report.html").exists()
    cal = scanqa.load_opencv_calibration(tmp_path / "board.xml")
    assert cal.covariance is not None
    # its covariance file too, which load_calibration(..., covariance=) takes
    with_file = scanqa.load_calibration(tmp_path / "board.xml",
                                        covariance=tmp_path / "board_covariance.json")
    np.testing.assert_allclose(with_file.covariance, cal.covariance, rtol=1e-12, atol=0)


def test_per_pose_messages_become_one_log_line_per_step_off_a_terminal(caplog):
    """A bar in a terminal (tqdm), and in logs one line per pose with its message, as the
    board calibration and characterisation now report (scanqa.progress.step_messages)."""
    import logging

    from scanqa.progress import Progress, step_messages

    with caplog.at_level(logging.INFO, logger="scanqa"), \
            Progress("calibrate", total=2, unit="pose") as bar:
        tell = step_messages(bar)
        tell("pose calseq1: 117 of 117 corners")
        tell("pose calseq3: 117 of 117 corners")
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["calibrate: pose 1/2 (pose calseq1: 117 of 117 corners)",
                     "calibrate: pose 2/2 (pose calseq3: 117 of 117 corners)"]
