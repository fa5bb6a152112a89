"""The observations of a calibration sweep: one decoded scan of the flat per position
and repeat, loaded (or decoded) one at a time (:mod:`scanqa.io.sweep` reads the manifest).
"""

from __future__ import annotations

import os
from collections.abc import Iterator

from scanqa.calibration.build import BuildReport, PlaneObservation, build_table
from scanqa.calibration.table import CalibrationTable
from scanqa.config import ScannerConfig
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io.sweep import Sweep, load_sweep, read_lateral

__all__ = ["Sweep", "calibrate", "iter_observations", "load_sweep"]


def iter_observations(sweep: Sweep) -> Iterator[PlaneObservation]:
    """Yield one PlaneObservation per scan, loading (or decoding) one at a time."""
    for pos in sweep.positions:
        lat = read_lateral(pos.lateral) if pos.lateral else (None, None)
        for src in pos.sources:
            pm = decode(src)
            if lat[0] is not None and lat[0].shape != pm.xp.shape:
                raise InputError(f"{pos.lateral}: lateral maps are {lat[0].shape[::-1]} px, "
                                 f"the scan {src} is {pm.xp.shape[::-1]} px")
            yield PlaneObservation(pos.z_mm, pm.xp, pm.mask, pm.modulation, pm.sigma_xp,
                                   lat[0], lat[1], str(src))


def calibrate(sweep: Sweep | str | os.PathLike, config: ScannerConfig,
              weights: str = "model", cell_px: int | None = None,
              min_modulation: float = 0.0) -> tuple[CalibrationTable, BuildReport]:
    """Build the calibration table of a sweep (the weighted calibration run).

    Parameters
    ----------
    sweep : Sweep or str or PathLike
        A loaded sweep manifest, or the path of its ``sweep.toml`` (or folder).
    config : ScannerConfig
        The scanner config; its ``[model]`` gives the noise-aware weights.
    weights : {"model", "modulation", "none"}
        Weight of each sample: 1 / sigma^2 from the optics model (default), from the
        decoder's phase noise, or equal weights.
    cell_px : int, optional
        Node spacing [camera px]; default about 0.45 mm on the object.
    min_modulation : float
        Samples with modulation below this are rejected [DN]; 0 keeps the decoder's mask.

    Returns
    -------
    table : CalibrationTable
        The table (``table.save(path)`` writes it).
    report : BuildReport
        Rejected samples by reason and the fit residual per position.
    """
    sweep = sweep if isinstance(sweep, Sweep) else load_sweep(sweep)
    return build_table(iter_observations(sweep), config, weights=weights, cell_px=cell_px,
                       min_modulation=min_modulation, provenance=sweep.provenance(),
                       total=sweep.observation_count())
