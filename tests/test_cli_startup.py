"""The command line loads only the module of the subcommand it runs.

``scanqa design dof`` (then ``scanqa dof``) took 4 s of CPU to start when every
subcommand's module (and with them matplotlib, scipy.stats, numba and open3d) was
imported before parsing; the map ``scanqa.cli.COMMANDS`` names the module of each
subcommand so that ``main`` imports the one it needs. These tests hold the map to what
the modules register, and check in a fresh interpreter which heavy libraries a
table-printing command loads.
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from scanqa.cli import COMMANDS, _Parser, _SubParsers, build_parser

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_map_names_what_each_module_registers(module):
    parser = _Parser(prog="scanqa")
    parser.register("action", "parsers", _SubParsers)
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)
    importlib.import_module(module).register(sub)
    assert tuple(sub.choices) == COMMANDS[module]


def test_full_parser_lists_every_command_once():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    names = [n for commands in COMMANDS.values() for n in commands]
    assert sorted(sub.choices) == sorted(names) and len(set(names)) == len(names)


def _loaded_after(args: list[str]) -> dict:
    code = ("import json, sys\nfrom scanqa.cli import main\n"
            f"code = main({args!r})\n"
            "heavy = ('matplotlib', 'numba', 'open3d', 'scipy.stats', 'scanqa.qa', "
            "'scanqa.simulator', 'scanqa.runs', 'scanqa.characterize')\n"
            "print(json.dumps({'code': code, 'loaded': [m for m in heavy if m in sys.modules]}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_table_command_loads_no_plotting_or_other_jobs():
    got = _loaded_after(["design", "dof", "--config", str(ROOT / "calib/paper_scanner.toml"),
                         "--json"])
    assert got == {"code": 0, "loaded": []}


def test_version_loads_no_subcommand():
    code = ("import sys\nfrom scanqa.cli import main\n"
            "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.startswith('scanqa.cli.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_unknown_command_still_lists_every_command(capsys):
    from scanqa.cli import main
    with pytest.raises(SystemExit) as stop:
        main(["curv"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'curv'" in err and "'characterize'" in err and "'design'" in err


def test_at_most_fifteen_commands_in_the_pipeline_s_order():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert len(sub.choices) <= 15
    assert list(sub.choices)[:9] == ["init", "simulate", "patterns", "describe", "decode",
                                     "sweep-manifest", "calibrate", "characterize", "annotate"]


CFG = str(ROOT / "calib/paper_scanner.toml")


@pytest.mark.parametrize(("old", "new"), [
    (["dof", "--config", CFG, "--json"], "'scanqa design dof'"),
    (["curve", "--config", CFG, "--json"], "'scanqa design curve'"),
    (["volume", "--config", CFG, "--step", "8", "--json"], "'scanqa design volume'"),
    (["flatten", "--config", CFG, "--json"], "'scanqa design flatten'"),
])
def test_old_design_names_run_with_a_one_line_notice(old, new, capsys):
    from scanqa.cli import main

    assert main(old) == 0
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and f"'scanqa {old[0]}' is now {new}" in err, err
    assert main(["design", *old]) == 0  # the same output under the new name
    assert capsys.readouterr() == (out, "")


@pytest.mark.parametrize(("old", "new"), [
    (["characterize-board", "nope1", "nope2", "--calibration", "nope.xml", "--config",
      "calib/slstudio_example.toml", "--out", "o"], "'scanqa characterize board'"),
    (["characterize-repeats", "nope_a", "nope_b", "--out", "o"],
     "'scanqa characterize repeats'"),
    (["characterize", "nope_dir", "--config", "calib/paper_scanner.toml"],
     "'scanqa characterize sweep SWEEP'"),
    (["characterize", "-q", "--config", "calib/paper_scanner.toml", "nope_dir"],
     "'scanqa characterize sweep SWEEP'"),
])
def test_old_characterize_forms_run_with_a_notice(old, new, capsys, monkeypatch):
    """The old names reach the same command: the notice, then its own one-line error."""
    from scanqa.cli import main

    monkeypatch.chdir(ROOT)
    assert main(old) == 2
    notice, error = capsys.readouterr().err.splitlines()
    assert f"is now {new}" in notice and "next release" in notice, notice
    assert error.startswith("scanqa: ") and "nope" in error, error


@pytest.mark.parametrize("words", [["characterize"], ["characterize", "sweep", "x"],
                                   ["characterize", "-v", "board", "x"],
                                   ["characterize", "--help"], ["design", "dof"], ["qa"]])
def test_new_forms_pass_unchanged(words, capsys):
    from scanqa.cli import renamed

    assert renamed(list(words)) == words
    assert capsys.readouterr().err == ""
