"""Nothing silent, round 3 (issue 45): each case a second adversary got through, refused or
warned with one line naming the file, field or request and the fix.

Covers: a publication interrupted between any two of its file operations; outputs that
would overwrite an input; tracebacks of compare, the mesh reader and the table reader;
physical values off by orders of magnitude in configs, phase maps, clouds and CSV files;
a zeroed, black or swapped frame in a phase set.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from scanqa.io import atomic


def _publish_old_then_new(root: Path) -> None:
    out = root / "out"
    with atomic.staged_dir(out) as stage:
        for name in ("budget.csv", "steps.csv", "report.html"):
            (stage / name).write_text(f"old {name}")
    with atomic.staged_dir(out) as stage:
        for name in ("budget.csv", "steps.csv", "report.html", "new.json"):
            (stage / name).write_text(f"new {name}")
        (stage / "sub").mkdir()
        (stage / "sub" / "x.txt").write_text("new x")


@pytest.mark.parametrize("after", [False, True], ids=["before-call", "after-call"])
def test_publication_interrupted_between_any_two_lines_loses_nothing(tmp_path, monkeypatch,
                                                                     after):
    """An interrupt before or after every rename or link of the second publication leaves
    the folder exactly as the first one wrote it, or exactly as the second (issue 45: a
    KeyboardInterrupt between two lines of the old _apply deleted budget.csv)."""
    old = {"budget.csv": b"old budget.csv", "steps.csv": b"old steps.csv",
           "report.html": b"old report.html"}
    new = {"budget.csv": b"new budget.csv", "steps.csv": b"new steps.csv",
           "report.html": b"new report.html", "new.json": b"new new.json",
           "sub/x.txt": b"new x"}
    real = {"replace": os.replace, "link": os.link, "rename": os.rename}
    outcomes = set()
    for k in range(40):
        calls = [0]

        def hook(name, *args, _k=k, _calls=calls, **kw):
            _calls[0] += 1
            if not after and _calls[0] == _k + 1:
                raise KeyboardInterrupt
            result = real[name](*args, **kw)
            if after and _calls[0] == _k + 1:
                raise KeyboardInterrupt
            return result

        root = tmp_path / f"run{k}"
        root.mkdir()
        for name in real:
            monkeypatch.setattr(atomic.os, name,
                                lambda *a, _n=name, **kw: hook(_n, *a, **kw))
        calls[0] = -10**6  # the first publication runs untouched
        with atomic.staged_dir(root / "out") as stage:
            for name, text in old.items():
                (stage / name).write_bytes(text)
        calls[0] = 0
        try:
            with atomic.staged_dir(root / "out") as stage:
                for name, text in new.items():
                    (stage / name).parent.mkdir(exist_ok=True)
                    (stage / name).write_bytes(text)
            outcome = "new"
        except KeyboardInterrupt:
            outcome = "interrupted"
        monkeypatch.undo()
        got = {str(p.relative_to(root / "out")): p.read_bytes()
               for p in sorted((root / "out").rglob("*")) if p.is_file()}
        assert got in (old, new), (k, outcome, got)
        assert (got == new) == (outcome == "new"), (k, outcome)
        assert [p.name for p in root.iterdir()] == ["out"], k  # no stage left behind
        outcomes.add(outcome)
        if outcome == "new":
            break
    assert outcomes == {"interrupted", "new"}


LAYOUT = Path(__file__).resolve().parents[1] / "calib" / "gauge_blocks_paper.toml"
SAMPLE_SCAN = Path(__file__).resolve().parents[1] / "sample_data" / "gauge_blocks" / "p000_r0"


def _one_line(capsys, code: int) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("scanqa: ")
             and not ln.startswith("scanqa: warning:") and not ln.startswith("scanqa decode:")
             and not ln.startswith("scanqa describe:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture()
def scan(tmp_path) -> Path:
    import shutil

    return Path(shutil.copytree(SAMPLE_SCAN, tmp_path / "scan"))


@pytest.mark.parametrize("argv", [["decode", "{scan}", "--out", "{scan}/p5_00.png"],
                                  ["decode", "{scan}", "--out", "{scan}/patterns.toml"],
                                  ["describe", "{scan}", "--out", "{scan}/p80_01.png",
                                   "--force", "--projector-width", "1280"]],
                         ids=["decode", "decode-manifest", "describe-force"])
def test_an_output_never_replaces_an_input(scan, argv, capsys):
    """decode SCAN --out SCAN/p5_00.png replaced a frame with an .npz (issue 45); now one
    line naming the file and the fix, with or without --force, and the frame unchanged."""
    from scanqa.cli import main

    name = argv[3].rsplit("/", 1)[1]
    before = (scan / name).read_bytes()
    code = main([a.format(scan=scan) for a in argv] + ["-q"])
    line = _one_line(capsys, code)
    what = "image file" if name.endswith(".png") else "pattern description"
    assert line == (f"scanqa: cannot write {scan / name}: it is one of this command's inputs "
                    f"(read as {what}), which no forcing replaces: give the output "
                    "another name or folder"), line
    assert (scan / name).read_bytes() == before


def test_writing_next_to_the_inputs_still_works(scan):
    """The documented decode SCAN --out SCAN/phase.npz, twice (the second replaces an
    output, not an input)."""
    from scanqa.cli import main

    for _ in range(2):
        assert main(["decode", str(scan), "--out", str(scan / "phase.npz"), "-q"]) == 0


def test_a_manifest_read_is_not_replaced_by_a_table_or_a_published_folder(tmp_path):
    """calibrate SWEEP --out SWEEP/sweep.toml replaced the manifest with the table (issue
    45): every writer of scanqa.io.atomic refuses an input the command read."""
    from scanqa.errors import InputError
    from scanqa.io.guard import command_inputs, regular_file

    manifest = tmp_path / "sweep.toml"
    manifest.write_text("x = 1\n")
    (tmp_path / "link").symlink_to(tmp_path, target_is_directory=True)
    with command_inputs():
        regular_file(tmp_path / "link" / "sweep.toml", "sweep manifest")
        with pytest.raises(InputError, match=r"it is one of this command's inputs \(read "
                           r"as sweep manifest\), which no forcing replaces"):
            atomic.write_text(manifest, "table")
        with pytest.raises(InputError, match="one of this command's inputs"):
            with atomic.staged_dir(tmp_path) as stage:
                (stage / "sweep.toml").write_text("table")
                (stage / "other.txt").write_text("x")
        atomic.write_text(tmp_path / "other.toml", "fine")
    assert manifest.read_text() == "x = 1\n" and not (tmp_path / "other.txt").exists()
    atomic.write_text(manifest, "outside a command: the library writes where it is told")


def _plane_cloud(n: int = 400, seed: int = 0):
    import numpy as np

    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-10, 10, (n, 2)), np.full(n, 400.0)]


@pytest.mark.parametrize("case", ["nan-sigmas", "coincident-reference", "collinear-reference",
                                  "degenerate-triangle"])
def test_compare_without_a_usable_sigma_or_surface_fails_before_writing(case, tmp_path,
                                                                         capsys):
    """compare raised a TypeError after writing its outputs when no compared point had a
    sigma (issue 45); a reference of coincident or collinear points, or a zero-area
    triangle, compared along an arbitrary normal. Now one line, and no output folder."""
    import numpy as np

    from scanqa.cli import main
    from scanqa.io.cloud import write_cloud

    xyz = _plane_cloud()
    sigma = np.full(len(xyz), np.nan if case == "nan-sigmas" else 5.0)
    write_cloud(tmp_path / "scan.ply", xyz, {"sigma_total_um": sigma})
    if case == "degenerate-triangle":
        ref = tmp_path / "ref.obj"
        ref.write_text("v -10 0 400\nv 0 0 400\nv 10 0 400\nf 1 2 3\n")
    else:
        ref = tmp_path / "ref.ply"
        pts = {"nan-sigmas": xyz, "coincident-reference": np.tile([[0.0, 0.0, 400.0]], (50, 1)),
               "collinear-reference": np.c_[np.linspace(-10, 10, 50), np.zeros(50),
                                            np.full(50, 400.0)]}[case]
        write_cloud(ref, pts, {})
    code = main(["compare", str(tmp_path / "scan.ply"), str(ref), "--out",
                 str(tmp_path / "cmp"), "-q"])
    line = _one_line(capsys, code)
    expected = ("none of the 400 compared points has a usable uncertainty" if case ==
                "nan-sigmas" else "no point of the cloud lies within reach of a surface")
    assert expected in line, line
    assert not (tmp_path / "cmp").exists()


@pytest.mark.parametrize("body", [
    b'{"asset": 5, "scenes": "x"}',
    b'{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],'
    b'"accessors":[{"bufferView":5,"count":3,"type":"VEC3","componentType":5126}]}'],
    ids=["wrong-kinds", "accessor-without-buffer"])
def test_a_garbage_glb_is_one_error(body, tmp_path):
    """trimesh's glTF reader raised AttributeError / UnboundLocalError inside (issue 45)."""
    import struct

    from scanqa.errors import InputError
    from scanqa.io.mesh import read_mesh

    body += b" " * (-len(body) % 4)
    glb = tmp_path / "part.glb"
    glb.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(body))
                    + struct.pack("<I", len(body)) + b"JSON" + body)
    with pytest.raises(InputError, match=r"^cannot load mesh .*part\.glb: \w+Error: .* \(need "
                       r"a valid STL, PLY, OBJ, OFF or GLB file\)$"):
        read_mesh(glb)


@pytest.fixture(scope="module")
def small_inputs(tmp_path_factory) -> dict[str, Path]:
    from .smallcases import write_inputs

    return write_inputs(tmp_path_factory.mktemp("inputs"))


def _rewrite_table(src: Path, dst: Path, meta_edit=None, array_edit=None) -> Path:
    import json

    import numpy as np

    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")[()]))
    if meta_edit:
        meta_edit(meta)
    if array_edit:
        array_edit(arrays)
    np.savez(dst, meta=np.array(json.dumps(meta)), **arrays)
    return dst


@pytest.mark.parametrize("edit", ["f_number", "z_mm", "float16"])
def test_table_metadata_and_arrays_are_type_checked(edit, small_inputs, tmp_path, capsys):
    """A table with ``camera.f_number = {}`` in its metadata raised inside
    calibration/table.py, a float16 array inside numba (issue 45): now the config is
    validated as a config, and float arrays of other widths are read as float64."""
    import numpy as np

    from scanqa.cli import main

    def meta_edit(meta):
        if edit == "f_number":
            meta["config"]["camera"]["f_number"] = {}
        if edit == "z_mm":
            meta["provenance"]["positions"] = [{"z_mm": "far"}]

    def array_edit(arrays):
        if edit == "float16":
            arrays["xyz"] = arrays["xyz"].astype(np.float16)
            arrays["sigma_node"] = arrays["sigma_node"].astype(np.float16)

    table = _rewrite_table(small_inputs["table"], tmp_path / "t.npz", meta_edit, array_edit)
    argv = ["annotate", str(small_inputs["phase"]), "--table", str(table), "--config",
            str(small_inputs["config"]), "--out", str(tmp_path / "c.ply"), "-q"]
    code = main(argv)
    if edit == "float16":
        assert code == 0, capsys.readouterr().err
        return
    line = _one_line(capsys, code)
    field = {"f_number": "camera.f_number", "z_mm": "provenance"}[edit]
    assert str(table) in line and field in line and "rebuild it" in line, line


@pytest.mark.parametrize(("name", "value", "suffix"), [
    ("in_volume", -4.0, ".ply"), ("sigma_total_um", 1e30, ".ply"), ("x_mm", 1e30, ".ply"),
    ("sigma_calibration_um", -1.0, ".csv")])
def test_per_point_values_outside_physical_limits_are_refused(name, value, suffix, tmp_path,
                                                              capsys):
    """A flag of -4 or a sigma of 1e30 reached summary.json (issue 45): the cloud readers
    check every column against its declared limits (io.cloud.VALUE_LIMITS)."""
    import numpy as np

    from scanqa.cli import main
    from scanqa.io.cloud import write_cloud

    xyz = _plane_cloud(100)
    attrs = {"sigma_total_um": np.full(100, 5.0), "sigma_calibration_um": np.full(100, 0.5),
             "in_volume": np.ones(100)}
    if name == "x_mm":
        xyz[3, 0] = value
    else:
        attrs[name][3] = value
    cloud = write_cloud(tmp_path / f"c{suffix}", xyz, attrs)
    code = main(["qa", str(cloud), "--layout", str(LAYOUT), "--out", str(tmp_path / "qa"),
                 "-q"])
    line = _one_line(capsys, code)
    assert f"{cloud}: {name} of point 3 is {value:g}, outside [" in line, line
    assert "a damaged file, or one in other units" in line and not (tmp_path / "qa").exists()


def test_a_csv_cell_that_overflows_is_refused(tmp_path, capsys):
    """A CSV cell 1e400 became inf (issue 45)."""
    from scanqa.cli import main

    csv = tmp_path / "c.csv"
    csv.write_text("x_mm,y_mm,z_mm,sigma_total_um\n1,2,400,5\n1,2,400,1e400\n")
    code = main(["qa", str(csv), "--layout", str(LAYOUT), "--out", str(tmp_path / "q"), "-q"])
    assert "sigma_total_um of point 1 is inf, outside [0, 1e+06] um" in _one_line(capsys, code)


def test_a_phase_map_claiming_exact_phases_is_refused(small_inputs, tmp_path, capsys):
    """sigma_xp = 0 on valid pixels was read as a perfect scan (issue 45)."""
    import numpy as np

    from scanqa.cli import main

    with np.load(small_inputs["phase"]) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["sigma_xp"] = np.where(np.isnan(arrays["sigma_xp"]), np.nan, 0.0).astype(np.float32)
    np.savez(tmp_path / "phase.npz", **arrays)
    code = main(["annotate", str(tmp_path / "phase.npz"), "--table", str(small_inputs["table"]),
                 "--config", str(small_inputs["config"]), "--out", str(tmp_path / "c.ply"),
                 "-q"])
    line = _one_line(capsys, code)
    assert f"phase map {tmp_path / 'phase.npz'}: sigma_xp must be > 0 [projector px] where " \
        "the pixel is valid" in line, line


@pytest.mark.parametrize("change", ["zeroed", "swapped"])
def test_a_zeroed_or_swapped_frame_is_not_decoded_silently(change, scan, capsys):
    """Zeroing p5_02.png decoded 67 % of the pixels with no warning, x_p off 0.43 px and
    sigma_xp down to 0.006 px (issue 45). Now a warning naming the set (and the frame)
    and no pixel trusted; the untouched scan decodes with no such warning."""
    import numpy as np
    from PIL import Image

    from scanqa.cli import main
    from scanqa.decoding.phasemap import load_phase_map

    assert main(["decode", str(scan), "--out", str(scan / "ok.npz"), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert load_phase_map(scan / "ok.npz").valid.mean() > 0.8
    if change == "zeroed":
        frame = np.asarray(Image.open(scan / "p5_02.png"))
        Image.fromarray(np.zeros_like(frame)).save(scan / "p5_02.png")
        expected = "set 'p5': frame 2 (p5_02.png) is black or zeroed"
    else:
        one, two = (scan / "p5_01.png").read_bytes(), (scan / "p5_02.png").read_bytes()
        (scan / "p5_01.png").write_bytes(two)
        (scan / "p5_02.png").write_bytes(one)
        expected = "set 'p5': its 4 frames (p5_00.png, p5_01.png, p5_02.png, p5_03.png) fit "
    assert main(["decode", str(scan), "--out", str(scan / "bad.npz"), "-q"]) == 0
    err = capsys.readouterr().err
    assert f"scanqa: warning: {expected}" in err, err
    assert load_phase_map(scan / "bad.npz").valid.sum() == 0


def test_repeats_of_another_scene_are_refused(small_inputs, tmp_path, capsys):
    """A "repeat" of another scene gave a measured std of the scenes' difference."""
    import numpy as np

    from scanqa.cli import main
    from scanqa.decoding.phasemap import save_phase_map

    from .smallcases import phase_map, small_config

    config = small_config()
    rng = np.random.default_rng(3)
    same = phase_map(config, 450.0)
    noisy = same.__class__(**{**same.__dict__, "xp": same.xp + rng.normal(0, 0.01,
                                                                          same.xp.shape)})
    save_phase_map(tmp_path / "same.npz", noisy)
    save_phase_map(tmp_path / "other.npz", phase_map(config, 458.0))
    argv = ["annotate", str(small_inputs["phase"]), "--table", str(small_inputs["table"]),
            "--config", str(small_inputs["config"]), "-q", "--repeats"]
    assert main([*argv, str(tmp_path / "same.npz"), "--out", str(tmp_path / "a.ply")]) == 0
    capsys.readouterr()
    code = main([*argv, str(tmp_path / "same.npz"), str(tmp_path / "other.npz"), "--out",
                 str(tmp_path / "b.ply")])
    line = _one_line(capsys, code)
    assert "repeat 2 differs from the scan by a median" in line and "another scene" in line
    assert not (tmp_path / "b.ply").exists()
