"""Whether the phase sets of a capture agree with their description, before any mask.

A coarse set whose period covers the coded width (a *cue*) gives every pixel its
coordinate ``x_c = P_c phi_c / (2 pi)``; a finer set of period ``P_f`` gives the same
coordinate modulo ``P_f``. For a correct description the residual

.. math:: r = (x_c - P_f \\phi_f / (2 \\pi)) \\bmod P_f

concentrates near 0 with the spread that the camera noise predicts; for a misdescribed
pair - a reversed shift sign or two frames swapped in one set only, the sets given each
other's files, a period ratio stated twice or half the truth, a frame of another set -
it spreads towards uniform over the period. The check measures it over *every* sampled
pixel whose predicted residual spread is small (not only the decode's survivors, which
the consistency mask has already chosen to agree):

.. math:: R = |\\langle e^{2 \\pi i r / P_f} \\rangle|, \\qquad
          R_{pred} = \\langle e^{-(2 \\pi \\sigma_r / P_f)^2 / 2} \\rangle

(the mean resultant length of the residual as an angle, and its expectation for a
Gaussian residual of the predicted spread ``sigma_r``; 0 for unrelated patterns, up to
``1/sqrt(n)``). When ``R < CONTRADICTED_RATIO R_pred`` the images contradict the
description, and the misreadings that would make the pair agree are tried on the same
pixels (the sign of one set - the cue's own direction along the camera tells which -,
the sets' frames swapped, and a scan of the period ratio from a fifth to five times the
stated one) to name the likely cause.

A frame listed twice (in one set or two, by name or by identical pixels) is also named:
one frame cannot show two patterns. Either finding masks every pixel of the
decode (:func:`scanqa.decoding.diagnostics.apply_guard`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scanqa.decoding import checks
from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.demodulate import ShiftFit, demodulate_flat, demodulate_sample
from scanqa.numeric import json_ready

#: Residual spread (in periods of the finer set) below which a pixel enters the test:
#: its expected resultant length is at least exp(-(2 pi / 6)^2 / 2) = 0.58 [-].
MAX_SPREAD_PERIODS = 1.0 / 6.0
#: Fewest pixels for the test (uniform residuals give R about 1/sqrt(n) = 0.045) [-].
MIN_PIXELS = 500
#: R below this share of R_pred says the images contradict the description [-].
CONTRADICTED_RATIO = 0.5
#: A misreading names the cause when it brings R to this share of R_pred [-].
EXPLAINED_RATIO = 0.7
#: Step of the scan of period ratios that names a misstated period [-].
RATIO_STEP = 0.05
#: A whole ratio near the best of the scan is named when its R is at least this share
#: of the best R (the peak is as wide as one cycle over the cue's covered range) [-].
WHOLE_RATIO_SHARE = 0.9


@dataclass(frozen=True)
class PairConsistency:
    """How a cue set and a finer set agree over the sampled pixels.

    Attributes
    ----------
    coarse, fine : str
        The two sets' names.
    pixels : int
        Pixels whose predicted residual spread is below ``MAX_SPREAD_PERIODS`` [-].
    resultant : float
        R, the mean resultant length of the residual as an angle [-].
    predicted : float
        R_pred, its expectation from the camera noise for a correct description [-].
    offset_px : float
        The circular mean of the residual [projector px].
    cause : str
        The misreading that makes the pair agree ("" when none or not needed).
    """

    coarse: str
    fine: str
    pixels: int
    resultant: float
    predicted: float
    offset_px: float
    cause: str = ""

    @property
    def contradicted(self) -> bool:
        """True when the images contradict the description of the pair."""
        return self.pixels >= MIN_PIXELS and \
            self.resultant < CONTRADICTED_RATIO * self.predicted

    def as_dict(self) -> dict:
        """Plain values for provenance (None for a test that had too few pixels)."""
        def num(v: float, digits: int) -> float | None:
            return json_ready(round(v, digits))

        return {"coarse": self.coarse, "fine": self.fine, "pixels": self.pixels,
                "resultant": num(self.resultant, 4), "predicted": num(self.predicted, 4),
                "offset_px": num(self.offset_px, 3), "contradicted": self.contradicted,
                "cause": self.cause}


@dataclass(frozen=True, eq=False)
class _Demod:
    """A set's phase fraction [cycles] and its predicted standard deviation [cycles]."""

    frac: np.ndarray
    sigma: np.ndarray


def _demod(pset: PhaseSet, frames: np.ndarray, sensor: SensorModel, quantised: bool,
           sign: float = 1.0, given: tuple | None = None) -> _Demod:
    if given is not None:  # (A, B, frac, var) of these frames, as demodulate_flat gives
        return _Demod(given[2], np.sqrt(given[3]) / (2.0 * np.pi))
    fit = ShiftFit.from_shifts([sign * s for s in pset.shifts_rad])
    flat = frames.reshape(frames.shape[0], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        _, _, frac, var = demodulate_flat(fit, flat, sensor, quantised)
    return _Demod(frac, np.sqrt(var) / (2.0 * np.pi))


def _resultant(coarse: _Demod, fine: _Demod, ratio: float, pixels: np.ndarray
               ) -> tuple[float, float]:
    """R and the circular mean [fine periods] of ``ratio frac_c - frac_f``."""
    z = np.exp(2j * np.pi * (ratio * coarse.frac[pixels] - fine.frac[pixels])).mean()
    return float(abs(z)), float(np.angle(z) / (2.0 * np.pi))


def _spread(coarse: _Demod, fine: _Demod, ratio: float) -> np.ndarray:
    """Predicted residual spread [fine periods] (NaN where a set has no modulation)."""
    s = np.hypot(ratio * coarse.sigma, fine.sigma)
    return np.where(np.isfinite(s), s, np.nan)


def pair_consistency(coarse: PhaseSet, fine: PhaseSet, frames_c: np.ndarray,
                     frames_f: np.ndarray, sensor: SensorModel, quantised: bool,
                     demods: dict | None = None) -> PairConsistency:
    """The residual test of a cue set against a finer set, with the likely cause.

    Parameters
    ----------
    coarse, fine : PhaseSet
        The cue (period >= the coded width) and a finer set.
    frames_c, frames_f : (N, h, W) arrays
        Their frames at the sampled rows [DN].
    sensor : SensorModel
        The camera noise (given or estimated from the images).
    quantised : bool
        Integer images (quantisation noise).
    demods : dict, optional
        The sets' demodulation of these frames by name
        (:func:`scanqa.decoding.demodulate.demodulate_sample`); default: demodulated here.

    Returns
    -------
    PairConsistency
        R, R_pred, the pixel count and - when contradicted - the cause.
    """
    ratio = coarse.period_px / fine.period_px
    demods = demods or {}
    dc, df = (_demod(coarse, frames_c, sensor, quantised, given=demods.get(coarse.name)),
              _demod(fine, frames_f, sensor, quantised, given=demods.get(fine.name)))
    spread = _spread(dc, df, ratio)
    with np.errstate(invalid="ignore"):
        pixels = spread < MAX_SPREAD_PERIODS
    n = int(pixels.sum())
    if n < MIN_PIXELS:
        return PairConsistency(coarse.name, fine.name, n, float("nan"), float("nan"), 0.0)
    r, mean = _resultant(dc, df, ratio, pixels)
    pred = float(np.exp(-0.5 * (2.0 * np.pi * spread[pixels]) ** 2).mean())
    found = PairConsistency(coarse.name, fine.name, n, r, pred, mean * fine.period_px)
    if not found.contradicted:
        return found
    cause = _likely_cause(coarse, fine, (frames_c, frames_f), (dc, df), pixels,
                          (sensor, quantised), pred)
    return PairConsistency(coarse.name, fine.name, n, r, pred, found.offset_px, cause)


def _likely_cause(coarse: PhaseSet, fine: PhaseSet, frames: tuple, demods: tuple,
                  pixels: np.ndarray, noise: tuple, pred: float) -> str:
    """The first misreading that brings R to ``EXPLAINED_RATIO R_pred``, or ""."""
    ratio = coarse.period_px / fine.period_px
    dc, df = demods
    if _resultant(dc, _demod(fine, frames[1], *noise, sign=-1.0), ratio,
                  pixels)[0] >= EXPLAINED_RATIO * pred:
        return _sign_cause(coarse, fine, dc, pixels.reshape(frames[0].shape[1:]))
    swapped = (_demod(coarse, frames[1], *noise), _demod(fine, frames[0], *noise))
    if _resultant(*swapped, ratio, pixels)[0] >= EXPLAINED_RATIO * pred:
        return (f"the files of sets {coarse.name!r} and {fine.name!r} are swapped (the "
                f"frames of {fine.name!r} carry the longer period): exchange their files")
    best, r = _best_ratio(dc, df, ratio, pixels)
    # the noise a ratio predicts grows with it: R_pred at the ratio found
    spread = _spread(dc, df, best)[pixels]
    if r >= EXPLAINED_RATIO * float(np.exp(-0.5 * (2.0 * np.pi * spread) ** 2).mean()):
        return _ratio_cause(coarse, fine, best)
    return ""


def _best_ratio(coarse: _Demod, fine: _Demod, ratio: float, pixels: np.ndarray
                ) -> tuple[float, float]:
    """The period ratio in [ratio / 5, 5 ratio] that makes the pair agree best, and its
    R: a grid of ``RATIO_STEP`` (a twentieth of a cycle over the cue's full range),
    refined tenfold about the best, on at most 1000 of the pixels."""
    idx = np.flatnonzero(pixels)[:: max(1, int(pixels.sum()) // 1000)]
    fc, ff = coarse.frac[idx], fine.frac[idx]

    def scan(grid: np.ndarray) -> np.ndarray:
        angle = 2.0 * np.pi * (np.outer(grid, fc) - ff)
        return np.hypot(np.cos(angle).mean(axis=1), np.sin(angle).mean(axis=1))

    grid = np.arange(ratio / 5.0, 5.0 * ratio, RATIO_STEP)
    best = float(grid[np.argmax(scan(grid))])
    fine_grid = np.linspace(best - RATIO_STEP, best + RATIO_STEP, 21)
    best = float(fine_grid[np.argmax(scan(fine_grid))])
    r = _resultant(coarse, fine, best, pixels)[0]
    whole = float(max(round(best), 1))  # periods are mostly whole fractions of the cue
    r_whole = _resultant(coarse, fine, whole, pixels)[0]
    return (whole, r_whole) if r_whole >= WHOLE_RATIO_SHARE * r else (best, r)


def _sign_cause(coarse: PhaseSet, fine: PhaseSet, dc: _Demod, lit: np.ndarray) -> str:
    """Which of the two sets has its sign reversed: the cue's own direction tells
    (a projector beside the camera sees its coordinate rise with the camera's)."""
    cue = dc.frac.reshape(lit.shape) * coarse.period_px
    falls = bool(checks.mirrored(cue, lit, coarse.orientation))
    one, other = (coarse, fine) if falls else (fine, coarse)
    why = ("its coordinate falls along the camera's direction" if falls else
           f"set {coarse.name!r} rises along the camera's direction")
    return (f"set {one.name!r} alone has its phase-shift sign reversed or two of its frames "
            f"swapped ({why}; if the projector is mounted mirrored, it is set "
            f"{other.name!r}): negate its shifts_rad, or check the order of its files")


def _ratio_cause(coarse: PhaseSet, fine: PhaseSet, true_ratio: float) -> str:
    """The period ratio the images show, and the two statements that give it."""
    stated = coarse.period_px / fine.period_px
    fine_px, coarse_px = coarse.period_px / true_ratio, fine.period_px * true_ratio
    return (f"the images show period({coarse.name}) / period({fine.name}) = "
            f"{true_ratio:.4g}, the description {stated:.4g}: set {fine.name!r} has "
            f"period_px {fine_px:.4g} (now {fine.period_px:g}) or set {coarse.name!r} has "
            f"period_px {coarse_px:.4g} (now {coarse.period_px:g}); check period_px of "
            "both and projector_width_px")


def cue_pairs(desc: PatternDescription) -> list[tuple[PhaseSet, PhaseSet]]:
    """(cue, finer set) pairs of one orientation: the cue's period covers the width."""
    phase = desc.phase_sets
    cues = [s for s in phase if s.period_px >= desc.projector_width_px]
    return [(c, f) for c in cues for f in phase
            if f.period_px < c.period_px and f.orientation == c.orientation]


def set_consistency(desc: PatternDescription, sample: Sequence[np.ndarray],
                    sensor: SensorModel, quantised: bool, demods: dict | None = None
                    ) -> list[PairConsistency]:
    """The residual test of every cue set against every finer phase set.

    Parameters
    ----------
    desc : PatternDescription
        The coding.
    sample : sequence of (N, h, W) arrays
        Each set's frames at the sampled rows, in ``desc.sets`` order [DN].
    sensor : SensorModel
        The camera noise.
    quantised : bool
        Integer images.
    demods : dict, optional
        The sample's sets demodulated once, by name
        (:func:`scanqa.decoding.demodulate.demodulate_sample`); default: done here.

    Returns
    -------
    list of PairConsistency
        One per pair (none without a cue set).
    """
    by_name = {s.name: st for s, st in zip(desc.sets, sample, strict=True)}
    pairs = cue_pairs(desc)
    if demods is None and pairs:  # a cue pairs with every finer set: demodulate once
        demods = demodulate_sample(desc.sets, sample, sensor, quantised)
    return [pair_consistency(c, f, by_name[c.name], by_name[f.name], sensor, quantised,
                             demods) for c, f in pairs]


def consistency_warnings(pairs: Sequence[PairConsistency]) -> list[str]:
    """One warning per contradicted pair, naming the likely cause and the key."""
    out = []
    for p in pairs:
        if not p.contradicted:
            continue
        cause = p.cause or ("no single misreading explains it: check shifts_rad, the "
                            "order of files, period_px and projector_width_px")
        out.append(
            f"the images contradict the description: set {p.coarse!r} and set {p.fine!r} "
            f"agree at {p.pixels} well-modulated sampled pixels no better than unrelated "
            f"patterns would (resultant {p.resultant:.2f}, noise predicts "
            f"{p.predicted:.2f}; every pixel is masked): {cause}")
    return out


def repeated_frames(desc: PatternDescription, sample: Sequence[np.ndarray]) -> list[str]:
    """A warning for each frame listed twice, by file name or by identical pixels.

    Pixels count only for frames that are not constant (a noiseless synthetic black or
    white frame may repeat).
    """
    frames, out = [], []
    for pset, st in zip(desc.sets, sample, strict=True):
        files = tuple(getattr(pset, "files", ()) or ())
        for k in range(st.shape[0]):
            name = files[k] if k < len(files) else None
            frames.append((f"{pset.name!r} ({name or f'frame {k}'})", name, st[k]))
    for i, (label, name, image) in enumerate(frames):
        for label2, name2, image2 in frames[:i]:
            if (name is not None and name == name2) or (
                    np.ptp(image) > 0 and np.array_equal(image, image2)):
                out.append(f"one image is listed twice: in set {label} and in set "
                           f"{label2} (one frame cannot show two patterns; every pixel "
                           "is masked); check the files of the sets")
                break
    return out
