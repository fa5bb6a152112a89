"""Clouds that viewers colour by the fringe offset: grey RGB and intensity in the PLY.

Debian's CloudCompare has no LAS plugin, so the PLY export carries what the LAS export
has (intensity and a grey RGB from ``offset_dn``, the fringe offset [DN]); these tests
read it back through the real CloudCompare binary and through Open3D. The expected grey
levels are computed here from the offsets with ``np.percentile`` (float64), independently
of :func:`scanqa.io.las.grey_levels` (its own quantile selection).
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.annotation import points
from scanqa.annotation.points import annotate
from scanqa.chunks import row_bands
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io.las import grey_levels, top_level
from scanqa.io.ply import DISPLAY_COMMENT, read_ply, write_ply

from .synth_sweep import plane_truth
from .test_annotate import H, W, _cloudcompare_asc, cfg, table  # noqa: F401 - fixtures


def _expected_grey(offset: np.ndarray) -> np.ndarray:
    """16-bit grey levels: the 99.9th percentile of the offset is 65535 (LAS intensity)."""
    off = np.nan_to_num(offset.astype(float), nan=0.0)
    return np.clip(np.rint(off * 65535 / np.percentile(off, 99.9)), 0, 65535)


@pytest.fixture(scope="module")
def scan(cfg):  # noqa: F811 - the fixture of test_annotate
    """A scan whose offset varies from 20 to 1200 DN across the image (a ramp with a
    pattern, so that the grey levels take ~250 values)."""
    xp, _ = plane_truth(cfg, 447.0)
    v, u = np.mgrid[0:H, 0:W]
    offset = 20.0 + 1180.0 * (u + W * v) / (W * H - 1) + 15.0 * np.sin(u)
    return PhaseMap(xp=xp, modulation=np.full(xp.shape, 400.0), offset=offset,
                    mask=np.zeros(xp.shape, np.uint8), sigma_xp=np.full(xp.shape, 0.02),
                    period_px=5.0, projector_width_px=1280)


@pytest.fixture(scope="module")
def cloud(scan, cfg, table):  # noqa: F811 - the fixture of test_annotate
    return annotate(scan, table, cfg)


def test_grey_levels_match_the_percentile_rule(cloud):
    off = cloud.attributes["offset_dn"]
    grey = grey_levels(off)
    expected = _expected_grey(off)
    np.testing.assert_array_equal(grey, expected)
    assert grey.max() == 65535
    # NaN and negative offsets are black; the top is the percentile, not the maximum
    np.testing.assert_array_equal(grey_levels(np.array([np.nan, -5.0, 10.0, 5.0])),
                                  _expected_grey(np.array([np.nan, -5.0, 10.0, 5.0])))
    assert len(np.unique(grey)) > 200


@pytest.mark.parametrize("fraction", [0.0, 0.5, 0.999, 1.0])
def test_top_level_is_numpys_percentile(fraction):
    rng = np.random.default_rng(3)
    for values in (rng.normal(900, 50, 100_003), rng.exponential(100, 5001),
                   np.full(999, 7.0), np.arange(3.0)):
        v = values.astype(np.float32)
        # the same two order statistics, interpolated in float64 (numpy: in float32)
        np.testing.assert_allclose(top_level(v, fraction), np.percentile(v, 100 * fraction),
                                   rtol=1e-6)
    assert top_level(np.empty(0, np.float32), 0.999) == 0.0


def test_ply_carries_grey_rgb_and_intensity_that_our_reader_leaves_out(cloud, tmp_path):
    path = cloud.write(tmp_path / "cloud.ply")
    head = path.read_bytes()[:8192].split(b"end_header")[0].decode()
    assert DISPLAY_COMMENT in head
    assert head.index("property float intensity") > head.index("property float "
                                                               "scalar_table_corr_mm")
    for colour in ("red", "green", "blue", "alpha"):
        assert f"property uchar {colour}\n" in head
    xyz, attrs, _ = read_ply(path)
    assert list(attrs) == list(cloud.attributes)  # derived, not data: left out again
    # a cloud with colours of its own keeps them, and gets no grey
    rgb = np.arange(len(cloud), dtype=np.uint8)
    own = write_ply(tmp_path / "own.ply", xyz, {**attrs, "red": rgb, "green": rgb,
                                                 "blue": rgb})
    assert DISPLAY_COMMENT not in own.read_bytes()[:8192].decode("ascii", "replace")
    np.testing.assert_array_equal(read_ply(own)[1]["green"], rgb)


def test_cloudcompare_shows_the_offset_as_intensity_and_grey(cloud, tmp_path):
    path = cloud.write(tmp_path / "cloud.ply")
    header, data = _cloudcompare_asc(path, tmp_path)
    assert header[3:6] == ["R", "G", "B"] and "intensity" in header  # (normals after)
    grey = _expected_grey(cloud.attributes["offset_dn"])
    np.testing.assert_array_equal(data[:, header.index("intensity")], grey)
    for channel in ("R", "G", "B"):  # 8-bit colour: the top byte of the 16-bit level
        np.testing.assert_array_equal(data[:, header.index(channel)], grey // 256)
    assert data[:, 3].min() < 10 and data[:, 3].max() == 255  # near black to white


def test_open3d_shows_the_offset_as_grey_colours(cloud, tmp_path):
    o3d = pytest.importorskip("open3d")
    path = cloud.write(tmp_path / "cloud.ply")
    grey = _expected_grey(cloud.attributes["offset_dn"])
    legacy = o3d.io.read_point_cloud(str(path))
    colours = np.asarray(legacy.colors)
    assert colours.shape == (len(cloud), 3)
    np.testing.assert_allclose(colours, np.repeat((grey // 256)[:, None], 3, 1) / 255,
                               atol=1e-12)  # Open3D scales uchar colours to [0, 1]
    pcd = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(pcd.point["intensity"].numpy().ravel(), grey)
    np.testing.assert_array_equal(pcd.point["colors"].numpy()[:, 0], grey // 256)


def test_las_and_ply_agree_on_intensity(cloud, tmp_path):
    laspy = pytest.importorskip("laspy")
    las = laspy.read(str(cloud.write(tmp_path / "cloud.las")))
    o3d = pytest.importorskip("open3d")
    pcd = o3d.t.io.read_point_cloud(str(cloud.write(tmp_path / "cloud.ply")))
    np.testing.assert_array_equal(np.asarray(las.intensity),
                                  pcd.point["intensity"].numpy().ravel())
    np.testing.assert_array_equal(np.asarray(las.red) >> 8,
                                  pcd.point["colors"].numpy()[:, 0])


def test_annotating_into_the_file_writes_the_same_bytes(scan, cloud, cfg, table,  # noqa: F811
                                                        tmp_path):
    """annotate(out=...) fills the records inside the output file's mapping (issue 31):
    byte for byte the file of the chunk packer, which packs separate copies of the arrays
    and takes its grey levels from grey_levels, an independent path; the returned cloud
    maps the published file read-only."""
    direct = annotate(scan, table, cfg, out=tmp_path / "direct.ply")
    packed = write_ply(tmp_path / "packed.ply", np.array(cloud.xyz),
                       {k: np.array(v) for k, v in cloud.attributes.items()}, cloud.metadata)
    assert (tmp_path / "direct.ply").read_bytes() == packed.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["direct.ply", "packed.ply"]
    np.testing.assert_array_equal(direct.xyz, cloud.xyz)
    assert not direct.attributes["sigma_total_um"].flags.writeable
    # written again (the chunk packer, as the records are read-only): the same bytes
    again = direct.write(tmp_path / "again.ply")
    assert again.read_bytes() == packed.read_bytes()


def test_display_of_the_file_mapping_blackens_negative_offsets(scan, cfg, table,  # noqa: F811
                                                               tmp_path):
    offset = scan.offset.copy()  # (a decoded pixel's offset is finite: no NaN to test)
    offset[1::5, ::4] = -40.0
    pm = PhaseMap(xp=scan.xp, modulation=scan.modulation, offset=offset, mask=scan.mask,
                  sigma_xp=scan.sigma_xp, period_px=5.0, projector_width_px=1280)
    cloud = annotate(pm, table, cfg, out=tmp_path / "c.ply")
    o3d = pytest.importorskip("open3d")
    pcd = o3d.t.io.read_point_cloud(str(tmp_path / "c.ply"))
    grey = _expected_grey(cloud.attributes["offset_dn"])
    assert (grey == 0).sum() > len(cloud) // 20
    np.testing.assert_array_equal(pcd.point["intensity"].numpy().ravel(), grey)
    np.testing.assert_array_equal(pcd.point["colors"].numpy()[:, 0], grey // 256)


def test_annotating_into_a_file_refuses_other_formats_and_empty_clouds(scan, cfg, table,  # noqa: F811
                                                                        tmp_path):
    with pytest.raises(InputError, match=r"give a \.ply name"):
        annotate(scan, table, cfg, out=tmp_path / "c.las")
    far = PhaseMap(xp=np.full_like(scan.xp, 1e6), modulation=scan.modulation,
                   offset=scan.offset, mask=scan.mask, sigma_xp=scan.sigma_xp,
                   period_px=5.0, projector_width_px=1280)
    with pytest.raises(InputError, match="no point lies inside the calibrated volume"):
        annotate(far, table, cfg, out=tmp_path / "c.ply")
    assert list(tmp_path.iterdir()) == []


def test_bands_fill_the_display_of_the_kept_points_only(scan, cfg, table, monkeypatch,  # noqa: F811
                                                        tmp_path):
    """Each band of annotate(out=...) fills its own display fields with a grey scale
    known before the bands run (issue 31): it must be that of the kept points' offsets
    only. Pixels left out (outside the calibrated volume) carry offsets 10x the others,
    which would move the 99.9th percentile; 13 bands on the pool instead of one. The
    reference is the chunk packer of write_ply (grey_levels of the written cloud)."""
    xp, offset = scan.xp.copy(), scan.offset.copy()
    xp[::7, ::3], offset[::7, ::3] = 1e6, 12000.0  # far outside: left out
    pm = PhaseMap(xp=xp, modulation=scan.modulation, offset=offset, mask=scan.mask,
                  sigma_xp=scan.sigma_xp, period_px=5.0, projector_width_px=1280)
    monkeypatch.setattr(points, "row_bands", lambda rows, size: row_bands(rows, size, 500))
    direct = annotate(pm, table, cfg, out=tmp_path / "direct.ply")
    assert direct.counts["out_of_volume"] == xp[::7, ::3].size
    assert np.all(direct.attributes["offset_dn"] < 1300.0)
    kept = annotate(pm, table, cfg)
    packed = write_ply(tmp_path / "packed.ply", np.array(kept.xyz),
                       {k: np.array(v) for k, v in kept.attributes.items()}, kept.metadata)
    assert (tmp_path / "direct.ply").read_bytes() == packed.read_bytes()


def test_the_display_fields_derive_from_the_ply_offset_property():
    """ply_display names the property it reads without importing ply (no cycle): the name
    must be the one ply writes the LAS intensity source under."""
    from scanqa.io import ply, ply_display
    from scanqa.io.las import INTENSITY_SOURCE

    assert ply_display.LEVEL_FIELD == ply.PREFIX + INTENSITY_SOURCE == "scalar_offset_dn"
