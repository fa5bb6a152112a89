"""The simulator's VDI/VDE 2634-2 artefacts: meshes close to the ideal spheres, the
measuring volume and the seven ball-bar positions computed by hand, the experiment's
files, and (slow) a simulated sphere through decoding, the table and ``scanqa qa``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.artefacts import read_artefact_layout
from scanqa.io.spec import read_spec
from scanqa.io.tomlfile import read_toml
from scanqa.model.config import load_config
from scanqa.simulator import scene
from scanqa.simulator.experiments import artefact_geometry

from .conftest import ROOT
from .shared_runs import sample_table

SAMPLE = str(ROOT / "sample_data" / "sample_scanner.toml") + "#sample"


@pytest.fixture(scope="module")
def sample_config():
    return load_config(ROOT / "sample_data" / "sample_scanner.toml", profile="sample")


def sampled_departure(mesh, radius, rng, n=200_000):
    """Largest |distance from the centre - R| over random points of the faces [mm]."""
    face = rng.integers(0, len(mesh.faces), n)
    w = rng.dirichlet([1.0, 1.0, 1.0], n)
    tri = mesh.vertices[mesh.faces[face]]
    pts = np.einsum("ij,ijk->ik", w, tri)
    return float(np.max(np.abs(np.linalg.norm(pts, axis=1) - radius)))


@pytest.mark.parametrize("diameter", [12.0, 25.4])
def test_sphere_mesh_is_the_coarsest_within_tolerance(diameter):
    rng = np.random.default_rng(0)
    mesh = scene.sphere_mesh((0.0, 0.0, 0.0), diameter)
    dev = sampled_departure(mesh, diameter / 2, rng)
    assert dev <= scene.SPHERE_TOLERANCE_MM
    # the reported departure (deepest face plane) bounds the sampled one from above
    reported = scene.sphere_mesh_deviation(mesh, (0, 0, 0), diameter / 2)
    assert dev <= reported <= 1.2 * dev
    # one subdivision coarser is outside the tolerance: the mesh is no finer than needed
    sub = round(math.log(len(mesh.faces) / 20, 4))
    coarser = trimesh.creation.icosphere(subdivisions=sub - 1, radius=diameter / 2)
    assert sampled_departure(coarser, diameter / 2, rng) > scene.SPHERE_TOLERANCE_MM


def test_measuring_volume_is_seen_by_the_camera(sample_config):
    cam = sample_config.camera
    vol = scene.measuring_volume(sample_config)
    cx, cy, cz = vol.centre_mm
    sx, sy, sz = vol.size_mm
    assert (cx, cy, cz, sz) == (0.0, 0.0, cam.focus_mm, scene.VOLUME_DEPTH_MM)
    f = cam.focal_mm * cam.focus_mm / (cam.focus_mm - cam.focal_mm) / (cam.pixel_um * 1e-3)
    near = cz - sz / 2
    # the near face's corners fall at 90 % of the half-width / half-height of the sensor
    assert f * (sx / 2) / near == pytest.approx(0.9 * cam.width_px / 2)
    assert f * (sy / 2) / near == pytest.approx(0.9 * cam.height_px / 2)


def test_seven_ball_bar_positions_fit_the_volume(sample_config):
    vol = scene.measuring_volume(sample_config)
    r = scene.BALL_DIAMETER_MM / 2
    length = scene.ball_bar_distance(vol, 2 * r)
    positions = scene.ball_bar_positions(vol, length)
    assert len(positions) == 7 and length == 40.0
    half = np.asarray(vol.size_mm) / 2
    centre = np.asarray(vol.centre_mm)
    for label, a, b in positions:
        assert np.linalg.norm(b - a) == pytest.approx(length)
        assert np.allclose((a + b) / 2, centre)
        for c in (a, b):  # each ball wholly inside the volume
            assert np.all(np.abs(c - centre) + r <= half + 1e-9), label
    # space diagonals run corner to corner: their direction is the half-extents'
    d = positions[0][2] - positions[0][1]
    assert np.allclose(d / np.linalg.norm(d), half / np.linalg.norm(half))
    # a bar 1 mm longer leaves a ball outside in at least one position
    longer = scene.ball_bar_positions(vol, length + 1.0)
    assert any(np.any(np.abs(c - centre) + r > half) for _, a, b in longer for c in (a, b))


def test_ball_bar_positions_are_numbered_one_to_seven(sample_config):
    assert artefact_geometry("ball-bar", sample_config, 7.0)["label"] == "face diagonal yz"
    with pytest.raises(InputError, match="ball-bar positions are the numbers 1-7"):
        artefact_geometry("ball-bar", sample_config, 8.0)


@pytest.mark.slow
def test_simulated_sphere_files_and_qa(tmp_path, capsys):
    """``scanqa simulate sphere`` writes a layout, a spec and the truth; the truth points
    lie on the ideal sphere within the mesh's departure; the scan, decoded and turned into
    points by the committed sweep's table, gives PS within U of the true diameter and PF
    within 20 % of its prediction, with every section in the PDF."""
    data = tmp_path / "sphere"
    assert main(["simulate", "sphere", "--config", SAMPLE, "--out", str(data),
                 "--quiet"]) == 0
    truth = read_toml(data / "truth.toml", "truth")["artefact"][0]
    assert truth["diameter_mm"] == 12.0 and truth["mesh_deviation_mm"] <= 2e-4
    layout = read_artefact_layout(data / "artefacts.toml")
    assert layout["sphere"][0]["scan"] == "p000"
    assert read_spec(data / "spec.toml").sphere.diameter_mm == 12.0
    hits = np.load(data / "truth" / "p000.npz")
    valid = hits["valid"] & np.isfinite(hits["Z"])
    pts = np.stack([hits["X"][valid], hits["Y"][valid], hits["Z"][valid]], axis=1)
    r = np.linalg.norm(pts - np.asarray(truth["centre_mm"]), axis=1) - 6.0
    assert valid.sum() > 1000
    assert r.max() <= 1e-9 and r.min() >= -truth["mesh_deviation_mm"] - 1e-9

    table = sample_table(tmp_path)  # scanqa calibrate of the committed sweep, SAMPLE
    out = tmp_path / "qa"
    assert main(["qa", str(data / "p000_r0"), "--table", str(table), "--config", SAMPLE,
                 "--layout", str(data / "artefacts.toml"), "--spec", str(data / "spec.toml"),
                 "--operator", "closed loop", "--out", str(out)]) == 0
    info = json.loads((out / "summary.json").read_text())
    pf, ps = info["quantities"]
    assert abs(ps["value_um"]) <= ps["U_um"], ps
    assert abs(pf["predicted_um"] / pf["value_um"] - 1) <= 0.2, pf
    assert info["selections"][0]["grazing_removed"] > 0
    assert info["header"]["Calibration"].startswith(str(table))
