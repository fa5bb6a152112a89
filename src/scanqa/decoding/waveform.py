"""Fringes that are not sine waves, found from the captures themselves.

An N-step set is demodulated as a sine; a fringe of any other profile - binarised to a
50 % square wave, clipped by saturation, distorted by a projector's gamma - leaves a
phase error that repeats N times per period for equal shifts (each harmonic h of the
profile with h = m N +- 1 folds into the fundamental) and that no noise model predicts.
A 3-step set of square waves, for instance, reads only 6 phase values: x_p is a
staircase that errs by up to +-P/12.

Over many periods the true phase of a scene is spread evenly, so the distribution of
the measured phase shows the error: with F the share of sampled pixels whose phase is
below psi (in cycles), ``e(psi) = psi - F(psi)`` is the error function up to a constant
(histogram equalisation). The part of e at harmonics that are multiples of N is the
profile's error; what is left - a scene that covers some phases more than others - falls
mostly at the other harmonics, and a set is named only when the multiples of N stand out
of them and the error exceeds ``MIN_ERROR_CYCLES`` of the period.

The shape of the error names the cause: a staircase (the phase clusters at a few values,
sawtooth error: its strongest harmonic holds ~60 % of the error's power) comes from
binarised or square fringes or hard clipping; a smooth ripple (one harmonic) from a
gamma. Its rms is carried into sigma_xp of the pixels whose x_p the set gives
(:func:`scanqa.decoding.decoder.decode_images`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.demodulate import ShiftFit, demodulate_flat, sample_variance

#: Bins of the measured phase over one cycle [-].
PHASE_BINS = 360
#: Smallest peak error of a set's profile, in cycles of its period, that names it [-]
#: (a 3-step square wave: 1/12; a gamma of 2.2 on a 3-step set: about 0.045; kamino410's
#: object1: 0.054 and 0.056; a sine seen by a camera that samples a period at only ten
#: pixels, the phases of a regular grid: up to 0.023).
MIN_ERROR_CYCLES = 0.03
#: Power at the multiples of N over the power at their neighbours (N k +- 1) that shows
#: the error is the profile's, not the scene's uneven cover of phases [-].
HARMONIC_CONTRAST = 10.0
#: Share of the error's power in its strongest harmonic below which it is a staircase
#: (a sawtooth: 6 / pi^2 = 0.61; a gamma ripple: above 0.9) [-].
STAIRCASE_SHARE = 0.8
#: Largest phase noise of a sampled pixel, ``sqrt(2 / N) sigma_I / B`` [rad], and fewest
#: pixels for a test.
MAX_SIGMA_RAD, MIN_PIXELS = 0.05, 2000


@dataclass(frozen=True)
class FringeShape:
    """What the phase distribution of one set says about its fringe profile.

    Attributes
    ----------
    name : str
        The set.
    period_px : float
        Its period [projector px].
    peak_px, rms_px : float
        Peak and rms of the x_p error its profile causes [projector px].
    staircase : bool
        The error is a staircase (the phase clusters at a few values), not a ripple.
    """

    name: str
    period_px: float
    peak_px: float
    rms_px: float
    staircase: bool

    def warning(self, steps: int, carried: bool) -> str:
        """One line naming the set, what was found and what the decode did with it."""
        if self.staircase:
            what = (f"its {steps}-step phase clusters at a few values (a staircase, as "
                    "binarised or square-wave fringes, or hard clipping, give)")
        else:
            what = (f"its {steps}-step phase ripples {steps} times per period (as a "
                    "projector's gamma or saturation gives)")
        done = (f"; its rms {self.rms_px:.2g} px is added to sigma_xp" if carried
                else "; it only orders finer sets")
        return (f"set {self.name!r} (period {self.period_px:g} px): the fringes are not sine "
                f"waves - {what}; x_p errs by up to +-{self.peak_px:.2g} px{done}. Project "
                "sine fringes, or correct the projector's response (scanqa decode "
                "--measure-response on a flat)")


def fringe_shape(pset: PhaseSet, frames: np.ndarray, sensor: SensorModel,
                 quantised: bool, demod: tuple | None = None) -> FringeShape | None:
    """The profile error of one set from a sample of its pixels, or None when its
    fringes are sine waves (or too few pixels are lit to tell).

    Parameters
    ----------
    pset : PhaseSet
        The set (period, shifts).
    frames : (N, M) array
        Its frames at the sampled pixels [DN].
    sensor : SensorModel
        Resolved noise model (gain and read noise known).
    quantised : bool
        Integer images.
    demod : tuple, optional
        (A, B, phase fraction, variance) of these frames as
        :func:`scanqa.decoding.demodulate.demodulate_flat` gives them; default:
        demodulated here.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        if demod is None:
            demod = demodulate_flat(ShiftFit.from_shifts(pset.shifts_rad), frames, sensor,
                                    quantised)
        a, b, frac, _ = demod
        # chosen by a noise that does not depend on the phase (a 3-step set's does,
        # through the shot noise, and a cut on it would carve a 3-fold pattern)
        lit = 2.0 * sample_variance(a, sensor, quantised) < \
            MAX_SIGMA_RAD ** 2 * pset.steps * b * b
    phase = frac[lit]
    if phase.size < MIN_PIXELS:
        return None
    hist = np.bincount((phase * PHASE_BINS).astype(np.intp) % PHASE_BINS,
                       minlength=PHASE_BINS)
    edges = np.arange(1, PHASE_BINS + 1) / PHASE_BINS
    error = edges - np.cumsum(hist) / phase.size
    spectrum = np.fft.rfft(error - error.mean())
    k = np.arange(spectrum.size)
    n = pset.steps
    own = (k > 0) & (k % n == 0)
    near = (k > 0) & ((k % n == 1) | (k % n == n - 1)) & (k < k[own].max())
    power_own = np.sum(np.abs(spectrum[own]) ** 2)
    power_near = np.mean(np.abs(spectrum[near]) ** 2) * np.count_nonzero(own)
    profile = np.fft.irfft(np.where(own, spectrum, 0), PHASE_BINS)
    peak = float(np.max(np.abs(profile)))
    if peak < MIN_ERROR_CYCLES or power_own < HARMONIC_CONTRAST * power_near:
        return None
    strongest = float(np.max(np.abs(spectrum[own]) ** 2) / power_own)
    return FringeShape(pset.name, pset.period_px, peak * pset.period_px,
                       float(np.sqrt(np.mean(profile ** 2))) * pset.period_px,
                       strongest < STAIRCASE_SHARE)


def fringe_shapes(desc: PatternDescription, sample: Sequence[np.ndarray],
                  sensor: SensorModel, quantised: bool, demods: dict | None = None
                  ) -> list[FringeShape]:
    """:func:`fringe_shape` of every phase set whose period is short enough for a scene
    to spread its phase (a quarter of the coded range or less), on the sample rows
    (``demods``: their demodulation by set name, when done already)."""
    out, demods = [], demods or {}
    for pset, stack in zip(desc.sets, sample, strict=True):
        if isinstance(pset, PhaseSet) and 4 * pset.period_px <= desc.projector_width_px:
            shape = fringe_shape(pset, stack.reshape(stack.shape[0], -1), sensor, quantised,
                                 demods.get(pset.name))
            if shape is not None:
                out.append(shape)
    return out
