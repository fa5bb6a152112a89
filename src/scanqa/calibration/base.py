"""What annotation and QA need of a calibration, and loading one by its file suffix.

Two calibrations turn decoded phase into metric points:

- :class:`~scanqa.calibration.table.CalibrationTable`, the nonparametric table built from a
  plane sweep (``.npz``, :func:`~scanqa.calibration.table.load_table`);
- :class:`~scanqa.calibration.parametric.ParametricCalibration`, pinhole camera and
  projector with lens distortion from an OpenCV calibration (``.xml``, ``.yml``,
  ``.yaml``, ``.json``, :func:`~scanqa.calibration.parametric.load_opencv_calibration`).

Both satisfy :class:`Calibration`; :func:`scanqa.annotation.points.annotate` accepts either.

A parametric calibration from another tool carries no calibration term unless its file
holds one; :func:`load_calibration` takes one beside it (:func:`with_calibration_term`):
a covariance file (:mod:`scanqa.io.covariance`) or a stated std [um]. A table carries
its own (its cell std) and takes neither.
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from scanqa.calibration.lookup import TableLookup
from scanqa.calibration.parametric import ParametricCalibration, load_opencv_calibration
from scanqa.calibration.table import load_table
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io.covariance import read_covariance
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
                     depth_range_mm: tuple[float, float] = (0.0, math.inf),
                     covariance: str | os.PathLike | None = None,
                     sigma_um: float | None = None) -> Calibration:
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
    covariance : str or PathLike, optional
        An OpenCV calibration's parameter covariance from a covariance file
        (:mod:`scanqa.io.covariance`; ``--calibration-covariance``).
    sigma_um : float, optional
        Instead: a stated calibration std of every point along its line of sight [um]
        (``--calibration-sigma-um``).

    Returns
    -------
    Calibration
    """
    if is_opencv_file(path):
        sizes = {} if config is None else {
            "camera_size": (config.camera.width_px, config.camera.height_px),
            "projector_size": (config.projector.width_px, config.projector.height_px)}
        cal = load_opencv_calibration(path, orientation, depth_range_mm, **sizes)
        return with_calibration_term(cal, covariance, sigma_um)
    if str(path).lower().endswith(".npz"):
        if covariance is not None or sigma_um is not None:
            raise InputError(f"{path} is a calibration table, which carries its own "
                             "calibration term (its cell std): a covariance file or a stated "
                             "std is for an OpenCV calibration; give neither")
        return load_table(path)
    raise InputError(f"{path}: unknown calibration format (a scanqa table .npz, or an OpenCV "
                     "calibration .xml, .yml, .yaml or .json)")


def with_calibration_term(cal: ParametricCalibration,
                          covariance: str | os.PathLike | None = None,
                          sigma_um: float | None = None) -> ParametricCalibration:
    """``cal`` with its calibration term given beside its file: the covariance of a
    covariance file, or a stated std; either replaces what the file held. Neither:
    ``cal`` unchanged.

    Parameters
    ----------
    cal : ParametricCalibration
        The calibration.
    covariance : str or PathLike, optional
        A covariance file (:mod:`scanqa.io.covariance`).
    sigma_um : float, optional
        A stated std of every point along its line of sight [um], >= 0 and finite.

    Raises
    ------
    InputError
        Both given, a stated std that is negative or not finite, or a bad covariance
        file (naming the file and the field).
    """
    if covariance is not None and sigma_um is not None:
        raise InputError("give either a calibration covariance file or a stated std of "
                         f"the calibration ({sigma_um:g} um), not both")
    if sigma_um is not None:
        if not (isinstance(sigma_um, (int, float)) and math.isfinite(sigma_um)
                and 0 <= sigma_um <= 1e6):
            raise InputError(f"the stated calibration std must be a number in [0, 1e6] "
                             f"um, got {sigma_um!r:.40}")
        return replace(cal, covariance=None, stated_sigma_mm=1e-3 * float(sigma_um),
                       term_source="a std stated beside the calibration "
                       "(--calibration-sigma-um, sigma_um)")
    if covariance is not None:
        return replace(cal, covariance=read_covariance(covariance), stated_sigma_mm=None,
                       term_source=f"covariance file {Path(covariance)}")
    return cal
