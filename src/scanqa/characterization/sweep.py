"""Characterisation of the scanner's noise from sweeps of a flat (Figs. 3 and 4).

For every position of a sweep - a camera sweep or a projector sweep (``scanqa simulate
camera-sweep``/``projector-sweep``, one device moving), or the calibration plane sweep
of a rigid scanner (its ``sweep.toml``: both devices defocus together):

1. decode the scan (:func:`scanqa.decoding.decoder.decode`);
2. fit a low-order (quadratic) surface to the flat's x_p map over a central region of
   the image, with one pass of 4-sigma rejection of unwrapping blunders; the residual
   std is the phase noise [projector px]; beside it, the decoder's own sensor-noise
   estimate (RMS of its sigma_xp) [projector px];
3. measure the attenuation as the squared median modulation relative to the position
   nearest to focus.

The measured attenuation is compared with A(C/omega_o) (Eq. 12) and the depth of field
per level with :mod:`scanqa.design.tools`. The phase noise is fitted by every variant of the
model where the moving devices' attenuation is at least ``min_attenuation``
(:mod:`scanqa.characterization.noisefit`): each parameter is reported as fitted, bounded or not
identifiable with its 95 % profile-likelihood interval, the variant that predicts
held-out positions best is selected, and it is compared with a constant. One sweep
moves one device: the other's attenuation is constant, so the "mixed" reading is only
offered when both devices move (a camera and a projector sweep together, or a
calibration sweep).
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from scanqa.characterization.noisefit import (
    JOINT_VARIANTS,
    SINGLE_SWEEP_VARIANTS,
    ConstantFit,
    NoiseData,
    VariantFit,
    fit_all,
    fit_constant,
    model_std,
    select,
)
from scanqa.decoding.decoder import decode, decode_pattern_dir
from scanqa.design import tools
from scanqa.errors import InputError, ScanQAError
from scanqa.io.fitted_model import read_fitted_model
from scanqa.io.manifest import read_manifest
from scanqa.io.sweep import load_sweep
from scanqa.model import geometry, optics
from scanqa.model.config import ScannerConfig, config_from_dict, first_difference
from scanqa.progress import Progress

__all__ = ["Characterization", "JointCharacterization", "PositionResult", "VariantFit",
           "apply_fitted_model", "characterize_sweep", "characterize_sweeps",
           "load_fitted_model", "measured_dof", "surface_residual_std"]

log = logging.getLogger(__name__)

#: Attenuation levels whose depth of field is compared (Tables 1 and 2) [-].
DOF_LEVELS = (0.25, 0.30, 0.36, 0.42, 0.49, 0.56, 0.64, 0.72, 0.81)
#: Side of the central region analysed on a calibration sweep's plane, on the object [mm]
#: (about that of a device sweep's 64 x 64 px window of the sample camera).
CALIBRATION_FIELD_MM = 15.0


@dataclass(frozen=True)
class PositionResult:
    """Measurements at one position of a sweep (lengths in mm, std in projector px).

    ``attenuation_model`` is the model attenuation of the moving devices (A_c, A_p or
    A_c A_p); ``sensor_std_px`` the decoder's sensor-noise estimate.
    """

    stage_mm: float
    z_c_mm: float
    z_p_mm: float
    residual_std_px: float
    modulation_dn: float
    attenuation: float
    attenuation_model: float
    valid_pixels: int
    sensor_std_px: float = float("nan")
    attenuation_camera_model: float = float("nan")
    attenuation_projector_model: float = float("nan")


def _variant_row(fit: VariantFit) -> dict:
    """The ``best_variant`` entry of a summary (what :func:`load_fitted_model` reads)."""
    return {**fit.model_overrides(), "rms_relative": fit.rms_relative,
            "cv_rms_relative": fit.cv_rms_relative,
            "parameters": [asdict(p) for p in fit.parameters],
            "identifiable": list(fit.identifiable)}


def _verdict(best: VariantFit, constant: ConstantFit) -> str:
    """One sentence: what the selection found, against the constant baseline."""
    if best.cv_rms_relative < constant.cv_rms_relative:
        return (f"{best.label} predicts held-out positions to {100 * best.cv_rms_relative:.1f} "
                f"% RMS, better than a constant ({100 * constant.cv_rms_relative:.1f} %)")
    return (f"no variant predicts held-out positions better than a constant "
            f"({100 * best.cv_rms_relative:.1f} % for {best.label} against "
            f"{100 * constant.cv_rms_relative:.1f} %): these data do not show the defocus "
            "dependence, and the fitted parameters are not supported by them")


def _summary_core(fits: tuple[VariantFit, ...], constant: ConstantFit) -> dict:
    best = select(fits)
    return {"best_variant": _variant_row(best), "fits": [_variant_row(f) for f in fits],
            "selection": "smallest leave-one-position-out RMS relative error",
            "constant": asdict(constant),
            "better_than_constant": best.cv_rms_relative < constant.cv_rms_relative,
            "verdict": _verdict(best, constant)}


@dataclass(frozen=True)
class Characterization:
    """Result of :func:`characterize_sweep`."""

    experiment: str
    period_px: float
    positions: tuple[PositionResult, ...]
    fits: tuple[VariantFit, ...]
    dof: tuple[dict, ...]
    min_attenuation: float
    attenuation_max_abs_error: float
    w_shape: bool
    constant: ConstantFit | None = None

    @property
    def best(self) -> VariantFit:
        """The variant that predicts held-out positions best."""
        return select(self.fits)

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with the model the data supported (:attr:`best`), saying so in
        ``[model] characterised_by``."""
        return self.best.apply_to(config).replace_model(
            characterised_by=f"scanqa characterize sweep: the {self.experiment} sweep")

    def model_std(self, fit: VariantFit, config: ScannerConfig) -> np.ndarray:
        """sigma_p * s_O of a fit at every position [projector px]."""
        return model_std(config, _noise_data(self.positions, self.period_px), fit.filter_floor,
                         fit.filter_form, fit.noise_reading, fit.sigma_p_px, fit.gamma,
                         fit.sensor_sigma_p_px)

    def summary(self) -> dict:
        """JSON-ready summary: best variant, every fit, the baseline, DOF table."""
        return {"experiment": self.experiment, "period_px": self.period_px,
                **_summary_core(self.fits, self.constant or fit_constant(
                    _fit_data(self.positions, self.period_px, self.min_attenuation))),
                "min_attenuation": self.min_attenuation,
                "attenuation_max_abs_error_r_le_0.5": self.attenuation_max_abs_error,
                "w_shape": self.w_shape, "dof": list(self.dof),
                "positions": [asdict(p) for p in self.positions]}


# ------------------------------------------------------------------------- reading

def _device_distances(config: ScannerConfig, entry: dict) -> tuple[float, float]:
    """Z_c and Z_p of the flat's centre (the axes' crossing) at one position [mm]."""
    c = config.axes_crossing_mm
    z_c = float(c[2]) - float(entry["camera_offset_mm"])
    z_p = float(np.linalg.norm(c - np.asarray(config.projector.position_mm))) \
        - float(entry["projector_offset_mm"])
    return z_c, z_p


def _central(shape: tuple[int, int], size: int) -> tuple[slice, slice]:
    h, w = shape
    sh, sw = min(size, h), min(size, w)
    return slice((h - sh) // 2, (h + sh) // 2), slice((w - sw) // 2, (w + sw) // 2)


def surface_residual_std(xp: np.ndarray, valid: np.ndarray) -> float:
    """Std of the residual of a quadratic surface fitted to x_p(u, v) [projector px].

    One pass of 4-sigma rejection removes unwrapping blunders before the final fit.
    """
    v, u = np.nonzero(valid)
    if u.size < 12:
        return float("nan")
    uc, vc = (u - u.mean()) / 100.0, (v - v.mean()) / 100.0
    design_m = np.column_stack([np.ones_like(uc), uc, vc, uc * uc, uc * vc, vc * vc])
    y = xp[v, u]
    keep = np.ones(y.size, bool)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(design_m[keep], y[keep], rcond=None)
        res = y - design_m @ coef
        keep = np.abs(res) <= 4.0 * np.std(res[keep]) + 1e-12
    return float(np.std(res[keep]))


def _measure_map(pm, roi_px: int) -> tuple[float, float, int, float]:
    """(residual std, median modulation, valid count, RMS decoder sigma_xp) of one scan's
    central ``roi_px`` square."""
    rows, cols = _central(pm.shape, roi_px)
    xp, valid = pm.xp[rows, cols], pm.valid[rows, cols]
    if not valid.any():
        return np.nan, np.nan, 0, np.nan
    mod = float(np.median(pm.modulation[rows, cols][valid]))
    sensor = float(np.sqrt(np.mean(np.square(pm.sigma_xp[rows, cols][valid]))))
    return surface_residual_std(xp, valid), mod, int(valid.sum()), sensor


# -------------------------------------------------------------------------- model

def _noise_data(positions: tuple[PositionResult, ...], period: float) -> NoiseData:
    return NoiseData(np.array([p.z_c_mm for p in positions]),
                     np.array([p.z_p_mm for p in positions]),
                     np.array([p.residual_std_px for p in positions]),
                     np.array([p.sensor_std_px for p in positions]), period)


def _fit_data(positions: tuple[PositionResult, ...], period: float, min_attenuation: float
              ) -> NoiseData:
    """The positions a noise fit uses: both devices' model attenuation is at least
    ``min_attenuation`` (the moving one's, as the other stays in focus) and the std is
    finite."""
    use = tuple(p for p in positions
                if min(p.attenuation_camera_model, p.attenuation_projector_model)
                >= min_attenuation and np.isfinite(p.residual_std_px)
                and p.residual_std_px > 0)
    return _noise_data(use, period)


# ---------------------------------------------------------------------- analysis

def measured_dof(z: np.ndarray, attenuation: np.ndarray, level: float) -> float:
    """Length of the interval around the peak where the attenuation is >= level [mm].

    Linear interpolation between positions; NaN when the sweep does not reach the
    level on both sides.
    """
    order = np.argsort(z)
    z, a = z[order], attenuation[order]
    k = int(np.nanargmax(a))
    below_lo = np.nonzero(a[:k] < level)[0]
    below_hi = np.nonzero(a[k:] < level)[0]
    if below_lo.size == 0 or below_hi.size == 0:
        return float("nan")
    i = below_lo[-1]
    j = k + below_hi[0]
    z_lo = z[i] + (level - a[i]) * (z[i + 1] - z[i]) / (a[i + 1] - a[i])
    z_hi = z[j - 1] + (level - a[j - 1]) * (z[j] - z[j - 1]) / (a[j] - a[j - 1])
    return float(z_hi - z_lo)


def _dof_rows(config: ScannerConfig, experiment: str, z: np.ndarray, att: np.ndarray,
              period: float) -> tuple[dict, ...]:
    if experiment not in ("camera-sweep", "projector-sweep"):
        return ()  # both devices move: no single device's depth of field
    rows = []
    for level in DOF_LEVELS:
        if experiment == "camera-sweep":
            model = tools.camera_dof(config, level, period).dof_mm
        else:
            model = tools.projector_dof(config, level, period).dof_mm
        sim = measured_dof(z, att, level)
        rows.append({"level": level, "dof_measured_mm": sim, "dof_model_mm": model,
                     "deviation_pct": 100.0 * (sim - model) / model})
    return tuple(rows)


def is_w_shape(z: np.ndarray, std: np.ndarray, focus: float) -> bool:
    """A local maximum of the std near focus with a lower minimum on each side."""
    order = np.argsort(z)
    z, s = z[order], std[order]
    k = int(np.argmin(np.abs(z - focus)))
    left, right = s[:k], s[k + 1:]
    if left.size < 2 or right.size < 2:
        return False
    i, j = int(np.argmin(left)), int(np.argmin(right))
    peak = s[k]
    return bool(left[i] < 0.8 * peak and right[j] < 0.8 * peak and left[0] > left[i]
                and right[-1] > right[j])


def characterize_sweep(sweep_dir: str | os.PathLike, config: ScannerConfig,
                       min_attenuation: float = 0.49, roi_px: int = 256) -> Characterization:
    """Decode a sweep and fit the model to it (Figs. 3, 4).

    Parameters
    ----------
    sweep_dir : str or PathLike
        Folder written by ``scanqa simulate camera-sweep`` or ``projector-sweep``, or a
        calibration sweep: its ``sweep.toml`` or a folder holding one.
    config : ScannerConfig
        The scanner config the model uses (its geometry gives Z_c, Z_p per position).
    min_attenuation : float
        Fit where the moving devices' model attenuation is at least this [-].
    roi_px : int
        Side of the central square analysed [px] (on a calibration sweep at most
        :data:`CALIBRATION_FIELD_MM` on the object).

    Returns
    -------
    Characterization
        Per-position measurements, every variant's fit, the baseline, the DOF table.
    """
    if not 0.0 < min_attenuation < 1.0:
        raise InputError(f"min_attenuation must be in (0, 1), got {min_attenuation}")
    sweep = Path(sweep_dir)
    if sweep.name == "sweep.toml" or (sweep / "sweep.toml").exists():
        return _characterize_plane_sweep(sweep, config, min_attenuation, roi_px)
    manifest = read_manifest(sweep)
    check_sweep_config(config, manifest, sweep / "manifest.toml")
    experiment = manifest.get("experiment")
    if experiment not in ("camera-sweep", "projector-sweep"):
        raise InputError(f"characterize needs a camera-sweep, a projector-sweep or a "
                         f"calibration sweep (sweep.toml), got experiment {experiment!r} in "
                         f"{sweep / 'manifest.toml'}")
    groups: dict[float, list] = {}
    entries = manifest["acquisition"]
    with Progress("characterize: decoding", len(entries), "scan", log) as bar:
        for entry in entries:
            meas = _measure_map(decode_pattern_dir(sweep / entry["folder"]), roi_px)
            key = float(entry["stage_mm"])
            groups.setdefault(key, [*_device_distances(config, entry), []])[2].append(meas)
            bar.update(1, note=entry["folder"])
    period = float(manifest["working_period_px"])
    positions = _positions(config, experiment, groups, period)
    return _analyse(config, experiment, positions, period, min_attenuation)


def _characterize_plane_sweep(path: Path, config: ScannerConfig, min_attenuation: float,
                              roi_px: int) -> Characterization:
    """A rigid scanner's calibration sweep: the flat at known Z, both devices defocus."""
    sweep = load_sweep(path)
    groups: dict[float, list] = {}
    period = None
    with Progress("characterize: decoding", len(sweep.positions), "position", log) as bar:
        for pos in sweep.positions:
            z_p = float(geometry.projector_depth(np.array([0.0, 0.0, pos.z_mm]), config))
            roi = min(roi_px, int(CALIBRATION_FIELD_MM * config.camera.principal_distance_px
                                  / pos.z_mm))
            for src in pos.sources:
                pm = decode(src)
                period = pm.period_px
                groups.setdefault(pos.z_mm, [pos.z_mm, z_p, []])[2].append(
                    _measure_map(pm, roi))
            bar.update(1, note=f"z = {pos.z_mm:g} mm")
    positions = _positions(config, "calibration-sweep", groups, float(period))
    return _analyse(config, "calibration-sweep", positions, float(period), min_attenuation)


def _positions(config: ScannerConfig, experiment: str, groups: dict, period: float
               ) -> tuple[PositionResult, ...]:
    """Average repeats per stage position and attach the model attenuation.

    ``groups`` maps stage position -> [Z_c, Z_p, [measurements of each repeat]].
    """
    stages = sorted(groups)
    mods = {s: np.nanmean([m[1] for m in groups[s][2]]) for s in stages}
    ref = min(stages, key=lambda s: abs(groups[s][0] - config.camera.focus_mm)
              + abs(groups[s][1] - config.projector.focus_mm))
    if not np.isfinite(mods[ref]) or mods[ref] <= 0:
        raise InputError("zero valid pixels at the position nearest to focus; cannot "
                         "normalise the modulation")
    out = []
    for s in stages:
        z_c, z_p, meas = groups[s]
        t = optics.optical_terms(np.array(z_c), np.array(z_p), config, period)
        a_c, a_p = float(t.attenuation_camera), float(t.attenuation_projector)
        a_model = {"camera-sweep": a_c, "projector-sweep": a_p}.get(experiment, a_c * a_p)
        std = float(np.sqrt(np.nanmean([m[0] ** 2 for m in meas])))
        sensor = float(np.sqrt(np.nanmean([m[3] ** 2 for m in meas])))
        out.append(PositionResult(s, z_c, z_p, std, float(mods[s]),
                                  float((mods[s] / mods[ref]) ** 2), a_model,
                                  int(sum(m[2] for m in meas)), sensor, a_c, a_p))
    return tuple(out)


def _variants(experiments: set[str]) -> tuple:
    """The variants the sweeps can tell apart: "mixed" needs both devices to move."""
    both = experiments >= {"camera-sweep", "projector-sweep"} \
        or "calibration-sweep" in experiments
    return JOINT_VARIANTS if both else SINGLE_SWEEP_VARIANTS


def _checked_fit_data(positions: tuple[PositionResult, ...], period: float,
                      min_attenuation: float) -> NoiseData:
    data = _fit_data(positions, period, min_attenuation)
    if data.n < 4:
        raise InputError(f"only {data.n} positions with attenuation >= {min_attenuation}; "
                         "need at least 4 to fit sigma_p and gamma and to check the fit on "
                         "held-out positions")
    return data


def _analyse(config: ScannerConfig, experiment: str, positions: tuple[PositionResult, ...],
             period: float, min_attenuation: float) -> Characterization:
    z_c = np.array([p.z_c_mm for p in positions])
    z_p = np.array([p.z_p_mm for p in positions])
    std = np.array([p.residual_std_px for p in positions])
    att = np.array([p.attenuation for p in positions])
    a_model = np.array([p.attenuation_model for p in positions])
    data = _checked_fit_data(positions, period, min_attenuation)
    fits = fit_all(config, data, _variants({experiment}))
    z = z_p if experiment == "projector-sweep" else z_c
    r_ok = np.array([min(p.attenuation_camera_model, p.attenuation_projector_model)
                     for p in positions]) >= float(optics.attenuation(0.5))
    att_err = float(np.max(np.abs(att - a_model)[r_ok])) if r_ok.any() else float("nan")
    focus = config.projector.focus_mm if experiment == "projector-sweep" else \
        config.camera.focus_mm
    return Characterization(experiment, period, positions, fits,
                            _dof_rows(config, experiment, z, att, period), min_attenuation,
                            att_err, is_w_shape(z, std, focus), fit_constant(data))


@dataclass(frozen=True)
class JointCharacterization:
    """Result of :func:`characterize_sweeps` over several sweeps."""

    sweeps: tuple[Characterization, ...]
    fits: tuple[VariantFit, ...]
    constant: ConstantFit | None = None

    @property
    def best(self) -> VariantFit:
        """The variant that predicts held-out positions best."""
        return select(self.fits)

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with the model the data supported (:attr:`best`), saying so in
        ``[model] characterised_by``."""
        return self.best.apply_to(config).replace_model(
            characterised_by=f"scanqa characterize sweep: the {self.experiment} sweeps")

    @property
    def experiment(self) -> str:
        return "+".join(c.experiment for c in self.sweeps)

    def summary(self) -> dict:
        return {"experiment": self.experiment, **_summary_core(self.fits, self.constant),
                "sweeps": [c.summary() for c in self.sweeps]}


def check_sweep_config(config: ScannerConfig, manifest: dict, source: Path) -> None:
    """Refuse a config whose camera or projector differs from the one a sweep's manifest
    records (a fit through the wrong geometry gives a wrong sigma_p without a sign)."""
    recorded = manifest.get("config")
    if recorded is None:
        return
    try:
        rec = config_from_dict(recorded, source=str(source))
    except ScanQAError as err:
        raise InputError(f"{source}: the recorded config is invalid ({err})") from None
    diff = first_difference(config, rec.to_dict())
    if diff is not None:
        section, k, mine, theirs = diff
        raise InputError(f"config {config.source or config.name} does not match the sweep "
                         f"{source.parent}: {section}.{k} = {mine!r} but the sweep was "
                         f"made with {theirs!r}; give the sweep's config or leave "
                         "the config out to use the one its manifest records")


def sweep_folder(sweep: str | os.PathLike) -> Path:
    """The folder of a sweep: a device sweep's folder itself, or the folder holding a
    calibration sweep's ``sweep.toml``."""
    path = Path(sweep)
    return path.parent if path.suffix == ".toml" else path


def sweep_config(sweep_dir: str | os.PathLike) -> ScannerConfig:
    """The scanner config recorded in a sweep's manifest (a device sweep's folder, or a
    calibration sweep's ``sweep.toml`` with the manifest beside it)."""
    folder = sweep_folder(sweep_dir)
    path = folder / "manifest.toml"
    recorded = read_manifest(folder).get("config")
    if not isinstance(recorded, dict):
        raise InputError(f"{path} records no scanner config: give the config the sweep was "
                         "made with")
    return config_from_dict(recorded, source=str(path))


def characterize_sweeps(sweep_dirs: list, config: ScannerConfig | None = None,
                        min_attenuation: float = 0.49, roi_px: int = 256
                        ) -> Characterization | JointCharacterization:
    """Characterise one sweep (:func:`characterize_sweep`) or fit several jointly.

    With several sweeps every position where both devices' attenuation is at least
    ``min_attenuation`` enters one fit per variant; ``"mixed"`` is among the readings
    when both devices move. ``config`` defaults to the one the first sweep's manifest
    records; a config whose camera or projector differs from a sweep's recorded one is
    refused.
    """
    config = config if config is not None else sweep_config(sweep_dirs[0])
    chars = [characterize_sweep(d, config, min_attenuation, roi_px) for d in sweep_dirs]
    if len(chars) == 1:
        return chars[0]
    periods = {c.period_px for c in chars}
    if len(periods) != 1:
        raise InputError(f"the sweeps use different working periods {sorted(periods)} px; "
                         "characterise them separately")
    parts = [_fit_data(c.positions, c.period_px, min_attenuation) for c in chars]
    data = NoiseData(*(np.concatenate([getattr(d, f) for d in parts])
                       for f in ("z_c", "z_p", "std_px", "sensor_px")), chars[0].period_px)
    fits = fit_all(config, data, _variants({c.experiment for c in chars}))
    return JointCharacterization(tuple(chars), fits, fit_constant(data))


def load_fitted_model(path: str | os.PathLike) -> dict:
    """The best variant of a characterisation ``summary.json`` as ``[model]`` overrides
    (:func:`scanqa.io.fitted_model.read_fitted_model`)."""
    return read_fitted_model(path)


def apply_fitted_model(config: ScannerConfig, path: str | os.PathLike) -> ScannerConfig:
    """``config`` with the model parameters and readings that the data supported."""
    fitted = load_fitted_model(path)  # its own errors name the file and what is wrong
    try:
        return config.replace_model(**fitted)
    except ScanQAError as err:
        raise InputError(f"{path}: fitted model is not a valid [model] table: {err}") from None
