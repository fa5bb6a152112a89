"""Camera noise from the images themselves, when the camera's gain and read noise are
not given.

Every source below yields samples of the intensity variance ``s^2`` with ``nu`` degrees
of freedom at an intensity level L; the model ``sigma_I^2 = a + b (L - black)`` (read
noise and quantisation, plus shot noise with ``b = 1 / gain``) is fitted to all samples
by weighted least squares (weights ``nu / sigma^4``, non-negative coefficients), with
samples beyond the 99.9 % chi-square quantile (edges, motion) dropped and the
truncation corrected. The first source the scan has is used, in this order:

1. residuals of the N-step fits (phase sets of N >= 4 frames): ``RSS / (N - 3)``;
2. offsets of two phase sets of one orientation: the offset A of each is the same mean
   level measured twice, up to what the projector's response adds (constant along a
   fringe);
3. the Gray-code frames that are clearly white (black) at a pixel against the white
   (black) reference frame; without a Gray code, repeated reference frames of one level;
4. pattern + inverse sums of a Gray code, one bit against the next.

Sources 2-4 compare images whose expected difference is not zero - stray light puts a
Gray code's white stripes below the white frame, a nonlinear projector shifts one
set's offset against another's - but changes only slowly, or not at all, along the
stripes and fringes. So each difference image is taken through the second difference
at a lag of :data:`LAG_PX` pixels *along* the fringes, ``(d[i - L] - 2 d[i] + d[i + L])
/ sqrt(6)``, which removes any level that is linear along them and keeps the noise
(its variance is the variance of d for noise uncorrelated beyond L - 1 px: cameras
whose noise is shared between neighbouring pixels, through demosaicing or the lens,
are read right at L = 3). Every pixel counts, whatever the sign of its deviation, and
the samples hold the quantisation of the frames they come from (noise of 0.5 DN or
more dithers it), as the phase frames do. The source is named in the decode summary
and the phase map's provenance; with none, one warning says that every sigma is
assumed and what to give.
"""

from __future__ import annotations

import itertools
import math
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

#: Pixels sampled (whole rows or columns, evenly spaced) for the estimate: the variance
#: is then known to better than 1 % (chi-square with one degree of freedom per sample).
SAMPLE_PIXELS = 60000
#: Fewest lines sampled for an estimate [-].
MIN_LINES = 24
#: Fewest usable samples for an estimate (the variance is then known to ~10 %).
MIN_SAMPLES = 200
#: Lag of the second differences along the fringes [px] (chosen on kamino410's gamma
#: flat, set A: the phase noise along its fringes is flat from lag 2 to 6, while lag 1
#: reads the camera's neighbour correlation; docs/noise_model.rst).
LAG_PX = 3
#: A Gray frame counts as white (black) where it is this share of the white - black
#: contrast above (below) the mid level at all three pixels of a difference [-].
STATE_MARGIN = 0.25
#: The warning of a decode whose every sigma is assumed.
ASSUMED_WARNING = (
    "every sigma of this scan is ASSUMED: the images hold no noise source (no phase set "
    "of 4 or more steps, no two phase sets of one orientation, no white and black frames, "
    "no Gray code with inverses) and [sensor] gives no gain and read noise; the default "
    "camera (4 e-/DN, 8 e-) is used - give [sensor] gain_e_per_dn and read_noise_e, or "
    "capture a white and a black frame or a second phase set")


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
        Samples the estimate used (0 for a given or default model) [-].
    """

    source: str
    sensor: SensorModel
    samples: int = 0

    @property
    def warning(self) -> str:
        """One line saying that every sigma is assumed and what to give, or ""."""
        return ASSUMED_WARNING if self.source.startswith("default model") and \
            "hold no noise source" in self.source else ""

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
    found = _samples(desc, stacks, sensor)
    if found is not None and found[0][0].size >= MIN_SAMPLES:
        (s2, dof, level), name = found
        if s2.size > 2 * SAMPLE_PIXELS:  # many frames' lines: an even share of them
            pick = np.linspace(0, s2.size - 1, 2 * SAMPLE_PIXELS).astype(int)
            s2, dof, level = s2[pick], dof[pick], level[pick]
        a, b = fit_variance(s2, dof, level - sensor.black_level_dn,
                            floor=1.0 / 48.0 if quantised else 1e-6)
        return NoiseEstimate(f"estimated from the images: {name}",
                             _to_sensor(sensor, a, b, quantised), int(s2.size))
    model = replace(sensor, gain_e_per_dn=DEFAULT_SENSOR.gain_e_per_dn,
                    read_noise_e=DEFAULT_SENSOR.read_noise_e)
    return NoiseEstimate("default model (4 e-/DN, 8 e-): the images hold no noise source "
                         "(give [sensor] gain_e_per_dn and read_noise_e)", model)


def _centres(length: int, width: int) -> np.ndarray:
    """Evenly spaced centre lines of ``width`` samples each, LAG_PX from either end,
    about SAMPLE_PIXELS samples in all, and at least MIN_LINES lines (a few lines would
    sample a few places of the scene only)."""
    count = max(MIN_LINES, min(length - 2 * LAG_PX, SAMPLE_PIXELS // max(width, 1)))
    count = min(count, max(length - 2 * LAG_PX, 1))
    return np.unique(np.linspace(LAG_PX, length - LAG_PX - 1, count).round().astype(int))


class _Lines:
    """Three lines per sample: a centre and its neighbours LAG_PX before and after it,
    taken along the fringes of one orientation (rows for vertical fringes)."""

    def __init__(self, shape: tuple[int, int], orientation: str, frames: int = 1) -> None:
        self.vertical = orientation != "horizontal"
        height, width = shape
        # frames: images each line is read from, sharing the SAMPLE_PIXELS between them
        width, height = (width, height) if self.vertical else (height, width)
        self.idx = _centres(height, width * max(frames, 1))

    def take(self, stack: np.ndarray) -> np.ndarray:
        """(3, N, M) float64: the lines before, at and after each centre, flattened."""
        axis = -2 if self.vertical else -1
        out = [np.take(stack, self.idx + k, axis=axis).astype(np.float64)
               for k in (-LAG_PX, 0, LAG_PX)]
        return np.stack([o.reshape(o.shape[0], -1) for o in out])


def _second(d: np.ndarray) -> np.ndarray:
    """Second difference of (3, ...) lines, scaled to the variance of one line."""
    return (d[0] - 2.0 * d[1] + d[2]) / math.sqrt(6.0)


def _samples(desc: PatternDescription, stacks: list[np.ndarray], sensor: SensorModel
             ) -> tuple[tuple, str] | None:
    """(s2, dof, level) of the first source the scan has, and its name."""
    shape = stacks[0].shape[1:]
    sets = list(zip(desc.sets, stacks, strict=True))
    phase = [(s, st) for s, st in sets if isinstance(s, PhaseSet)]
    long_sets = [(s, st) for s, st in phase if s.steps >= 4]
    sat = sensor.saturation_dn
    if long_sets:
        names = ", ".join(s.name for s, _ in long_sets)
        return _residual_samples(long_sets, shape, sat), \
            f"residuals of the N-step fits ({names})"
    pairs = [p for o in ("vertical", "horizontal")
             for p in itertools.pairwise([x for x in phase if x[0].orientation == o])]
    if pairs:
        names = ", ".join(f"{a.name} vs {b.name}" for (a, _), (b, _) in pairs)
        return _offset_samples(pairs, shape, sat), \
            f"offsets of the phase sets ({names}), second differences along the fringes"
    gray = next(((s, st) for s, st in sets if isinstance(s, GrayCodeSet)), None)
    ref = next(((s, st) for s, st in sets if isinstance(s, ReferenceSet)), None)
    if ref is not None:
        how = "repeats of the white and black levels" + (
            " (the Gray code's stripes against the white and black frames, second "
            "differences along the stripes)" if gray is not None else "")
        return _level_samples(ref, gray, shape, sat), how
    if gray is not None and gray[0].inverse != "none":
        return _inverse_samples(*gray, shape, sat), \
            "pattern + inverse sums of the Gray code, bit against bit"
    return None


def _unsat(lines: np.ndarray, sat: float) -> np.ndarray:
    """Samples none of whose frames and lines is clipped: at or above saturation, or at
    or below zero (a camera clips its noise there, which would read low)."""
    return ~np.any((lines >= sat) | (lines <= 0), axis=(0, 1))


def _residual_samples(sets: list, shape: tuple, sat: float) -> tuple:
    parts = []
    for pset, st in sets:
        f = _Lines(shape, pset.orientation).take(st)[1]
        keep = ~np.any((f >= sat) | (f <= 0), axis=0)
        fit = ShiftFit.from_shifts(pset.shifts_rad)
        dof = pset.steps - 3
        f = f[:, keep]
        parts.append((fit_residual(fit, f) / dof, np.full(f.shape[1], dof),
                      fit.rows[0] @ f))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _offset_samples(pairs: list, shape: tuple, sat: float) -> tuple:
    """The offsets of two phase sets of one orientation, differenced along the fringes:
    ``var(A_i - A_j) = sigma_I^2 (q_i + q_j)`` with ``q`` each offset's variance factor."""
    parts = []
    for (sa, fa), (sb, fb) in pairs:
        lines = _Lines(shape, sa.orientation)
        la, lb = lines.take(fa), lines.take(fb)
        ra = ShiftFit.from_shifts(sa.shifts_rad).rows[0]
        rb = ShiftFit.from_shifts(sb.shifts_rad).rows[0]
        a, b = np.einsum("n,lnm->lm", ra, la), np.einsum("n,lnm->lm", rb, lb)
        keep = _unsat(la, sat) & _unsat(lb, sat)
        d = _second(a - b)[keep]
        parts.append((d * d / (ra @ ra + rb @ rb), np.ones(d.size),
                      0.5 * (a[1] + b[1])[keep]))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _level_samples(ref: tuple, gray: tuple | None, shape: tuple, sat: float) -> tuple:
    """White and black levels measured twice.

    With a Gray code, each of its frames is compared with the reference frame of the
    level it shows at a pixel - white (black) where it is clearly above (below) the mid
    level at all three pixels of the difference, so that cell edges stay out and no
    deviation is kept or dropped for its own sign. Without a Gray code, repeated
    reference frames of one level give their within-level variance.
    """
    rset, rst = ref
    is_white = np.array([v == "white" for v in rset.levels])
    orientation = gray[0].orientation if gray is not None else "vertical"
    lines = _Lines(shape, orientation, gray[1].shape[0] if gray is not None else 1)
    rl = lines.take(rst)
    if gray is None:
        keep = _unsat(rl, sat)
        parts = [_repeat_deviations(rl[1][is_white][:, keep]),
                 _repeat_deviations(rl[1][~is_white][:, keep])]
        return tuple(np.concatenate(p) for p in zip(*parts, strict=True))
    white, black = rl[:, is_white].mean(axis=1), rl[:, ~is_white].mean(axis=1)
    contrast = white - black
    mid = 0.5 * (white + black)
    gl = lines.take(gray[1])
    keep = _unsat(rl, sat) & _unsat(gl, sat) & np.all(contrast > 0, axis=0)
    parts = []
    for k in range(gl.shape[1]):
        g = gl[:, k]
        for sign, level, n_ref in ((1.0, white, is_white.sum()), (-1.0, black,
                                                                  (~is_white).sum())):
            state = keep & np.all(sign * (g - mid) > STATE_MARGIN * contrast, axis=0)
            d = _second(g - level)[state]
            parts.append((d * d / (1.0 + 1.0 / n_ref), np.ones(d.size),
                          0.5 * (g[1] + level[1])[state]))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _inverse_samples(gray: GrayCodeSet, st: np.ndarray, shape: tuple, sat: float) -> tuple:
    """Pattern + inverse sums of consecutive bits, differenced along the stripes: each sum
    is the white plus the black level, up to what a nonlinear camera adds at cell edges."""
    plain, inverse = gray.frame_order()
    gl = _Lines(shape, gray.orientation, gray.bits).take(st)
    keep = _unsat(gl, sat)
    sums = gl[:, plain] + gl[:, inverse]
    parts = []
    for k in range(gray.bits - 1):
        d = _second(sums[:, k] - sums[:, k + 1])[keep]
        parts.append((d * d / 4.0, np.ones(d.size),
                      0.25 * (sums[1, k] + sums[1, k + 1])[keep]))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


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

    ``quantised``: the estimate holds the quantisation variance 1/12 DN^2 (every source
    compares frames rounded independently), which the model adds by itself for integer
    images, so it is taken out of the read noise.
    """
    gain = 1.0 / b if b > 1e-9 else 1e9
    read_var = max(a - (1.0 / 12.0 if quantised else 0.0), 0.0)
    return replace(sensor, gain_e_per_dn=gain, read_noise_e=float(np.sqrt(read_var)) * gain)
