"""Fitting the noise model to measured phase noise: variants, intervals, selection.

Input: per sweep position the distances Z_c, Z_p [mm] of the flat, the measured std of
x_p [projector px] and, when the decoder gave one, its sensor-noise estimate [px]. For
every variant of the model (:data:`SINGLE_SWEEP_VARIANTS`, :data:`JOINT_VARIANTS`) the
free parameters are fitted by least squares on log(model / measured), so every position
counts by its relative error; the model comes from :func:`scanqa.model.optics.optical_terms`,
the one model chain.

What the data identify is reported per parameter (:class:`Parameter`), from the profile
likelihood: for parameter theta_j the deviance D(theta_j) = n log(RSS(theta_j) / RSS_min),
with the other parameters re-fitted at every theta_j, is compared with chi^2_1(95 %) =
3.84. The interval where D stays below it is the 95 % confidence interval. A parameter
whose interval reaches both ends of its range is *not identifiable*: it is held at a
stated value (the config's gamma; the decoder's sensor noise) and the rest is re-fitted;
one whose interval reaches one end is *bounded* (the data give a one-sided limit); only
a closed interval is *fitted*. With Eq. 17 as printed (no floor) sigma_p and gamma enter
only as their product: gamma is held and the product is reported.

A variant is selected on held-out positions: each position is predicted by the fit to
all the others (leave-one-out), and the variant with the smallest RMS relative error of
those predictions wins, so that a variant with more parameters gains nothing by
fitting noise. A constant (no defocus dependence at all) is scored the same way; a best
variant that does not beat it is reported as such.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
from scipy.optimize import brentq, least_squares

from scanqa.model import optics
from scanqa.model.config import ScannerConfig

#: Variants (filter_floor, filter_form, noise_reading) one sweep can tell apart: the
#: paper's readings with Eq. 17 as printed, then the two-source model with both forms,
#: and with the sum form's smooth floor (F^2 = 1 + N / gamma^2, the law flattening's
#: filter follows; :func:`scanqa.model.readings.smooth_floor`).
SINGLE_SWEEP_VARIANTS = (("none", "product", "power"), ("none", "product", "amplitude"),
                         ("one", "product", "power"), ("one", "product", "amplitude"),
                         ("one", "product", "two_source"), ("one", "sum", "two_source"),
                         ("smooth", "sum", "two_source"))
#: With both devices moving (a camera and a projector sweep, or a calibration sweep) the
#: "mixed" reading is told apart from the others too.
JOINT_VARIANTS = (*SINGLE_SWEEP_VARIANTS, ("none", "product", "mixed"),
                  ("one", "product", "mixed"))
#: Range of gamma searched [-] and of the noise parameters [projector px].
GAMMA_RANGE = (1.0, 100.0)
NOISE_RANGE = (1e-6, 10.0)
#: chi^2 quantile of one degree of freedom at 95 %: the profile-likelihood threshold.
CHI2_95 = 3.841458820694124
#: Parameter statuses.
STATUSES = ("fitted", "bounded", "not identifiable")


@dataclass(frozen=True)
class NoiseData:
    """Measured phase noise per position (arrays of one shape).

    ``sensor_px`` is the decoder's sensor-noise estimate per position (NaN when unknown).
    """

    z_c: np.ndarray
    z_p: np.ndarray
    std_px: np.ndarray
    sensor_px: np.ndarray
    period_px: float

    @property
    def n(self) -> int:
        return int(self.std_px.size)


@dataclass(frozen=True)
class Parameter:
    """One model parameter as the data determine it.

    ``status`` is "fitted" (a closed 95 % interval), "bounded" (the interval reaches one
    end of the searched range: a one-sided limit) or "not identifiable" (both ends: the
    value is held, ``why`` says at what and why). ``low``/``high`` are the 95 %
    profile-likelihood interval in the parameter's unit (NaN when held).
    """

    name: str
    value: float
    status: str
    low: float = math.nan
    high: float = math.nan
    why: str = ""


@dataclass(frozen=True)
class VariantFit:
    """Fit of one variant of the model: values, what is identifiable, and scores.

    ``rms_relative`` is the RMS of model / measured - 1 over the fitted positions;
    ``cv_rms_relative`` the same for leave-one-out predictions (the selection score).
    """

    filter_floor: str
    noise_reading: str
    sigma_p_px: float
    gamma: float
    rms_relative: float
    filter_form: str = "product"
    sensor_sigma_p_px: float = 0.0
    cv_rms_relative: float = math.nan
    parameters: tuple[Parameter, ...] = ()
    identifiable: tuple[dict, ...] = ()
    n_positions: int = 0

    @property
    def label(self) -> str:
        return f"{self.filter_floor}/{self.filter_form}/{self.noise_reading}"

    def parameter(self, name: str) -> Parameter | None:
        return next((p for p in self.parameters if p.name == name), None)

    def model_overrides(self) -> dict:
        """The ``[model]`` values this fit supports."""
        return {"filter_floor": self.filter_floor, "noise_reading": self.noise_reading,
                "filter_form": self.filter_form, "sigma_p_px": self.sigma_p_px,
                "gamma": self.gamma, "sensor_sigma_p_px": self.sensor_sigma_p_px}

    def apply_to(self, config: ScannerConfig) -> ScannerConfig:
        """``config`` with this fit's model parameters and readings."""
        return config.replace_model(**self.model_overrides())


@dataclass(frozen=True)
class ConstantFit:
    """The baseline without any defocus dependence: one std for every position [px]."""

    std_px: float
    rms_relative: float
    cv_rms_relative: float


# ----------------------------------------------------------------------------- model

@dataclass(frozen=True)
class _Spec:
    """A variant and which of its parameters (sigma_p, gamma, sensor) are free."""

    floor: str
    form: str
    reading: str
    free: tuple[str, ...]
    held: dict = field(default_factory=dict)


def model_std(config: ScannerConfig, data: NoiseData, floor: str, form: str, reading: str,
              sigma_p: float, gamma: float, sensor: float = 0.0) -> np.ndarray:
    """sigma_p s_O of a variant at every position [projector px] (the model chain)."""
    t = optics.optical_terms(data.z_c, data.z_p, config, data.period_px, gamma, floor,
                             reading, form, sensor_ratio=sensor / sigma_p)
    return sigma_p * t.s_o


def _terms(config: ScannerConfig, data: NoiseData, form: str) -> optics.OpticalTerms:
    """The optics at the positions, once per fit (:meth:`OpticalTerms.s_o_with` varies
    gamma, floor and reading without re-running them)."""
    return optics.optical_terms(data.z_c, data.z_p, config, data.period_px, 1.0, "none",
                                "amplitude", form)


def _values(spec: _Spec, x: np.ndarray) -> dict:
    vals = dict(spec.held)
    vals.update({name: float(np.exp(v)) for name, v in zip(spec.free, x, strict=True)})
    return vals


@dataclass(frozen=True)
class _Problem:
    """The optics at the fitted positions (one filter form) and the measured stds."""

    terms: optics.OpticalTerms
    std: np.ndarray

    @property
    def n(self) -> int:
        return int(self.std.size)

    @functools.cached_property
    def log_std(self) -> np.ndarray:
        """log of the measured stds, once per problem (every residual needs it)."""
        return np.log(self.std)

    def take(self, idx: np.ndarray) -> _Problem:
        arrays = {f.name: getattr(self.terms, f.name)[idx]
                  for f in fields(self.terms) if isinstance(getattr(self.terms, f.name),
                                                            np.ndarray)}
        return _Problem(replace(self.terms, **arrays), self.std[idx])

    def model(self, spec: _Spec, values: dict) -> np.ndarray:
        sp = values["sigma_p"]
        return sp * self.terms.s_o_with(values["gamma"], spec.floor, spec.reading,
                                        values.get("sensor", 0.0) / sp)


def _problem(config: ScannerConfig, data: NoiseData, form: str) -> _Problem:
    return _Problem(_terms(config, data, form), data.std_px)


def _residuals(prob: _Problem, spec: _Spec, x: np.ndarray) -> np.ndarray:
    r = np.log(prob.model(spec, _values(spec, x))) - prob.log_std
    return np.where(np.isfinite(r), r, 10.0)  # a NaN model (past J1's zero) fits badly


def _bounds(spec: _Spec) -> tuple[np.ndarray, np.ndarray]:
    rng = {"sigma_p": NOISE_RANGE, "gamma": GAMMA_RANGE, "sensor": NOISE_RANGE}
    lo = np.log([rng[n][0] for n in spec.free])
    hi = np.log([rng[n][1] for n in spec.free])
    return lo, hi


def _starts(spec: _Spec, prob: _Problem) -> list[np.ndarray]:
    s0 = float(np.median(prob.std))
    guess = {"sigma_p": [s0], "gamma": [1.5, 3.0, 10.0], "sensor": [0.3 * s0]}
    grids = np.meshgrid(*[np.log(guess[n]) for n in spec.free], indexing="ij")
    return [np.array(p) for p in zip(*(g.ravel() for g in grids), strict=True)]


def _fit(prob: _Problem, spec: _Spec, starts: list[np.ndarray] | None = None
         ) -> tuple[np.ndarray, float]:
    """Best free parameters (log values, in ``spec.free`` order) and their RSS.

    Where sigma_p is a pure scale of the model - it is free and the sensor part, if any,
    is free too (then fitted as its ratio to sigma_p) - the scale is solved in closed
    form (the mean log ratio) and only the other parameters are searched.
    """
    if "sigma_p" in spec.free and ("sensor" in spec.free or spec.reading != "two_source"):
        return _fit_projected(prob, spec, starts)
    if not spec.free:
        return np.empty(0), float(np.sum(_residuals(prob, spec, np.empty(0)) ** 2))
    lo, hi = _bounds(spec)
    best = None
    for x0 in starts or _starts(spec, prob):
        res = least_squares(lambda x: _residuals(prob, spec, x),
                            np.clip(x0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi))
        if best is None or res.cost < best.cost:
            best = res
    return best.x, float(2.0 * best.cost)


#: Search range of the sensor-to-scene ratio inside the projected fit [-].
_RHO_RANGE = (1e-5, 1e3)


def _projected_residuals(prob: _Problem, spec: _Spec, y: np.ndarray
                         ) -> tuple[np.ndarray, float]:
    """Log residuals with the scale log sigma_p solved in closed form, and that scale.
    ``y`` holds log gamma and/or log rho, those of them that are free."""
    inner = dict(zip(_inner_names(spec), np.exp(y), strict=True))
    gamma = inner.get("gamma", spec.held.get("gamma", 1.0))
    rho = inner.get("rho", 0.0)
    g = np.log(prob.terms.s_o_with(gamma, spec.floor, spec.reading, rho))
    d = np.where(np.isfinite(g), prob.log_std - g, -10.0)
    scale = float(np.mean(d))
    return scale - d, scale


def _inner_names(spec: _Spec) -> list[str]:
    return [{"sensor": "rho"}.get(n, n) for n in spec.free if n != "sigma_p"]


def _fit_projected(prob: _Problem, spec: _Spec, starts: list[np.ndarray] | None
                   ) -> tuple[np.ndarray, float]:
    names = _inner_names(spec)
    rng = {"gamma": GAMMA_RANGE, "rho": _RHO_RANGE}
    lo = np.log([rng[n][0] for n in names])
    hi = np.log([rng[n][1] for n in names])
    seeds = [_to_inner(spec, x0) for x0 in starts] if starts else _grid_starts(
        prob, spec, lo, hi)
    best = None
    for y0 in seeds:
        if not names:
            y, cost = np.empty(0), None
        else:
            res = least_squares(lambda y: _projected_residuals(prob, spec, y)[0],
                                np.clip(y0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi))
            y = res.x
        r, scale = _projected_residuals(prob, spec, y)
        cost = float(np.sum(r * r))
        if best is None or cost < best[1]:
            best = (_from_inner(spec, y, scale), cost)
    return best


def _grid_starts(prob: _Problem, spec: _Spec, lo: np.ndarray, hi: np.ndarray
                 ) -> list[np.ndarray]:
    """The best few points of a coarse grid over the inner parameters."""
    if lo.size == 0:
        return [np.empty(0)]
    axes = [np.linspace(a, b, 9 if lo.size == 1 else 6) for a, b in zip(lo, hi, strict=True)]
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], -1)
    cost = [float(np.sum(_projected_residuals(prob, spec, y)[0] ** 2)) for y in grid]
    return [grid[i] for i in np.argsort(cost)[:3]]


def _to_inner(spec: _Spec, x: np.ndarray) -> np.ndarray:
    v = dict(zip(spec.free, x, strict=True))
    out = []
    for n in _inner_names(spec):
        out.append(v["sensor"] - v["sigma_p"] if n == "rho" else v[n])
    return np.array(out)


def _from_inner(spec: _Spec, y: np.ndarray, scale: float) -> np.ndarray:
    inner = dict(zip(_inner_names(spec), y, strict=True))
    out = []
    for n in spec.free:
        out.append(scale if n == "sigma_p" else scale + inner["rho"] if n == "sensor"
                   else inner[n])
    lo, hi = _bounds(spec)
    return np.clip(np.array(out), lo, hi)


# ------------------------------------------------------------------- identifiability

def _deviance(prob: _Problem, spec: _Spec, x_hat: np.ndarray, rss_min: float, j: int):
    """D(theta_j) - chi^2 threshold as a function of log theta_j, the others re-fitted."""
    name = spec.free[j]
    rest = spec.free[:j] + spec.free[j + 1:]
    start = [np.delete(x_hat, j)]
    seen: dict[float, float] = {}

    def dev(v: float) -> float:
        # brentq evaluates its bracket's ends again: the range's end, tried first by
        # _interval, and the centre, shared by the low and the high interval
        v = float(v)
        if v not in seen:
            held = _Spec(spec.floor, spec.form, spec.reading, rest,
                         {**spec.held, name: float(np.exp(v))})
            _, rss = _fit(prob, held, start)
            seen[v] = prob.n * math.log(max(rss, 1e-300) / max(rss_min, 1e-300)) - CHI2_95
        return seen[v]

    return dev


def _interval(prob: _Problem, spec: _Spec, x_hat: np.ndarray, rss_min: float, j: int
              ) -> tuple[float, float, bool, bool]:
    """95 % profile-likelihood interval of free parameter j (values, not logs) and whether
    it reaches the low / high end of the searched range."""
    dev = _deviance(prob, spec, x_hat, rss_min, j)
    lo, hi = (b[j] for b in _bounds(spec))
    centre = float(np.clip(x_hat[j], lo, hi))
    ends = []
    for end in (lo, hi):
        if dev(end) <= 0.0:
            ends.append((end, True))
        elif abs(end - centre) < 1e-9:
            ends.append((end, False))
        else:
            ends.append((brentq(dev, min(end, centre), max(end, centre), xtol=1e-3), False))
    (low, open_lo), (high, open_hi) = ends
    return float(np.exp(low)), float(np.exp(high)), open_lo, open_hi


def _status(open_lo: bool, open_hi: bool) -> str:
    return "not identifiable" if open_lo and open_hi else \
        "bounded" if open_lo or open_hi else "fitted"


def _why_held(name: str, config: ScannerConfig, data: NoiseData, spec: _Spec,
              held: float) -> str:
    """Why a parameter cannot be identified, and what it is held at."""
    t = optics.optical_terms(data.z_c, data.z_p, config, data.period_px, 1.0, "none",
                             "amplitude", spec.form)
    f = t.filter_factor
    filtered = int(np.sum(f > 1.0))
    if name == "gamma":
        if filtered == 0:
            why = ("F = 1 at every position even with gamma = 1 (the camera blur never "
                   "spreads wider than the noise's correlation area), so gamma has no effect")
        elif np.ptp(f) <= 1e-6 * np.max(f):
            why = ("the camera blur is the same at every position (the camera does not "
                   "move), so gamma only rescales sigma_p")
        else:
            why = ("the profile likelihood stays within its 95 % threshold over gamma "
                   f"{GAMMA_RANGE[0]:g}-{GAMMA_RANGE[1]:g}")
        return f"{why}; held at the config's {held:.4g}"
    return (f"the sensor and scene-side terms scale alike wherever F = 1 (F > 1 at "
            f"{filtered} of {data.n} positions even with gamma = 1), so only their "
            f"quadrature sum is identifiable; the sensor part is held at {held:.4g} px "
            "(the decoder's sensor model)")


def _sensor_estimate(config: ScannerConfig, data: NoiseData) -> float:
    """The decoder's sensor noise scaled to focus, median over positions [px]: the
    sensor part of two_source is 1 / sqrt(A_c A_p) times it."""
    t = optics.optical_terms(data.z_c, data.z_p, config, data.period_px)
    scaled = data.sensor_px * np.sqrt(t.attenuation_camera * t.attenuation_projector)
    scaled = scaled[np.isfinite(scaled)]
    return float(np.median(scaled)) if scaled.size else math.nan


def _initial_spec(config: ScannerConfig, floor: str, form: str, reading: str
                  ) -> tuple[_Spec, dict]:
    free, held, why = ["sigma_p"], {"gamma": config.model.gamma, "sensor": 0.0}, {}
    if floor != "none":  # a floor ("one", "smooth") makes F depend on gamma in shape
        free.append("gamma")
        held.pop("gamma")
    else:
        why["gamma"] = ("with Eq. 17 as printed (no floor) F is proportional to 1 / gamma, "
                        "so sigma_p and gamma enter only as sigma_p x gamma; held at the "
                        f"config's {config.model.gamma:.4g}")
    if reading == "two_source":
        free.append("sensor")
        held.pop("sensor")
    return _Spec(floor, form, reading, tuple(free), held), why


def fit_variant(config: ScannerConfig, data: NoiseData, floor: str, form: str,
                reading: str) -> VariantFit:
    """Fit one variant, find what is identifiable, and score it on held-out positions.

    Parameters
    ----------
    config : ScannerConfig
        Optics of the scanner; its gamma is held where gamma is not identifiable.
    data : NoiseData
        Measured phase noise per position.
    floor, form, reading : str
        The variant (``filter_floor``, ``filter_form``, ``noise_reading``).

    Returns
    -------
    VariantFit
    """
    spec, why = _initial_spec(config, floor, form, reading)
    prob = _problem(config, data, form)
    while True:
        x, rss = _fit(prob, spec)
        intervals = {n: _interval(prob, spec, x, rss, j) for j, n in enumerate(spec.free)}
        lost = [n for n, iv in intervals.items() if iv[2] and iv[3] and n != "sigma_p"]
        if "sensor" in intervals and intervals["sensor"][2] and intervals["sigma_p"][2] \
                and "sensor" not in lost:  # either may vanish: they trade off
            lost.append("sensor")
        if not lost:
            break
        held = dict(spec.held)
        for name in lost:
            value = config.model.gamma if name == "gamma" else _sensor_estimate(config, data)
            if not math.isfinite(value):
                value = float(np.exp(x[spec.free.index(name)]))
            held[name] = value
            why[name] = _why_held(name, config, data, spec, value)
        spec = _Spec(floor, form, reading, tuple(n for n in spec.free if n not in lost), held)
    values = _values(spec, x)
    params = _parameters(spec, values, intervals, why)
    m = prob.model(spec, values)
    return VariantFit(floor, reading, values["sigma_p"], values["gamma"],
                      _rms(m / data.std_px - 1.0), form, values.get("sensor", 0.0),
                      _cv_rms(prob, spec, x), params,
                      _combinations(config, data, spec, values, params), data.n)


_NAMES = {"sigma_p": "sigma_p_px", "gamma": "gamma", "sensor": "sensor_sigma_p_px"}


def _parameters(spec: _Spec, values: dict, intervals: dict, why: dict
                ) -> tuple[Parameter, ...]:
    names = ["sigma_p", "gamma"] + (["sensor"] if spec.reading == "two_source" else [])
    out = []
    for name in names:
        if name in intervals:
            lo, hi, olo, ohi = intervals[name]
            out.append(Parameter(_NAMES[name], values[name], _status(olo, ohi), lo, hi))
        else:
            out.append(Parameter(_NAMES[name], values[name], "not identifiable",
                                 why=why.get(name, "")))
    return tuple(out)


def _combinations(config: ScannerConfig, data: NoiseData, spec: _Spec, values: dict,
                  params: tuple[Parameter, ...]) -> tuple[dict, ...]:
    """What the data identify where a parameter alone is not, and the noise at focus."""
    sp = params[0]
    out = []
    if spec.floor == "none":
        g = values["gamma"]
        out.append({"name": "sigma_p_px * gamma", "value": sp.value * g,
                    "low": sp.low * g, "high": sp.high * g})
    if spec.reading == "two_source" and "sensor" not in spec.free:
        s = values["sensor"]
        out.append({"name": "sqrt(sigma_p_px^2 + sensor_sigma_p_px^2)",
                    "value": math.hypot(sp.value, s), "low": math.hypot(sp.low, s),
                    "high": math.hypot(sp.high, s)})
    focus = NoiseData(np.array([config.camera.focus_mm]), np.array([config.projector.focus_mm]),
                      np.ones(1), np.full(1, np.nan), data.period_px)
    at_focus = model_std(config, focus, spec.floor, spec.form, spec.reading,
                         values["sigma_p"], values["gamma"], values.get("sensor", 0.0))
    out.append({"name": "phase noise at focus [px]", "value": float(at_focus[0])})
    return tuple(out)


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(r))))


def _cv_rms(prob: _Problem, spec: _Spec, x: np.ndarray) -> float:
    """RMS relative error of each position predicted by the fit to all the others."""
    errors = []
    for i in range(prob.n):
        keep = np.arange(prob.n) != i
        xi, _ = _fit(prob.take(keep), spec, [x])
        m = prob.take(~keep).model(spec, _values(spec, xi))
        errors.append(float(m[0] / prob.std[i] - 1.0))
    return _rms(np.array(errors))


def fit_constant(data: NoiseData) -> ConstantFit:
    """The no-defocus baseline: the geometric mean of the stds, scored like a variant."""
    logs = np.log(data.std_px)
    c = float(np.exp(logs.mean()))
    loo = np.exp((logs.sum() - logs) / max(data.n - 1, 1))
    return ConstantFit(c, _rms(c / data.std_px - 1.0), _rms(loo / data.std_px - 1.0))


def fit_all(config: ScannerConfig, data: NoiseData, variants: tuple) -> tuple[VariantFit, ...]:
    """:func:`fit_variant` for every (floor, form, reading) of ``variants``."""
    return tuple(fit_variant(config, data, fl, fo, rd) for fl, fo, rd in variants)


def select(fits: tuple[VariantFit, ...]) -> VariantFit:
    """The variant that predicts held-out positions best (smallest leave-one-out RMS)."""
    return min(fits, key=lambda f: (f.cv_rms_relative, len(f.parameters)))
