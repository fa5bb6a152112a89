"""The usable volume (Sect. 5.1, Fig. 6) against a voxel-by-voxel evaluation.

:func:`scanqa.design.tools.usable_volume` evaluates the model once per distinct (Z_c, Z_p) pair
and broadcasts the frusta tests; the reference here stacks every voxel centre, projects
it with the pinhole camera and projector and calls :func:`scanqa.model.optics.predict` on each,
as the function did before it was made fast enough for the design page.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scanqa.design import tools
from scanqa.errors import RangeError
from scanqa.model import geometry, optics


def reference_counts(config, level, step, coc_max=None):
    """(total, usable) voxel counts of the grid usable_volume uses, one voxel at a time."""
    focus = config.camera.focus_mm
    zs = tools._z_grid(0.75 * focus, 1.25 * focus, step)
    half = tools.field_half_extent(config, 1.25 * focus)
    xs = np.arange(-half[0], half[0] + step, step)
    ys = np.arange(-half[1], half[1] + step, step)
    z, y, x = np.meshgrid(zs, ys, xs, indexing="ij")
    pts = np.stack([x, y, z], axis=-1)
    cam, proj = config.camera, config.projector
    u = cam.principal_distance_px * x / z + cam.principal_point_px[0]
    v = cam.principal_distance_px * y / z + cam.principal_point_px[1]
    qp = geometry.to_projector_frame(pts, config)  # a matmul rounds differently at the edges
    xp = proj.principal_distance_px * qp[..., 0] / qp[..., 2] + proj.principal_point_px[0]
    yp = proj.principal_distance_px * qp[..., 1] / qp[..., 2] + proj.principal_point_px[1]
    inside = (u >= -0.5) & (u <= cam.width_px - 0.5) & (v >= -0.5) \
        & (v <= cam.height_px - 0.5) & (qp[..., 2] > 0) & (xp >= -0.5) \
        & (xp <= proj.width_px - 0.5) & (yp >= -0.5) & (yp <= proj.height_px - 0.5)
    pred = optics.predict(pts, config)
    good = pred.attenuation_camera * pred.attenuation_projector >= level
    if coc_max is not None:
        good &= optics.image_blur_diameter(z, cam.focal_mm, cam.focus_mm,
                                           cam.aperture_mm) <= coc_max
    return int(inside.sum()), int((inside & good).sum())


def off_plane(config):
    """The paper scanner with its projector raised 30 mm: Z_p then varies with Y too."""
    proj = dataclasses.replace(config.projector, position_mm=(140.0, -30.0, 0.0))
    return dataclasses.replace(config, projector=proj)


@pytest.mark.parametrize("variant", ["paper", "off_plane"])
@pytest.mark.parametrize(("level", "coc_max"), [(0.49, None), (0.49, 0.030), (0.81, None)])
def test_usable_volume_counts_every_voxel_as_the_reference(paper_config, variant, level,
                                                           coc_max):
    config = paper_config if variant == "paper" else off_plane(paper_config)
    step = 4.0  # coarse: the reference holds the whole grid in memory
    vol = tools.usable_volume(config, level, step=step, coc_max_mm=coc_max)
    total, usable = reference_counts(config, level, step, coc_max)
    assert (vol.total_mm3, vol.usable_mm3) == (total * step**3, usable * step**3)
    assert 0 < usable < total


def test_paper_scanner_volume_at_fig6_thresholds(paper_config):
    """The numbers the design page must show (Fig. 6: A_c A_p >= 0.49, c_c < 0.030 mm),
    at the 1 mm voxels of ``scanqa design volume``; recorded when the fast path replaced the
    voxel-by-voxel loop, which gave the same 906957 and 92242 mm^3."""
    vol = tools.usable_volume(paper_config, 0.49)
    assert (vol.total_mm3, vol.usable_mm3) == (906957.0, 92242.0)
    cut = tools.usable_volume(paper_config, 0.49, coc_max_mm=0.030)
    assert cut.usable_mm3 < vol.usable_mm3


def test_coc_band_solves_eq14(paper_config):
    near, far = tools.coc_band(paper_config, 0.030)
    # c_c at the band's ends is the threshold (Eq. 14), to rounding
    np.testing.assert_allclose(tools.camera_image_blur(np.array([near, far]), paper_config),
                               0.030, rtol=1e-12)
    assert near < paper_config.camera.focus_mm < far
    with pytest.raises(RangeError, match="coc_max_mm must be > 0"):
        tools.coc_band(paper_config, 0.0)
