"""Temporal unwrapping along the planned chain, with a reason for every mask.

A Gray code alone gives x_p from its cells: the cell centre, or for an edge pixel (one
undecidable bit between two neighbouring cells, :mod:`scanqa.decoding.gray`) the edge
between them (:func:`gray_coordinate`). Otherwise the absolute start is the Gray code
(ordering its phase set), a phase whose period covers the coded range, or a synthetic
(beat) period that does (:mod:`scanqa.decoding.chain`). Each further step is unwrapped
by the previous step's estimate x: the fringe order is ``k = rint(x / P - f)`` with f
the wrapped phase in cycles, and the residual ``x / P - f - k`` measures the
disagreement. x_p is the finest phase set's own ``(f + k) P`` (every set fused by
inverse variance with ``fuse_periods``). A pixel is

- *low modulation* when a set's modulation is below ``min_modulation_dn``, when its
  predicted phase noise (times the margin) exceeds the accepted residual, when an
  unwrapping step's odds of the neighbouring order exceed those of a ``3 margin``
  sigma excursion (:func:`_unwrap_step`), when its undecidable Gray bits leave a span
  of cells the phase cannot order (:func:`_gray_order`; a Gray code alone: any
  undecidable bit but an edge pixel's), or when the phase lies too close to the Gray
  order's decision boundary for its noise - unless the next set tells the neighbouring
  orders apart (non-nested periods): the Gray code then leaves them open and that set's
  phase decides (:func:`_resolve_orders`);
- *inconsistent* when an observed residual exceeds the accepted one (or the phase
  lies outside its decided Gray cell by more than ``gray_edge_cells`` and its noise);
- *out of range* when the result lies outside [-0.5, width - 0.5).

Everything works on flat row chunks (no per-pixel Python loop); counts for the decode
summary (how many pixels each step checked and rejected, why pixels were dark, how the
periods disagree) are gathered in a :class:`ChainStats`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from scanqa.compiled import HAVE_NUMBA
from scanqa.decoding import chain
from scanqa.decoding.coding import GrayCodeSet, PatternDescription, ReferenceSet, SensorModel
from scanqa.decoding.demodulate import TWO_PI, ShiftFit, demodulate_flat, sample_variance
from scanqa.decoding.gray import decode_gray, reference_levels
from scanqa.decoding.phasemap import (
    MASK_INCONSISTENT,
    MASK_LOW_MODULATION,
    MASK_OUT_OF_RANGE,
    MASK_SATURATED,
    MASK_VALID,
)
from scanqa.decoding.response import PhaseErrorTable, ProjectorResponse

#: Reasons for low modulation (bits of a uint8), in the order the summary names them.
LOW_FLOOR, LOW_PHASE, LOW_STEP, LOW_GRAY = 1, 2, 4, 8
LOW_REASONS = {LOW_FLOOR: "modulation below thresholds.min_modulation_dn",
               LOW_PHASE: "phase too noisy for its own period",
               LOW_STEP: "predicted unwrapping residual too large",
               LOW_GRAY: "Gray-code bit undecidable (dark, shadow or cell edge)"}
#: Every this many valid pixels one enters the period-disagreement statistics.
DISAGREEMENT_STRIDE = 7


@dataclass(frozen=True, eq=False)
class _SetPlan:
    name: str
    period_px: float
    steps: int
    fit: ShiftFit
    correction: PhaseErrorTable | None


@dataclass(frozen=True, eq=False)
class UnwrapPlan:
    """Everything the row decoder needs, computed once per decode.

    Attributes
    ----------
    phase : tuple
        Phase sets, coarsest first, with their least-squares constants.
    steps : tuple of chain.Step
        The unwrapping chain (absolute start first).
    gray : GrayCodeSet or None
        The Gray-code set.
    reference : ReferenceSet or None
        The white/black reference set.
    gray_threshold : str
        "inverse", "reference" or "offset" (empty without Gray code).
    gray_cell_px : float
        Gray cell width [projector px].
    sensor : SensorModel
        Resolved noise model (gain, read noise, bit depth and saturation).
    quantised : bool
        Integer images: add the quantisation variance.
    desc : PatternDescription
        The coding (thresholds, width, options).
    gray_frames : tuple of int
        Frames of the Gray set that ``gray`` decodes (all bits unless the finest were
        dropped: then ``gray`` is the coarser code, its inverses grouped after it).
    systematic : dict of str to tuple
        Measured systematic disagreement of the step that decides the orders a Gray
        code leaves open with the Gray-ordered set: ripple tables over the two wrapped
        phases [px] and a bound of the rest [cycles of the step]
        (:func:`scanqa.decoding.decoder._systematic`); steps not named: none.
    """

    phase: tuple
    steps: tuple
    gray: GrayCodeSet | None
    reference: ReferenceSet | None
    gray_threshold: str
    gray_cell_px: float
    sensor: SensorModel
    quantised: bool
    desc: PatternDescription
    gray_frames: tuple = ()
    systematic: dict = field(default_factory=dict)

    @classmethod
    def build(cls, desc: PatternDescription, sensor: SensorModel, quantised: bool,
              response: ProjectorResponse | None = None, gray_bits: int | None = None
              ) -> UnwrapPlan:
        """Plan for a description, a resolved sensor model and an optional response;
        ``gray_bits`` keeps only that many most significant Gray bits (the cells grow
        by 2 per bit dropped)."""
        if response is not None and desc.phase_sets:
            response.check_covers(desc.phase_sets)
        phase = tuple(_SetPlan(s.name, s.period_px, s.steps, ShiftFit.from_shifts(s.shifts_rad),
                               response.table_for(s) if response else None)
                      for s in desc.phase_sets)
        steps = ()
        if phase:
            ordered = desc.ordered_set
            steps = chain.plan_chain(
                [p.period_px for p in phase], [p.name for p in phase],
                desc.projector_width_px, desc.thresholds.max_period_ratio,
                start=None if ordered is None else [p.name for p in phase].index(ordered.name))
        gray, cell, frames = _coarser_gray(desc, gray_bits)
        return cls(phase, steps, gray, desc.reference_set, desc.gray_threshold,
                   cell, sensor, quantised, desc, frames)


def _coarser_gray(desc: PatternDescription, bits: int | None):
    """(Gray set, cell [px], frames) decoding only the ``bits`` most significant bits."""
    gray, cell = desc.gray_set, desc.gray_cell_px
    if gray is None:
        return None, cell, ()
    plain, inverse = gray.frame_order()
    if bits is None or bits >= gray.bits:
        return gray, cell, ()
    frames = plain[:bits] if inverse is None else np.concatenate([plain[:bits],
                                                                  inverse[:bits]])
    cell *= 2 ** (gray.bits - bits)
    layout = "none" if inverse is None else "grouped"
    return (replace(gray, bits=bits, cell_px=cell, inverse=layout), cell,
            tuple(int(i) for i in frames))


@dataclass(eq=False)
class ChainStats:
    """Counts gathered over all chunks for the decode summary.

    ``checked[name]`` pixels reached the step (not yet low or saturated),
    ``rejected[name]`` of them were inconsistent, ``uniform[name]`` is the share an
    unrelated pattern would reject, ``noisy[name]`` were first marked low there;
    ``edges[name]`` counts the valid edge pixels of a Gray code decoded alone;
    ``low[bit]`` counts masked pixels by low-modulation reason; ``disagreement[name]``
    holds samples of each set's coordinate minus x_p at valid pixels, ``positions[name]``
    x_p at the same pixels [projector px].
    """

    checked: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    uniform: dict = field(default_factory=dict)
    noisy: dict = field(default_factory=dict)
    low: dict = field(default_factory=dict)
    disagreement: dict = field(default_factory=dict)
    edges: dict = field(default_factory=dict)
    positions: dict = field(default_factory=dict)

    def count(self, table: str, key: str, n: int) -> None:
        getattr(self, table)[key] = getattr(self, table).get(key, 0) + int(n)

    def merge(self, other: ChainStats) -> None:
        """Add the counts and samples of another chunk (chunks merged in row order keep
        the samples in row order, whatever thread decoded them)."""
        for table in ("checked", "rejected", "noisy", "low", "edges"):
            for key, n in getattr(other, table).items():
                self.count(table, key, n)
        self.uniform.update(other.uniform)
        for key, parts in other.disagreement.items():
            self.disagreement.setdefault(key, []).extend(parts)
        for key, parts in other.positions.items():
            self.positions.setdefault(key, []).extend(parts)


@dataclass(eq=False)
class _Flags:
    """Per-pixel reasons collected while decoding one chunk."""

    saturated: np.ndarray
    low: np.ndarray
    inconsistent: np.ndarray

    @classmethod
    def zeros(cls, size: int) -> _Flags:
        return cls(np.zeros(size, bool), np.zeros(size, np.uint8), np.zeros(size, bool))

    def open(self) -> np.ndarray:
        """Pixels neither saturated nor low so far."""
        return (self.low == 0) & ~self.saturated


def unwrap_rows(plan: UnwrapPlan, frames: dict[str, np.ndarray],
                out: dict[str, np.ndarray], stats: ChainStats) -> None:
    """Decode one chunk of rows in place.

    Parameters
    ----------
    plan : UnwrapPlan
        Constants of the decode.
    frames : dict of str to (N, h, W) arrays
        The chunk's frames of every set, keyed by set name [DN].
    out : dict of str to (h, W) arrays
        Views into the outputs ``xp``, ``modulation``, ``offset``, ``mask``,
        ``sigma_xp`` (and ``x:<set>`` for per-set coordinates); written in place.
    stats : ChainStats
        Updated with this chunk's counts.
    """
    shape = out["xp"].shape
    flat = {k: v.reshape(v.shape[0], -1) for k, v in frames.items()}
    flags = _Flags.zeros(int(np.prod(shape)))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sets = [_demodulate_set(plan, sp, flat[sp.name], flags) for sp in plan.phase]
        gray = _gray(plan, flat, sets, flags)
        x, var, per_set = _run_chain(plan, sets, gray, flags, stats)
        mask = _mask(plan, x, flags)
        valid = mask == MASK_VALID
        _gather(plan, per_set, gray, x, valid, mask, flags, stats)
        out["xp"][...] = np.where(valid, x, np.nan).reshape(shape)
        out["sigma_xp"][...] = np.where(valid, np.sqrt(var), np.nan).reshape(shape)
        for name, (xs, _) in per_set.items():
            if f"x:{name}" in out:
                out[f"x:{name}"][...] = np.where(valid, xs, np.nan).reshape(shape)
    out["mask"][...] = mask.reshape(shape)
    offset, modulation = (sets[-1][0], sets[-1][1]) if sets else (gray[1].mid_dn,
                                                                   gray[1].contrast_dn)
    out["offset"][...] = offset.reshape(shape)
    out["modulation"][...] = modulation.reshape(shape)


def _demodulate_set(plan: UnwrapPlan, sp: _SetPlan, frames: np.ndarray,
                    flags: _Flags) -> tuple[np.ndarray, ...]:
    """(A, B, f, var_x) of one set; flags saturation and per-set low modulation."""
    flags.saturated |= frames.max(axis=0) >= plan.sensor.saturation_dn
    a, b, frac, var_phi = demodulate_flat(sp.fit, frames, plan.sensor, plan.quantised)
    if sp.correction is not None:
        frac, gain = sp.correction.correct(frac)
        var_phi = var_phi * gain * gain
    th = plan.desc.thresholds
    if th.min_modulation_dn > 0:
        flags.low |= (b < th.min_modulation_dn).view(np.uint8) * np.uint8(LOW_FLOOR)
    # the wrapped phase itself must be reliable to within the accepted residual
    noisy = ~(var_phi * (th.unwrap_sigma_margin / TWO_PI) ** 2 <= th.unwrap_max_residual ** 2)
    flags.low |= noisy.view(np.uint8) * np.uint8(LOW_PHASE)
    var_phi *= (sp.period_px / TWO_PI) ** 2  # this set's own array: scaled in place
    return a, b, frac, var_phi


def _gray(plan: UnwrapPlan, flat: dict, sets: list, flags: _Flags):
    """(set name, GrayDecode) of the chunk, or None without Gray code."""
    gray = plan.gray
    if gray is None:
        return None
    threshold = None
    if plan.gray_threshold == "reference":
        threshold = reference_levels(plan.reference, flat[plan.reference.name], plan.sensor,
                                     plan.quantised)
    elif plan.gray_threshold == "offset":
        index = [p.name for p in plan.phase].index(plan.steps[0].name)
        a = sets[index][0]
        threshold = (a, sample_variance(a, plan.sensor, plan.quantised)
                     / plan.phase[index].steps)
    th = plan.desc.thresholds
    frames = flat[gray.name]
    if plan.gray_frames:
        frames = frames[list(plan.gray_frames)]
    dec = decode_gray(gray, frames, plan.sensor, plan.quantised,
                      th.gray_min_contrast_sigma, threshold)
    if plan.steps:  # a phase decides the order wherever the span of cells is narrower
        # than its period (edge pixels, blurred fine bits: :func:`_gray_order`), or than
        # three periods where a further set tells neighbouring orders apart
        period = plan.steps[0].period_px
        if defers_orders(plan):
            reach = 0.5 * dec.span * plan.gray_cell_px + _gray_edge(plan, period)
            unknown = reach >= 1.5 * period
        else:
            unknown = (dec.span > 1) & (dec.span * plan.gray_cell_px > period)
    else:
        unknown = dec.undecidable
    flags.low |= unknown.view(np.uint8) * np.uint8(LOW_GRAY)
    return gray.name, dec


def _step_phase(plan: UnwrapPlan, step: chain.Step, sets: list
                ) -> tuple[np.ndarray, np.ndarray]:
    """Wrapped phase [cycles] and coordinate variance [px^2] of a (synthetic) step."""
    if step.is_set:
        index = step.weights.index(1)
        return sets[index][2], sets[index][3]
    frac = np.zeros_like(sets[0][2])
    var_cycles = np.zeros_like(frac)
    for w, sp, s in zip(step.weights, plan.phase, sets, strict=True):
        if w:
            frac += w * s[2]
            var_cycles += (w * w / sp.period_px ** 2) * s[3]
    return frac - np.floor(frac), var_cycles * step.period_px ** 2


def _run_chain(plan: UnwrapPlan, sets: list, gray, flags: _Flags, stats: ChainStats):
    """x_p and its variance, and every phase set's own (x, var) by name."""
    per_set: dict = {}
    if not plan.steps:  # a Gray code alone
        return *gray_coordinate(gray[1].cell, gray[1].edge, plan.gray_cell_px), per_set
    first, rest = plan.steps[0], plan.steps[1:]
    frac, var = _step_phase(plan, first, sets)
    open_orders = None
    if gray is not None:
        x, open_orders = _gray_order(plan, first, gray[1], frac, var, flags, stats)
    else:
        x = _absolute(plan, first, frac)
    if first.is_set:
        per_set[first.name] = (x, var)
    period = first.period_px
    for step in rest:  # a set coarser than the estimate is unwrapped, but not used on
        frac_s, var_s = _step_phase(plan, step, sets)
        if open_orders is not None:  # the Gray code left neighbouring orders open
            _resolve_orders(plan, first, step, x, var, frac_s, var_s, open_orders, flags)
            open_orders = None
        x_s = _unwrap_step(plan, step, x, var, frac_s, var_s, flags, stats)
        if step.period_px < period:
            x, var, period = x_s, var_s, step.period_px
        if step.is_set:
            per_set[step.name] = (x_s, var_s)
    if not plan.desc.options.fuse_periods:
        return *per_set[plan.phase[-1].name], per_set
    weight = sum(1.0 / v for _, v in per_set.values())
    fused = sum(xs / v for xs, v in per_set.values()) / weight
    return fused, 1.0 / weight, per_set


def gray_coordinate(cell: np.ndarray, edge: np.ndarray, cell_px: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """x_p and its variance from Gray cells alone.

    Cell k covers ``[k w - 1/2, (k + 1) w - 1/2)`` (w = ``cell_px``; column j lies in
    cell ``floor(j / w)``). A decided pixel gets the cell centre ``k w + (w - 1) / 2``
    and, uniform over the cell, the variance ``w^2 / 12``. An edge pixel of cells k and
    k + 1 gets their shared edge ``(k + 1) w - 1/2`` and the variance of a uniform
    distribution over both cells, ``(2 w)^2 / 12``: its decided bits place it in one of
    the two cells and nothing more. Often it lies much closer to the edge (a sharp
    projector greys a bit only near its edge), but how close depends on the projector's
    blur and the contrast, which the decoder does not know: a blur that washes out the
    finest stripes greys their bit over most of the stripe, and the pixel may then be
    anywhere in its two cells. The uniform distribution is the one claim that holds in
    every case (measured numbers: docs/codings.rst, "Gray-code cells and edges").

    Parameters
    ----------
    cell : (M,) int
        Cell index, the lower one for an edge pixel [-].
    edge : (M,) bool
        Edge pixels of ``cell`` and ``cell + 1``.
    cell_px : float
        Cell width w [projector px].

    Returns
    -------
    x, variance : (M,) float64
        Coordinate [projector px] and its variance [px^2].
    """
    w = cell_px
    x = cell * w + 0.5 * (w - 1.0) + np.where(edge, 0.5 * w, 0.0)
    return x, np.where(edge, w * w / 3.0, w * w / 12.0)


def _absolute(plan: UnwrapPlan, step: chain.Step, frac: np.ndarray) -> np.ndarray:
    """Coordinate from a phase whose period covers the coded range.

    The unused part of the period is centred on the ends of the range, so that noise
    at either end cannot wrap to the other.
    """
    period = step.period_px
    margin = 0.5 + 0.5 * (period - plan.desc.projector_width_px)
    x = frac * period
    x += margin
    # x lies in [0, 2 P) for frac in [0, 1): the modulo is one exact subtraction
    x -= np.where(x >= period, period, 0.0)
    x -= margin
    return x


def defers_orders(plan: UnwrapPlan) -> bool:
    """True when the Gray-ordered set's order may be left open between neighbouring
    orders for the next step of the chain to decide (:func:`_resolve_orders`): a set or
    beat follows, and a shift of one ordered period moves its phase by at least a quarter
    cycle (periods that do not nest; orders two periods apart it may not tell apart, and
    such pixels stay masked)."""
    if plan.gray is None or len(plan.steps) < 2:
        return False
    ratio = plan.steps[0].period_px / plan.steps[1].period_px
    return abs(ratio - round(ratio)) >= 0.25


def _gray_edge(plan: UnwrapPlan, period: float) -> float:
    """How far the phase may fall outside its Gray cells [px]: ``gray_edge_cells``; where
    one order must come out of the Gray code alone, at most ``(P - cell) / 2`` (one order
    accepted at most), else up to a period (:func:`defers_orders`)."""
    w = plan.gray_cell_px
    edge = plan.desc.thresholds.gray_edge_cells * w
    if defers_orders(plan):
        return min(edge, max(period - w, 0.5 * w))
    return min(edge, 0.5 * max(period - w, 0.0))


def _gray_order(plan: UnwrapPlan, step: chain.Step, dec, frac: np.ndarray,
                var: np.ndarray, flags: _Flags, stats: ChainStats):
    """Fringe order of the ordered set from the Gray cells (interval test).

    A pixel may lie in ``dec.span`` cells from ``dec.first`` (one where every bit is
    decided): the order puts the phase nearest their centre, and it is accepted when
    the phase falls inside them (give or take ``gray_edge_cells``) and no other order
    does. A pixel of one cell whose phase falls outside is inconsistent; a wider span
    the phase cannot order is undecidable (low modulation). Either way the phase must
    keep its own noise margin from the decision boundary half a period away.

    Where the next step tells neighbouring orders apart (:func:`defers_orders`; a Gray
    cell as wide as the period, as OpenCV's codes of non-nested sets have), a pixel whose
    phase also fits the order below or above (or lies within its noise of the boundary)
    keeps them open: returns ``(x, open)`` with ``open`` None or (pixels, (n, 2) bool:
    order -1 and +1 still possible) for :func:`_resolve_orders`.
    """
    period, w = step.period_px, plan.gray_cell_px
    th = plan.desc.thresholds
    edge = _gray_edge(plan, period)
    half = 0.5 * w * dec.span
    centre = dec.first * w + half - 0.5
    k = np.rint(centre / period - frac)
    x = (frac + k) * period
    dist = np.abs(x - centre)
    # the phase may fall outside the cells by the edge tolerance and its own noise
    accept = half + edge + 3.0 * th.unwrap_sigma_margin * np.sqrt(var)
    full = dec.span == 1
    outside = dist > accept
    ambiguous = period - dist <= accept
    clearance = 0.5 * period - dist
    noisy = ~(var * (3.0 * th.unwrap_sigma_margin) ** 2 <= clearance * clearance)
    open_orders = None
    if defers_orders(plan):
        d = x - centre
        lower = (np.abs(d - period) <= accept) | (noisy & (d >= 0))
        upper = (np.abs(d + period) <= accept) | (noisy & (d < 0))
        undecided = ~outside & (lower | upper)
        pixels = np.flatnonzero(undecided & flags.open())
        if pixels.size:
            open_orders = (pixels, np.column_stack([lower[pixels], upper[pixels]]),
                           full[pixels], centre[pixels], half[pixels])
        ambiguous &= ~undecided
        noisy &= ~undecided
    bad = outside | (ambiguous & full)
    flags.low |= (ambiguous & ~full).view(np.uint8) * np.uint8(LOW_GRAY)
    noisy &= ~bad
    _check_step(stats, f"{plan.gray.name} -> {step.name}", flags, bad,
                1.0 - min(1.0, (w + 2.0 * edge) / period), noisy, judged=full)
    return x, open_orders


def _resolve_orders(plan: UnwrapPlan, first: chain.Step, step: chain.Step, x: np.ndarray,
                    var_x: np.ndarray, frac: np.ndarray, var_step: np.ndarray,
                    open_orders, flags: _Flags) -> None:
    """Decide the orders the Gray code left open by the next step's phase, in place.

    Each open order (the one taken, and one period below or above) predicts the step's
    phase; the order whose prediction is nearest is taken when every other open order's
    odds against it, ``exp(-(r_o^2 - r^2) / (2 sigma^2))`` for residuals r [cycles],
    stay below those of a ``3 margin`` sigma excursion: sigma is the predicted noise of
    the two phases. The residuals are first corrected by the measured ripple of the two
    sets at the pixel's phases (a projector's gamma, :attr:`UnwrapPlan.systematic`) and
    reduced by the bound of what the ripple leaves, which may account for that much of
    a residual at no cost, while an order it cannot explain must be told apart by the
    noise. An order inside the decoded cells (to its noise) is only challenged by the
    other orders inside them: the Gray code speaks against one that only the edge
    tolerance admits, and two orders two periods apart may read alike in the step. A
    pixel left undecided is masked as the Gray order alone would have masked it
    (inconsistent, or an undecidable Gray bit for a pixel between cells).
    """
    pixels, sides, full, centre, half = open_orders
    th = plan.desc.thresholds
    period, p_step = first.period_px, step.period_px
    base = x[pixels]
    cand = base[:, None] + np.array([0.0, -period, period])[None, :]
    r = cand / p_step - frac[pixels, None]
    e1, e2, bound = plan.systematic.get(step.name, (None, None, 0.0))
    if e1 is not None:  # the measured ripple of the two sets at these phases
        r -= (e1[ripple_bin(base / period, e1.size)]
              - e2[ripple_bin(frac[pixels], e2.size)])[:, None] / p_step
    r = np.abs(r - np.rint(r))
    possible = np.column_stack([np.ones(pixels.size, bool), sides])
    r = np.where(possible, r, np.inf)
    best = np.argmin(r, axis=1)
    rows = np.arange(pixels.size)
    r_best = r[rows, best]
    sigma2 = (var_x[pixels] + var_step[pixels]) / (p_step * p_step)
    # an order inside the decoded cells is not challenged by one that only the edge
    # tolerance admits (the step may not tell two orders apart that are two periods apart)
    noise = 3.0 * th.unwrap_sigma_margin * np.sqrt(var_x[pixels])
    inside = np.abs(cand - centre[:, None]) <= (half + noise)[:, None]
    r = np.where(inside[rows, best][:, None] & ~inside, np.inf, r)
    r[rows, best] = np.inf
    # a residual within the systematic bound costs nothing; beyond it, the noise decides
    r_other = np.maximum(r.min(axis=1) - bound, 0.0)
    r_best = np.maximum(r_best - bound, 0.0)
    clear = r_other * r_other - r_best * r_best >= sigma2 * (3.0 * th.unwrap_sigma_margin) ** 2
    x[pixels] = cand[rows, best]
    flags.inconsistent[pixels[~clear & full]] = True
    flags.low[pixels[~clear & ~full]] |= np.uint8(LOW_GRAY)


def ripple_bin(cycles: np.ndarray, bins: int) -> np.ndarray:
    """Bin of a ripple table of ``bins`` bins for a coordinate in periods [-]."""
    return (np.mod(cycles, 1.0) * bins).astype(np.intp) % bins


def _unwrap_step(plan: UnwrapPlan, step: chain.Step, x: np.ndarray, var_x: np.ndarray,
                 frac: np.ndarray, var_step: np.ndarray, flags: _Flags,
                 stats: ChainStats) -> np.ndarray:
    """Unwrap one step with the current estimate; its own coordinate."""
    th = plan.desc.thresholds
    period, margin2 = step.period_px, (3.0 * th.unwrap_sigma_margin) ** 2
    # the odds of the neighbouring order against the one taken, for the observed residual
    # and the predicted noise, exp(-(1 - 2 |r|) / (2 sigma^2)), must stay below those of
    # a 3 margin sigma excursion, exp(-(3 margin)^2 / 2); with numba in one pass
    if HAVE_NUMBA:
        from scanqa.decoding.phasekernel import unwrap_step_compiled
        x_s, bad, noisy = unwrap_step_compiled(x, var_x, frac, var_step, period,
                                               th.unwrap_max_residual, margin2)
    else:
        r = x / period - frac
        k = np.rint(r)
        residual = np.abs(r - k)
        bad = residual > th.unwrap_max_residual
        noisy = ~(1.0 - 2.0 * residual >= (var_x + var_step) / (period * period) * margin2)
        x_s = (frac + k) * period
    _check_step(stats, step.name, flags, bad, 1.0 - 2.0 * th.unwrap_max_residual, noisy)
    return x_s


def _check_step(stats: ChainStats, name: str, flags: _Flags, bad: np.ndarray,
                uniform: float, noisy: np.ndarray, judged: np.ndarray | None = None
                ) -> None:
    """Record a step's rejections and noise flags (counts over ``judged`` pixels)."""
    open_ = flags.open() if judged is None else flags.open() & judged
    stats.count("noisy", name, np.count_nonzero(open_ & noisy))
    flags.low |= noisy.view(np.uint8) * np.uint8(LOW_STEP)
    open_ &= ~noisy
    stats.count("checked", name, np.count_nonzero(open_))
    stats.count("rejected", name, np.count_nonzero(open_ & bad))
    stats.uniform[name] = uniform
    flags.inconsistent |= bad


def _mask(plan: UnwrapPlan, x: np.ndarray, flags: _Flags) -> np.ndarray:
    """Reason codes, the first reason that applies winning."""
    outside = ~((x >= -0.5) & (x < plan.desc.projector_width_px - 0.5))
    mask = np.full(x.shape, MASK_VALID, np.uint8)
    mask[outside] = MASK_OUT_OF_RANGE
    mask[flags.inconsistent] = MASK_INCONSISTENT
    mask[(flags.low != 0) | ~np.isfinite(x)] = MASK_LOW_MODULATION
    mask[flags.saturated] = MASK_SATURATED
    return mask


def _gather(plan: UnwrapPlan, per_set: dict, gray, x: np.ndarray, valid: np.ndarray,
            mask: np.ndarray, flags: _Flags, stats: ChainStats) -> None:
    """Low-modulation reasons and samples of the disagreement of every set with x_p."""
    low = flags.low[mask == MASK_LOW_MODULATION]
    for bit in LOW_REASONS:
        stats.count("low", bit, np.count_nonzero(low & bit))
    if gray is not None and not plan.steps:
        stats.count("edges", gray[0], np.count_nonzero(gray[1].edge & valid))
    pick = np.flatnonzero(valid)[::DISAGREEMENT_STRIDE]
    if not pick.size:
        return
    for name, (xs, _) in per_set.items():
        if plan.desc.options.fuse_periods or name != plan.phase[-1].name:
            stats.disagreement.setdefault(name, []).append(xs[pick] - x[pick])
            stats.positions.setdefault(name, []).append(x[pick])
    if gray is not None and plan.steps:
        w = plan.gray_cell_px
        pick = pick[gray[1].span[pick] == 1]  # pixels of one known cell
        centre = gray[1].cell[pick] * w + 0.5 * (w - 1.0)
        stats.disagreement.setdefault(gray[0], []).append(centre - x[pick])
        stats.positions.setdefault(gray[0], []).append(x[pick])
