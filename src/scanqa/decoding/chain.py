"""The unwrapping chain: in which order periods are unwrapped, and with which beats.

Temporal unwrapping needs an absolute start - a phase whose period covers the coded
range, or a Gray code - and then goes from coarse to fine: each period is unwrapped by
the estimate of the previous step, which works while the previous estimate's noise is
small against the new period. The chain is planned once per coding from the periods
alone:

- start: the Gray-ordered set; else the coarsest phase set if its period covers
  ``projector_width_px``; else the least noisy *synthetic* period that does;
- then every phase set from coarse to fine; where the step from the current estimate
  to the next set is too long (period ratio times noise amplification above
  ``max_period_ratio``), synthetic periods are inserted.

A synthetic period is an integer combination of the phase sets (heterodyne, or
multi-wavelength, unwrapping [1]_): the wrapped phase ``f = sum n_i f_i`` (mod 1
cycle) of sets with periods ``P_i`` is the wrapped phase of the period ``1 / |sum n_i /
P_i|``. Two sets of periods 66.7 and 100 px beat at 200 px; three sets of 70, 64 and 59
fringes over the panel reach one fringe with ``(-1, 2, -1)``. Its noise is that of the
sets amplified by ``P sqrt(sum n_i^2)`` (in px), which the decoder propagates, so the
reliability of every step follows from the predicted noise as for real periods.
Coefficients run over -2..2 (-1..1 beyond four sets), which covers the two- and
three-frequency schemes.

References
----------
.. [1] C. Reich, R. Ritter, J. Thesing, "White light heterodyne principle for 3D-
   measurement", Proc. SPIE 3100, 1997.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

from scanqa.errors import ConfigError


@dataclass(frozen=True)
class Step:
    """One phase of the chain: a phase set or a synthetic (beat) period.

    Attributes
    ----------
    name : str
        The set's name, or ``beat(...)`` naming the combination.
    weights : tuple of int
        Coefficient of each phase set (coarsest-first order) in the wrapped phase [-].
    period_px : float
        Period of the (synthetic) phase [projector px].
    """

    name: str
    weights: tuple
    period_px: float

    @property
    def is_set(self) -> bool:
        """True for a real phase set (one coefficient 1, the rest 0)."""
        return sum(abs(w) for w in self.weights) == 1

    @property
    def gain(self) -> float:
        """Noise amplification relative to one set of equal phase noise [-]."""
        return math.sqrt(sum(w * w for w in self.weights))

    @property
    def reach_px(self) -> float:
        """Period times noise amplification: what the next step's ratio is taken of [px]."""
        return self.period_px * self.gain


def plan_chain(periods: Sequence[float], names: Sequence[str], width_px: float,
               max_ratio: float, start: int | None = None) -> tuple[Step, ...]:
    """Steps of the unwrapping chain, absolute start first.

    Parameters
    ----------
    periods : sequence of float
        Periods of the phase sets, coarsest first [projector px].
    names : sequence of str
        Their names (for messages and step names).
    width_px : float
        Coded range [projector px].
    max_ratio : float
        Largest accepted ``reach / period`` of one step [-].
    start : int, optional
        Index of the set a Gray code orders (the absolute start); default: a phase.

    Returns
    -------
    tuple of Step
        Every phase set exactly once, with synthetic periods where needed.

    Raises
    ------
    ConfigError
        When no absolute start exists or a step cannot be bridged.

    Examples
    --------
    >>> [s.name for s in plan_chain([100.0, 66.7], ["a", "b"], 200.0, 64.0)]
    ['beat(b-a)', 'a', 'b']
    """
    units = [Step(n, tuple(int(i == j) for j in range(len(periods))), float(p))
             for i, (p, n) in enumerate(zip(periods, names, strict=True))]
    synthetic = _combinations(periods, names)
    first = _start(units, synthetic, width_px, start)
    steps, current = [first], first
    for nxt in (u for u in units if u is not first):
        while current.reach_px / nxt.period_px > max_ratio:
            current = _bridge(current, nxt, synthetic, max_ratio)
            steps.append(current)
        steps.append(nxt)
        current = nxt
    return tuple(steps)


def _start(units: list[Step], synthetic: list[Step], width_px: float,
           start: int | None) -> Step:
    """The absolute start: the Gray-ordered set, a covering set or a covering beat."""
    if start is not None:
        return units[start]
    reach = width_px * (1 - 1e-9)  # a beat of 20, 17 and 15 fringes is 800 px less 3e-12
    if units[0].period_px >= reach:
        return units[0]
    covering = [s for s in synthetic if s.period_px >= reach]
    if covering:
        return min(covering, key=lambda s: s.reach_px)
    coarse = units[0]
    raise ConfigError(
        f"periods cannot be unwrapped: the coarsest period_px = {coarse.period_px:g} (set "
        f"{coarse.name!r}) is shorter than projector_width_px = {width_px:g}, so x_p is "
        "ambiguous, and no beat of the periods (P1 P2 / |P1 - P2|) reaches it either; check "
        "projector_width_px and period_px, or describe the Gray code or coarse period "
        f"that was captured with them (a phase set with period_px >= {width_px:g})")


def _bridge(current: Step, nxt: Step, synthetic: list[Step], max_ratio: float) -> Step:
    """A synthetic period between ``current`` and ``nxt`` that shortens the step."""
    usable = [s for s in synthetic
              if current.reach_px / s.period_px <= max_ratio and s.reach_px < current.reach_px
              and s.period_px > nxt.period_px]
    if usable:
        return min(usable, key=lambda s: s.reach_px / nxt.period_px)
    ratio = current.reach_px / nxt.period_px
    raise ConfigError(
        f"periods cannot be unwrapped: set {current.name!r} (period_px = "
        f"{current.period_px:g}) cannot unwrap set {nxt.name!r} (period_px = "
        f"{nxt.period_px:g}): the ratio {ratio:.4g} must be <= "
        f"thresholds.max_period_ratio = {max_ratio:g}; add an intermediate period (or "
        "raise max_period_ratio if the noise allows it)")


def _combinations(periods: Sequence[float], names: Sequence[str]) -> list[Step]:
    """Synthetic periods: integer combinations of two or more sets."""
    n = len(periods)
    span = range(-2, 3) if n <= 4 else range(-1, 2)
    if n > 8:
        return []
    out = []
    for weights in itertools.product(span, repeat=n):
        nonzero = [w for w in weights if w]
        if len(nonzero) < 2 or math.gcd(*nonzero) != 1:
            continue
        freq = sum(w / p for w, p in zip(weights, periods, strict=True))
        if freq <= 1e-12:  # keeps one sign of each pair; drops infinite periods
            continue
        out.append(Step(_beat_name(weights, names), tuple(weights), 1.0 / freq))
    return out


def _beat_name(weights: Sequence[int], names: Sequence[str]) -> str:
    """``beat(a-b)``, ``beat(2 b-a-c)``: the combination in words."""
    terms = []
    for w, name in sorted(zip(weights, names, strict=True), key=lambda t: -t[0]):
        if w:
            sign = "-" if w < 0 else ("+" if terms else "")
            terms.append(f"{sign}{abs(w)} {name}" if abs(w) > 1 else f"{sign}{name}")
    return f"beat({''.join(terms)})"
