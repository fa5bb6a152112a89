"""Temporal unwrapping: coarse-to-fine periods or a Gray code, with reasons for masks.

The absolute start comes either from the coarsest phase set (its period covers the coded
range) or from a Gray code that orders it. Each finer set is then unwrapped by the
current estimate x: the fringe order is ``k = rint((x - f P) / P)`` with f the wrapped
phase in cycles, the residual ``r - k`` measures the disagreement, and the new set is
fused into x by inverse-variance weighting. A pixel is

- *low modulation* when a set's modulation is below ``min_modulation_dn``, when its
  predicted phase noise (times the margin) exceeds the accepted residual, when the
  predicted residual of an unwrapping step does, or when a Gray bit is undecidable;
- *inconsistent* when an observed residual exceeds the accepted one;
- *out of range* when the result lies outside [-0.5, width - 0.5).

Everything works on flat row chunks (no per-pixel Python loop).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, SensorModel, Thresholds
from scanqa.decoding.demodulate import TWO_PI, ShiftFit, demodulate_flat, sample_variance
from scanqa.decoding.phasemap import (
    MASK_INCONSISTENT,
    MASK_LOW_MODULATION,
    MASK_OUT_OF_RANGE,
    MASK_SATURATED,
    MASK_VALID,
)

#: Half-width of a Gray-code stripe in cycles of the ordered period (stripes are P / 2).
GRAY_QUANTISATION = 0.25


@dataclass(frozen=True, eq=False)
class _SetPlan:
    name: str
    period_px: float
    steps: int
    fit: ShiftFit


@dataclass(frozen=True, eq=False)
class UnwrapPlan:
    """Everything the row decoder needs, computed once per decode.

    Attributes
    ----------
    phase : tuple
        Phase sets, coarsest first, with their least-squares constants.
    gray : GrayCodeSet or None
        The Gray-code set ordering ``phase[0]``.
    sensor : SensorModel
        Resolved noise model (bit depth and saturation filled in).
    quantised : bool
        Integer images: add the quantisation variance.
    thresholds : Thresholds
        Decision thresholds.
    width_px : int
        Coded range [projector px].
    """

    phase: tuple
    gray: GrayCodeSet | None
    sensor: SensorModel
    quantised: bool
    thresholds: Thresholds
    width_px: int

    @classmethod
    def build(cls, desc: PatternDescription, sensor: SensorModel,
              quantised: bool) -> UnwrapPlan:
        """Plan for a description and a resolved sensor model."""
        phase = tuple(_SetPlan(s.name, s.period_px, s.steps, ShiftFit.from_shifts(s.shifts_rad))
                      for s in desc.phase_sets)
        return cls(phase, desc.gray_set, sensor, quantised, desc.thresholds,
                   desc.projector_width_px)


@dataclass(eq=False)
class _Flags:
    """Per-pixel reasons collected while decoding one chunk."""

    saturated: np.ndarray
    low: np.ndarray
    inconsistent: np.ndarray

    @classmethod
    def zeros(cls, size: int) -> _Flags:
        return cls(*(np.zeros(size, bool) for _ in range(3)))


def unwrap_rows(plan: UnwrapPlan, frames: dict[str, np.ndarray],
                out: dict[str, np.ndarray]) -> None:
    """Decode one chunk of rows in place.

    Parameters
    ----------
    plan : UnwrapPlan
        Constants of the decode.
    frames : dict of str to (N, h, W) arrays
        The chunk's frames of every set, keyed by set name [DN].
    out : dict of str to (h, W) arrays
        Views into the outputs ``xp``, ``modulation``, ``offset``, ``mask``,
        ``sigma_xp``; written in place.
    """
    shape = out["xp"].shape
    flat = {k: v.reshape(v.shape[0], -1) for k, v in frames.items()}
    flags = _Flags.zeros(int(np.prod(shape)))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sets = [_demodulate_set(plan, sp, flat[sp.name], flags) for sp in plan.phase]
        x, var = _absolute_start(plan, sets[0], flat, flags)
        for sp, measured in zip(plan.phase[1:], sets[1:], strict=True):
            x, var = _unwrap_step(plan.thresholds, sp.period_px, x, var, measured, flags)
        mask = _mask(plan, x, flags)
        valid = mask == MASK_VALID
        out["xp"][...] = np.where(valid, x, np.nan).reshape(shape)
        out["sigma_xp"][...] = np.where(valid, np.sqrt(var), np.nan).reshape(shape)
    out["mask"][...] = mask.reshape(shape)
    out["offset"][...] = sets[-1][0].reshape(shape)
    out["modulation"][...] = sets[-1][1].reshape(shape)


def _demodulate_set(plan: UnwrapPlan, sp: _SetPlan, frames: np.ndarray,
                    flags: _Flags) -> tuple[np.ndarray, ...]:
    """(A, B, f, var_x) of one set; flags saturation and per-set low modulation."""
    flags.saturated |= frames.max(axis=0) >= plan.sensor.saturation_dn
    a, b, frac, var_phi = demodulate_flat(sp.fit, frames, plan.sensor, plan.quantised)
    th = plan.thresholds
    if th.min_modulation_dn > 0:
        flags.low |= b < th.min_modulation_dn
    # the wrapped phase itself must be reliable to within the accepted residual
    flags.low |= ~(var_phi * (th.unwrap_sigma_margin / TWO_PI) ** 2
                   <= th.unwrap_max_residual ** 2)
    return a, b, frac, var_phi * (sp.period_px / TWO_PI) ** 2


def _absolute_start(plan: UnwrapPlan, coarse: tuple, flat: dict[str, np.ndarray],
                    flags: _Flags) -> tuple[np.ndarray, np.ndarray]:
    """Absolute x and its variance from the coarsest set (and the Gray code)."""
    a0, _, frac0, var0 = coarse
    period = plan.phase[0].period_px
    if plan.gray is None:
        # centre the unused part of the period on the ends of the coded range
        margin = 0.5 + 0.5 * (period - plan.width_px)
        return np.mod(frac0 * period + margin, period) - margin, var0
    half = _gray_half_period_index(plan, flat[plan.gray.name], a0, flags)
    th = plan.thresholds
    r = ((half + 0.5) * 0.5 - frac0)
    k = np.rint(r)
    flags.inconsistent |= np.abs(r - k) > th.gray_max_residual
    slack = th.gray_max_residual - GRAY_QUANTISATION
    flags.low |= ~(var0 * th.unwrap_sigma_margin ** 2 <= (slack * period) ** 2)
    return (frac0 + k) * period, var0


def _gray_half_period_index(plan: UnwrapPlan, frames: np.ndarray, offset: np.ndarray,
                            flags: _Flags) -> np.ndarray:
    """Decoded half-period index h of every pixel; flags undecidable bits."""
    gray = plan.gray
    bits = gray.bits
    f = frames.astype(np.float64)
    if gray.inverse:
        diff = f[:bits] - f[bits:]
        var = (sample_variance(f[:bits], plan.sensor, plan.quantised)
               + sample_variance(f[bits:], plan.sensor, plan.quantised))
    else:
        diff = f - offset
        steps = plan.phase[0].steps
        var = (sample_variance(f, plan.sensor, plan.quantised)
               + sample_variance(offset, plan.sensor, plan.quantised) / steps)
    z = plan.thresholds.gray_min_contrast_sigma
    flags.low |= (diff * diff < z * z * var).any(axis=0)
    binary = np.zeros(f.shape[1], bool)
    half = np.zeros(f.shape[1], np.int64)
    for bit in diff > 0:  # most significant first: b_i = b_(i-1) xor g_i
        binary ^= bit
        half = (half << 1) | binary
    return half


def _unwrap_step(th: Thresholds, period: float, x: np.ndarray, var_x: np.ndarray,
                 measured: tuple, flags: _Flags) -> tuple[np.ndarray, np.ndarray]:
    """Unwrap one finer set with the current estimate and fuse it in."""
    _, _, frac, var_i = measured
    r = x / period - frac
    k = np.rint(r)
    flags.inconsistent |= np.abs(r - k) > th.unwrap_max_residual
    predicted = (var_x + var_i) * (th.unwrap_sigma_margin / period) ** 2
    flags.low |= ~(predicted <= th.unwrap_max_residual ** 2)
    w_x, w_i = 1.0 / var_x, 1.0 / var_i
    fused = (x * w_x + (frac + k) * period * w_i) / (w_x + w_i)
    return fused, 1.0 / (w_x + w_i)


def _mask(plan: UnwrapPlan, x: np.ndarray, flags: _Flags) -> np.ndarray:
    """Reason codes, the first reason that applies winning."""
    outside = ~((x >= -0.5) & (x < plan.width_px - 0.5))
    mask = np.full(x.shape, MASK_VALID, np.uint8)
    mask[outside] = MASK_OUT_OF_RANGE
    mask[flags.inconsistent] = MASK_INCONSISTENT
    mask[flags.low | ~np.isfinite(x)] = MASK_LOW_MODULATION
    mask[flags.saturated] = MASK_SATURATED
    return mask
