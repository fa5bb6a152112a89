"""E57 clouds (ASTM E2807): written by scanqa, read back by pye57's own bindings of
libE57Format (every field, its unit, the provenance), by scanqa, and from E57 files that
pye57 itself wrote; the command line's ``--out c.e57`` and its refusal without pye57.

The expected values are the annotated cloud's own arrays (metres = mm / 1000 computed
here) and what pye57 reads; the pye57 reads below use its public API and libE57 buffers
directly, not :mod:`scanqa.io.e57`.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.cloud import read_cloud, write_cloud
from scanqa.io.e57 import NORMAL_FIELDS, NORMALS

from .test_annotate import REQUIRE_CLIENTS, _clean_qt_env, cfg, scan, table  # noqa: F401
from .test_failures import inputs, one_line_error  # noqa: F401 - fixtures

pye57 = pytest.importorskip("pye57", reason="pye57 not installed (pip install 'scanqa[e57]')")
from pye57 import libe57  # noqa: E402


def _pye57_fields(path: Path) -> tuple[list[str], dict[str, np.ndarray], object]:
    """Every point field of scan 0 as float64, read with libE57 buffers, and the scan."""
    e57 = pye57.E57(str(path))
    header = e57.get_header(0)
    n = header.point_count
    data = {f: np.empty(n, np.float64) for f in header.point_fields}
    buffers = libe57.VectorSourceDestBuffer()
    for name, array in data.items():
        buffers.append(libe57.SourceDestBuffer(e57.image_file, name, array, n, True, True))
    reader = header.points.reader(buffers)
    assert reader.read() == n
    reader.close()
    return list(header.point_fields), data, (e57, header)


def _extensions(e57) -> list[tuple[str, str]]:
    imf = e57.image_file
    return [(imf.extensionsPrefix(i), imf.extensionsUri(i))
            for i in range(imf.extensionsCount())]


@pytest.fixture(scope="module")
def cloud(cfg, table):  # noqa: F811
    return annotate(scan(cfg)[0], table, cfg)


def test_pye57_reads_every_field_with_its_unit_and_the_provenance(cloud, tmp_path):
    path = cloud.write(tmp_path / "c.e57")
    fields, data, (e57, header) = _pye57_fields(path)
    assert fields[:4] == ["cartesianX", "cartesianY", "cartesianZ", "intensity"]
    # annotate's normals in the E57 surface-normals extension, the rest in scanqa's
    field = {name: NORMAL_FIELDS.get(name, f"scanqa:{name}") for name in cloud.attributes}
    assert fields[4:] == list(field.values())
    assert ("nor", NORMALS[1]) in _extensions(e57)
    # metres, 64-bit
    for i, axis in enumerate("XYZ"):
        np.testing.assert_allclose(data[f"cartesian{axis}"], cloud.xyz[:, i] / 1000,
                                   rtol=0, atol=1e-15)
    np.testing.assert_array_equal(data["intensity"], cloud.attributes["offset_dn"])
    for name, values in cloud.attributes.items():  # float32 as written
        np.testing.assert_array_equal(data[field[name]], values.astype(np.float64),
                                      err_msg=name)
    node = header.node
    assert ("scanqa", "urn:x-scanqa:e57:1.0") in _extensions(e57)
    units = {name: node["scanqa:fields"][name]["unit"].value() for name in cloud.attributes
             if name not in NORMAL_FIELDS}
    assert units["sigma_total_um"] == "um" and units["offset_dn"] == "DN"
    assert units["s_t_um_px"] == "um/px" and units["s_o"] == "-"
    assert json.loads(node["scanqa:metadata"].value()) == json.loads(
        json.dumps(cloud.metadata))
    # the standard's own read of the coordinates agrees (pye57's read_scan_raw)
    raw = e57.read_scan_raw(0, ignore_unsupported_fields=True)
    np.testing.assert_array_equal(raw["cartesianX"], data["cartesianX"])
    e57.close()


def test_round_trip_through_read_cloud(cloud, tmp_path):
    path = cloud.write(tmp_path / "c.e57")
    xyz, attrs, meta = read_cloud(path)
    np.testing.assert_allclose(xyz, cloud.xyz, rtol=0, atol=1e-9)
    assert list(attrs) == list(cloud.attributes)  # intensity is offset_dn: not twice
    for name, values in cloud.attributes.items():
        np.testing.assert_array_equal(attrs[name], values, err_msg=name)
    assert meta == json.loads(json.dumps(cloud.metadata))


def test_normals_travel_in_the_e57_normals_extension(tmp_path):
    rng = np.random.default_rng(3)
    xyz = rng.normal(0, 10, (50, 3)) + np.array([0.0, 0.0, 450.0])
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    attrs = {"nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2],
             "sigma_total_um": np.full(50, np.nan, np.float32)}  # NaN survives too
    path = write_cloud(tmp_path / "n.e57", xyz, attrs)
    fields, data, (e57, _) = _pye57_fields(path)
    assert {"nor:normalX", "nor:normalY", "nor:normalZ"} <= set(fields)
    assert ("nor", "http://www.libe57.org/E57_NOR_surface_normals.txt") in _extensions(e57)
    np.testing.assert_allclose(data["nor:normalZ"], normals[:, 2], rtol=1e-7)
    e57.close()
    _, back, _ = read_cloud(path)
    np.testing.assert_allclose(back["nx"], normals[:, 0], rtol=1e-7)
    assert np.isnan(back["sigma_total_um"]).all()


def test_reads_an_e57_written_by_pye57_with_a_pose(tmp_path):
    """A file from another writer: pye57's own write_scan_raw (float32 coordinates in
    metres, intensity, colours, a pose that turns the scan 90 deg about Z and moves it)."""
    rng = np.random.default_rng(4)
    n = 200
    local = rng.uniform(-0.05, 0.05, (n, 3)).astype(np.float32)
    data = {"cartesianX": local[:, 0], "cartesianY": local[:, 1],
            "cartesianZ": local[:, 2], "intensity": rng.uniform(0, 1, n).astype(np.float32),
            "colorRed": rng.integers(0, 256, n).astype(np.uint8),
            "colorGreen": np.zeros(n, np.uint8), "colorBlue": np.zeros(n, np.uint8)}
    path = tmp_path / "other.e57"
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])  # 90 deg about Z
    with pye57.E57(str(path), mode="w") as out:
        out.write_scan_raw(data, rotation=q, translation=np.array([1.0, 2.0, 3.0]))
    xyz, attrs, meta = read_cloud(path)
    expected = np.stack([-local[:, 1], local[:, 0], local[:, 2]], -1).astype(float)
    expected = 1000 * (expected + np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(xyz, expected, atol=1e-6)
    np.testing.assert_array_equal(attrs["brightness"], data["intensity"])
    np.testing.assert_array_equal(attrs["red"], data["colorRed"])
    assert meta == {}
    # and scanqa writes what it read (brightness and red are valid attribute names)
    write_cloud(tmp_path / "again.ply", xyz, attrs, meta)


def test_a_file_that_is_not_e57_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.e57"
    bad.write_text("not an e57 file\n")
    with pytest.raises(InputError, match=r"cannot read E57 file .*bad\.e57: ") as err:
        read_cloud(bad)
    assert "\n" not in str(err.value)


def test_annotate_writes_e57_from_the_command_line(inputs, tmp_path):  # noqa: F811
    out = tmp_path / "c.e57"
    code = main(["annotate", str(inputs["phase"]), "--table", str(inputs["table"]),
                 "--config", str(inputs["config"]), "--out", str(out), "-q"])
    assert code == 0
    fields, _, (e57, header) = _pye57_fields(out)
    assert "scanqa:sigma_total_um" in fields and header.point_count > 0
    meta = json.loads(header.node["scanqa:metadata"].value())
    assert meta["format"].startswith("scanqa-cloud") and "config" in meta
    e57.close()


def test_e57_without_pye57_is_refused_before_any_work(inputs, tmp_path, capsys,  # noqa: F811
                                                      monkeypatch):
    import scanqa.cli.annotate as cli_annotate
    import scanqa.io.e57 as e57_io

    monkeypatch.setattr(e57_io, "available", lambda: False)

    def no_work(*args, **kwargs):
        raise AssertionError("decoded before refusing the suffix")

    monkeypatch.setattr(cli_annotate, "decode", no_work)
    code = main(["annotate", str(inputs["phase"]), "--table", str(inputs["table"]),
                 "--config", str(inputs["config"]), "--out", str(tmp_path / "c.e57")])
    assert "E57 needs pye57 (pip install 'scanqa[e57]')" in one_line_error(capsys, code)
    assert list(tmp_path.iterdir()) == []


def _cloudcompare_e57_plugin() -> bool:
    """CloudCompare is installed with its E57 I/O plugin (Debian 12's has none)."""
    exe = shutil.which("CloudCompare")
    if not exe:
        return False
    roots = [Path(exe).resolve().parents[1] / "lib", Path("/usr/lib"), Path("/usr/lib64")]
    # lib/cloudcompare or lib/<multiarch triplet>/cloudcompare, as Debian installs it (a
    # recursive search of /usr/lib cost 1.5 s at every collection)
    return any(any(r.glob(pattern)) for r in roots if r.is_dir()
               for pattern in ("cloudcompare/plugins/*E57*", "*/cloudcompare/plugins/*E57*"))


@pytest.mark.skipif(not _cloudcompare_e57_plugin(),
                    reason="CloudCompare without its E57 plugin (Debian 12 builds none)")
def test_cloudcompare_reads_the_e57(cloud, tmp_path):
    path = cloud.write(tmp_path / "c.e57")
    run = subprocess.run([shutil.which("xvfb-run"), "-a", shutil.which("CloudCompare"),
                          "-SILENT", "-NO_TIMESTAMP", "-O", str(path), "-C_EXPORT_FMT", "ASC",
                          "-ADD_HEADER", "-SAVE_CLOUDS"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300, stdin=subprocess.DEVNULL, env=_clean_qt_env())
    assert run.returncode == 0, run.stderr[-2000:]
    asc = next(tmp_path.glob("*.asc"))
    header = asc.read_text().splitlines()[0].lstrip("/").split()
    data = np.loadtxt(asc, comments="//", ndmin=2)
    # CloudCompare keeps coordinates in float32 and in the file's unit (metres)
    np.testing.assert_allclose(data[:, :3], cloud.xyz / 1000, atol=1e-7)
    assert "Intensity" in header or "intensity" in header
