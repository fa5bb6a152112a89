"""One progress style (scanqa.progress) and logging through the 'scanqa' logger."""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import pytest

from scanqa import progress
from scanqa.cli import build_parser, main
from scanqa.progress import NORMAL, QUIET, Progress, configure_logging

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data"


@pytest.fixture(autouse=True)
def _restore_logger():
    logger = logging.getLogger("scanqa")
    state = (logger.level, logger.propagate, list(logger.handlers))
    yield
    logger.setLevel(state[0])
    logger.propagate = state[1]
    logger.handlers[:] = state[2]


def test_log_mode_is_one_line_per_step(capsys):
    """stderr is not a terminal (a log file): whole lines, no carriage returns."""
    configure_logging(NORMAL)
    with Progress("calibrate", 3, "scan") as bar:
        for z in (430, 440, 450):
            bar.update(1, note=f"z = {z} mm")
    err = capsys.readouterr().err
    assert err.splitlines() == ["calibrate: scan 1/3 (z = 430 mm)",
                                "calibrate: scan 2/3 (z = 440 mm)",
                                "calibrate: scan 3/3 (z = 450 mm)"]
    assert "\r" not in err


def test_fractional_steps_log_whole_ones(capsys):
    configure_logging(NORMAL)
    with Progress("simulate", 2, "scan") as bar:
        for _ in range(14):
            bar.update(1 / 7)  # tiles of a scan: sums to 1.9999999999999998
    assert capsys.readouterr().err.splitlines() == ["simulate: scan 1/2", "simulate: scan 2/2"]


def test_quiet_shows_nothing_and_unconfigured_python_too(capsys, monkeypatch):
    configure_logging(QUIET)
    with Progress("demo", 2) as bar:
        bar.update(2)
    logging.getLogger("scanqa").handlers.clear()
    logging.getLogger("scanqa").setLevel(logging.NOTSET)  # a program that set up nothing
    monkeypatch.setattr(progress, "_is_terminal", lambda: True)
    with Progress("demo", 2) as bar:
        bar.update(2)
    assert capsys.readouterr().err == ""


def test_terminal_gets_a_bar_whose_line_ends_before_an_error(capsys, monkeypatch):
    configure_logging(NORMAL)
    monkeypatch.setattr(progress, "_is_terminal", lambda: True)
    with pytest.raises(RuntimeError), Progress("calibrate", 5, "scan") as bar:
        bar.update(2)
        logging.getLogger("scanqa.x").info("a note")  # printed above the bar, not in it
        raise RuntimeError
    err = capsys.readouterr().err
    assert "\r" in err and "2/5" in err and err.endswith("\n")
    assert "\ra note\n" in err  # the bar's line is cleared, the note printed, the bar redrawn


def test_every_subcommand_takes_v_and_q():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name, parser in sub.choices.items():
        flags = {s: a.dest for a in parser._actions for s in a.option_strings}
        assert flags["-v"] == flags["--verbose"] == "verbose", name
        assert flags["-q"] == "quiet", name


def _broken_sweep(tmp_path: Path) -> Path:
    """A sweep whose third scan is a folder without a patterns.toml."""
    (tmp_path / "empty").mkdir()
    rows = [(424.0, SAMPLE / "calibration_sweep" / "p000_r0"),
            (426.0, SAMPLE / "calibration_sweep" / "p001_r0"), (428.0, tmp_path / "empty"),
            (430.0, SAMPLE / "calibration_sweep" / "p003_r0")]
    text = 'format = "scanqa-sweep/1"\n' + "".join(
        f'\n[[position]]\nz_mm = {z}\npatterns = ["{p}"]\n' for z, p in rows)
    (tmp_path / "sweep.toml").write_text(text)
    return tmp_path / "sweep.toml"


@pytest.mark.parametrize("terminal", [False, True])
def test_calibrate_error_starts_its_own_line(terminal, tmp_path, capsys, monkeypatch):
    """The error of the third scan comes after the progress of the first two, on a line
    of its own (it used to be glued to a '\\r' counter)."""
    monkeypatch.setattr(progress, "_is_terminal", lambda: terminal)
    code = main(["calibrate", str(_broken_sweep(tmp_path)), "--config",
                 f"{SAMPLE}/sample_scanner.toml#sample", "--out", str(tmp_path / "t.npz")])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.replace("\r", "\n").splitlines()
    assert lines[-1].startswith("scanqa: no pattern description"), err
    assert "2/4" in err
    if not terminal:
        assert err.splitlines()[:2] == ["calibrate: scan 1/4 (z = 424 mm)",
                                        "calibrate: scan 2/4 (z = 426 mm)"]
    assert "\nscanqa: " in err and "\r" not in err.split("\nscanqa: ")[-1]


def test_the_library_never_prints():
    """Only the command line (and progress.py) writes to stdout or stderr."""
    from tests.source_index import modules, nodes

    offenders = []
    for path in modules():  # each parsed once per process (tests/source_index.py)
        rel = path.relative_to(ROOT / "src" / "scanqa")
        if rel.parts[0] == "cli" or rel.name == "progress.py":
            continue
        for node in nodes(path, ast.Call, ast.Attribute):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "print":
                offenders.append((str(rel), node.lineno))
            if isinstance(node, ast.Attribute) and node.attr in ("stdout", "stderr") \
                    and getattr(node.value, "id", "") == "sys":
                offenders.append((str(rel), node.lineno))
    assert offenders == []
