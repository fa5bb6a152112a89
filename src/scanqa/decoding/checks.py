"""What the captures say about their own description: checks run on the data.

A decode trusts its ``patterns.toml``; a few misdescriptions leave traces in the images
that no correct description does, and are looked for here:

- *unresolved Gray bits*: the finest bits' contrast (bit against its threshold) falls
  below the noise where the projector's optics blur their stripes away, and they are
  decidable at few pixels only (:func:`scanqa.decoding.gray.bit_resolution`); they are
  dropped with a note;
- *white and black swapped*: the frames named white are darker than those named black;
- *inverse frames out of order*: a coarse bit and its stated inverse read the same level
  over much of the frame (a coarse stripe is never blurred to grey);
- *a misstated period*: two sets' coordinates drift apart linearly across the panel
  (their ratio is off), where correct periods disagree by noise and ripple only;
- *a reversed phase-shift sign* (or bits read inverted): x_p runs against the camera's
  own direction (a mirrored decode), or - where the guard masked a step - reading the
  phase with the opposite sign, or the bits with their inverses swapped, makes the step
  agree.

The checks read a sample of rows (:func:`sample_rows`) or the decoded map, and return
plain warnings (strings that name the likely cause and the key to fix) or notes. The
residual test of a cue set against the finer sets, over every well-modulated sampled
pixel before any mask, and frames listed twice, are in
:mod:`scanqa.decoding.consistency`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, SensorModel
from scanqa.decoding.demodulate import sample_variance
from scanqa.decoding.gray import (
    RESOLVED_SHARE,
    bit_resolution,
    reference_levels,
    resolved_bits,
)
from scanqa.errors import InputError
from scanqa.numeric import robust_std

#: Rows of the image the sample checks read (evenly spread).
SAMPLE_ROWS = 64
#: Share of lit pixels at which a check calls the description wrong [-].
WRONG_SHARE = 0.5
#: Share of a coarse bit's lit pixels reading the level of its inverse that calls the
#: inverse layout wrong (a correct layout: the pixels on that bit's one edge) [-].
INVERSE_SHARE = 0.25
#: Drift of a set against x_p across the decoded range, in the robust spread of the set's
#: disagreement about the line (noise and the ripple of a projector's gamma, which a
#: drift must stand out of), that calls a period misstated; and the smallest drift that
#: does [projector px].
DRIFT_SPREADS, DRIFT_MIN_PX = 1.0, 0.5
#: Largest deviation of the drift's bin medians from its line, as a share of the drift,
#: for the drift to be called a misstated period outright: a period off by a ratio makes
#: the two coordinates part exactly linearly (synthetic rigs: at most 0.02), where a
#: coarse set's own distortion (its gamma, a brightness change between its frames) bends
#: or steps (the real board's whole-frame column sets, periods right: 0.20-0.34 at drifts
#: of 9-15 px). A bent drift is still reported, worded as the likelier cause: on real
#: captures a fine period misstated by 0.5-1 % also bends (0.08-0.27), so it cannot be
#: told from the cue's distortion and is not dropped [-].
DRIFT_BEND_SHARE = 0.1
#: Share of the decoded pixels in camera rows (columns) along which x_p falls that calls
#: the decode mirrored [-].
MIRRORED_SHARE = 0.75


def sample_rows(stacks: Sequence[np.ndarray], rows: int = SAMPLE_ROWS) -> list[np.ndarray]:
    """Every k-th row of each (N, H, W) stack, as contiguous (N, h, W) arrays [DN] (each
    check reshapes them; a strided view would be copied by every one)."""
    height = stacks[0].shape[1]
    step = max(1, height // rows)
    return [np.ascontiguousarray(st[:, ::step]) for st in stacks]


def _flat(stack: np.ndarray) -> np.ndarray:
    return stack.reshape(stack.shape[0], -1)


def gray_threshold(desc: PatternDescription, by_name: dict, sensor: SensorModel,
                   quantised: bool):
    """The Gray code's per-pixel threshold (mid, variance) on flat frames, or None."""
    kind = desc.gray_threshold
    if kind == "reference":
        return reference_levels(desc.reference_set, by_name[desc.reference_set.name],
                                sensor, quantised)
    if kind == "offset":
        ordered = desc.ordered_set
        frames = by_name[ordered.name].astype(np.float64)
        a = frames.mean(axis=0)
        return a, sample_variance(a, sensor, quantised) / ordered.steps
    return None


def gray_bits(desc: PatternDescription, sample: Sequence[np.ndarray], sensor: SensorModel,
              quantised: bool) -> tuple[int | None, list[str]]:
    """Gray bits resolved by the optics, and a note naming the dropped ones.

    Returns
    -------
    bits : int or None
        Most significant bits to decode; None keeps all (or there is no Gray code).
    notes : list of str
        One note when bits are dropped.

    Raises
    ------
    InputError
        When the bits left give cells too wide to order the phase set.
    """
    gray = desc.gray_set
    if gray is None or gray.bits < 2:
        return None, []
    by_name = {s.name: _flat(st) for s, st in zip(desc.sets, sample, strict=True)}
    threshold = gray_threshold(desc, by_name, sensor, quantised)
    share, ratio = bit_resolution(gray, by_name[gray.name], sensor, quantised,
                                  desc.thresholds.gray_min_contrast_sigma, threshold)
    if not np.isfinite(share).all():
        return None, []
    least = RESOLVED_SHARE["ordering" if desc.phase_sets else "alone"]
    keep = resolved_bits(share, least)
    if keep == gray.bits:
        return None, []
    cell = desc.gray_cell_px * 2 ** (gray.bits - keep)
    dropped = ", ".join(f"{b + 1} ({100 * share[b]:.0f} %, contrast {100 * ratio[b]:.0f} %)"
                        for b in range(keep, gray.bits))
    note = (f"Gray bits finer than the optics resolve, dropped: bit {dropped} of "
            f"{gray.bits} (most significant first; share of the lit pixels where the bit "
            f"is decidable, below {100 * least:.0f} %, and its contrast in % of the "
            f"coarsest bit's): the {keep} coarser bits give cells of {cell:g} px")
    ordered = desc.ordered_set
    if ordered is not None and cell > ordered.period_px:
        raise InputError(
            f"set {gray.name!r}: {note}, wider than the period {ordered.period_px:g} px of "
            f"set {ordered.name!r}, so no fringe order can be decided; project coarser "
            "Gray cells or a sharper focus, or order a coarser set (orders = ...)")
    return keep, [note]


def reference_swapped(desc: PatternDescription, sample: Sequence[np.ndarray],
                      sensor: SensorModel, quantised: bool) -> list[str]:
    """A warning when the frames named white are darker than those named black."""
    ref = desc.reference_set
    if ref is None:
        return []
    frames = _flat(sample[desc.sets.index(ref)]).astype(np.float64)
    white = np.array([v == "white" for v in ref.levels])
    w, b = frames[white].mean(axis=0), frames[~white].mean(axis=0)
    var = (sample_variance(w, sensor, quantised) / white.sum()
           + sample_variance(b, sensor, quantised) / (~white).sum())
    lit = (w - b) ** 2 > 9.0 * var
    if lit.sum() < 100:
        return []
    darker = float(np.mean(w[lit] < b[lit]))
    if darker < WRONG_SHARE:
        return []
    return [f"set {ref.name!r}: the frames named white are darker than those named black "
            f"at {100 * darker:.0f} % of the lit pixels - white and black are swapped; "
            f"fix levels (now {list(ref.levels)}, likely "
            f"{[('black' if v == 'white' else 'white') for v in ref.levels]})"]


def inverse_layout(desc: PatternDescription, sample: Sequence[np.ndarray],
                   sensor: SensorModel, quantised: bool) -> list[str]:
    """A warning when a coarse Gray bit reads the level of its stated inverse.

    Lit pixels are those whose full contrast over the Gray frames exceeds 10 noise
    standard deviations of their mean level, so that noise cannot make a bit and its
    inverse read alike.
    """
    gray = desc.gray_set
    if gray is None or gray.inverse == "none":
        return []
    f = _flat(sample[desc.sets.index(gray)]).astype(np.float64)
    full = f.max(axis=0) - f.min(axis=0)
    lit = full * full > 100.0 * sample_variance(f.mean(axis=0), sensor, quantised)
    if lit.sum() < 100:
        return []
    plain, inverse = gray.frame_order()
    same = np.abs(f[plain] - f[inverse])[:, lit] < 0.25 * full[lit]
    coarse = min(3, gray.bits)
    share = same[:coarse].mean(axis=1)
    if share.max() < INVERSE_SHARE:
        return []
    other = "grouped" if gray.inverse == "interleaved" else "interleaved"
    bit = int(np.argmax(share))
    return [f"set {gray.name!r}: bit {bit + 1} and the frame stated as its inverse read "
            f"the same level at {100 * share[bit]:.0f} % of the lit pixels (a coarse stripe "
            f"is never blurred to grey): the frames are not in the stated order; check "
            f"inverse (now {gray.inverse!r}; {other!r}?) and the order of files"]


def period_drift(desc: PatternDescription, samples: dict, positions: dict) -> list[str]:
    """Warnings for sets whose coordinate drifts against x_p: a misstated period when the
    drift is a line, the set's own distortion first when it bends
    (:data:`DRIFT_BEND_SHARE`).

    Parameters
    ----------
    samples : dict of str to (n,) float
        Each set's coordinate minus x_p at sampled valid pixels [projector px].
    positions : dict of str to (n,) float
        x_p at the same pixels [projector px].
    """
    out = []
    periods = {s.name: s.period_px for s in desc.phase_sets}
    finest = desc.phase_sets[-1] if desc.phase_sets else None
    for name, d in samples.items():
        x = positions[name]
        if d.size < 200 or finest is None:
            continue
        slope, drift, spread, bend = _drift(x, d)
        if abs(drift) < max(DRIFT_MIN_PX, DRIFT_SPREADS * spread):
            continue
        # d = x_set - x_p = x (P_true / P_stated - 1) for a misstated finest set
        suggested = finest.period_px * (1.0 + slope)
        what = (f"set {name!r} (period_px {periods[name]:g})" if name in periods
                else f"Gray code {name!r}")
        if bend > DRIFT_BEND_SHARE * abs(drift):
            out.append(
                f"{what} and x_p drift apart by {drift:+.3g} px across the decoded range, "
                f"but not along a line (it bends by up to {bend:.2g} px; noise spread "
                f"{spread:.2g} px): more like {name!r}'s own distortion (a projector's gamma "
                "on a long period, light changing between its frames) than a misstated "
                f"period; if the periods were not the ones projected, set {finest.name!r} "
                f"would have period_px {suggested:.5g} (now {finest.period_px:g})")
            continue
        out.append(
            f"{what} and x_p drift apart by {drift:+.3g} px across the decoded range "
            f"(a ratio off by {100 * slope:+.2g} %; their noise spread is "
            f"{spread:.2g} px): a period_px is misstated; if {name!r} is right, set "
            f"{finest.name!r} has period_px {suggested:.5g} (now {finest.period_px:g}); "
            "check period_px of every set, cell_px and projector_width_px")
    return out


def _drift(x: np.ndarray, d: np.ndarray) -> tuple[float, float, float, float]:
    """Slope [-] of d against x from medians in 8 bins, the drift it makes over the
    sampled range [px], the robust spread of d about the line (1.4826 median absolute
    deviation) [px] and the bins' largest deviation from the line [px], from at most
    20000 of the samples."""
    step = max(1, d.size // 20000)
    x, d = x[::step], d[::step]
    edges = np.quantile(x, np.linspace(0.0, 1.0, 9))
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 7)
    xm = np.array([np.median(x[which == i]) for i in range(8) if np.any(which == i)])
    dm = np.array([np.median(d[which == i]) for i in range(8) if np.any(which == i)])
    if xm.size < 3 or np.ptp(xm) <= 0:
        return 0.0, 0.0, 0.0, 0.0
    slope, intercept = np.polyfit(xm, dm, 1)
    resid = d - (slope * x + intercept)
    spread = robust_std(resid)
    bend = float(np.max(np.abs(dm - (slope * xm + intercept))))
    return float(slope), float(slope * np.ptp(xm)), spread, bend


def mirrored(xp: np.ndarray, valid: np.ndarray, orientation: str) -> list[str]:
    """A warning when x_p falls along the camera's direction of the fringes' coordinate.

    A projector beside the camera, mounted the same way up, sees its columns (rows)
    increase with the camera's; a reversed phase-shift sign mirrors every set, and
    the sets still agree with one another, so only the direction shows it. Each camera
    row (column) with enough valid pixels - of at most 256 evenly spread - votes with the
    sign of its covariance of x_p and the camera coordinate, weighted by its valid
    pixels (depth edges and fringe-order jumps move a row's covariance little).
    """
    if orientation != "vertical":
        xp, valid = xp.T, valid.T
    step = max(1, xp.shape[0] // 256)  # 256 lines are plenty for a vote
    xp, valid = xp[::step], valid[::step]
    x = np.where(valid, xp, 0.0)
    n = valid.sum(axis=1)
    rows = n >= 20
    if n[rows].sum() < 1000:
        return []
    u = np.arange(x.shape[1], dtype=np.float64)
    x, valid, n = x[rows], valid[rows], n[rows]
    # sum over the valid pixels of (u - u_mean)(x - x_mean) = sum u x - n u_mean x_mean,
    # x being 0 elsewhere: two matrix-vector products, no (lines, width) temporary
    u_mean = (valid @ u) / n
    x_mean = x.sum(axis=1) / n
    cov = x @ u - n * u_mean * x_mean
    falling = float(n[cov < 0].sum() / n.sum())
    if falling < MIRRORED_SHARE:
        return []
    along = "columns" if orientation == "vertical" else "rows"
    coord = "x_p" if orientation == "vertical" else "y_p"
    return [f"{coord} falls along the camera's {along} in {100 * falling:.0f} % of the "
            "decoded pixels: the decode looks mirrored - a reversed phase-shift sign "
            "(shifts_rad: is frame k shifted by +2 pi k / N or -2 pi k / N?) or inverse "
            "frames taken for the bits; if the projector is mounted mirrored against the "
            "camera, this is expected"]


def likely_cause(desc: PatternDescription, sample: Sequence[np.ndarray],
                 guard: Callable[[PatternDescription, list], bool]) -> list[str]:
    """Which misreading makes a step the guard masked agree.

    Parameters
    ----------
    guard : callable
        ``guard(desc, stacks)`` is True when a decode of the stacks trips the guard.
    """
    tries = []
    if desc.phase_sets:
        flipped = tuple(_flip_sign(s) if s in desc.phase_sets else s for s in desc.sets)
        tries.append(("the phase-shift sign is reversed: negate shifts_rad of the phase "
                      "sets", _replace_sets(desc, flipped), list(sample)))
    gray = desc.gray_set
    if gray is not None and gray.inverse != "none":
        swapped = list(sample)
        i = desc.sets.index(gray)
        plain, inverse = gray.frame_order()
        order = np.empty(gray.frames, int)
        order[plain], order[inverse] = inverse, plain
        swapped[i] = sample[i][order]
        tries.append((f"set {gray.name!r}: each bit and its inverse are swapped (the "
                      "inverse frame comes first); reorder the files", desc, swapped))
        other = "grouped" if gray.inverse == "interleaved" else "interleaved"
        tries.append((f"set {gray.name!r}: the inverse frames are {other}, not "
                      f"{gray.inverse}: set inverse = {other!r}",
                      _replace_sets(desc, tuple(_relayout(s, other) for s in desc.sets)),
                      list(sample)))
    for cause, alt_desc, alt_sample in tries:
        if not guard(alt_desc, alt_sample):
            return [f"misstated coding: {cause}"]
    return []


def _flip_sign(pset):
    return replace(pset, shifts_rad=tuple(-s for s in pset.shifts_rad))


def _relayout(pset, layout: str):
    return replace(pset, inverse=layout) if isinstance(pset, GrayCodeSet) else pset


def _replace_sets(desc: PatternDescription, sets: tuple) -> PatternDescription:
    return replace(desc, sets=sets)
