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
