"""The observations of a calibration sweep: one decoded scan of the flat per position
and repeat, loaded (or decoded) one at a time (:mod:`scanqa.io.sweep` reads the manifest).

A sweep with marker frames (``markers`` on every position and a ``[target]`` table) gets
its lateral geometry from the printed target: :func:`marker_geometry` detects it in every
marker frame and fits the camera and the stage (:mod:`scanqa.calibration.sweep_fit`), and
each observation carries the X, Y, Z of the target plane per pixel.

Before anything is built, :func:`check_sweep` compares the sweep with the config: the
``[scanner]`` table of the manifest, the config a simulated sweep was made with
(``manifest.toml`` beside it), the image size, and the scale of the images (the phase's
slope across the image, or the marker-derived focal length) against ``camera.pixel_um``
and ``camera.focal_mm``. Each mismatch is one error naming the file, the key and the fix.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from scanqa.calibration.build import BuildReport, PlaneObservation, build_table, check_camera_size
from scanqa.calibration.sweep_fit import SweepGeometry, fit_sweep_geometry, geometry_from_summary
from scanqa.calibration.table import CalibrationTable
from scanqa.calibration.target import ChessboardSpec, detect_chessboard
from scanqa.calibration.uncertainty import (
    GeometryCovariance,
    marker_covariance,
    marker_error_summary,
    parametric_covariance,
)
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io import manifest as manifest_file
from scanqa.io.images import read_image
from scanqa.io.opencv import require_opencv
from scanqa.io.sweep import SCANNER_FIELDS, Sweep, load_sweep, read_lateral
from scanqa.io.tomlfile import read_toml
from scanqa.model import geometry, optics
from scanqa.model.config import ScannerConfig, first_difference

__all__ = ["Sweep", "calibrate", "check_sweep", "geometry_covariance", "iter_observations",
           "load_sweep", "marker_geometry", "marker_image"]

#: The images' scale may differ from the config's by this factor before it is an error
#: (distortion and a tilted target change the local scale by a few per cent) [-].
SCALE_TOLERANCE = 1.25
#: The bound on the table's error: this share of the optics model's single-point sigma
#: on the camera axis at focus (the 0.1 sigma criterion, docs/calibration.rst) [-].
TABLE_BOUND_SIGMA = 0.1
#: Config sections a simulated sweep must share with the config it is calibrated with.
_SIMULATED_SECTIONS = ("camera", "projector")


def iter_observations(sweep: Sweep, geometry: SweepGeometry | None = None
                      ) -> Iterator[PlaneObservation]:
    """Yield one PlaneObservation per scan, loading (or decoding) one at a time.

    With ``geometry`` (:func:`marker_geometry`), each carries the target plane's X, Y, Z
    per pixel at its stage reading.
    """
    for pos in sweep.positions:
        lat = read_lateral(pos.lateral) if pos.lateral else (None, None)
        z_map = None
        for src in pos.sources:
            pm = decode(src)
            if geometry is not None and z_map is None:
                lat_x, lat_y, z_map = geometry.plane_points(pos.z_mm, pm.xp.shape[1],
                                                            pm.xp.shape[0])
                lat = (lat_x, lat_y)
            if lat[0] is not None and lat[0].shape != pm.xp.shape:
                raise InputError(f"{pos.lateral}: lateral maps are {lat[0].shape[::-1]} px, "
                                 f"the scan {src} is {pm.xp.shape[::-1]} px")
            yield PlaneObservation(pos.z_mm, pm.xp, pm.mask, pm.modulation, pm.sigma_xp,
                                   lat[0], lat[1], str(src), z_map)


def marker_geometry(sweep: Sweep, config: ScannerConfig) -> SweepGeometry:
    """Detect the printed target in every marker frame and fit camera and stage.

    Raises
    ------
    InputError
        The sweep has no marker frames, a frame is not the camera's size, the target is
        not found, or the fitted focal length contradicts the config's pixel size.
    """
    require_opencv("the printed target of a sweep's marker frames")
    if not sweep.has_markers or sweep.target is None:
        raise InputError(f"{sweep.path}: no marker frames (give 'markers' on every "
                         "position and a [target] table)")
    cells = sweep.target.get("marker_cells")
    spec = ChessboardSpec(float(sweep.target["square_mm"]),
                          *(() if cells is None else (tuple(map(tuple, cells)),)))
    detections, size = [], None
    for pos in sweep.positions:
        image = marker_image(pos.marker_frames, config)
        size = image.shape
        detections.append(detect_chessboard(image, spec, str(pos.marker_frames[0])))
    geometry = fit_sweep_geometry(detections, [p.z_mm for p in sweep.positions], config,
                                  size[1], size[0])
    _check_focal(geometry, config, sweep.path)
    return geometry


def marker_image(frames, config: ScannerConfig) -> np.ndarray:
    """The mean of one position's marker frames, (H, W) float64 [DN].

    The target does not move between them, so averaging N frames divides the image
    noise's variance, and with it that of the corners and of the marker fit (its target
    rotation above all: docs/calibration.rst, "How many marker frames"), by N.

    Raises
    ------
    InputError
        A frame is not the camera's size.
    """
    total = None
    for frame in frames:
        image = read_image(frame)
        _check_size(image.shape, config, frame)
        total = image.astype(float) if total is None else total + image
    return total / len(frames)


def _check_size(shape: tuple, config: ScannerConfig, source) -> None:
    """A marker frame must be the config's camera size."""
    cam = config.camera
    if tuple(shape[:2]) != (cam.height_px, cam.width_px):
        raise InputError(
            f"{source}: the image is {shape[1]} x {shape[0]} px but the config "
            f"({config.source or config.name}) has camera.width_px x camera.height_px = "
            f"{cam.width_px} x {cam.height_px}: use the config of the camera that took the "
            "sweep (for binned images, the binned size and pixel_um)")


def _check_focal(geometry: SweepGeometry, config: ScannerConfig, where) -> None:
    """The marker-derived focal length must match focal_mm / pixel_um."""
    fitted = float(geometry.camera.matrix[0, 0])
    _check_ratio(fitted / config.camera.principal_distance_px, config, where,
                 f"the printed target gives a focal length of {fitted:.0f} px")


def _check_ratio(ratio: float, config: ScannerConfig, where, what: str) -> None:
    if not (1.0 / SCALE_TOLERANCE < ratio < SCALE_TOLERANCE):
        cam, name = config.camera, config.source or config.name
        raise InputError(
            f"{where}: {what}, {ratio:.3g} times what the config ({name}) implies "
            f"with camera.pixel_um = {cam.pixel_um:g} and "
            f"camera.focal_mm = {cam.focal_mm:g}: set camera.pixel_um to the pixel size of "
            "these images (binning multiplies it) and focal_mm to the lens's")


def check_sweep(sweep: Sweep, config: ScannerConfig) -> None:
    """Refuse a config that disagrees with the sweep (module notes).

    Raises
    ------
    InputError
        On the first mismatch, naming the file, the key and the fix.
    """
    _check_scanner_table(sweep, config)
    _check_simulated(sweep, config)


def _check_scanner_table(sweep: Sweep, config: ScannerConfig) -> None:
    for key, field in SCANNER_FIELDS.items():
        have = (sweep.scanner or {}).get(key)
        want = getattr(config.camera, field)
        if have is not None and not np.isclose(float(have), float(want), rtol=1e-9):
            raise InputError(
                f"{sweep.path}: [scanner] {key} = {have} but the config "
                f"({config.source or config.name}) has camera.{field} = {want}: calibrate "
                "with the config the sweep was captured with")


def _check_simulated(sweep: Sweep, config: ScannerConfig) -> None:
    """A simulated sweep's manifest.toml records its config: camera and projector must
    be the same."""
    manifest = Path(sweep.path).parent / "manifest.toml"
    if not manifest.is_file():
        return
    data = read_toml(manifest, "experiment manifest")
    if data.get("format") == manifest_file.FORMAT:  # another file of that name: not ours
        manifest_file.SCHEMA.validate(data, manifest)
    sim = data.get("config")
    if not isinstance(sim, dict):
        return
    diff = first_difference(config, sim, _SIMULATED_SECTIONS)
    if diff is not None:
        section, key, mine, value = diff
        raise InputError(
            f"{manifest}: the sweep was simulated with {section}.{key} = {value} "
            f"but the config ({config.source or config.name}) has {mine}: calibrate "
            f"with the simulated config (its name: {sim.get('name', '?')!r}, e.g. "
            "the same file and profile given to 'scanqa simulate')")


def check_scale(obs: PlaneObservation, config: ScannerConfig) -> None:
    """The phase's slope across the image centre must match the config's pinhole.

    Raises
    ------
    InputError
        The measured x_p per camera pixel is off by more than :data:`SCALE_TOLERANCE`.
    """
    h, w = check_camera_size(obs, config)
    r0, r1, c0, c1 = h // 2 - h // 8, h // 2 + h // 8 + 1, w // 2 - w // 8, w // 2 + w // 8 + 1
    slope = np.nanmedian(np.diff(obs.xp[r0:r1, c0:c1], axis=1))
    cam = config.camera
    f, u0 = cam.principal_distance_px, cam.principal_point_px[0]
    pts = np.array([[(u - u0) / f * obs.z_mm, 0.0, obs.z_mm] for u in (u0 - 5, u0 + 5)])
    qp = geometry.to_projector_frame(pts, config)
    xp = config.projector.principal_distance_px * qp[:, 0] / qp[:, 2]
    predicted = (xp[1] - xp[0]) / 10.0
    if np.isfinite(slope) and predicted != 0:
        _check_ratio(float(slope / predicted), config, obs.source,
                     f"the phase changes by {slope:.4g} projector px per camera px at "
                     f"z = {obs.z_mm:g} mm")


def _checked(observations: Iterator[PlaneObservation], sweep: Sweep,
             config: ScannerConfig) -> Iterator[PlaneObservation]:
    """Pass observations through; on the first, check its size (the build's own check
    first), then the sweep's records (:func:`check_sweep`), then the images' scale."""
    for i, obs in enumerate(observations):
        if i == 0:
            check_camera_size(obs, config)
            check_sweep(sweep, config)
            check_scale(obs, config)
        yield obs


def calibrate(sweep: Sweep | str | os.PathLike, config: ScannerConfig,
              weights: str = "model", cell_px: int | None = None,
              min_modulation: float = 0.0, use_markers: bool = True
              ) -> tuple[CalibrationTable, BuildReport]:
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
    use_markers : bool
        Take the lateral geometry from the marker frames when the sweep has them
        (otherwise from ``lateral`` maps or the config's pinhole).

    Returns
    -------
    table : CalibrationTable
        The table (``table.save(path)`` writes it); a marked sweep's fitted geometry is
        in its provenance under ``target_geometry``.
    report : BuildReport
        Rejected samples by reason and the fit residual per position. The marker fit's
        implied error (:func:`~scanqa.calibration.uncertainty.marker_error_summary`,
        against :func:`table_bound_mm`) is in ``target_geometry["marker_error"]``.
    """
    sweep = sweep if isinstance(sweep, Sweep) else load_sweep(sweep)
    geometry = marker_geometry(sweep, config) if use_markers and sweep.has_markers else None
    prov = sweep.provenance()
    if geometry is not None:
        prov["target_geometry"] = geometry.summary()
        prov["target_geometry"]["marker_error"] = marker_error_summary(
            geometry, [p.z_mm for p in sweep.positions],
            len(sweep.positions[0].marker_frames), table_bound_mm(config))
    return build_table(_checked(iter_observations(sweep, geometry), sweep, config), config,
                       weights=weights, cell_px=cell_px, min_modulation=min_modulation,
                       provenance=prov, total=sweep.observation_count())


def table_bound_mm(config: ScannerConfig) -> float:
    """:data:`TABLE_BOUND_SIGMA` times the model's single-point sigma on the camera axis
    at the focus distance [mm]."""
    focus = config.camera.focus_mm
    return TABLE_BOUND_SIGMA * float(optics.predict(np.array([0.0, 0.0, focus]),
                                                    config).sigma)


def geometry_covariance(cal) -> GeometryCovariance | None:
    """The geometric parameters and covariance a calibration carries
    (:class:`~scanqa.calibration.uncertainty.GeometryCovariance`), or None: a marker
    table's fit (its ``target_geometry`` provenance with the parameter vector), or a
    parametric calibration with a covariance (a board calibration's joint fit)."""
    covariance = getattr(cal, "covariance", None)
    if covariance is not None and hasattr(cal, "projector"):
        return parametric_covariance(cal, covariance)
    summary = (getattr(cal, "provenance", None) or {}).get("target_geometry") or {}
    if len(summary.get("parameters", [])) == 15:
        return marker_covariance(geometry_from_summary(summary))
    return None
