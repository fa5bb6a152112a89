"""The calibration stage of the virtual scanner: a tilted stage axis and a printed target.

A real calibration stage does not move exactly along the camera axis, and a real flat
carries a printed pattern. ``[simulator] stage_tilt_deg`` tilts the stage axis against
the camera axis (towards ``stage_tilt_azimuth_deg``), ``target_tilt_deg`` turns the flat
about the X axis, and ``target = "chessboard"`` prints the marked chessboard of
:class:`scanqa.calibration.target.ChessboardSpec` on it.

The stage reading p puts the flat's centre (the chessboard's origin corner) at
``(0, 0, Z_ref) + (p - Z_ref) d`` with d the stage axis and Z_ref the camera's focus
distance, so that at p = Z_ref the origin lies on the camera axis; without tilt this is
today's flat at world Z = p.

Albedo: white 1, black ``1 - contrast``; the marker frame sees ``target_contrast``, the
fringe frames ``target_fringe_contrast`` (a print in a colour the fringe light hardly
sees keeps the phase free of texture bias). Each supersample gets the chessboard
box-filtered over its footprint on the target (exact for a footprint aligned with the
squares), and the marker dots their area coverage, so edges are anti-aliased.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanqa.calibration.target import ChessboardSpec
from scanqa.model.config import ScannerConfig
from scanqa.simulator import devices
from scanqa.simulator.devices import Pose
from scanqa.simulator.scene import Scene, flat_target


@dataclass(frozen=True)
class TargetFrame:
    """Pose of the printed target: origin and axes (rows e_x, e_y, e_z) in the world [mm].

    e_z points away from the scanner (into the target), so (e_x, e_y, e_z) is right
    handed like the camera frame.
    """

    origin: np.ndarray
    axes: np.ndarray

    def to_target(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 3) target coordinates [mm]."""
        return (np.asarray(points, float) - self.origin) @ self.axes.T

    def to_world(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) target-plane coordinates -> (..., 3) world points [mm]."""
        xy = np.asarray(xy, float)
        return self.origin + xy[..., :1] * self.axes[0] + xy[..., 1:2] * self.axes[1]


@dataclass(frozen=True)
class PrintedTarget:
    """A chessboard printed on a flat at a known frame."""

    frame: TargetFrame
    board: ChessboardSpec
    contrast: float
    fringe_contrast: float

    def albedo(self, world: np.ndarray, footprint_mm: np.ndarray, fringe: bool
               ) -> np.ndarray:
        """Reflectance of world points on the target, box-filtered over ``footprint_mm``.

        Parameters
        ----------
        world : (..., 3) float
            Points on the target [mm].
        footprint_mm : (...) float
            Side of each sample's footprint on the target [mm].
        fringe : bool
            Under the fringe light (``fringe_contrast``) or in the marker frame.
        """
        contrast = self.fringe_contrast if fringe else self.contrast
        t = self.frame.to_target(world)
        level = chessboard_level(self.board, t[..., 0], t[..., 1], footprint_mm)
        return 1.0 - contrast * (1.0 - level)


def _square_wave(x: np.ndarray, square: float, width: np.ndarray) -> np.ndarray:
    """Box-filtered square wave, +1 on [0, square), -1 on [square, 2 square) [-]."""
    ph = np.mod(x, 2.0 * square)
    dist = np.minimum(np.minimum(ph, np.abs(ph - square)), 2.0 * square - ph)
    sign = np.where(ph < square, 1.0, -1.0)
    return sign * np.clip(dist / np.maximum(width / 2.0, 1e-12), 0.0, 1.0)


def chessboard_level(board: ChessboardSpec, x: np.ndarray, y: np.ndarray,
                     footprint_mm: np.ndarray) -> np.ndarray:
    """White fraction of the marked chessboard around target points (x, y) [-]."""
    sq = board.square_mm
    level = 0.5 + 0.5 * _square_wave(x, sq, footprint_mm) * _square_wave(y, sq, footprint_mm)
    for i, j in board.marker_cells:
        d = np.hypot(x - (i + 0.5) * sq, y - (j + 0.5) * sq) - board.dot_radius * sq
        cover = np.clip(0.5 - d / np.maximum(footprint_mm, 1e-12), 0.0, 1.0)
        dot = 0.0 if board.is_white(i, j) else 1.0
        level = level * (1.0 - cover) + cover * dot
    return level


def stage_axis(config: ScannerConfig) -> np.ndarray:
    """Unit direction of the stage's motion in the world frame [-]."""
    sim = config.simulator
    t, az = math.radians(sim.stage_tilt_deg), math.radians(sim.stage_tilt_azimuth_deg)
    return np.array([math.sin(t) * math.cos(az), math.sin(t) * math.sin(az), math.cos(t)])


def target_frame(config: ScannerConfig, stage_mm: float) -> TargetFrame:
    """Frame of the flat at stage reading ``stage_mm`` (module notes) [mm]."""
    sim = config.simulator
    d = stage_axis(config)
    ref = config.camera.focus_mm
    origin = np.array([0.0, 0.0, stage_mm]) + (stage_mm - ref) * (d - [0.0, 0.0, 1.0])
    a = math.radians(sim.target_tilt_deg)
    axes = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)],
                     [0.0, -math.sin(a), math.cos(a)]])
    return TargetFrame(origin, axes)


def stage_flat(config: ScannerConfig, stage_mm: float,
               size_mm: tuple[float, float] = (200.0, 170.0)) -> Scene:
    """The calibration flat at a stage reading, printed when ``target`` asks for it."""
    sim = config.simulator
    frame = target_frame(config, stage_mm)
    flat = flat_target(frame.origin, -frame.axes[2], size_mm,
                       name=f"plane_z{stage_mm:g}")
    if sim.target != "none":
        flat.texture = PrintedTarget(frame, ChessboardSpec(sim.target_square_mm),
                                     sim.target_contrast, sim.target_fringe_contrast)
    return flat


def corner_truth(config: ScannerConfig, camera: Pose, target: PrintedTarget,
                 corners_xy: np.ndarray) -> np.ndarray:
    """Exact sensor positions (u, v) of target-plane points, e.g. chessboard corners.

    Parameters
    ----------
    corners_xy : (n, 2) float
        Target-plane coordinates [mm].

    Returns
    -------
    (n, 2) float
        Distorted sensor coordinates, pixel centres at integers [px].
    """
    u, v = devices.project_to_camera(config, camera, target.frame.to_world(corners_xy))
    return np.stack([u, v], -1)
