"""Nothing lost, nothing silent: every failure path of the outside audit, one test each.

The promise: a failure is one line ``scanqa: ...`` and exit 2 (no traceback), a valid
input gives a correct result, a command publishes its outputs together or not at all,
temporaries go on SIGTERM as on Ctrl-C, and files get the mode the umask gives.
Write failures that need a full or read-only disk are simulated by making the write
path raise ENOSPC/EROFS (no mount is needed); one test also fills a real 1 MiB tmpfs
where the machine allows it (root).
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io import atomic
from scanqa.io.ply import read_ply, write_ply

from .shared_runs import share_demo_characterisation, share_sweep_characterisation
from .smallcases import BLOCKS, LAYOUT_TOML, gauge_cloud, small_config, write_inputs
from .synth_sweep import sweep

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data"
#: The console script, for subprocesses.
CLI = "import sys; from scanqa.cli import main; sys.exit(main())"


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


def qa_argv(cloud: Path, layout: Path, out: Path, *extra: str) -> list[str]:
    return ["qa", str(cloud), "--layout", str(layout), "--out", str(out), "-q", *extra]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (hidden ones too) and its content."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


# ------------------------------------------------------------------ write failures


def test_output_path_that_is_a_folder(inputs, tmp_path, capsys):
    (tmp_path / "c.ply").mkdir()
    code = main(["annotate", str(inputs["phase"]), "--table", str(inputs["table"]),
                 "--config", str(inputs["config"]), "--out", str(tmp_path / "c.ply"), "-q"])
    assert "it is a folder" in one_line_error(capsys, code)
    (tmp_path / "t.npz").mkdir()
    code = main(["calibrate", str(SAMPLE / "calibration_sweep"), "--config",
                 f"{SAMPLE}/sample_scanner.toml#sample", "--out", str(tmp_path / "t.npz")])
    assert "it is a folder" in one_line_error(capsys, code)


def _no_space(monkeypatch) -> None:
    """Writing a PLY's vertices fails half way with ENOSPC, as on a full disk."""
    import scanqa.io.ply as ply

    def full(fh, *args):
        fh.write(b"\0" * 1000)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(ply, "_write_records", full)


def test_full_disk_leaves_no_partial_qa_output(inputs, tmp_path, capsys, monkeypatch):
    """The QA's fifth file (cloud_qa.ply) fails: none of the five is published, and the
    outputs of an earlier run stay as they were."""
    out = tmp_path / "qa"
    assert main(qa_argv(inputs["ply"], inputs["layout"], out)) == 0
    before = snapshot(out)
    _no_space(monkeypatch)
    line = one_line_error(capsys, main(qa_argv(inputs["ply"], inputs["layout"], out,
                                               "--margin", "0.5")))
    assert "No space left on device" in line and str(out / "cloud_qa.ply") in line
    assert snapshot(out) == before
    fresh = tmp_path / "fresh"
    one_line_error(capsys, main(qa_argv(inputs["ply"], inputs["layout"], fresh)))
    assert not fresh.exists() and [p.name for p in tmp_path.iterdir()] == ["qa"]


def test_read_only_filesystem(inputs, tmp_path, capsys, monkeypatch):
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(atomic, "_new_temp", read_only)  # every temporary file and folder
    line = one_line_error(capsys, main(qa_argv(inputs["ply"], inputs["layout"],
                                               tmp_path / "qa")))
    assert "Read-only file system" in line
    code = main(["annotate", str(inputs["phase"]), "--table", str(inputs["table"]),
                 "--config", str(inputs["config"]), "--out", str(tmp_path / "c.ply"), "-q"])
    assert "Read-only file system" in one_line_error(capsys, code)
    assert list(tmp_path.iterdir()) == []


def test_demo_and_characterize_publish_together_or_not_at_all(tmp_path, capsys, monkeypatch):
    """A failure in the demo's third stage, after the characterisation was written (or in
    characterize's plots, after its summary), leaves no folder."""
    from scanqa.report import characterization as report
    from scanqa.runs import demo

    def fail(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(demo, "calibrate", fail)
    share_demo_characterisation(monkeypatch)  # the demo's first stage, as test_demo's
    code = main(["demo", "--out", str(tmp_path / "d"), "--data", str(SAMPLE), "-q"])
    assert "No space left" in one_line_error(capsys, code)
    monkeypatch.setattr(report, "_plot", fail)
    share_sweep_characterisation(monkeypatch)  # the fit, as the manifest-config test's
    code = main(["characterize", "sweep", str(SAMPLE / "camera_sweep"),
                 "--out", str(tmp_path / "c"), "-q"])
    assert "No space left" in one_line_error(capsys, code)
    assert list(tmp_path.iterdir()) == []


def _mount_tiny_tmpfs(path: Path) -> bool:
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    path.mkdir()
    run = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(path)],
                         capture_output=True)
    return run.returncode == 0


def test_full_disk_on_a_real_tmpfs(inputs, tmp_path, capsys):
    disk = tmp_path / "tiny"
    if not _mount_tiny_tmpfs(disk):
        pytest.skip("mounting a 1 MiB tmpfs needs root; the simulated ENOSPC test covers it")
    try:
        big = inputs["ply"].parent / "big.ply"
        xyz, attrs = gauge_cloud(spacing_mm=0.05)  # ~120 k points: 5 MB with the QA fields
        write_ply(big, xyz, attrs)
        line = one_line_error(capsys, main(qa_argv(big, inputs["layout"], disk / "qa")))
        assert "No space left on device" in line
        assert list(disk.iterdir()) == []
    finally:
        subprocess.run(["umount", str(disk)], check=False)


# ------------------------------------------------------------------ SIGTERM, modes


SIGTERM_SCRIPT = """
import os, signal, sys
from pathlib import Path
import scanqa.report.qa as report
from scanqa.cli import main

real = report.render
def render(*args, **kwargs):  # SIGTERM while the QA's files are being written
    os.kill(os.getpid(), signal.SIGTERM)
    return real(*args, **kwargs)
report.render = render
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_mid_write_removes_temporaries(inputs, tmp_path):
    out = tmp_path / "qa"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)])}
    run = subprocess.run([sys.executable, "-c", SIGTERM_SCRIPT,
                          *qa_argv(inputs["ply"], inputs["layout"], out)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 143, run.stderr
    assert run.stderr.strip() == "scanqa: terminated"
    assert list(tmp_path.iterdir()) == []  # no output, no hidden staging folder


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield lambda mask: os.umask(mask)
    os.umask(old)


def test_outputs_get_the_mode_the_umask_gives(inputs, tmp_path, umask):
    out = tmp_path / "qa"
    assert main(qa_argv(inputs["ply"], inputs["layout"], out)) == 0
    assert {p.name: p.stat().st_mode & 0o777 for p in out.iterdir()} == dict.fromkeys(
        ("blocks.csv", "steps.csv", "budget.csv", "summary.json", "report.html", "cloud_qa.ply"),
        0o644)
    assert out.stat().st_mode & 0o777 == 0o755
    (out / "blocks.csv").chmod(0o600)
    umask(0o027)
    assert main(qa_argv(inputs["ply"], inputs["layout"], out)) == 0
    assert (out / "blocks.csv").stat().st_mode & 0o777 == 0o640  # not the old 0600
    assert (tmp_path / "x.txt").exists() is False
    assert atomic.write_text(tmp_path / "x.txt", "x").stat().st_mode & 0o777 == 0o640


# ------------------------------------------------------------------ PLY headers


def _ply(tmp_path: Path, header: str, body: bytes = b"", name: str = "h.ply") -> Path:
    path = tmp_path / name
    path.write_bytes(header.encode("ascii") + body)
    return path


BAD_HEADERS = {
    "element vertex many": ("element vertex many", "whole number COUNT"),
    "missing count": ("element vertex", "whole number COUNT"),
    "format without a value": ("format", "expected 'format FORMAT 1.0'"),
    "property without a name": ("property float", "expected 'property TYPE NAME'"),
    "duplicate property": ("property float x", "appears twice"),
    "unknown type": ("property float128 w", "expected 'property TYPE NAME'"),
}


@pytest.mark.parametrize("case", sorted(BAD_HEADERS))
def test_malformed_ply_headers(case, tmp_path):
    line, message = BAD_HEADERS[case]
    lines = ["ply", "format binary_little_endian 1.0", "element vertex 2",
             "property float x", "property float y", "property float z"]
    if line.startswith("format"):
        lines[1] = line
    elif line.startswith("element"):
        lines[2] = line
    else:
        lines.append(line)
    path = _ply(tmp_path, "\n".join([*lines, "end_header"]) + "\n", bytes(32))
    with pytest.raises(InputError, match=message):
        read_ply(path)


def test_ply_vertex_count_larger_than_the_file(tmp_path):
    """1e12 declared vertices: refused from the file size, before any allocation."""
    path = _ply(tmp_path, "ply\nformat binary_little_endian 1.0\nelement vertex "
                          "1000000000000\nproperty float x\nproperty float y\nproperty float z\n"
                          "end_header\n", bytes(120))
    with pytest.raises(InputError, match="1000000000000 vertices of 12 bytes "
                                         r"\(12000000000000 bytes\) but 120 bytes follow"):
        read_ply(path)


def _open3d_clouds(tmp_path: Path) -> dict[str, Path]:
    """The small gauge cloud written by Open3D (binary and ascii) with normals and
    colours, and as CloudCompare writes it (float x y z, colours, scalar_Intensity,
    big-endian)."""
    import open3d as o3d

    xyz, _ = gauge_cloud()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    pcd.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, -1.0], (len(xyz), 1)))
    pcd.colors = o3d.utility.Vector3dVector(np.full((len(xyz), 3), 0.5))
    out = {}
    for ascii_ in (False, True):
        out[f"open3d_{'ascii' if ascii_ else 'binary'}"] = p = \
            tmp_path / f"o3d_{ascii_}.ply"
        assert o3d.io.write_point_cloud(str(p), pcd, write_ascii=ascii_)
    rec = np.empty(len(xyz), [("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("red", "u1"),
                              ("green", "u1"), ("blue", "u1"), ("scalar_Intensity", ">f4"),
                              ("scalar_Distance", ">f4")])
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["red"], rec["green"], rec["blue"] = 200, 100, 50
    rec["scalar_Intensity"], rec["scalar_Distance"] = 7.0, 0.25
    header = ["ply", "format binary_big_endian 1.0", "comment Created by CloudCompare",
              "obj_info Generated by CloudCompare!", f"element vertex {len(xyz)}",
              *[f"property {'uchar' if rec.dtype[n].kind == 'u' else 'float'} {n}"
                for n in rec.dtype.names], "end_header"]
    out["cloudcompare"] = _ply(tmp_path, "\n".join(header) + "\n", rec.tobytes(), "cc.ply")
    return out


def test_open3d_and_cloudcompare_clouds_load_and_carry_their_extras(tmp_path, capsys):
    import open3d as o3d

    (tmp_path / "layout.toml").write_text(LAYOUT_TOML)
    for name, path in _open3d_clouds(tmp_path).items():
        xyz, attrs, _ = read_ply(path)
        np.testing.assert_allclose(xyz, gauge_cloud()[0], atol=1e-3)  # float32, ascii
        out = tmp_path / f"qa_{name}"
        assert main(qa_argv(path, tmp_path / "layout.toml", out)) == 0, capsys.readouterr()
        back = o3d.t.io.read_point_cloud(str(out / "cloud_qa.ply"))
        assert "scalar_qa_residual_um" in back.point
        if name.startswith("open3d"):
            assert {"nx", "ny", "nz", "red"} <= set(attrs)
            np.testing.assert_allclose(back.point.normals.numpy()[:, 2], -1.0)
            assert "colors" in back.point
        else:
            assert attrs["Distance"][0] == np.float32(0.25)
            assert "Intensity" not in attrs  # CloudCompare would read it as intensity
            np.testing.assert_array_equal(back.point.colors.numpy()[0], [200, 100, 50])


# ------------------------------------------------------------------ resource limits


def _forged_npz(path: Path, real: Path, key: str, shape: tuple) -> Path:
    """A copy of ``real`` whose entry ``key`` declares ``shape`` but holds 16 bytes."""
    import io
    import zipfile

    with np.load(real) as npz:
        arrays = {k: npz[k] for k in npz.files if k != key}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False,
                                                "shape": shape})
    with zipfile.ZipFile(buf, "a") as zf:
        zf.writestr(f"{key}.npy", head.getvalue() + bytes(16))
    path.write_bytes(buf.getvalue())
    return path


def test_sizes_are_checked_before_allocation(inputs, tmp_path, capsys):
    forged = _forged_npz(tmp_path / "phase.npz", inputs["phase"], "xp", (10**12,))
    code = main(["annotate", str(forged), "--table", str(inputs["table"]), "--config",
                 str(inputs["config"]), "--out", str(tmp_path / "c.ply"), "-q"])
    assert "shape (1000000000000,) of float64 (8000000000000 bytes) but the entry holds 16" \
        in one_line_error(capsys, code)
    code = main(["calibrate", str(SAMPLE / "calibration_sweep"), "--config",
                 f"{SAMPLE}/sample_scanner.toml#sample", "--cell", "100000",
                 "--out", str(tmp_path / "t.npz"), "-q"])
    assert "got 100000" in one_line_error(capsys, code) and not (tmp_path / "t.npz").exists()


def test_volume_step_is_checked_before_allocation(tmp_path):
    """In a subprocess with a time limit: unchecked, this grid takes hours."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    run = subprocess.run([sys.executable, "-c", CLI, "design", "volume", "--config",
                          str(ROOT / "calib" / "paper_scanner.toml"), "--step", "0.01"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 2
    assert run.stderr.startswith("scanqa: a voxel size of 0.01 mm gives 8") and \
        "use a step of at least" in run.stderr and run.stderr.count("\n") == 1


# ------------------------------------------------------------------ damaged files


def test_truncated_and_bit_flipped_tables(inputs, tmp_path, capsys):
    data = inputs["table"].read_bytes()
    rng = np.random.default_rng(3)
    cases = [data[:len(data) // 2], data[:100]]
    for pos in rng.integers(200, len(data) - 200, 12):  # bit flips in the compressed data
        flipped = bytearray(data)
        flipped[pos] ^= 0x10
        cases.append(bytes(flipped))
    for k, blob in enumerate(cases):
        bad = tmp_path / f"t{k}.npz"
        bad.write_bytes(blob)
        code = main(["annotate", str(inputs["phase"]), "--table", str(bad), "--config",
                     str(inputs["config"]), "--out", str(tmp_path / "c.ply"), "-q"])
        assert str(bad) in one_line_error(capsys, code), k


def test_table_meta_without_width(inputs, tmp_path, capsys):
    with np.load(inputs["table"]) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays["meta"]))
    del meta["width_px"]
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "t.npz", **arrays)
    code = main(["annotate", str(inputs["phase"]), "--table", str(tmp_path / "t.npz"),
                 "--config", str(inputs["config"]), "--out", str(tmp_path / "c.ply")])
    assert "lacks width_px" in one_line_error(capsys, code)


def test_zero_sigmas_and_table_correlation(tmp_path, capsys):
    """sigma_model_um = 0 is refused (issue 27: it was read as "no prediction" and the
    block reported "predicted nan, ok"); table_corr_mm = 0 is taken as an unknown
    correlation: the steps stay finite."""
    xyz, attrs = gauge_cloud()
    attrs["table_corr_mm"][:] = 0.0
    write_ply(tmp_path / "c.ply", xyz, attrs)
    (tmp_path / "layout.toml").write_text(LAYOUT_TOML)
    assert main(qa_argv(tmp_path / "c.ply", tmp_path / "layout.toml", tmp_path / "qa")) == 0
    info = json.loads((tmp_path / "qa" / "summary.json").read_text())
    assert all(s["u_um"] > 0 for s in info["steps"])
    attrs["sigma_model_um"][5] = 0.0
    write_ply(tmp_path / "c.ply", xyz, attrs)
    code = main(qa_argv(tmp_path / "c.ply", tmp_path / "layout.toml", tmp_path / "qa2"))
    assert "sigma_model_um holds 1 values that are 0" in one_line_error(capsys, code)
    assert not (tmp_path / "qa2").exists()


# ------------------------------------------------------------- meaningless inputs


def _cloud(tmp_path: Path, xyz: np.ndarray) -> Path:
    return write_ply(tmp_path / "c.ply", xyz, {"sigma_model_um": np.full(len(xyz), 4.0)})


@pytest.mark.parametrize("case", ["empty", "all_nan", "metres"])
def test_meaningless_clouds_are_refused(case, tmp_path, capsys):
    xyz = gauge_cloud()[0]
    xyz = {"empty": xyz[:0], "all_nan": np.full_like(xyz, np.nan), "metres": xyz / 1e3}[case]
    (tmp_path / "layout.toml").write_text(LAYOUT_TOML)
    code = main(qa_argv(_cloud(tmp_path, xyz), tmp_path / "layout.toml", tmp_path / "qa"))
    line = one_line_error(capsys, code)
    assert ("metres" in line) if case == "metres" else ("no points" in line), line
    assert not (tmp_path / "qa").exists()


BAD_NUMBERS = {
    "--margin nan": (["--margin", "nan"], "argument --margin: must be a finite number >= 0"),
    "--outliers nan": (["--outliers", "nan"], "argument --outliers: must be"),
    "--outliers 0": (["--outliers", "0"], "argument --outliers: must be a finite number > 0"),
    "--k nan": (["--k", "nan"], "argument --k: must be"),
    "--k -2": (["--k", "-2"], "argument --k: must be a finite number > 0"),
    "--tile inf": (["--tile", "inf"], "argument --tile: must be"),
}


@pytest.mark.parametrize("case", sorted(BAD_NUMBERS))
def test_nan_and_negative_qa_numbers(case, inputs, tmp_path, capsys):
    extra, message = BAD_NUMBERS[case]
    with pytest.raises(SystemExit) as exc:
        main(qa_argv(inputs["ply"], inputs["layout"], tmp_path / "qa", *extra))
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "qa").exists()


@pytest.mark.parametrize("argv", [["design", "curve", "--period", "0"],
                                  ["design", "curve", "--step", "nan"],
                                  ["design", "volume", "--level", "nan"],
                                  ["design", "dof", "--periods", "5,inf"],
                                  ["calibrate", "sweep", "--cell", "0", "--out", "t.npz"]])
def test_design_and_calibrate_numbers(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--config", str(ROOT / "calib" / "paper_scanner.toml")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith("scanqa ") and "Traceback" not in err
    assert "must be" in err or "expected finite numbers" in err


def _layout(tmp_path: Path, **changes) -> Path:
    blocks = [dict(id=b, nominal_height_mm=h, region_mm=list(r)) for b, h, r in BLOCKS]
    for key, value in changes.items():
        bid, field = key.split("__")
        blocks[int(bid) - 1][field] = value
    text = 'format = "scanqa-gauge-layout/1"\n' + "".join(
        "\n[[block]]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in b.items()) for b in blocks)
    (tmp_path / "layout.toml").write_text(text)
    return tmp_path / "layout.toml"


def _toml(v) -> str:
    from scanqa.io.tomlfile import dumps_toml

    return dumps_toml({"v": v}).split(" = ", 1)[1].strip()


@pytest.mark.parametrize("changes, message", [
    ({"1__nominal_height_mm": float("inf")},
     r"nominal_height_mm must be a finite number in \(0, 1000\] \[mm\]"),
    ({"2__region_mm": [-5.0, float("inf"), -5.0, 5.0]}, "region_mm must be"),
    ({"3__region_mm": [4.0, 16.0, -5.0, 5.0]}, "blocks 2 .* and 3 .* overlap"),
    ({"1__top_z_mm": "high"}, "top_z_mm must be a finite number"),
])
def test_bad_layouts(changes, message, inputs, tmp_path, capsys):
    layout = _layout(tmp_path, **changes)
    line = one_line_error(capsys, main(qa_argv(inputs["ply"], layout, tmp_path / "qa")))
    assert re.search(message, line), line


# ------------------------------------------------------------------ TOML types


def test_wrong_toml_types(tmp_path, capsys):
    """A table where a number is expected, a list of numbers where tables are."""
    cfg = (ROOT / "calib" / "paper_scanner.toml").read_text()
    (tmp_path / "c.toml").write_text(cfg + "\n[profiles]\nx = 3\n")
    code = main(["design", "dof", "--config", f"{tmp_path / 'c.toml'}#x"])
    assert "[profiles.x] must be a table" in one_line_error(capsys, code)
    base = cfg[:cfg.index("[profiles.")]
    (tmp_path / "d.toml").write_text(base.replace('name = "paper_scanner"',
                                                  'name = "p"\nprofiles = 3'))
    code = main(["design", "dof", "--config", str(tmp_path / "d.toml")])
    assert "profiles must be [profiles.NAME] tables" in one_line_error(capsys, code)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('format = "scanqa-sweep/1"\nposition = [1, 2, 3]\n')
    code = main(["calibrate", str(sweep), "--config", str(ROOT / "calib" /
                                                          "paper_scanner.toml"),
                 "--out", str(tmp_path / "t.npz")])
    assert "[[position]] must be an array of tables" in one_line_error(capsys, code)


# ------------------------------------------------------------------ stdout


def test_stdout_closed_early_and_full(tmp_path):
    """'curve | head -1' stops quietly (exit 141, like a Unix filter killed by SIGPIPE);
    stdout on /dev/full is one line and exit 2. (The reader of the pipe is gone before
    the command writes: the same EPIPE as 'head' exiting, without a race.)"""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    argv = [sys.executable, "-c", CLI, "design", "curve", "--config",
            str(ROOT / "calib" / "paper_scanner.toml")]
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        run = subprocess.run(argv, stdout=write_end, stderr=subprocess.PIPE, env=env,
                             timeout=300)
    finally:
        os.close(write_end)
    assert run.returncode == 141 and run.stderr == b""
    if not Path("/dev/full").exists():
        return
    with open("/dev/full", "w") as full:
        run = subprocess.run(argv, stdout=full, stderr=subprocess.PIPE, text=True, env=env,
                             timeout=300)
    assert run.returncode == 2
    assert run.stderr == "scanqa: cannot write to standard output: No space left on device\n"


# ------------------------------------------------------- config that does not match


def test_calibrate_refuses_a_config_of_another_camera(tmp_path, capsys):
    code = main(["calibrate", str(SAMPLE / "calibration_sweep"), "--config",
                 str(ROOT / "calib" / "paper_scanner.toml"), "--out", str(tmp_path / "t.npz"),
                 "-q"])
    line = one_line_error(capsys, code)
    assert "is 306 x 256 px but the camera of config" in line and "2448 x 2048 px" in line
    assert list(tmp_path.iterdir()) == []


def test_characterize_uses_or_checks_the_manifest_config(tmp_path, capsys, monkeypatch):
    """Without --config the sweep's recorded config is used (the fit matches the sample
    profile's sigma_p, which came from this sweep); the paper's config is refused."""
    share_sweep_characterisation(monkeypatch)  # the fit, as the publish-together test's
    code = main(["characterize", "sweep", str(SAMPLE / "camera_sweep"), "--config",
                 str(ROOT / "calib" / "paper_scanner.toml"), "--out", str(tmp_path / "a")])
    line = one_line_error(capsys, code)
    assert "camera.f_number = 8.0 but the sweep was made with 11.0" in line
    assert main(["characterize", "sweep", str(SAMPLE / "camera_sweep"),
                 "--out", str(tmp_path / "b"), "-q"]) == 0
    best = json.loads((tmp_path / "b" / "summary.json").read_text())["best_variant"]
    from scanqa.model.config import load_config

    profile = load_config(SAMPLE / "sample_scanner.toml", profile="sample").model
    assert best["noise_reading"] == profile.noise_reading
    assert best["sigma_p_px"] == pytest.approx(profile.sigma_p_px, rel=0.01)


# ------------------------------------------------------------------ parquet


def test_parquet_without_an_engine_is_refused_before_any_work(inputs, tmp_path, capsys,
                                                              monkeypatch):
    import scanqa.cli.annotate as cli_annotate
    import scanqa.io.cloud as cloud_io

    monkeypatch.setattr(cloud_io, "parquet_engine", lambda: None)

    def no_work(*args, **kwargs):
        raise AssertionError("decoded before refusing the suffix")

    monkeypatch.setattr(cli_annotate, "decode", no_work)
    code = main(["annotate", str(inputs["phase"]), "--table", str(inputs["table"]),
                 "--config", str(inputs["config"]), "--out", str(tmp_path / "c.parquet")])
    assert "Parquet needs pyarrow (pip install 'scanqa[parquet]')" in one_line_error(capsys,
                                                                                      code)
    assert capsys.readouterr().out == "" and list(tmp_path.iterdir()) == []


# ------------------------------------------------------------- code that hid bugs


def test_no_blanket_exception_handlers_in_the_library():
    """'except Exception' and 'except TypeError' hid bugs: only the listed ones remain."""
    import ast

    allowed = {("progress.py", "Exception"),   # logging.Handler.emit's own contract
               ("atomic.py", "BaseException"),  # rolls a publication back, re-raises
               ("parsing.py", "TypeError"),     # a patterns.toml value of a wrong type
               ("response.py", "TypeError"),    # a response.toml value of a wrong type
               ("phasemap.py", "TypeError"),    # json.dumps of a provenance
               ("fitted_model.py", "TypeError"),  # a summary.json value of a wrong type
               ("geometry.py", "TypeError"),    # lru_cache of a hand-built config
               ("rig.py", "TypeError"),         # a design-page setting of a wrong type
               ("optimisation.py", "TypeError"),  # a design spec value of a wrong type
               # the design page's server answers an unexpected error with a 500 and
               # keeps its traceback (server.errors, stderr), not with an empty reply
               ("server.py", "Exception"),
               # one scan's failure (or its workers' deaths) becomes its row in the
               # results table and the batch goes on (docs/cluster.rst)
               ("cluster.py", "Exception"),
               ("covariance.py", "TypeError")}  # a covariance file's ragged matrix
    from tests.source_index import modules, nodes

    found = []
    for path in modules():  # each parsed once per process (tests/source_index.py)
        for node in nodes(path, ast.ExceptHandler):
            if node.type is not None:
                names = [n.id for n in ast.walk(node.type) if isinstance(n, ast.Name)]
                found += [(path.name, n) for n in names
                          if n in ("Exception", "BaseException", "TypeError")]
    assert set(found) - allowed == set(), found


def test_mesh_errors_are_one_line_and_bugs_are_not_hidden(tmp_path, monkeypatch):
    import trimesh

    from scanqa.simulator import scene

    bad = tmp_path / "m.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n"
                    b"1\n2\n")
    with pytest.raises(InputError, match=r"cannot load mesh|holds no triangles"):
        scene.load_mesh(bad)

    def bug(*args, **kwargs):
        raise ZeroDivisionError("a bug in the loader")

    monkeypatch.setattr(trimesh, "load", bug)
    with pytest.raises(ZeroDivisionError):
        scene.load_mesh(bad)


def test_singular_smoothing_windows_are_counted_and_reported(monkeypatch, caplog):
    from scanqa.calibration import build

    x = np.arange(100.0).reshape(10, 10)
    w = np.full_like(x, 1e-300)  # positive but numerically nothing ...
    w[:, 4:6] = 1.0              # ... but two columns of cells: no quadratic in u
    xs, ws, singular = build.smooth_cells(x, w, 8.0)
    assert singular > 0
    kept = (ws == w) & (xs == x)
    assert kept.sum() >= singular
    real = build.smooth_cells
    monkeypatch.setattr(build, "smooth_cells", lambda *a: (*real(*a)[:2], 3))
    cfg = small_config()
    with caplog.at_level("WARNING", logger="scanqa"):
        _, report = build.build_table(sweep(cfg, np.arange(430.0, 470.1, 8.0)), cfg,
                                      cell_px=8)
    assert report.unsmoothed_cells == 3 * 6 and report.as_dict()["unsmoothed_cells"] == 18
    assert "18 cell estimates kept unsmoothed" in caplog.text


@pytest.mark.parametrize(("text", "message"), [
    # a face pointing past the vertex list: trimesh reads it, the ray caster then failed
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999\n", r"IndexError|a face refers to vertex"),
    # vertices of two coordinates: Open3D's ray caster raised a RuntimeError
    ("v 0 0\nv 1 0\nv 0 1\nv 1 1\nf 1 2 3\nf 2 3 4\n", r"vertices have 2 coordinates"),
])
def test_malformed_reference_meshes_are_one_clear_error(tmp_path, text, message):
    """Meshes an ad-hoc fuzz of `scanqa compare` found crashing past the reader."""
    from scanqa.cli import main
    from scanqa.io.ply import write_ply
    from tests.smallcases import gauge_cloud

    xyz, attrs = gauge_cloud()
    write_ply(tmp_path / "cloud.ply", xyz, attrs, {"source": "tests"})
    (tmp_path / "ref.obj").write_text(text)
    with pytest.raises(InputError, match=message):
        from scanqa.io.mesh import read_mesh
        read_mesh(tmp_path / "ref.obj")
    assert main(["compare", str(tmp_path / "cloud.ply"), str(tmp_path / "ref.obj"),
                 "--out", str(tmp_path / "out"), "-q"]) == 2
    assert not (tmp_path / "out").exists()
