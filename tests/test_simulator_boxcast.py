"""The box scene's cast (scanqa.simulator.boxcast) against open3d's, ray by ray.

The reference is open3d's cast of the same float32 rays (``Scene._open3d_hits``, one
call); the renderer's hits, truth and images depend on the hit triangle only, so the
triangles must be equal for every ray - including rays aimed at the boxes' edges,
corners and the triangles' diagonals, where open3d's float32 decision and the exact one
may part (those are handed to open3d).
"""

from __future__ import annotations

from dataclasses import asdict, replace

import numpy as np
import pytest
import trimesh

from scanqa.model.config import CameraConfig
from scanqa.simulator import boxcast, devices, experiments, raykernels, render, scene


def _gauge(paper_config, width, height):
    """The gauge scan's acquisition with the paper's camera binned to width x height
    (the whole field of view: every block, edge and shadow)."""
    cam = paper_config.camera
    binned = CameraConfig(**{**asdict(cam), "width_px": width, "height_px": height,
                             "pixel_um": cam.pixel_um * cam.width_px / width})
    config = replace(paper_config, camera=binned)
    pos = experiments.build_positions("gauge-blocks", config, [0.0])[0]
    return config, experiments.acquisition(config, pos, 0, "gauge-blocks")


def _edge_rays(sc, origin, rng):
    """Rays from ``origin`` aimed at points on every box's edges, corners and face
    diagonals, and at points 1e-5 mm to 3e-3 mm beside them (float32, as cast)."""
    targets = []
    for k in range(len(sc.mesh.faces) // 12):
        tri = sc.mesh.vertices[sc.mesh.faces[12 * k:12 * k + 12]]  # (12, 3, 3)
        for a, b in ((0, 1), (1, 2), (2, 0)):  # the triangles' edges, diagonals included
            f = rng.uniform(0, 1, (12, 8, 1))
            targets.append((tri[:, a, None] * f + tri[:, b, None] * (1 - f)).reshape(-1, 3))
    targets = np.concatenate(targets)
    nudge = rng.normal(0, 1, targets.shape)
    nudge *= rng.choice([0.0, 1e-5, 1e-4, 1e-3, 3e-3], (len(targets), 1)) / np.linalg.norm(
        nudge, axis=1, keepdims=True)
    rays = np.empty((len(targets), 6), np.float32)
    rays[:, :3], rays[:, 3:] = origin, targets + nudge - origin
    return rays


def test_box_table_finds_the_gauge_scenes_boxes_only():
    gauge = scene.gauge_block_artefact()
    assert gauge.boxes is not None and gauge.boxes.shape == (9, 3, 2, 7)  # plate + 8
    # every triangle appears once, on the side of its box that it lies on
    faces = np.sort(gauge.boxes[:, :, :, 1:3].reshape(-1))
    np.testing.assert_array_equal(faces, np.arange(len(gauge.mesh.faces)))
    turned = trimesh.creation.box(extents=[10.0, 20.0, 30.0])  # 12 triangles, a box
    assert scene.Scene(turned.copy()).boxes is not None
    turned.apply_transform(trimesh.transformations.rotation_matrix(0.1, [0, 0, 1]))
    assert scene.Scene(turned).boxes is None  # not axis-aligned
    assert scene.flat_target([0.0, 0.0, 450.0], [0.0, 0.0, -1.0]).boxes is None
    assert scene.Scene(trimesh.creation.icosphere(1)).boxes is None  # 80 triangles


@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize("kind", ["camera", "shadow", "both"])
def test_box_cast_picks_open3ds_triangle_for_every_ray(paper_config, kind):
    # every supersample of the whole field of view (320 x 256 binned pixels, s = 3),
    # and its shadow ray from the projector to the hit, plus rays aimed at the edges;
    # "both": the two origins in one call (no shared origin: the slab test decides)
    config, acq = _gauge(paper_config, 320 if kind != "both" else 160, 256 if kind != "both"
                         else 128)
    sc, rng = acq.scene, np.random.default_rng(31)
    win = devices.sensor_window(config)
    uu, vv = render._supersample_grid(config, win, (0, win.height, 0, win.width), 0)
    origins, dirs = devices.camera_rays(config, acq.camera, uu, vv)
    origin = np.ascontiguousarray(origins.reshape(-1, 3)[0], np.float64)
    rays = raykernels.camera_rays32(origin, np.ascontiguousarray(dirs).reshape(-1, 3))
    camera = np.concatenate([rays, _edge_rays(sc, origin, rng)])
    if kind != "camera":
        pts = render._points(config, acq, uu, vv, 1)
        origin = np.asarray(acq.projector.centre, np.float64)
        hit = pts.hit.ravel()
        rays = raykernels.shadow_rays32(pts.world.reshape(-1, 3), hit, origin)
    rays = np.concatenate([rays, _edge_rays(sc, origin, rng)])
    if kind != "shadow":
        rays = camera if kind == "camera" else np.concatenate([camera, rays])
    sides = np.ascontiguousarray(sc.boxes[..., 0])  # (B, 3, 2) the boxes' bounds [mm]
    assert boxcast._windows(rays, sides)[:, 4].all() == (kind != "both")
    ref_prim, ref_t = sc._open3d_hits(rays, 0)
    code, _ = boxcast.first_triangles(rays, sc.boxes, boxcast.AMBIGUOUS_MM)
    prim, t = sc.first_hits(rays, 1)
    np.testing.assert_array_equal(prim, ref_prim)
    np.testing.assert_array_equal(np.isfinite(t), np.isfinite(ref_t))
    hit = ref_prim != raykernels.NO_HIT
    # the float32 ray parameters agree to open3d's float32 rounding (relative 1e-6)
    np.testing.assert_allclose(t[hit], ref_t[hit], rtol=1e-6)
    ambiguous = code == boxcast.AMBIGUOUS
    assert 0 < ambiguous.sum() < 0.02 * len(rays)  # the fallback ran, for few rays
    assert hit.any() and (kind == "shadow" or (~hit).any())


@pytest.mark.compiled_vs_numpy
def test_without_the_tolerance_some_triangles_differ_from_open3ds(paper_config):
    # why the rays near a decision go to open3d: decided exactly, rays aimed at the
    # diagonals and edges pick another triangle than open3d's float32 test now and then
    _, acq = _gauge(paper_config, 64, 64)
    sc = acq.scene
    rays = _edge_rays(sc, np.asarray(acq.camera.centre, np.float64),
                      np.random.default_rng(5))
    ref_prim, _ = sc._open3d_hits(rays, 0)
    code, _ = boxcast.first_triangles(rays, sc.boxes, 0.0)
    ref = np.where(ref_prim == raykernels.NO_HIT, boxcast.MISS, ref_prim.astype(np.int64))
    assert (code != ref).any()
    code, _ = boxcast.first_triangles(rays, sc.boxes, boxcast.AMBIGUOUS_MM)
    clear = code != boxcast.AMBIGUOUS
    np.testing.assert_array_equal(code[clear], ref[clear])
