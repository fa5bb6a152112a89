"""The virtual phase-shift scanner: scenes, pinhole devices, image formation, experiments.

It forms images from physics (ray casting, numerical defocus integration, noise before
and after the camera blur, sensor) and never draws noise from the closed-form sigma of
:mod:`scanqa.model.optics`; agreement with the model is a measured result
(``scanqa characterize``).

Main entry points: :func:`run_experiment` (write an experiment folder),
:func:`render_images` and :func:`truth_for` (one acquisition in memory),
:func:`scanqa.io.manifest.read_manifest` (read a folder back).
"""

from __future__ import annotations

from scanqa.simulator.devices import Pose, camera_pose, projector_pose, sensor_window
from scanqa.simulator.experiments import (
    EXPERIMENTS,
    acquisition,
    build_positions,
    pattern_description,
    run_experiment,
)
from scanqa.simulator.render import Acquisition, Truth, render_images, truth_for
from scanqa.simulator.scene import (
    GAUGE_HEIGHTS_MM,
    Scene,
    flat_target,
    gauge_block_artefact,
    load_mesh,
    paper_gauge_layout,
    plane_scene,
)

__all__ = [
    "EXPERIMENTS", "GAUGE_HEIGHTS_MM", "Acquisition", "Pose", "Scene", "Truth",
    "acquisition", "build_positions", "camera_pose", "flat_target", "gauge_block_artefact",
    "load_mesh", "paper_gauge_layout", "pattern_description", "plane_scene",
    "projector_pose", "render_images", "run_experiment", "sensor_window", "truth_for",
]
