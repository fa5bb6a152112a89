"""The compiled demodulation (scanqa.decoding.phasekernel) against the numpy path it
replaces, on 4-step (the simple phase variance) and 3-step sets (the cubic term), on
integer and float frames, on dark pixels (B = 0) and on whole decodes.

Tolerances follow the operations (tests/cpu_targets.py): the phase is one libm or SIMD
atan2 and a product, the variance about ten operations on terms as large as the sample
variance; nothing float is compared bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa import compiled
from scanqa.decoding import demodulate, unwrap
from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.demodulate import ShiftFit, demodulate_flat
from scanqa.decoding.phasekernel import unwrap_step_compiled

from .cpu_targets import op_bound

needs_numba = pytest.mark.skipif(not compiled.HAVE_NUMBA,
                                 reason="numba not installed: nothing compiled to compare")
SENSOR = SensorModel(bit_depth=12, gain_e_per_dn=4.0, read_noise_e=8.0).resolved(
    np.dtype(np.uint16))


def _numpy(monkeypatch, *args):
    with monkeypatch.context() as m:
        m.setattr(demodulate, "HAVE_NUMBA", False)
        return demodulate_flat(*args)


def _frames(shifts, dtype, rng, n=4000):
    """Fringe samples over every phase, with noise, some flat pixels (all frames equal)
    and, for integers, the repeats of small values that quantisation gives."""
    phi = rng.uniform(0.0, 2 * np.pi, n)
    amp = rng.uniform(0.0, 900.0, n)
    frames = 1500.0 + amp * np.cos(phi[None, :] + np.asarray(shifts)[:, None])
    frames += rng.normal(0.0, 3.0, frames.shape)
    frames[:, :50] = 7.0  # all frames equal: B = 0 up to the fit's rounding
    if np.dtype(dtype).kind == "u":
        frames[:, 50:400] = rng.integers(0, 12, (len(shifts), 350))  # dark, repeated
        return np.clip(np.rint(frames), 0, 4095).astype(dtype)
    return frames.astype(dtype)


@needs_numba
@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize("shifts", [tuple(2 * np.pi * k / 4 for k in range(4)),
                                    (0.0, -2 * np.pi / 3, -4 * np.pi / 3),
                                    (0.0, 1.3, 2.9, 4.4)])
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_compiled_demodulation_agrees_with_numpy(monkeypatch, shifts, dtype):
    rng = np.random.default_rng(44)
    frames = _frames(shifts, dtype, rng)
    fit = ShiftFit.from_shifts(shifts)
    quantised = np.dtype(dtype).kind == "u"
    a_c, b_c, f_c, v_c = demodulate_flat(fit, frames, SENSOR, quantised)
    a_n, b_n, f_n, v_n = _numpy(monkeypatch, fit, frames, SENSOR, quantised)
    np.testing.assert_array_equal(a_c, a_n)  # the same numpy product on both paths
    # B: two products, an add and a square root of terms up to B
    assert np.all(np.abs(b_c - b_n) <= op_bound(4, b_n + 1.0))
    # phase: an atan2 (2 ulp) and a product; compared on the circle
    d = np.abs(f_c - f_n)
    assert np.all(np.minimum(d, 1.0 - d) <= op_bound(3, 1.0))
    assert np.all((f_c >= 0.0) & (f_c <= 1.0))
    np.testing.assert_array_equal(np.isinf(v_c), np.isinf(v_n))  # B = 0 on both
    live = ~np.isinf(v_n)
    # variance: about ten operations, each relative to the result
    assert np.all(np.abs(v_c[live] - v_n[live]) <= op_bound(12, v_n[live]))


@needs_numba
@pytest.mark.compiled_vs_numpy
def test_compiled_decode_agrees_with_numpy(monkeypatch):
    """A three-period 4-step decode through both paths: the same masks and x_p."""
    periods, width = (640.0, 80.0, 16.0), 640
    desc = PatternDescription(width, tuple(PhaseSet(f"p{p:g}", p, 4) for p in periods),
                              sensor=SensorModel(bit_depth=12, gain_e_per_dn=4.0,
                                                 read_noise_e=8.0))
    rng = np.random.default_rng(45)
    xp = np.linspace(0.0, width - 4.0, 300)[None, :] + np.linspace(0, 3, 60)[:, None]
    amp = np.linspace(30.0, 1000.0, 60)[:, None]  # dark rows to bright ones
    stacks = []
    for p in periods:
        k = np.arange(4)[:, None, None]
        frames = 1500.0 + amp * np.cos(2 * np.pi * xp / p + 2 * np.pi * k / 4)
        frames += rng.normal(0.0, 3.0, frames.shape)
        stacks.append(np.clip(np.rint(frames), 0, 4095).astype(np.uint16))
    fast = decode_images(desc, stacks)
    with monkeypatch.context() as m:
        m.setattr(demodulate, "HAVE_NUMBA", False)
        m.setattr(unwrap, "HAVE_NUMBA", False)
        slow = decode_images(desc, stacks)
    np.testing.assert_array_equal(fast.mask, slow.mask)  # no threshold within 1e-12
    assert fast.valid.mean() > 0.5
    v = fast.valid
    # x_p = (f + k) P: the phase's bound times the period
    assert np.all(np.abs(fast.xp[v] - slow.xp[v]) <= op_bound(5, 16.0 + width))
    assert np.max(np.abs(fast.xp[v] - xp[v])) < 0.5  # and both decode the truth
    assert math.isfinite(float(np.nanmax(fast.sigma_xp)))


@needs_numba
@pytest.mark.compiled_vs_numpy
def test_compiled_unwrap_step_is_the_numpy_step():
    """The same basic operations in the same order, without contraction: equal on every
    IEEE-754 machine, ties of rint (half to even) included."""
    rng = np.random.default_rng(46)
    n, period = 5000, 16.0
    x = rng.uniform(-10.0, 1290.0, n)
    frac = rng.uniform(0.0, 1.0, n)
    frac[:100] = np.mod(x[:100] / period + 0.5, 1.0)  # residuals near a half
    x[100:200] = (np.arange(100) + 0.5) * period  # rint ties of r = k + 1/2
    frac[100:200] = 0.0
    var_x, var_s = rng.uniform(0.0, 4.0, n), rng.uniform(0.0, 0.1, n)
    var_x[:20] = np.nan
    got = unwrap_step_compiled(x, var_x, frac, var_s, period, 0.25, 9.0)
    r = x / period - frac
    k = np.rint(r)
    residual = np.abs(r - k)
    noisy = ~(1.0 - 2.0 * residual >= (var_x + var_s) / (period * period) * 9.0)
    np.testing.assert_array_equal(got[0], (frac + k) * period)
    np.testing.assert_array_equal(got[1], residual > 0.25)
    np.testing.assert_array_equal(got[2], noisy)
    assert got[2][:20].all()  # an unknown variance is noisy
