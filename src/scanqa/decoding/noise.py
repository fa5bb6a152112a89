"""Camera noise from the images themselves, when the camera's gain and read noise are
not given.

Every source below yields, per pixel, a sample variance ``s^2`` with ``nu`` degrees of
freedom at an intensity level L; the model ``sigma_I^2 = a + b (L - black)`` (read noise
and quantisation, plus shot noise with ``b = 1 / gain``) is fitted to all samples by
weighted least squares (weights ``nu / sigma^4``, non-negative coefficients), with
samples beyond the 99.9 % chi-square quantile (edges, motion) dropped and the
truncation corrected. The first source the scan has is used, in this order:

1. residuals of the N-step fits (phase sets of N >= 4 frames): ``RSS / (N - 3)``;
2. repeats of the white and black levels: the Gray-code frames that are white (black)
   at a pixel against the white (black) reference frame, deviations away from mid grey
   only (blur at cell edges pulls a frame towards mid grey, never beyond its level);
   without a Gray code, repeated reference frames of one level;
3. pattern + inverse sums of a Gray code: ``var_k(P_k + I_k) / 2`` at the mid level
   (repeats of one level round the same way every time, so 2. and 3. hold no
   quantisation noise, which the model adds for integer images);
4. offsets of two phase sets: ``(A_i - A_j)^2 / (q_i + q_j)``, the offsets being the same
   mean level measured twice (``q`` is the variance factor of each set's offset).

Residual-type estimates also hold what the model does not explain - fringe harmonics
of a nonlinear projector in 1. and 4. - so they err on the side of more noise. The
source is named in the decode summary and the phase map's provenance.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import gammainc, gammaincinv

from scanqa.decoding.coding import (
    DEFAULT_SENSOR,
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
)
from scanqa.decoding.demodulate import ShiftFit, fit_residual

#: Pixels sampled (whole rows, evenly spaced) for the estimate: the variance is then
#: known to about 1 % (chi-square with one degree of freedom per sample).
SAMPLE_PIXELS = 60000
#: Fewest usable samples for an estimate (the variance is then known to ~10 %).
MIN_SAMPLES = 200


@dataclass(frozen=True)
class NoiseEstimate:
    """Noise model in use and where it came from.

    Attributes
    ----------
    source : str
        Where the noise came from, in words.
    sensor : SensorModel
        Resolved model with gain and read noise.
    samples : int
        Pixels the estimate used (0 for a given or default model) [-].
    """

    source: str
    sensor: SensorModel
    samples: int = 0

    def as_dict(self) -> dict:
        """JSON-ready summary (for the phase map's provenance)."""
        s = self.sensor
        floor = s.read_noise_dn ** 2
        return {"source": self.source, "samples": self.samples,
                "read_noise_dn": float(np.sqrt(floor)),
                "gain_e_per_dn": float(s.gain_e_per_dn),
                "sigma_dn_at_100dn": float(np.sqrt(floor + 100.0 / s.gain_e_per_dn))}


def resolve_noise(desc: PatternDescription, stacks: list[np.ndarray], sensor: SensorModel,
                  quantised: bool) -> NoiseEstimate:
    """The noise model of a decode: the sensor's, or estimated from the images.

    Parameters
    ----------
    desc : PatternDescription
        The coding (its ``options.noise`` chooses).
    stacks : list of (N, H, W) arrays
        One stack per set, in ``desc.sets`` order [DN].
    sensor : SensorModel
        The sensor model with bit depth and saturation resolved.
    quantised : bool
        Integer images.

    Returns
    -------
    NoiseEstimate
        The model and its source.
    """
    mode = desc.options.noise
    if mode == "sensor" or (mode == "auto" and sensor.knows_noise):
        model = sensor if sensor.knows_noise else replace(
            sensor, gain_e_per_dn=DEFAULT_SENSOR.gain_e_per_dn,
            read_noise_e=DEFAULT_SENSOR.read_noise_e)
        what = "[sensor] gain and read noise" if sensor.knows_noise else \
            "default model (4 e-/DN, 8 e-; decode.noise = 'sensor' without [sensor] gain)"
        return NoiseEstimate(f"sensor model: {what}", model)
    found = _samples(desc, _sampled(stacks), sensor)
    if found is not None and found[0][0].size >= MIN_SAMPLES:
        (s2, dof, level), name = found
        a, b = fit_variance(s2, dof, level - sensor.black_level_dn,
                            floor=1.0 / 48.0 if quantised else 1e-6)
        # repeats of one level round the same way every time: no quantisation in them
        has_q = quantised and not name.startswith(("repeats", "pattern + inverse"))
        return NoiseEstimate(f"estimated from the images: {name}",
                             _to_sensor(sensor, a, b, has_q), int(s2.size))
    model = replace(sensor, gain_e_per_dn=DEFAULT_SENSOR.gain_e_per_dn,
                    read_noise_e=DEFAULT_SENSOR.read_noise_e)
    return NoiseEstimate("default model (4 e-/DN, 8 e-): the images hold no noise source "
                         "(give [sensor] gain_e_per_dn and read_noise_e)", model)


def _sampled(stacks: list[np.ndarray]) -> list[np.ndarray]:
    """Evenly spaced whole rows of every stack, flattened to (N, M) float64."""
    height, width = stacks[0].shape[1:]
    step = max(1, (height * width) // SAMPLE_PIXELS)
    return [st[:, ::step].reshape(st.shape[0], -1).astype(np.float64) for st in stacks]


def _samples(desc: PatternDescription, flat: list[np.ndarray], sensor: SensorModel
             ) -> tuple[tuple, str] | None:
    """(s2, dof, level) of the first source the scan has, and its name."""
    unsat = ~np.any([f.max(axis=0) >= sensor.saturation_dn for f in flat], axis=0)
    by_kind = {type(s): (s, f[:, unsat]) for s, f in zip(desc.sets, flat, strict=True)}
    phase = [(s, f[:, unsat]) for s, f in zip(desc.sets, flat, strict=True)
             if isinstance(s, PhaseSet)]
    long_sets = [(s, f) for s, f in phase if s.steps >= 4]
    if long_sets:
        names = ", ".join(s.name for s, _ in long_sets)
        return _residual_samples(long_sets), f"residuals of the N-step fits ({names})"
    gray, ref = by_kind.get(GrayCodeSet), by_kind.get(ReferenceSet)
    if ref is not None:
        return _level_samples(ref, gray), "repeats of the white and black levels"
    if gray is not None and gray[0].inverse != "none":
        return _inverse_samples(*gray), "pattern + inverse sums of the Gray code"
    if len(phase) >= 2:
        pairs = ", ".join(f"{a.name} vs {b.name}" for (a, _), (b, _) in
                          itertools.pairwise(phase))
        return _offset_samples(phase), f"offsets of the phase sets ({pairs})"
    return None


def _residual_samples(sets: list) -> tuple:
    parts = []
    for pset, f in sets:
        fit = ShiftFit.from_shifts(pset.shifts_rad)
        dof = pset.steps - 3
        parts.append((fit_residual(fit, f) / dof, np.full(f.shape[1], dof), fit.rows[0] @ f))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _offset_samples(sets: list) -> tuple:
    parts = []
    for (sa, fa), (sb, fb) in itertools.pairwise(sets):
        ra, rb = ShiftFit.from_shifts(sa.shifts_rad).rows[0], \
            ShiftFit.from_shifts(sb.shifts_rad).rows[0]
        a, b = ra @ fa, rb @ fb
        parts.append(((a - b) ** 2 / (ra @ ra + rb @ rb), np.ones(a.size), 0.5 * (a + b)))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _inverse_samples(gray: GrayCodeSet, f: np.ndarray) -> tuple:
    plain, inverse = gray.frame_order()
    sums = f[plain] + f[inverse]
    return sums.var(axis=0, ddof=1) / 2.0, np.full(f.shape[1], gray.bits - 1.0), \
        sums.mean(axis=0) / 2.0


def _level_samples(ref: tuple, gray: tuple | None) -> tuple:
    """Deviations of repeated white or black frames from the reference level.

    With a Gray code, its frames that are white (black) at a pixel are compared with
    the white (black) reference frame, counting only deviations away from mid grey: a
    frame on a blurred cell edge is pulled towards mid grey, never beyond its level, so
    the far half of the deviations is noise alone (for symmetric noise). Without a Gray
    code, repeated reference frames of one level are compared with their mean.
    """
    rset, rf = ref
    is_white = np.array([v == "white" for v in rset.levels])
    white, black = rf[is_white].mean(axis=0), rf[~is_white].mean(axis=0)
    if gray is None:
        parts = [_repeat_deviations(rf[is_white]), _repeat_deviations(rf[~is_white])]
        return tuple(np.concatenate(p) for p in zip(*parts, strict=True))
    g = gray[1]
    mid = 0.5 * (white + black)
    is_w = g > mid
    level = np.where(is_w, white, black)
    dev = g - level
    away = np.where(is_w, dev > 0, dev < 0) & (white > black)
    n_ref = np.where(is_w, is_white.sum(), (~is_white).sum())
    s2 = dev[away] ** 2 / (1.0 + 1.0 / n_ref[away])
    return s2, np.ones(s2.size), level[away]


def _repeat_deviations(frames: np.ndarray) -> tuple:
    """Within-level sample variance of repeated frames of one level."""
    n = frames.shape[0]
    if n < 2:
        return np.empty(0), np.empty(0), np.empty(0)
    return frames.var(axis=0, ddof=1), np.full(frames.shape[1], n - 1.0), \
        frames.mean(axis=0)


def fit_variance(s2: np.ndarray, dof: np.ndarray, level: np.ndarray,
                 floor: float = 1e-6, iterations: int = 5) -> tuple[float, float]:
    """Fit ``s2 ~ a + b level`` robustly (chi-square weights and trimming).

    Parameters
    ----------
    s2 : (n,) float
        Sample variances [DN^2].
    dof : (n,) float
        Their degrees of freedom [-].
    level : (n,) float
        Intensity level above black [DN].
    floor : float
        Smallest variance used for weights [DN^2] (a quarter of the quantisation
        variance for integer images: below it the weights mean nothing).
    iterations : int
        Reweighting passes [-].

    Returns
    -------
    a, b : float
        Floor [DN^2] and shot slope [DN].
    """
    level = np.maximum(level, 0.0)
    values, index = np.unique(dof, return_inverse=True)
    quantile = 2.0 * gammaincinv(values / 2.0, 0.999)  # chi-square 99.9 % quantile
    cut = (quantile / values)[index]
    coef = _nnls2(level, s2, dof)
    keep = np.ones(s2.size, bool)
    for _ in range(iterations):
        pred = np.maximum(coef[0] + coef[1] * level, floor)
        keep = s2 <= cut * pred
        coef = _nnls2(level[keep], s2[keep], dof[keep] / pred[keep] ** 2)
    # E[s2 | s2 <= c] = P(chi2_(nu+2) <= c nu) / P(chi2_nu <= c nu) E[s2]
    kept = (gammainc(values / 2.0 + 1.0, quantile / 2.0)
            / gammainc(values / 2.0, quantile / 2.0))[index]
    coef = coef / float(np.mean(kept[keep]))
    return float(max(coef[0], floor)), float(coef[1])


def _nnls2(level: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares ``y ~ a + b level`` with a, b >= 0 (normal equations)."""
    wl = w * level
    normal = np.array([[w.sum(), wl.sum()], [wl.sum(), wl @ level]])
    rhs = np.array([w @ y, wl @ y])
    try:
        coef = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        coef = np.array([-1.0, -1.0])
    if (coef >= 0).all():
        return coef
    # one coefficient at its bound 0: the better of the two one-term fits
    only = [max(rhs[i] / normal[i, i], 0.0) if normal[i, i] > 0 else 0.0 for i in (0, 1)]
    cost = [only[i] * (only[i] * normal[i, i] - 2 * rhs[i]) for i in (0, 1)]
    return np.array([only[0], 0.0]) if cost[0] <= cost[1] else np.array([0.0, only[1]])


def _to_sensor(sensor: SensorModel, a: float, b: float, quantised: bool) -> SensorModel:
    """The sensor model whose sample variance is ``a + b (I - black)``.

    ``quantised``: the estimate holds the quantisation variance 1/12 DN^2, which the
    model adds by itself for integer images, so it is taken out of the read noise.
    """
    gain = 1.0 / b if b > 1e-9 else 1e9
    read_var = max(a - (1.0 / 12.0 if quantised else 0.0), 0.0)
    return replace(sensor, gain_e_per_dn=gain, read_noise_e=float(np.sqrt(read_var)) * gain)
