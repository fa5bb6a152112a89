"""Nothing silent, round 2 (issue 27): the classes an independent adversary found.

Each test crafts the adversary's input in ``tmp_path`` (small, in milliseconds) and
checks the promise: one line ``scanqa: ...`` naming the file, the field and the fix, exit
2, no traceback, no allocation or decompression beyond the limit, no temporary left.
"""

from __future__ import annotations

import io
import os
import shutil
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.guard import LIMIT_VARIABLE
from scanqa.io.images import read_image, read_stack
from scanqa.io.npzfile import load_npz
from scanqa.io.tomlfile import read_toml

from .smallcases import command, write_inputs


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    return write_inputs(tmp_path_factory.mktemp("inputs"))


def one_line_error(capsys, code: int) -> str:
    """The one stderr line of a failed run (asserts the promise)."""
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln and not ln.startswith("scanqa: warning:")]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("scanqa: "), err
    return lines[0]


def _patterns(inputs, tmp_path: Path) -> Path:
    folder = tmp_path / "patterns"
    shutil.copytree(inputs["patterns"], folder)
    return folder


def _decode(folder: Path, tmp_path: Path) -> list[str]:
    (tmp_path / "out").mkdir(exist_ok=True)
    return ["decode", str(folder), "--out", str(tmp_path / "out" / "phase.npz"), "-q"]


# ------------------------------------------------------------------ TOML


@pytest.mark.parametrize("opening", ["[", "{a = "])
def test_deeply_nested_toml_is_one_error(opening, inputs, tmp_path, capsys):
    closing = "]" if opening == "[" else "}"
    config = tmp_path / "config.toml"
    config.write_text(inputs["config"].read_text() + "deep = " + opening * 400
                      + closing * 400 + "\n")
    paths = {**inputs, "config": config}
    code = main([*command("config", paths, tmp_path), "-q"])
    message = one_line_error(capsys, code)
    assert str(config) in message and "nested 400 deep" in message


def test_toml_nesting_count_skips_strings_and_comments(tmp_path):
    path = tmp_path / "a.toml"
    path.write_text('a = "' + "[" * 100 + '"  # ' + "{" * 100 + "\nb = [[1], [2]]\n"
                    "c = '''" + "[" * 50 + "'''\n")
    assert read_toml(path, "test")["b"] == [[1], [2]]


def test_a_fifo_in_place_of_a_toml_file_is_refused(tmp_path):
    fifo = tmp_path / "config.toml"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        read_toml(fifo, "scanner config")


# ------------------------------------------------------------------ images


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR declares ``width`` x ``height`` 8-bit grey pixels and whose
    image data is a few bytes (the adversary's header-only bomb)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("side", [30000, 100000])
def test_png_header_claiming_huge_dimensions(side, inputs, tmp_path, capsys):
    folder = _patterns(inputs, tmp_path)
    (folder / "p1280_00.png").write_bytes(_png_header(side, side))
    message = one_line_error(capsys, main(_decode(folder, tmp_path)))
    assert "p1280_00.png" in message
    assert not any((tmp_path / "out").iterdir())


def test_image_size_limit_is_checked_before_decoding(tmp_path, monkeypatch):
    """Below Pillow's own bomb limit, scanqa's size limit refuses before decoding."""
    path = tmp_path / "big.png"
    path.write_bytes(_png_header(4000, 4000))
    monkeypatch.setenv(LIMIT_VARIABLE, "1")
    with pytest.raises(InputError, match=r"declares 4000 x 4000 px.*SCANQA_MAX_INPUT_MB"):
        read_image(path)


def test_a_fifo_named_in_patterns_toml_does_not_block_decode(inputs, tmp_path, capsys):
    folder = _patterns(inputs, tmp_path)
    (folder / "p80_02.png").unlink()
    os.mkfifo(folder / "p80_02.png")
    message = one_line_error(capsys, main(_decode(folder, tmp_path)))  # returns at once
    assert "p80_02.png" in message and "not a regular file" in message


# ------------------------------------------------------------------ stacks and npz


def _npy_header(shape: tuple, dtype: str = "<u2") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue() + bytes(64)


def test_stack_npy_header_claiming_149_gib(tmp_path):
    path = tmp_path / "stack.npy"
    path.write_bytes(_npy_header((4, 100000, 100000), "<f4"))
    with pytest.raises(InputError, match=r"stack.npy.*declares shape \(4, 100000, 100000\)"):
        read_stack(path)


def test_stack_npz_header_claiming_149_gib(tmp_path):
    path = tmp_path / "stack.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("frames.npy", _npy_header((4, 100000, 100000), "<f4"))
    with pytest.raises(InputError, match=r"stack.npz, entry 'frames'.*declares shape"):
        read_stack(path)


def test_truncated_stack_npz(tmp_path):
    path = tmp_path / "stack.npz"
    np.savez(path, frames=np.zeros((4, 8, 8), np.uint8))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(InputError, match=r"stack\.npz: damaged or not an \.npz file"):
        read_stack(path)


@pytest.mark.parametrize("bit", [0, 6, 13])  # encrypted, strong encryption, masked header
def test_npz_entry_with_the_encrypted_flag(bit, inputs, tmp_path, capsys):
    data = bytearray(inputs["phase"].read_bytes())
    # set the flag in every local and central header
    for sig, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        start = 0
        while (start := data.find(sig, start)) >= 0:
            data[start + offset + bit // 8] |= 1 << (bit % 8)
            start += 4
    phase = tmp_path / "phase.npz"
    phase.write_bytes(bytes(data))
    out = tmp_path / "out"
    out.mkdir()
    code = main([*command("phase", {**inputs, "phase": phase}, out), "-q"])
    message = one_line_error(capsys, code)
    assert "phase.npz" in message and "encrypted" in message


def test_deflate_bomb_is_refused_before_decompression(tmp_path, monkeypatch):
    """An honest deflate stream at ~1000:1 (deflate's own limit) declaring more than the
    limit is refused from the archive's directory: nothing is decompressed."""
    monkeypatch.setenv(LIMIT_VARIABLE, "1")  # 1 MiB, so that a 4 MiB bomb suffices
    path = tmp_path / "bomb.npz"
    np.savez_compressed(path, xp=np.zeros((1024, 1024), np.float32))
    assert path.stat().st_size < 10_000
    import tracemalloc

    tracemalloc.start()
    with pytest.raises(InputError, match=r"bomb.npz: its entries declare 4194\d+ bytes"):
        load_npz(path, "phase map")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20


# ------------------------------------------------------------------ PLY, CSV, phase maps


def test_ply_metadata_holding_1e999(tmp_path, capsys):
    """json reads 1e999 as inf; the QA's re-export (allow_nan=False) raised ValueError."""
    from scanqa.io.ply import write_ply

    from .smallcases import LAYOUT_TOML, gauge_cloud

    xyz, attrs = gauge_cloud()
    path = write_ply(tmp_path / "c.ply", xyz, attrs, {"source": "tests", "gain": 1.5})
    data = path.read_bytes()
    assert data.count(b'"gain":1.5') == 1
    path.write_bytes(data.replace(b'"gain":1.5', b'"gain":1e999'))
    (tmp_path / "layout.toml").write_text(LAYOUT_TOML)
    code = main(["qa", str(path), "--layout", str(tmp_path / "layout.toml"), "--out",
                 str(tmp_path / "qa"), "-q"])
    message = one_line_error(capsys, code)
    assert "c.ply: the scanqa-meta header comment" in message and "1e999" in message
    assert not (tmp_path / "qa").exists()


def _phase_file(inputs, tmp_path: Path, **changes) -> Path:
    """The valid phase map with arrays or scalars changed, written by the file layer
    (which checks structure, not values)."""
    from scanqa.io.phasemap import ARRAYS, read_phase_file, write_phase_file

    arrays, scalars = read_phase_file(inputs["phase"])
    arrays = {k: np.array(v) for k, v in arrays.items()}
    for key, value in changes.items():
        if key in ARRAYS:
            arrays[key][3, 4] = value
        else:
            scalars[key] = value
    return write_phase_file(tmp_path / "phase.npz", arrays, **scalars)


@pytest.mark.parametrize("change, message", [
    ({"sigma_xp": -0.01}, r"sigma_xp must be >= 0 .* 1 pixels are not \(first at row 3, "
                          r"column 4: -0\.01"),
    ({"sigma_xp": np.inf}, "sigma_xp must be >= 0"),
    ({"modulation": np.inf}, "modulation must be finite"),
    ({"modulation": np.nan}, "modulation must be finite"),
    ({"offset": -np.inf}, "offset must be finite"),
    ({"orientation": "diagonal"}, "orientation must be one of vertical, horizontal, got "
                                  "'diagonal'"),
])
def test_phase_map_values_are_validated(change, message, inputs, tmp_path, capsys):
    import re

    phase = _phase_file(inputs, tmp_path, **change)
    out = tmp_path / "out"
    out.mkdir()
    code = main([*command("phase", {**inputs, "phase": phase}, out), "-q"])
    line = one_line_error(capsys, code)
    assert "phase.npz" in line and re.search(message, line), line
    assert not any(out.iterdir())


def test_cloud_csv_is_a_plain_table_with_a_metadata_sidecar(tmp_path):
    import pandas as pd

    from scanqa.io.cloud import csv_sidecar, read_cloud, write_cloud

    xyz = np.arange(30.0).reshape(10, 3)
    path = write_cloud(tmp_path / "c.csv", xyz, {"sigma_model_um": np.full(10, 4.0)},
                       {"format": "scanqa-cloud/1", "model": {"gamma": 1.0}})
    frame = pd.read_csv(path)  # a plain reader: every point, the right columns
    assert list(frame.columns) == ["x_mm", "y_mm", "z_mm", "sigma_model_um"]
    assert len(frame) == 10 and frame["z_mm"].iloc[-1] == 29.0
    assert csv_sidecar(path).name == "c.csv.json"
    assert read_cloud(path)[2]["model"] == {"gamma": 1.0}
    legacy = tmp_path / "old.csv"  # scanqa before the sidecar: a first '# scanqa-meta' line
    legacy.write_text('# scanqa-meta {"source": "old"}\n' + path.read_text())
    assert read_cloud(legacy)[2] == {"source": "old"}


def test_non_numeric_csv_cells_are_an_error(tmp_path, capsys):
    from scanqa.io.cloud import read_cloud

    path = tmp_path / "c.csv"
    path.write_text("x_mm,y_mm,z_mm,sigma_model_um,label\n1,2,3,4,a\n1,2,3,x4,b\n"
                    "1,2,,nan,c\n")
    with pytest.raises(InputError, match=r"column 'sigma_model_um', row 2 \(line 3\).*not a "
                                         "number"):
        read_cloud(path)
    path.write_text("x_mm,y_mm,z_mm,label\n1,2,3,a\n1,2,,b\n")
    xyz, attrs, _ = read_cloud(path)  # an empty cell is no value; a text column is left out
    assert np.isnan(xyz[1, 2]) and "label" not in attrs


# ------------------------------------------------------------------ layouts and blocks

_BLOCK = '\n[[block]]\nid = {id}\nnominal_height_mm = {h}\nregion_mm = {r}\n'


def _layout_text(blocks=((1, 20.0, "[-16.0, -6.0, -5.0, 5.0]"),
                         (2, 10.0, "[-5.0, 5.0, -5.0, 5.0]"),
                         (3, 5.0, "[6.0, 16.0, -5.0, 5.0]")), top: str = "") -> str:
    return ('format = "scanqa-gauge-layout/1"\n' + top
            + "".join(_BLOCK.format(id=b, h=h, r=r) for b, h, r in blocks))


@pytest.mark.parametrize("text, message", [
    (_layout_text(((2**63, 20.0, "[-16.0, -6.0, -5.0, 5.0]"),
                   (2, 10.0, "[-5.0, 5.0, -5.0, 5.0]"))),
     r"\[\[block\]\] 1 \(9223372036854775808\): id must be a whole number in "
     r"\[0, 2147483647\] \(the block's number\), got 9223372036854775808"),
    (_layout_text(((1, 1e300, "[-16.0, -6.0, -5.0, 5.0]"),
                   (2, 10.0, "[-5.0, 5.0, -5.0, 5.0]"))),
     r"\[\[block\]\] 1 \(1\): nominal_height_mm must be a finite number in \(0, 1000\] "
     r"\[mm\]"),
    (_layout_text(((1, 20.0, "[-16.0, -6.0, -5.0, 5.0]"),)), "holds one \\[\\[block\\]\\]"),
    (_layout_text(top="[base]\nregion_mm = [-45.0, 45.0, -37.5, 37.5]\nnormall = [0, 0, 1]\n"),
     r"\[base\]: unknown key 'normall' \(known: region_mm, normal\)"),
    (_layout_text(top="[base]\nnormal = [0, 0, 0]\n"), r"\[base\]: normal must be"),
    (_layout_text(top="base_z_mm = 1e300\n"), "base_z_mm must be a finite number"),
])
def test_layouts_the_adversary_wrote(text, message, inputs, tmp_path, capsys):
    import re

    layout = tmp_path / "layout.toml"
    layout.write_text(text)
    code = main(["qa", str(inputs["ply"]), "--layout", str(layout), "--out",
                 str(tmp_path / "qa"), "-q"])
    line = one_line_error(capsys, code)
    assert "layout.toml" in line and re.search(message, line), line
    assert not (tmp_path / "qa").exists()


def test_a_block_with_nine_points_is_flagged_not_decided(tmp_path):
    import json

    from scanqa.io.ply import write_ply
    from scanqa.qa.blocks import MIN_POINTS

    from .smallcases import LAYOUT_TOML, gauge_cloud

    xyz, attrs = gauge_cloud()
    inner = (np.abs(xyz[:, 0] - 11.0) < 4.0) & (np.abs(xyz[:, 1]) < 3.5)  # block 3's
    keep = xyz[:, 0] < 6.0
    keep[np.flatnonzero(inner)[:9]] = True  # nine points left on block 3
    path = write_ply(tmp_path / "c.ply", xyz[keep], {k: v[keep] for k, v in attrs.items()})
    (tmp_path / "layout.toml").write_text(LAYOUT_TOML)
    assert main(["qa", str(path), "--layout", str(tmp_path / "layout.toml"), "--out",
                 str(tmp_path / "qa"), "-q"]) in (0, 1)
    info = json.loads((tmp_path / "qa" / "summary.json").read_text())
    block = next(b for b in info["blocks"] if b["block_id"] == 3)
    assert block["n_points"] == 9 < MIN_POINTS and block["status"] == "too_few_points"
    step = next(s for s in info["steps"] if s["block_b"] == 3)
    assert step["decision"] == "not evaluated" and not step["evaluated"]
    assert any("block 3: only 9 points" in n for n in info["notes"])


# ------------------------------------------------------------------ calibration


def test_calibrate_with_one_scan_listed_at_eight_positions(inputs, tmp_path, capsys):
    """The adversary's sweep: the same phase file at 8 positions (a singular matrix in the
    per-node fit before)."""
    shutil.copy(inputs["phase"], tmp_path / "phase.npz")
    (tmp_path / "sweep.toml").write_text('format = "scanqa-sweep/1"\n' + "".join(
        f'\n[[position]]\nz_mm = {z}\nphase = ["phase.npz"]\n' for z in range(430, 470, 5)))
    code = main(["calibrate", str(tmp_path / "sweep.toml"), "--config",
                 str(inputs["config"]), "--out", str(tmp_path / "t.npz"), "-q"])
    message = one_line_error(capsys, code)
    assert "one scan is listed at two positions" in message and "435" in message
    assert not (tmp_path / "t.npz").exists()


def test_a_sweep_whose_phases_do_not_move_is_refused():
    """Not the same file but the same phases to 1e-9 px: no singular matrix, no table."""
    from dataclasses import replace

    from scanqa.calibration.build import build_table

    from .smallcases import small_config
    from .synth_sweep import sweep

    config = small_config()
    scans = list(sweep(config, np.arange(430.0, 470.1, 10.0), seed=1))
    frozen = [replace(scans[0], z_mm=s.z_mm, source=s.source, xp=scans[0].xp + 1e-9 * i)
              for i, s in enumerate(scans)]
    with pytest.raises(InputError, match="the phases barely change over the sweep's 430 to "
                                         "470 mm"):
        build_table(frozen, config, cell_px=8)


# ------------------------------------------------------------------ signals and start-up


@pytest.mark.parametrize("moment", ["file", "folder"])
def test_sigterm_just_after_a_temporary_is_made(moment, inputs, tmp_path, monkeypatch,
                                                capsys):
    """The adversary's SIGTERM lands right after the temporary exists (before, the name
    was only known once mkstemp returned: a hidden file was left)."""
    import signal

    real_open, real_mkdir = os.open, os.mkdir

    def open_then_term(path, *args, **kwargs):
        fd = real_open(path, *args, **kwargs)
        if moment == "file" and Path(path).name.startswith(".cloud.ply."):
            os.kill(os.getpid(), signal.SIGTERM)
        return fd

    def mkdir_then_term(path, *args, **kwargs):
        real_mkdir(path, *args, **kwargs)
        if moment == "folder" and Path(path).name.startswith(".scanqa-stage-"):
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(os, "open", open_then_term)
    monkeypatch.setattr(os, "mkdir", mkdir_then_term)
    out = tmp_path / "out"
    out.mkdir()
    kind = "phase" if moment == "file" else "layout"  # annotate writes a file, qa a folder
    code = main([*command(kind, inputs, out / "qa" if kind == "layout" else out), "-q"])
    assert code == 143 and "scanqa: terminated" in capsys.readouterr().err
    assert list(tmp_path.rglob("*")) == [out]  # nothing, hidden or not


def test_ctrl_c_during_start_up_is_one_line(monkeypatch, capsys):
    """KeyboardInterrupt while the command modules are imported: no traceback."""
    import importlib

    import scanqa.cli as cli

    def interrupted(name, *args):
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib, "import_module", interrupted)
    assert cli.main(["design", "dof", "--config", "x.toml"]) == 130
    assert capsys.readouterr().err == "scanqa: interrupted\n"


def test_importing_the_command_line_is_light():
    """``import scanqa.cli`` (what the console script does before main runs) imports no
    library module, so a Ctrl-C then is caught by main."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", "import sys, scanqa.cli; print(sorted(m for "
                          "m in sys.modules if m.startswith(('scanqa', 'numpy'))))"],
                         capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1]
                                                                / "src")})
    assert run.stdout.strip() == "['scanqa', 'scanqa._version', 'scanqa.cli', 'scanqa.errors']"


# ------------------------------------------------------------------ outputs and decisions


def _qa(inputs, out: Path, *extra: str) -> int:
    return main(["qa", str(inputs["ply"]), "--layout", str(inputs["layout"]), "--out",
                 str(out), *extra])


def test_the_verdict_is_on_the_console_in_the_summary_and_the_exit_status(inputs, tmp_path,
                                                                          capsys):
    import json

    code = _qa(inputs, tmp_path / "qa", "--strict")
    console = capsys.readouterr().out
    info = json.loads((tmp_path / "qa" / "summary.json").read_text())
    from scanqa.qa.verdict import EXIT_STATUS

    assert info["verdict"] in EXIT_STATUS and code == EXIT_STATUS[info["verdict"]]
    line = next(ln for ln in console.splitlines() if ln.startswith("verdict: "))
    assert line.startswith(f"verdict: {info['verdict']} (")
    assert "against T = 20 um (the default: give --tolerance)" in line  # not silent
    assert info["tolerance_um"] == 20.0 and info["tolerance_source"] == "default"
    # decision and "within U" are separate words, on the console and in the CSV
    steps = [ln for ln in console.splitlines() if ln.startswith("step ")]
    assert steps and all(": pass" in s or ": fail" in s or ": undecided" in s
                         or ": not evaluated" in s for s in steps)
    assert not any("outside U" in s or "(within U)" in s for s in steps)
    # a failing tolerance fails, in the exit status too
    code = _qa(inputs, tmp_path / "qa0", "--strict", "--tolerance", "0")
    info = json.loads((tmp_path / "qa0" / "summary.json").read_text())
    assert info["tolerance_source"] == "given" and info["verdict"] in ("FAIL", "UNDECIDED")
    assert code == EXIT_STATUS[info["verdict"]] != 0
    assert _qa(inputs, tmp_path / "qa1", "--tolerance", "0") == 0  # without --strict


def test_csv_outputs_are_quoted_and_reports_reproducible(inputs, tmp_path, monkeypatch):
    import csv

    import pandas as pd

    from scanqa.report.qa import BUDGET_COLUMNS, STEP_COLUMNS

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert _qa(inputs, tmp_path / "qa", "-q") == 0
    first = (tmp_path / "qa" / "report.html").read_bytes()
    assert _qa(inputs, tmp_path / "qa", "-q") == 0
    assert (tmp_path / "qa" / "report.html").read_bytes() == first
    assert b"2023-11-14 22:13 +0000" in first  # the date SOURCE_DATE_EPOCH gives
    budget = tmp_path / "qa" / "budget.csv"
    rows = list(csv.reader(budget.open()))
    assert len({len(r) for r in rows}) == 1  # no ragged row
    frame = pd.read_csv(budget)
    assert any("," in str(c) for c in frame["source"])  # the cells that broke it
    assert set(BUDGET_COLUMNS) <= set(frame.columns)
    assert frame["contribution_um"].dtype.kind == "f"  # not shifted into a text column
    steps = pd.read_csv(tmp_path / "qa" / "steps.csv")
    assert list(steps.columns) == list(STEP_COLUMNS)


def test_one_decision_rule_for_blocks_and_artefacts():
    import math

    from scanqa.qa import vdi2634, verdict
    from scanqa.qa.blocks import StepResult

    assert vdi2634.decide is verdict.decide
    for error_mm, u_um in ((math.nan, 1.0), (0.001, math.inf), (0.001, 1.0), (0.03, 1.0)):
        step = StepResult(1, 2, 0.0, error_mm, u_um, 2.0, 20.0)
        assert step.decision == verdict.decide(1e3 * error_mm, 2.0 * u_um, 20.0)
    assert verdict.decide(math.nan, 1.0, 20.0) == "not evaluated"


def test_a_stated_k_at_low_nu_eff_is_noted():
    from scanqa.qa.blocks import StepResult, coverage_notes
    from scanqa.qa.budget import Budget, Component, coverage_factor

    budget = Budget((Component("noise", "A", "", 1.0, "um", 1.0, 8.9),), 2.0, False, 0.0)
    step = StepResult(1, 2, 0.0, 0.0, budget.u_um, budget.k, 20.0, budget)
    (note,) = coverage_notes([step])
    assert note.startswith("step 1-2: nu_eff = 8.9, for which k = 2 covers less than 95 %")
    assert f"gives k = {coverage_factor(8.9):.3g})" in note  # 2.27 at 95 %
    wide = Budget((Component("noise", "A", "", 1.0, "um", 1.0, 200.0),), 2.0, False, 0.0)
    assert coverage_notes([StepResult(1, 2, 0.0, 0.0, 1.0, 2.0, 20.0, wide)]) == []


def test_npz_entry_with_another_compression_method(inputs, tmp_path):
    """Found by the extended fuzzer: method 14 (LZMA) with deflate data raised LZMAError."""
    data = bytearray(inputs["table"].read_bytes())
    start = 0
    while (start := data.find(b"PK\x01\x02", start)) >= 0:
        data[start + 10:start + 12] = (14).to_bytes(2, "little")
        start += 4
    path = tmp_path / "table.npz"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"table\.npz, entry .*compression method 14"):
        load_npz(path, "calibration table")
