"""What annotation and QA need of a calibration, and loading one by its file suffix.

Two calibrations turn decoded phase into metric points:

- :class:`~scanqa.calibration.table.CalibrationTable`, the nonparametric table built from a
  plane sweep (``.npz``, :func:`~scanqa.calibration.table.load_table`);
- :class:`~scanqa.calibration.parametric.ParametricCalibration`, pinhole camera and
  projector with lens distortion from an OpenCV calibration (``.xml``, ``.yml``,
  ``.yaml``, ``.json``, :func:`~scanqa.calibration.parametric.load_opencv_calibration`).

Both satisfy :class:`Calibration`; :func:`scanqa.annotation.points.annotate` accepts either.
"""

from __future__ import annotations

import math
import os
from typing import Any, Protocol, runtime_checkable

import numpy as np

from scanqa.calibration.lookup import TableLookup
from scanqa.calibration.parametric import load_opencv_calibration
from scanqa.calibration.table import load_table
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io.opencv import is_opencv_file
from scanqa.model.config import ScannerConfig


@runtime_checkable
class Calibration(Protocol):
    """A map from camera pixel and decoded phase to metric points (module notes).

    ``apply_rows`` and ``in_volume_rows`` are called from several threads at once on
    disjoint bands of rows; ``image_grid`` (per-image constants, computed once) is read
    first, before the threads share it.
    """

    @property
    def width_px(self) -> int:
        """Camera image width [px]."""

    @property
    def height_px(self) -> int:
        """Camera image height [px]."""

    @property
    def weights(self) -> str:
        """How the calibration's samples were weighted (for output metadata)."""

    @property
    def cell_px(self) -> float:
        """Spacing over which the calibration's own errors are smoothed [camera px]."""

    @property
    def z_range_mm(self) -> tuple[float, float]:
        """Depth range the calibration covers [mm]."""

    @property
    def provenance(self) -> dict:
        """Where the calibration came from (plain JSON)."""

    @property
    def image_grid(self) -> Any:
        """Per-image constants of whole-image lookups (computed once)."""

    def apply_rows(self, xp_rows: np.ndarray, row0: int = 0, select: np.ndarray | None = None,
                   extrapolate: bool = False) -> TableLookup:
        """X, Y, Z [mm], dQ/dx_p [mm / projector px], own sigma [mm] and in-volume flag of
        rows row0.. of a phase map [projector px] (all pixels, or flat indices
        ``select``); points outside the volume are NaN unless ``extrapolate``."""

    def in_volume_rows(self, xp_rows: np.ndarray, row0: int = 0) -> np.ndarray:
        """Whether each phase of rows row0.. lies inside the calibrated volume."""

    def check_scan(self, config: ScannerConfig, phase_map: PhaseMap,
                   source: str = "scan") -> None:
        """Raise one clear error unless scan and config belong to the calibrated scanner."""


def load_calibration(path: str | os.PathLike, config: ScannerConfig | None = None,
                     orientation: str = "vertical",
                     depth_range_mm: tuple[float, float] = (0.0, math.inf)) -> Calibration:
    """Load a calibration table (``.npz``) or an OpenCV calibration (``.xml``, ``.yml``,
    ``.yaml``, ``.json``, optionally ``.gz``).

    Parameters
    ----------
    path : str or PathLike
        The file.
    config : ScannerConfig, optional
        Supplies the camera and projector sizes an OpenCV file may lack.
    orientation : str
        Fringe orientation of the scans an OpenCV calibration will triangulate
        ("vertical": x_p, "horizontal": y_p); a table ignores it.
    depth_range_mm : (float, float)
        Z_c range an OpenCV calibration counts as in volume [mm]; a table has its own.

    Returns
    -------
    Calibration
    """
    if is_opencv_file(path):
        sizes = {} if config is None else {
            "camera_size": (config.camera.width_px, config.camera.height_px),
            "projector_size": (config.projector.width_px, config.projector.height_px)}
        return load_opencv_calibration(path, orientation, depth_range_mm, **sizes)
    if str(path).lower().endswith(".npz"):
        return load_table(path)
    raise InputError(f"{path}: unknown calibration format (a scanqa table .npz, or an OpenCV "
                     "calibration .xml, .yml, .yaml or .json)")
