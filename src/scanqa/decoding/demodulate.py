"""Demodulation of one N-step phase-shift set: offset, modulation, wrapped phase and
its predicted noise.

For frame k of a set of period P the image model is ``I_k = A + B cos(phi + delta_k)``,
``phi = 2 pi x_p / P``, so a least-squares fit of ``I_k = A + C cos delta_k + S sin
delta_k`` gives the offset A, the modulation ``B = hypot(C, S)`` and the wrapped phase
``phi = atan2(-S, C)`` for any N >= 3 shifts (equal shifts reduce to the classical
N-step formulas).

Noise: each sample has variance ``sigma_I^2 = r^2 + 1/12 + (I - black) / g`` [DN^2]
(read noise r [DN], quantisation when the images are integers, shot noise with the gain
g [e-/DN]). First-order propagation through the fit gives the phase variance per pixel
(exact for unequal shifts and for N = 3, where the shot-noise term depends on phi); for
N >= 4 equal shifts it is the familiar ``2 sigma_I^2 / (N B^2)`` [1]_. The projector
coordinate noise is ``sigma_xp = sigma_phi P / (2 pi)``.

References
----------
.. [1] C. Rathjen, "Statistical properties of phase-shift algorithms", J. Opt. Soc. Am.
   A 12(9), 1995.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scanqa.compiled import HAVE_NUMBA, note_numpy_path
from scanqa.decoding.coding import DEFAULT_SENSOR, PhaseSet, SensorModel
from scanqa.errors import InputError

TWO_PI = 2.0 * np.pi
log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class WrappedPhase:
    """Result of demodulating one phase set.

    Attributes
    ----------
    phase_rad : (H, W) float64
        Wrapped phase phi in [0, 2 pi) [rad].
    offset_dn : (H, W) float64
        Offset A [DN].
    modulation_dn : (H, W) float64
        Modulation B [DN].
    sigma_phase_rad : (H, W) float64
        Predicted standard deviation of phi [rad].
    """

    phase_rad: np.ndarray
    offset_dn: np.ndarray
    modulation_dn: np.ndarray
    sigma_phase_rad: np.ndarray


@dataclass(frozen=True, eq=False)
class ShiftFit:
    """Constants of the least-squares fit for one set of shifts.

    ``rows`` maps the N samples to (A, C, S) and ``design`` back; the other fields are
    the coefficients of the phase variance polynomial (see :func:`_phase_variance`).
    """

    rows: np.ndarray
    quad: tuple[float, float, float]
    cubic: tuple[float, float, float, float]
    design: np.ndarray

    @classmethod
    def from_shifts(cls, shifts_rad: Sequence[float]) -> ShiftFit:
        d = np.asarray(shifts_rad, dtype=np.float64)
        c, s = np.cos(d), np.sin(d)
        design = np.column_stack([np.ones_like(d), c, s])
        rows = np.linalg.pinv(design)
        p1, p2 = rows[1], rows[2]
        quad = (float(p1 @ p1), float(p1 @ p2), float(p2 @ p2))
        cubic = (float(p1 ** 2 @ s), float(p1 ** 2 @ c - 2 * (p1 * p2) @ s),
                 float(p2 ** 2 @ s - 2 * (p1 * p2) @ c), float(p2 ** 2 @ c))
        if max(abs(t) for t in cubic) < 1e-12:
            cubic = (0.0, 0.0, 0.0, 0.0)
        return cls(rows, quad, cubic, design)

    @property
    def simple(self) -> bool:
        """True when the phase variance is ``var(I) q11 / B^2`` (no cubic, q12 = 0,
        q11 = q22: N >= 4 equal shifts)."""
        q11, q12, q22 = self.quad
        return not any(self.cubic) and abs(q12) <= 1e-12 * q11 and \
            abs(q11 - q22) <= 1e-12 * q11


def variance_floor(sensor: SensorModel, quantised: bool) -> float:
    """The signal-independent part of :func:`sample_variance`: read noise and, for
    integer images, quantisation [DN^2]."""
    return sensor.read_noise_dn ** 2 + (1.0 / 12.0 if quantised else 0.0)


def sample_variance(intensity_dn: np.ndarray, sensor: SensorModel,
                    quantised: bool) -> np.ndarray:
    """Variance of one intensity sample from the sensor noise model.

    Parameters
    ----------
    intensity_dn : (...) float
        Expected sample value [DN].
    sensor : SensorModel
        Gain [e-/DN], read noise [e-] and black level [DN].
    quantised : bool
        Add the quantisation variance 1/12 [DN^2] (integer images).

    Returns
    -------
    (...) float64
        ``r^2 + q + max(I - black, 0) / g`` [DN^2].

    Examples
    --------
    >>> float(sample_variance(np.float64(100.0), SensorModel(gain_e_per_dn=4.0,
    ...       read_noise_e=8.0), quantised=False))
    29.0
    """
    floor = variance_floor(sensor, quantised)
    signal = np.asarray(intensity_dn, dtype=np.float64) - sensor.black_level_dn
    if signal.ndim == 0:
        return floor + max(float(signal), 0.0) / sensor.gain_e_per_dn
    np.maximum(signal, 0.0, out=signal)  # one temporary, updated in place
    signal /= sensor.gain_e_per_dn
    signal += floor
    return signal


def _fit_rows(fit: ShiftFit, frames: np.ndarray) -> np.ndarray:
    """(3, M) float64 least-squares (A, C, S) of (N, M) samples."""
    return fit.rows @ frames.astype(np.float64)


def _phase_variance(fit: ShiftFit, a: np.ndarray, c: np.ndarray, s: np.ndarray,
                    b2: np.ndarray, sensor: SensorModel, quantised: bool) -> np.ndarray:
    """Variance of phi = atan2(-S, C) to first order, per pixel [rad^2].

    ``dphi/dI_k = (S p1_k - C p2_k) / B^2`` and ``var I_k = e + (C cos d_k + S sin d_k)
    / g`` with ``e = var(A)`` of the noise model; the sum over k is a polynomial in C, S
    whose constant coefficients come from the fit rows p1, p2. For N >= 4 equal shifts
    the cubic vanishes and the quadratic is ``q B^2``: the variance is ``e q / B^2``.
    """
    q11, q12, q22 = fit.quad
    var = sample_variance(a, sensor, quantised)
    with np.errstate(divide="ignore", invalid="ignore"):
        if fit.simple:
            var *= q11
            var /= b2
            var[~(b2 > 0)] = np.inf
            return var
        var *= q11 * s * s - 2.0 * q12 * s * c + q22 * c * c
        if any(fit.cubic):
            t1, t2, t3, t4 = fit.cubic
            var += (((t1 * s + t2 * c) * s + t3 * c * c) * s + t4 * c * c * c) \
                / sensor.gain_e_per_dn
        return np.where(b2 > 0, var / (b2 * b2), np.inf)


def fit_residual(fit: ShiftFit, frames: np.ndarray) -> np.ndarray:
    """Sum of squared residuals of the least-squares fit of (N, M) samples [DN^2].

    With N > 3 frames it is ``(N - 3) sigma_I^2`` on average for white noise (plus any
    harmonic of the fringe that the N shifts do not alias into the fundamental).
    """
    f = frames.astype(np.float64)
    model = fit.design @ _fit_rows(fit, f)
    return ((f - model) ** 2).sum(axis=0)


def demodulate_flat(fit: ShiftFit, frames: np.ndarray, sensor: SensorModel,
                    quantised: bool) -> tuple[np.ndarray, ...]:
    """Offset, modulation, phase fraction [cycles in [0, 1)] and phase variance; with
    numba, all but the fit in one compiled pass (:mod:`scanqa.decoding.phasekernel`)."""
    if HAVE_NUMBA:  # imported here: numba loads at a decode, not with the package
        from scanqa.decoding.phasekernel import demodulate_compiled
        return demodulate_compiled(_fit_rows(fit, frames), fit.quad, fit.cubic, fit.simple,
                                   variance_floor(sensor, quantised), sensor.black_level_dn,
                                   sensor.gain_e_per_dn)
    note_numpy_path(log, "the decode's demodulation (about 1.2 x the CPU)")
    a, c, s = _fit_rows(fit, frames)
    b2 = c * c
    b2 += s * s
    var = _phase_variance(fit, a, c, s, b2, sensor, quantised)
    frac = np.negative(s, out=s)  # the fit's S is not needed again: reused in place
    np.arctan2(frac, c, out=frac)
    frac *= 1.0 / TWO_PI
    frac += frac < 0
    return a, np.sqrt(b2), frac, var


def demodulate_sample(sets: Sequence, sample: Sequence[np.ndarray], sensor: SensorModel,
                      quantised: bool) -> dict[str, tuple[np.ndarray, ...]]:
    """Every phase set of a sample demodulated once, for the checks that read it.

    Parameters
    ----------
    sets : sequence of PatternSet
        The description's sets, in the order of ``sample``; only the phase sets are
        demodulated.
    sample : sequence of (N, h, W) arrays
        The sets' frames at the sampled rows [DN].
    sensor : SensorModel
        Resolved noise model.
    quantised : bool
        Integer images.

    Returns
    -------
    dict of str to tuple
        ``{set name: (A [DN], B [DN], phase fraction [cycles], phase variance
        [rad^2])}``, flat (h W,) arrays, as :func:`demodulate_flat` gives them.
    """
    out = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        for pset, frames in zip(sets, sample, strict=True):
            if isinstance(pset, PhaseSet):
                out[pset.name] = demodulate_flat(ShiftFit.from_shifts(pset.shifts_rad),
                                                 frames.reshape(frames.shape[0], -1),
                                                 sensor, quantised)
    return out


def demodulate(images: np.ndarray, shifts_rad: Sequence[float] | None = None,
               sensor: SensorModel | None = None) -> WrappedPhase:
    """Wrapped phase, offset, modulation and phase noise of one N-step set.

    Parameters
    ----------
    images : (N, H, W) array
        The N frames, N >= 3 [DN].
    shifts_rad : sequence of float, optional
        Phase shift delta_k of each frame [rad]; default ``2 pi k / N``.
    sensor : SensorModel, optional
        Noise model; default (or without gain and read noise)
        :data:`~scanqa.decoding.coding.DEFAULT_SENSOR`, 4 e-/DN and 8 e-.

    Returns
    -------
    WrappedPhase
        phi in [0, 2 pi), A, B and sigma_phi of every pixel.

    Examples
    --------
    >>> x = np.array([[0.5, 1.0, 7.25]])
    >>> frames = np.stack([100 + 50 * np.cos(2 * np.pi * x / 8 + 2 * np.pi * k / 4)
    ...                    for k in range(4)])
    >>> (demodulate(frames).phase_rad * 8 / (2 * np.pi)).round(9).tolist()
    [[0.5, 1.0, 7.25]]
    """
    stack = np.asarray(images)
    if stack.ndim != 3 or stack.shape[0] < 3:
        raise InputError(f"images must be an (N, H, W) stack with N >= 3, got {stack.shape}")
    n = stack.shape[0]
    shifts = TWO_PI * np.arange(n) / n if shifts_rad is None else shifts_rad
    if len(shifts) != n:
        raise InputError(f"got {len(shifts)} shifts_rad for {n} images; give one per image")
    fit = ShiftFit.from_shifts(shifts)
    quantised = stack.dtype.kind in "ui"
    sensor = DEFAULT_SENSOR if sensor is None or not sensor.knows_noise else sensor
    with np.errstate(invalid="ignore"):
        a, b, frac, var = demodulate_flat(fit, stack.reshape(n, -1), sensor, quantised)
    shape = stack.shape[1:]
    return WrappedPhase(TWO_PI * frac.reshape(shape), a.reshape(shape), b.reshape(shape),
                        np.sqrt(var).reshape(shape))
