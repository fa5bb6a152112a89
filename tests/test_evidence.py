"""``[model] characterised_by`` names evidence, not words: a characterisation file and the
start of its sha256, checked when a config is loaded; free text, a missing file, a file
changed since and a file that is no characterisation are each refused in one line."""

from __future__ import annotations

import json

import pytest

from scanqa.cli import main
from scanqa.errors import ConfigError
from scanqa.io.fitted_model import evidence
from scanqa.model.config import load_config
from tests.conftest import ROOT

SLSTUDIO_CONFIG = ROOT / "calib" / "slstudio_example.toml"


def _config(tmp_path, line: str):
    path = tmp_path / "scanner.toml"
    path.write_text(SLSTUDIO_CONFIG.read_text().replace(
        "[model]\n", f"[model]\ncharacterised_by = {json.dumps(line)}\n", 1))
    return path


def test_free_text_is_refused_in_one_line(tmp_path, capsys):
    """The issue's case: "vendor datasheet" in a copy of calib/slstudio_example.toml made
    the skull's sigma 14x small, silently."""
    path = _config(tmp_path, "vendor datasheet")
    with pytest.raises(ConfigError, match="does not name a characterisation"):
        load_config(path)
    code = main(["design", "dof", "--config", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "vendor datasheet" in err
    assert "summary.json sha256" in err


def test_a_named_summary_is_checked_by_its_hash(tmp_path):
    summary = tmp_path / "board" / "summary.json"
    summary.parent.mkdir()
    summary.write_text(json.dumps({"kind": "board", "noise_law": {
        "read_var_dn2": 0.32, "shot_dn": 0.027, "systematic_um": 64.0}}))
    line = evidence(summary, "scanqa characterize board").replace(f"{tmp_path}/", "")
    assert line.startswith("board/summary.json sha256 ") and line.endswith(" board)")
    config = load_config(_config(tmp_path, line))  # relative to the config's folder
    assert config.model.characterised_by == f"{tmp_path.resolve()}/{line}"  # from here on
    summary.write_text(summary.read_text() + "\n")
    with pytest.raises(ConfigError, match="changed since the config named it"):
        load_config(_config(tmp_path, line))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(_config(tmp_path, line.replace("board/", "nope/")))
    other = tmp_path / "other.json"
    other.write_text("{}")
    with pytest.raises(ConfigError, match="is not a characterisation summary"):
        load_config(_config(tmp_path, evidence(other)))


def test_the_shipped_configs_name_their_evidence():
    for path, profile in ((ROOT / "calib" / "paper_scanner.toml", None),
                          (ROOT / "sample_data" / "sample_scanner.toml", None),
                          (ROOT / "sample_data" / "sample_scanner.toml", "sample")):
        config = load_config(path, profile=profile)
        assert " sha256 " in config.model.characterised_by, (path, profile)


def test_a_config_written_elsewhere_names_its_evidence_by_absolute_path(tmp_path):
    """A loaded config names its evidence by absolute path, so that the design page's
    export, or any copy of its tables, loads from any folder."""
    from scanqa.design.rig import config_toml_dict
    from scanqa.io.tomlfile import dumps_toml

    data = config_toml_dict(load_config(ROOT / "calib" / "paper_scanner.toml"))
    line = data["model"]["characterised_by"]
    assert line.startswith(str(ROOT / "calib" / "paper_scanner_fig3.json") + " sha256 ")
    path = tmp_path / "exported.toml"
    path.write_text(dumps_toml(data))
    assert load_config(path).model.characterised_by == line
