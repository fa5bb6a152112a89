"""Sweep manifests and ``scanqa calibrate`` end to end on a small synthetic sweep."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scanqa.calibration.table import load_table
from scanqa.cli import main
from scanqa.decoding.phasemap import PhaseMap, save_phase_map
from scanqa.errors import InputError
from scanqa.io.sweep import load_sweep

from .conftest import paper_config_text
from .synth_sweep import small_camera, sweep

ZS = (440.0, 445.0, 450.0, 455.0, 460.0, 465.0)


def _phase_map(obs) -> PhaseMap:
    shape = obs.xp.shape
    return PhaseMap(xp=obs.xp, modulation=np.full(shape, 500.0), offset=np.full(shape, 1000.0),
                    mask=np.zeros(shape, np.uint8), sigma_xp=obs.sigma_xp, period_px=5.0,
                    projector_width_px=1280)


def _write_sweep(folder, cfg, zs=ZS, repeats=2, lines=None):
    obs = sweep(cfg, zs, seed=1, repeats=repeats)
    entries = []
    for k, z in enumerate(zs):
        names = []
        for r in range(repeats):
            name = f"p{k:02d}_r{r}.npz"
            save_phase_map(folder / name, _phase_map(obs[k * repeats + r]))
            names.append(name)
        entries.append(f"[[position]]\nz_mm = {z}\nphase = {json.dumps(names)}\n")
    text = 'format = "scanqa-sweep/1"\n' + "".join(lines if lines is not None else entries)
    (folder / "sweep.toml").write_text(text)
    return folder / "sweep.toml", entries


@pytest.fixture(scope="module")
def small_cfg_file(tmp_path_factory, paper_config):
    folder = tmp_path_factory.mktemp("cfg")
    text = paper_config_text().replace("width_px = 2448", "width_px = 96") \
        .replace("height_px = 2048", "height_px = 64")
    path = folder / "small.toml"
    path.write_text(text)
    return path


def test_calibrate_cli_writes_table_and_reports(tmp_path, capsys, paper_config,
                                                small_cfg_file):
    cfg = small_camera(paper_config, 96, 64)
    manifest, _ = _write_sweep(tmp_path, cfg)
    out = tmp_path / "table.npz"
    code = main(["calibrate", str(manifest), "--config", str(small_cfg_file), "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "12 scans at 6 positions" in captured.out
    table = load_table(out)
    assert (table.width_px, table.height_px) == (96, 64)
    assert table.z_range_mm == (440.0, 465.0)
    info = json.loads((tmp_path / "table_report.json").read_text())
    assert len(info["positions"]) == 12 and info["weights"] == "model"
    html = (tmp_path / "table_report.html").read_text()
    assert html.count("<img") == 2 and "Rejected samples" in html


@pytest.mark.parametrize(("edit", "message"), [
    (lambda e: e[:2], "needs at least 3 \\[\\[position\\]\\] entries, got 2"),
    (lambda e: [e[0], e[0].replace("p00", "p01"), *e[2:]], "repeats z_mm = 440.0"),
    (lambda e: [e[1], e[0], *e[2:]], "increasing z_mm: position 2 \\(z_mm = 440.0\\)"),
    (lambda e: [e[0].replace("p00_r0", "nope"), *e[1:]], "nope.npz does not exist"),
    (lambda e: [e[0].replace("z_mm = 440.0\n", ""), *e[1:]],
     r"\[\[position\]\] 1: z_mm is missing"),
    (lambda e: [e[0] + "stage = 1\n", *e[1:]], "unknown key 'stage'"),
])
def test_bad_manifests(tmp_path, paper_config, edit, message):
    cfg = small_camera(paper_config, 32, 32)
    _, entries = _write_sweep(tmp_path, cfg)
    manifest, _ = _write_sweep(tmp_path, cfg, lines=edit(entries))
    with pytest.raises(InputError, match=message):
        load_sweep(manifest)


def test_unreadable_phase_file_and_mismatched_sizes(tmp_path, capsys, paper_config,
                                                    small_cfg_file):
    cfg = small_camera(paper_config, 96, 64)
    manifest, _ = _write_sweep(tmp_path, cfg)
    (tmp_path / "p02_r1.npz").write_bytes(b"not a zip")
    code = main(["calibrate", str(manifest), "--config", str(small_cfg_file), "--out",
                 str(tmp_path / "t.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "p02_r1.npz" in err and "Traceback" not in err
    assert not (tmp_path / "t.npz").exists()  # nothing half-written
    other = small_camera(paper_config, 48, 64)
    save_phase_map(tmp_path / "p02_r1.npz", _phase_map(sweep(other, [450.0])[0]))
    code = main(["calibrate", str(manifest), "--config", str(small_cfg_file), "--out",
                 str(tmp_path / "t.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "all scans must come from one camera" in err
