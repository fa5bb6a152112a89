"""The README's Python API examples run as written (in order, in a scratch folder, on the
sample data of ``scanqa.sample_data_path()``), and ``help(scanqa)`` lists the jobs."""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np

import scanqa

from .conftest import ROOT


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


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
