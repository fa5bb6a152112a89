"""Characterisation of a camera or projector sweep (the procedure of Figs. 3 and 4).

For every position of a sweep of an optical flat (``scanqa simulate camera-sweep`` or
``projector-sweep``, or measured data in the same folder layout):

1. decode the scan (:func:`scanqa.decoding.decoder.decode_pattern_dir`);
2. fit a low-order (quadratic) surface to the flat's x_p map over a central region of
   the image, with one pass of 4-sigma rejection of unwrapping blunders; the residual
   std is the phase noise [projector px];
3. measure the attenuation as the squared median modulation relative to the position
   nearest to focus.

The measured attenuation is compared with A(C/omega_o) (Eq. 12) and the depth of field
per level with :mod:`scanqa.design`; the residual std is fitted by
``sigma_p * s_O`` (Eqs. 17-19) for each of the model's readings (docs/model.rst:
``filter_floor`` none/one x ``noise_reading`` power/amplitude), where the swept
device's attenuation is at least ``min_attenuation``. With ``filter_floor = "none"``
only the product sigma_p * gamma is identifiable, so gamma is held at the config's
value there. The variant with the smallest RMS relative error is the one the data
supports.

One sweep moves one device: the other's attenuation is constant, so a single sweep
cannot tell how the noise scales with the other device's defocus. Given a camera and a
projector sweep, :func:`characterize_sweeps` fits one sigma_p and gamma to both at once
for every reading including ``"mixed"`` (camera power, projector amplitude).
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from scanqa import design, optics
from scanqa.config import FILTER_FLOORS, NOISE_READINGS, ScannerConfig, config_from_dict
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.errors import InputError, ScanQAError
from scanqa.io.fitted_model import read_fitted_model
from scanqa.io.manifest import read_manifest
from scanqa.progress import Progress

log = logging.getLogger(__name__)

#: Readings one sweep can tell apart ("mixed" equals "power" on a camera sweep and
#: "amplitude" on a projector sweep, up to the fitted sigma_p).
SINGLE_SWEEP_READINGS = ("power", "amplitude")
#: Attenuation levels whose depth of field is compared (Tables 1 and 2) [-].
DOF_LEVELS = (0.25, 0.30, 0.36, 0.42, 0.49, 0.56, 0.64, 0.72, 0.81)


@dataclass(frozen=True)
class PositionResult:
    """Measurements at one position of a sweep (lengths in mm, std in projector px)."""

    stage_mm: float
    z_c_mm: float
    z_p_mm: float
    residual_std_px: float
    modulation_dn: float
    attenuation: float
    attenuation_model: float
    valid_pixels: int


@dataclass(frozen=True)
class VariantFit:
    """Fit of sigma_p (and gamma) for one reading of the model."""

    filter_floor: str
    noise_reading: str
    sigma_p_px: float
    gamma: float
    gamma_fitted: bool
    rms_relative: float

    def model_overrides(self) -> dict:
        """The ``[model]`` values this fit supports."""
        return {"filter_floor": self.filter_floor, "noise_reading": self.noise_reading,
                "sigma_p_px": self.sigma_p_px, "gamma": self.gamma}

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with this fit's model parameters and readings."""
        return config.replace_model(**self.model_overrides())


def _best(fits: tuple[VariantFit, ...]) -> VariantFit:
    """The variant with the smallest RMS relative error."""
    return min(fits, key=lambda f: f.rms_relative)


def _variant_row(fit: VariantFit) -> dict:
    """The ``best_variant`` entry of a summary (what :func:`load_fitted_model` reads)."""
    return {"filter_floor": fit.filter_floor, "noise_reading": fit.noise_reading,
            "sigma_p_px": fit.sigma_p_px, "gamma": fit.gamma,
            "rms_relative": fit.rms_relative}


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

    @property
    def best(self) -> VariantFit:
        """The variant with the smallest RMS relative error."""
        return _best(self.fits)

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with the model the data supported (:attr:`best`)."""
        return self.best.apply_to(config)

    def model_std(self, fit: VariantFit, config: ScannerConfig) -> np.ndarray:
        """sigma_p * s_O of a fit at every position [projector px]."""
        z_c = np.array([p.z_c_mm for p in self.positions])
        z_p = np.array([p.z_p_mm for p in self.positions])
        return fit.sigma_p_px * _scale(config, z_c, z_p, self.period_px, fit.gamma,
                                       fit.filter_floor, fit.noise_reading)

    def summary(self) -> dict:
        """JSON-ready summary: best variant, every fit, DOF table, key numbers."""
        return {"experiment": self.experiment, "period_px": self.period_px,
                "best_variant": _variant_row(self.best),
                "fits": [asdict(f) for f in self.fits],
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


def _measure(sweep_dir: Path, entries: list[dict], roi_px: int) -> list[tuple]:
    """(residual std, median modulation, valid count) per acquisition."""
    out = []
    with Progress("characterize: decoding", len(entries), "scan", log) as bar:
        for entry in entries:
            pm = decode_pattern_dir(sweep_dir / entry["folder"])
            rows, cols = _central(pm.shape, roi_px)
            xp, valid = pm.xp[rows, cols], pm.valid[rows, cols]
            mod = float(np.median(pm.modulation[rows, cols][valid])) if valid.any() else np.nan
            out.append((surface_residual_std(xp, valid), mod, int(valid.sum())))
            bar.update(1, note=entry["folder"])
    return out


# -------------------------------------------------------------------------- model

def _model_attenuation(config: ScannerConfig, z_c: np.ndarray, z_p: np.ndarray,
                       period: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_camera, A_projector) of the model at the given distances [-]."""
    t = optics.optical_terms(z_c, z_p, config, period)
    return t.attenuation_camera, t.attenuation_projector


def _scale(config: ScannerConfig, z_c: np.ndarray, z_p: np.ndarray, period: float,
           gamma: float, floor: str, reading: str) -> np.ndarray:
    """s_O (Eq. 19) at the given distances for one reading [-]."""
    return optics.optical_terms(z_c, z_p, config, period, gamma, floor, reading).s_o


def fit_variant(config: ScannerConfig, z_c: np.ndarray, z_p: np.ndarray,
                period: float, std: np.ndarray, floor: str, reading: str) -> VariantFit:
    """Least-squares fit (relative residuals) of sigma_p and gamma >= 1 for one reading."""
    fit_gamma = floor == "one"

    def rel(params: np.ndarray) -> np.ndarray:
        gamma = float(np.exp(params[1])) + 1.0 if fit_gamma else config.model.gamma
        model = np.exp(params[0]) * _scale(config, z_c, z_p, period, gamma, floor, reading)
        return model / std - 1.0

    best = None
    for g0 in ((0.1, 1.0, 3.0, 10.0) if fit_gamma else (0.0,)):
        x0 = [np.log(np.median(std)), np.log(g0)] if fit_gamma else [np.log(np.median(std))]
        res = least_squares(rel, x0)
        if best is None or res.cost < best.cost:
            best = res
    gamma = float(np.exp(best.x[1])) + 1.0 if fit_gamma else config.model.gamma
    rms = float(np.sqrt(np.mean(rel(best.x) ** 2)))
    return VariantFit(floor, reading, float(np.exp(best.x[0])), gamma, fit_gamma, rms)


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
    rows = []
    for level in DOF_LEVELS:
        if experiment == "camera-sweep":
            model = design.camera_dof(config, level, period).dof_mm
        else:
            model = design.projector_dof(config, level, period).dof_mm
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
    """Decode a camera/projector sweep and fit the model to it (Figs. 3, 4).

    Parameters
    ----------
    sweep_dir : str or PathLike
        Folder written by ``scanqa simulate camera-sweep`` or ``projector-sweep``.
    config : ScannerConfig
        The scanner config the model uses (its geometry gives Z_c, Z_p per position).
    min_attenuation : float
        Fit where the swept device's model attenuation is at least this [-].
    roi_px : int
        Side of the central square analysed [px].

    Returns
    -------
    Characterization
        Per-position measurements, the four fits, the DOF table.
    """
    sweep = Path(sweep_dir)
    manifest = read_manifest(sweep)
    check_sweep_config(config, manifest, sweep / "manifest.toml")
    experiment = manifest.get("experiment")
    if experiment not in ("camera-sweep", "projector-sweep"):
        raise InputError(f"characterize needs a camera-sweep or projector-sweep, got "
                         f"experiment {experiment!r} in {sweep / 'manifest.toml'}")
    if not 0.0 < min_attenuation < 1.0:
        raise InputError(f"min_attenuation must be in (0, 1), got {min_attenuation}")
    entries = manifest["acquisition"]
    period = float(manifest["working_period_px"])
    measured = _measure(sweep, entries, roi_px)
    positions = _positions(config, experiment, entries, measured, period)
    return _analyse(config, experiment, positions, period, min_attenuation)


def _positions(config: ScannerConfig, experiment: str, entries: list[dict],
               measured: list[tuple], period: float) -> tuple[PositionResult, ...]:
    """Average repeats per stage position and attach model attenuation."""
    stages = sorted({float(e["stage_mm"]) for e in entries})
    ref = min(stages, key=abs)
    mods = {s: np.nanmean([m[1] for e, m in zip(entries, measured, strict=True)
                           if float(e["stage_mm"]) == s]) for s in stages}
    if not np.isfinite(mods[ref]) or mods[ref] <= 0:
        raise InputError("zero valid pixels at the position nearest to focus; cannot "
                         "normalise the modulation")
    out = []
    for s in stages:
        group = [(e, m) for e, m in zip(entries, measured, strict=True)
                 if float(e["stage_mm"]) == s]
        z_c, z_p = _device_distances(config, group[0][0])
        a_c, a_p = _model_attenuation(config, np.array(z_c), np.array(z_p), period)
        a_model = float(a_c if experiment == "camera-sweep" else a_p)
        std = float(np.sqrt(np.nanmean([m[0] ** 2 for _, m in group])))
        out.append(PositionResult(s, z_c, z_p, std, float(mods[s]),
                                  float((mods[s] / mods[ref]) ** 2), a_model,
                                  int(sum(m[2] for _, m in group))))
    return tuple(out)


def _fitted(positions: tuple[PositionResult, ...], min_attenuation: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Z_c, Z_p, std) of the positions the noise fit uses: the swept device's model
    attenuation is at least ``min_attenuation`` and the std is finite."""
    use = [p for p in positions
           if p.attenuation_model >= min_attenuation and np.isfinite(p.residual_std_px)]
    return (np.array([p.z_c_mm for p in use]), np.array([p.z_p_mm for p in use]),
            np.array([p.residual_std_px for p in use]))


def _analyse(config: ScannerConfig, experiment: str, positions: tuple[PositionResult, ...],
             period: float, min_attenuation: float) -> Characterization:
    z_c = np.array([p.z_c_mm for p in positions])
    z_p = np.array([p.z_p_mm for p in positions])
    std = np.array([p.residual_std_px for p in positions])
    att = np.array([p.attenuation for p in positions])
    a_model = np.array([p.attenuation_model for p in positions])
    fz_c, fz_p, fstd = _fitted(positions, min_attenuation)
    if fstd.size < 3:
        raise InputError(f"only {fstd.size} positions with attenuation >= "
                         f"{min_attenuation}; need at least 3 to fit sigma_p and gamma")
    fits = tuple(fit_variant(config, fz_c, fz_p, period, fstd, fl, rd)
                 for fl in FILTER_FLOORS for rd in SINGLE_SWEEP_READINGS)
    z = z_c if experiment == "camera-sweep" else z_p
    r_ok = a_model >= float(optics.attenuation(0.5))
    att_err = float(np.max(np.abs(att - a_model)[r_ok])) if r_ok.any() else float("nan")
    focus = config.camera.focus_mm if experiment == "camera-sweep" else \
        config.projector.focus_mm
    return Characterization(experiment, period, positions, fits,
                            _dof_rows(config, experiment, z, att, period), min_attenuation,
                            att_err, is_w_shape(z, std, focus))


@dataclass(frozen=True)
class JointCharacterization:
    """Result of :func:`characterize_sweeps` over several sweeps."""

    sweeps: tuple[Characterization, ...]
    fits: tuple[VariantFit, ...]

    @property
    def best(self) -> VariantFit:
        """The variant with the smallest RMS relative error."""
        return _best(self.fits)

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with the model the data supported (:attr:`best`)."""
        return self.best.apply_to(config)

    @property
    def experiment(self) -> str:
        return "+".join(c.experiment for c in self.sweeps)

    def summary(self) -> dict:
        return {"experiment": self.experiment, "best_variant": _variant_row(self.best),
                "fits": [asdict(f) for f in self.fits],
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
    for section in ("camera", "projector"):
        mine, theirs = asdict(getattr(config, section)), asdict(getattr(rec, section))
        diff = [k for k in mine if mine[k] != theirs[k]]
        if diff:
            k = diff[0]
            raise InputError(f"config {config.source or config.name} does not match the sweep "
                             f"{source.parent}: {section}.{k} = {mine[k]!r} but the sweep was "
                             f"made with {theirs[k]!r}; give the sweep's config or leave "
                             "--config out to use the one its manifest records")


def sweep_config(sweep_dir: str | os.PathLike) -> ScannerConfig:
    """The scanner config recorded in a sweep's manifest."""
    path = Path(sweep_dir) / "manifest.toml"
    recorded = read_manifest(Path(sweep_dir)).get("config")
    if not isinstance(recorded, dict):
        raise InputError(f"{path} records no scanner config: give the config the sweep was "
                         "made with (--config)")
    return config_from_dict(recorded, source=str(path))


def characterize_sweeps(sweep_dirs: list, config: ScannerConfig | None = None,
                        min_attenuation: float = 0.49, roi_px: int = 256
                        ) -> Characterization | JointCharacterization:
    """Characterise one sweep (:func:`characterize_sweep`) or fit several jointly.

    With several sweeps every position where its swept device's attenuation is at least
    ``min_attenuation`` enters one fit of sigma_p and gamma per reading; ``"mixed"`` is
    among the readings when a camera and a projector sweep are both given. ``config``
    defaults to the one the first sweep's manifest records; a config whose camera or
    projector differs from a sweep's recorded one is refused.
    """
    config = config if config is not None else sweep_config(sweep_dirs[0])
    chars = [characterize_sweep(d, config, min_attenuation, roi_px) for d in sweep_dirs]
    if len(chars) == 1:
        return chars[0]
    periods = {c.period_px for c in chars}
    if len(periods) != 1:
        raise InputError(f"the sweeps use different working periods {sorted(periods)} px; "
                         "characterise them separately")
    kinds = {c.experiment for c in chars}
    readings = NOISE_READINGS if kinds == {"camera-sweep", "projector-sweep"} \
        else SINGLE_SWEEP_READINGS
    z_c, z_p, std = (np.concatenate(a) for a in zip(
        *(_fitted(c.positions, min_attenuation) for c in chars), strict=True))
    fits = tuple(fit_variant(config, z_c, z_p, chars[0].period_px, std, fl, rd)
                 for fl in FILTER_FLOORS for rd in readings)
    return JointCharacterization(tuple(chars), fits)


def load_fitted_model(path: str | os.PathLike) -> dict:
    """The best variant of a characterisation ``summary.json`` as ``[model]`` overrides
    (:func:`scanqa.io.fitted_model.read_fitted_model`)."""
    return read_fitted_model(path)


def apply_fitted_model(config: ScannerConfig, path: str | os.PathLike) -> ScannerConfig:
    """``config`` with the model parameters and readings that the data supported."""
    try:
        return config.replace_model(**load_fitted_model(path))
    except ScanQAError as err:
        raise InputError(f"{path}: fitted model is not a valid [model] table: {err}") from None
