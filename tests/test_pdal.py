"""Our LAS export in a real PDAL: ``pdal info`` lists the attributes as dimensions with
their descriptions, and the pipeline documented in docs/formats.rst (read from the page
itself) keeps exactly the points numpy keeps. Skipped where no ``pdal`` is installed
(Debian 12 packages none; ``tools/install_syslibs.sh test`` installs Debian's where the
archive has it)."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.io.las import describe

from .test_annotate import cfg, scan, table  # noqa: F401 - fixtures

ROOT = Path(__file__).resolve().parents[1]
PDAL = shutil.which("pdal")
needs_pdal = pytest.mark.skipif(PDAL is None, reason=(
    "pdal not installed: Debian 12 packages none and PyPI's pdal is bindings without a "
    "binary wheel (tools/install_syslibs.sh test installs Debian's where the archive has "
    "it; docs/formats.rst, PDAL, says how a lab runs the pipeline)"))


def documented_pipeline() -> list:
    """The JSON block of docs/formats.rst's PDAL paragraph."""
    text = (ROOT / "docs" / "formats.rst").read_text(encoding="utf-8")
    section = text[text.index(".. _pdal-pipeline:"):]
    block = re.search(r"\.\. code-block:: json\n\n((?:   .*\n|\n)+)", section).group(1)
    return json.loads(block)


def test_the_documented_pipeline_is_valid_json_with_a_range_filter():
    stages = documented_pipeline()
    assert [s["type"] for s in stages] == ["readers.las", "filters.range", "writers.las"]
    assert stages[1]["limits"] == "sigma_total_um[:25]"


@pytest.fixture(scope="module")
def las_cloud(cfg, table, tmp_path_factory):  # noqa: F811
    folder = tmp_path_factory.mktemp("pdal")
    cloud = annotate(scan(cfg)[0], table, cfg)
    return cloud, cloud.write(folder / "cloud.las")


@needs_pdal
def test_pdal_info_lists_the_sigma_dimensions_with_their_descriptions(las_cloud):
    cloud, path = las_cloud
    run = subprocess.run([PDAL, "info", "--schema", "--metadata", str(path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    info = json.loads(run.stdout)
    dims = {d["name"] for d in info["schema"]["dimensions"]}
    assert set(cloud.attributes) <= dims
    # the extra-bytes record (LASF_Spec 4): 192 bytes per dimension, name at 4..36,
    # description at 160..192
    vlrs = [v for k, v in info["metadata"].items() if k.startswith("vlr_")
            and v.get("user_id") == "LASF_Spec" and v.get("record_id") == 4]
    raw = base64.b64decode(vlrs[0]["data"])
    found = {raw[i + 4:i + 36].split(b"\0")[0].decode(): raw[i + 160:i + 192].split(b"\0")[0]
             .decode() for i in range(0, len(raw), 192)}
    for name in ("sigma_total_um", "sigma_model_um", "sx_um", "s_t_um_px"):
        assert found[name] == describe(name)
    assert found["sigma_total_um"] == "sigma_total [um]"


@needs_pdal
def test_the_documented_pipeline_keeps_what_numpy_keeps(las_cloud, tmp_path):
    laspy = pytest.importorskip("laspy")
    cloud, path = las_cloud
    stages = documented_pipeline()
    # this small cloud's sigma_total spans 3.8-4.3 um: a threshold inside that range
    # (written with two decimals, as a user would) splits it
    threshold = round(float(np.median(cloud.attributes["sigma_total_um"])), 2)
    stages[1]["limits"] = stages[1]["limits"].replace(":25]", f":{threshold}]")
    stages[0]["filename"] = str(path)
    stages[2]["filename"] = str(tmp_path / "kept.las")
    (tmp_path / "keep.json").write_text(json.dumps(stages))
    run = subprocess.run([PDAL, "pipeline", str(tmp_path / "keep.json")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    keep = cloud.attributes["sigma_total_um"].astype(np.float64) <= threshold
    assert 0 < keep.sum() < len(cloud)  # the threshold splits this cloud
    kept = laspy.read(str(tmp_path / "kept.las"))
    assert len(kept.points) == keep.sum()
    ours = 1e3 * np.stack([kept.x, kept.y, kept.z], -1)
    order = np.lexsort(cloud.xyz[keep].T)
    np.testing.assert_allclose(ours[np.lexsort(ours.T)], cloud.xyz[keep][order], atol=1e-4)
    np.testing.assert_array_equal(np.sort(np.asarray(kept["sigma_total_um"])),
                                  np.sort(cloud.attributes["sigma_total_um"][keep]))
