"""The demodulation of :func:`scanqa.decoding.demodulate.demodulate_flat` after the fit,
as one compiled pass over the pixels.

From the least-squares fit (A, C, S) numpy makes the modulation, the phase variance and
the phase in some fifteen passes over the chunk, each with its temporary, and libm's
``atan2`` (through ``np.arctan2``). Compiled (numba, the optional ``fast`` extra), the
same operations run in the same order pixel by pixel - correctly rounded IEEE-754
operations without contraction, and the same libm ``atan2`` - so the results are the
numpy path's, bit for bit where numpy's ``arctan2`` is libm's (on another CPU numpy may
pick a SIMD ``arctan2``: tests compare the two within the rounding the operations allow).

The fit stays a numpy matrix product: a loop would sum in another order than BLAS, and
an integer image makes C or S exactly zero (two frames equal) far more often than
chance, where the sign of the rounding left decides a phase of 0 or of a full cycle.

An unwrapping step (:func:`scanqa.decoding.unwrap._unwrap_step`: the order, the
residual and its two tests) is one pass too, :func:`unwrap_step_compiled`.

Without numba :data:`scanqa.compiled.HAVE_NUMBA` is False and the numpy path runs.
"""

from __future__ import annotations

import math

import numpy as np

from scanqa.compiled import njit

_CYCLES = 1.0 / (2.0 * math.pi)


@njit(cache=True, nogil=True, error_model="numpy")
def _demodulate(a, c, s, floor, black, gain, quad, cubic, simple, b_out, frac_out, var_out):
    """B, the phase fraction and the phase variance from the fit (A, C, S), with the
    numpy path's operations in its order."""
    if simple:
        _variance_simple(a, c, s, floor, black, gain, quad[0], var_out)
    else:
        _variance_general(a, c, s, floor, black, gain, quad, cubic, var_out)
    for i in range(a.size):
        ci, si = c[i], s[i]
        b2 = ci * ci
        b2 += si * si
        b_out[i] = math.sqrt(b2)
        frac = math.atan2(-si, ci) * _CYCLES
        frac_out[i] = frac + 1.0 if frac < 0.0 else frac


@njit(cache=True, nogil=True, error_model="numpy")
def _variance_simple(a, c, s, floor, black, gain, q11, var_out):
    """``var(I) q11 / B^2`` (inf where B = 0), with var(I) of ``sample_variance``."""
    for i in range(a.size):
        b2 = c[i] * c[i]
        b2 += s[i] * s[i]
        var = (max(a[i] - black, 0.0) / gain + floor) * q11 / b2
        var_out[i] = var if b2 > 0.0 else np.inf


@njit(cache=True, nogil=True, error_model="numpy")
def _variance_general(a, c, s, floor, black, gain, quad, cubic, var_out):
    """The phase variance polynomial of ``demodulate._phase_variance`` (unequal shifts,
    N = 3) [rad^2]."""
    q11, q12, q22 = quad
    t1, t2, t3, t4 = cubic
    cubic_on = t1 != 0.0 or t2 != 0.0 or t3 != 0.0 or t4 != 0.0
    for i in range(a.size):
        ci, si = c[i], s[i]
        b2 = ci * ci
        b2 += si * si
        var = max(a[i] - black, 0.0) / gain + floor
        var *= q11 * si * si - 2.0 * q12 * si * ci + q22 * ci * ci
        if cubic_on:
            var += (((t1 * si + t2 * ci) * si + t3 * ci * ci) * si + t4 * ci * ci * ci) / gain
        var_out[i] = var / (b2 * b2) if b2 > 0.0 else np.inf


def demodulate_compiled(fit_acs: np.ndarray, quad: tuple, cubic: tuple, simple: bool,
                        floor: float, black: float, gain: float) -> tuple[np.ndarray, ...]:
    """The compiled twin of :func:`scanqa.decoding.demodulate.demodulate_flat` after the
    fit.

    Parameters
    ----------
    fit_acs : (3, M) float64
        The least-squares (A, C, S) of every pixel [DN].
    quad, cubic : tuple of float
        Coefficients of the phase variance polynomial (``ShiftFit``) [-].
    simple : bool
        The variance is ``var(I) q11 / B^2`` (N >= 4 equal shifts).
    floor, black, gain : float
        Sample variance ``floor + max(I - black, 0) / gain``: floor [DN^2], black level
        [DN], gain [e-/DN].

    Returns
    -------
    a, b, frac, var : (M,) float64
        Offset [DN], modulation [DN], phase fraction [cycles in [0, 1)], phase variance
        [rad^2] (inf where B = 0).
    """
    a, c, s = fit_acs
    b, frac, var = np.empty(a.size), np.empty(a.size), np.empty(a.size)
    _demodulate(a, c, s, float(floor), float(black), float(gain),
                tuple(float(v) for v in quad), tuple(float(v) for v in cubic), bool(simple),
                b, frac, var)
    return a, b, frac, var


@njit(cache=True, nogil=True, error_model="numpy")
def _unwrap_step(x, var_x, frac, var_step, period, max_residual, margin2, x_out, bad,
                 noisy):
    """The order k = rint(x / P - f), the coordinate (f + k) P, and the residual's two
    tests, with the numpy path's operations in its order."""
    p2 = period * period
    for i in range(x.size):
        r = x[i] / period - frac[i]
        k = np.rint(r)
        residual = abs(r - k)
        bad[i] = residual > max_residual
        variance = (var_x[i] + var_step[i]) / p2
        noisy[i] = not (1.0 - 2.0 * residual >= variance * margin2)
        x_out[i] = (frac[i] + k) * period


def unwrap_step_compiled(x: np.ndarray, var_x: np.ndarray, frac: np.ndarray,
                         var_step: np.ndarray, period: float, max_residual: float,
                         margin2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One unwrapping step in one pass.

    Parameters
    ----------
    x, var_x : (M,) float64
        The current estimate [px] and its variance [px^2].
    frac, var_step : (M,) float64
        The step's wrapped phase [cycles] and its coordinate variance [px^2].
    period : float
        The step's period P [px].
    max_residual : float
        Largest accepted residual [cycles].
    margin2 : float
        ``(3 unwrap_sigma_margin)^2`` [-].

    Returns
    -------
    x_step : (M,) float64
        ``(f + rint(x / P - f)) P`` [px].
    bad, noisy : (M,) bool
        Residual above ``max_residual``; the neighbouring order's odds too high.
    """
    n = x.size
    x_step, bad, noisy = np.empty(n), np.empty(n, np.bool_), np.empty(n, np.bool_)
    _unwrap_step(x, var_x, frac, var_step, float(period), float(max_residual),
                 float(margin2), x_step, bad, noisy)
    return x_step, bad, noisy
