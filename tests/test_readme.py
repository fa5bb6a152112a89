"""The README's Python API examples run as written (in order, in a scratch folder, on the
sample data of ``scanqa.sample_data_path()``), and ``help(scanqa)`` lists the jobs. The
board example (a ```py block: it needs the calib extra and board captures) runs on
simulated phase-shift board poses (scanqa.simulator.boardfringes)."""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np
import pytest

import scanqa

from .conftest import ROOT


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def board_blocks(text: str) -> list[str]:
    """The ```py blocks: the board path, run from the repository only (the wheel check
    leaves the calib extra out, and a wheel ships no board captures)."""
    return re.findall(r"```py\n(.*?)```", text, flags=re.S)


def test_readme_api_examples_run(tmp_path, monkeypatch):
    # in a folder without the repository's sample_data/: the examples find the sample
    # data through scanqa.sample_data_path(), as from an installed wheel (make
    # wheel-check runs them there with tools/readme_examples.py)
    blocks = python_blocks((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(blocks) >= 3, "the README shows the three jobs as ```python blocks"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        for block in blocks:
            exec(compile(block, "README.md", "exec"), namespace)
    assert namespace["data"] == scanqa.sample_data_path()
    # the API's real-scanner calls on the sample data: describe, compare with a best fit,
    # a characterisation applied (its sigmas then come from the characterised model)
    assert [p.name for p in namespace["described"]] == ["described.toml"]
    assert (tmp_path / "cmp" / "summary.json").exists()
    assert namespace["cloud"].sigma_source["kind"] == "characterised"
    assert "characterisation" in namespace["characterised"].model.characterised_by
    # what the examples made is real: a table, a cloud with its model, a QA report
    assert (tmp_path / "table.npz").stat().st_size > 0
    cloud = scanqa.read_cloud(tmp_path / "cloud.ply")
    assert cloud.model["noise_reading"] == "two_source"  # the sample profile's model
    assert len(cloud) > 10000
    qa_dir = next(p for p in tmp_path.iterdir() if (p / "report.html").exists())
    assert (qa_dir / "summary.json").exists()
    # the example config predicts what the sample scanner measures (within a factor 1.5)
    blocks_ok = [b for b in namespace["qa"].blocks if b.status == "ok"]
    ratios = [b.ratio for b in blocks_ok]
    assert blocks_ok and all(0.67 < r < 1.5 for r in ratios), ratios


def test_help_lists_the_jobs():
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        help(scanqa)
    out = text.getvalue()
    for name in ("load_config", "decode", "calibrate", "annotate", "run_qa", "write_report",
                 "characterize", "read_cloud"):
        assert re.search(rf"^\s+{name}( = \w+)?\(", out, flags=re.M), name


def test_cloud_converts_to_open3d_and_pandas():
    xyz = np.array([[0.0, 1.0, 450.0], [1.0, 2.0, 451.0]])
    cloud = scanqa.AnnotatedCloud(xyz, {"sigma_model_um": np.array([5.0, 6.0], np.float32)},
                                  metadata={"model": {"gamma": 3.0}})
    pcd = cloud.to_open3d()
    np.testing.assert_array_equal(pcd.point["positions"].numpy(), xyz)
    np.testing.assert_array_equal(pcd.point["sigma_model_um"].numpy().ravel(), [5.0, 6.0])
    frame = cloud.to_dataframe()
    assert list(frame.columns) == ["x_mm", "y_mm", "z_mm", "sigma_model_um"]
    np.testing.assert_array_equal(frame["z_mm"], [450.0, 451.0])
    assert frame.attrs["scanqa"]["model"]["gamma"] == 3.0


def test_sample_data_path_finds_the_sample_data(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the working directory: the package's location
    data = scanqa.sample_data_path()
    assert (data / "sample_scanner.toml").is_file()
    assert (data / "gauge_blocks" / "layout.toml").read_bytes() == (
        ROOT / "calib" / "gauge_blocks_paper.toml").read_bytes()  # the README's layout


#: The simulated scanner and poses of the board example: seed 7 was looked at while the
#: renderer was written; this one was named before it was first run.
BOARD_SEED = 4801


def _board_captures(folder):
    """Three board poses and a plate (scanqa.simulator.boardfringes, ~7 s of CPU, kept
    in the test cache) in ``folder/board`` and ``folder/part``; the truth."""
    import tempfile
    from pathlib import Path

    from scanqa.simulator.boardfringes import write_board_captures

    from .diskcache import cached

    def build():
        with tempfile.TemporaryDirectory() as tmp:
            made = write_board_captures(Path(tmp) / "board", BOARD_SEED, part=Path(tmp) / "part")
            files = {str(p.relative_to(tmp)): p.read_bytes() for p in Path(tmp).rglob("*")
                     if p.is_file()}
            return files, made.truth, made.noise, made.part_pose

    files, truth, noise, part_pose = cached("board_fringe_captures", build, BOARD_SEED)
    for name, data in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    return truth, noise, part_pose


@pytest.mark.slow
def test_readme_board_example_runs_on_simulated_captures(tmp_path, monkeypatch):
    """The README's board path as written, in a folder laid out as its text says: board
    poses, columns.toml and rows.toml in board/, a scan in part/ and scanner.toml, the
    config ``scanqa init --calibration`` writes from the scanner's earlier calibration
    (here the simulated truth) with its two MEASURE keys filled. Checked against the
    simulator's truth: the calibration, the noise law, the plate's plane (~16 s of CPU)."""
    pytest.importorskip("cv2", reason="the board path needs the calib extra (OpenCV)")
    from scanqa.calibration.board_fit import compare
    from scanqa.calibration.parametric import from_opencv
    from scanqa.calibration.pinhole import rotation_matrix
    from scanqa.runs.onboarding import placeholders, scanner_config_text

    blocks = board_blocks((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(blocks) == 1, "the README's one board example is the one ```py block"
    truth, noise, (rvec, tvec) = _board_captures(tmp_path)
    text = scanner_config_text(from_opencv(truth), 11.0, 7.6, None, None,
                               [16.0, 96.0, 912.0], "simulated")
    assert placeholders(text) == ["camera.f_number", "projector.aperture_mm"]
    text = text.replace('f_number = "MEASURE"', "f_number = 8.0")
    (tmp_path / "scanner.toml").write_text(
        text.replace('aperture_mm = "MEASURE"', "aperture_mm = 4.0"))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()) as out:
        exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert out.getvalue() == "characterised\n"  # what the example's comment says
    # one geometry: the config written for the earlier calibration keeps working with
    # the board's recalibration, whose projector pose the cloud's config holds: -Rp^T Tp
    # (warned about only past a recalibration's tolerance)
    fitted = namespace["result"].data
    np.testing.assert_allclose(
        namespace["cloud"].metadata["config"]["projector"]["position_mm"],
        -fitted.Rp.T @ fitted.Tp, atol=1e-6)
    for name in ("board.xml", "board_report.html", "board_covariance.json",
                 "board_noise/summary.json", "board_noise/cells.csv"):
        assert (tmp_path / name).is_file(), name
    # the calibration against the simulated scanner: the issue-42 bounds of the Gray-code
    # poses (tests/test_board_gray.py); measured on seed 7: 0.35 %, 0.04 %, 0.17 %, 0.13 deg
    diff = compare(namespace["result"].data, truth)
    assert abs(diff["camera_focal_rel"]) < 0.02 and abs(diff["projector_focal_rel"]) < 0.02
    assert abs(diff["baseline_rel"]) < 0.02 and diff["rotation_deg"] < 0.5
    # the noise law: the simulated shot noise within 15 % (seed 7: +5 %), and each pose
    # predicted by the others' law within [0.8, 1.25] (seed 7: 0.99-1.04)
    law = namespace["law"]
    assert law["noise_law"]["shot_dn"] == pytest.approx(noise["shot_dn"], rel=0.15)
    ratios = [row["ratio_random"] for row in law["held_out"]]
    assert len(ratios) == 6 and all(0.8 <= r <= 1.25 for r in ratios), ratios
    # the plate: its points off the true plane by no more than the calibration's own
    # predicted error allows (seed 7: 1.33 mm off at 400 mm, sigma_calibration 1.25 mm
    # from three poses), their sigmas the characterised ones
    cloud = namespace["cloud"]
    normal = rotation_matrix(np.asarray(rvec))[:, 2]
    offset_um = 1e3 * float(np.median(cloud.xyz @ normal - normal @ np.asarray(tvec)))
    calib_um = float(np.median(cloud.attributes["sigma_calibration_um"]))
    assert len(cloud) > 100000 and abs(offset_um) < 3 * calib_um, (offset_um, calib_um)
    assert cloud.sigma_source["kind"] == "characterised"
