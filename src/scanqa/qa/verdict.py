"""The overall verdict of a QA report from its ISO 14253-1 decisions.

PASS when every decision is a pass; FAIL when any is a fail; otherwise UNDECIDED when
a decision falls in an uncertainty zone, INCOMPLETE when some quantities passed and the
rest could not be evaluated, and NOT EVALUATED when nothing was decided (no MPE or
tolerance, or nothing measurable). The counts travel with the verdict so that a report
shows what it rests on.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from scanqa.errors import MethodError

#: The decisions a verdict counts.
DECISIONS = ("pass", "fail", "undecided", "not evaluated")
#: The verdicts, worst first.
VERDICTS = ("FAIL", "UNDECIDED", "INCOMPLETE", "NOT EVALUATED", "PASS")


def decide(value: float, expanded: float, limit: float) -> str:
    """The ISO 14253-1 decision of a measured deviation against a limit: the one rule of
    every scanqa QA (gauge-block steps against a tolerance T, VDI/VDE 2634-2 quantities
    against an MPE).

    Parameters
    ----------
    value : float
        The measured deviation E (an error, a test value) [any length unit].
    expanded : float
        Its expanded uncertainty U [same unit].
    limit : float
        The tolerance or maximum permissible error [same unit].

    Returns
    -------
    str
        "pass" when |E| <= limit - U (conformance proven), "fail" when |E| > limit + U
        (non-conformance proven), "undecided" between, and "not evaluated" when any input
        is NaN or infinite (nothing can be decided).

    Notes
    -----
    ISO 14253-1:2017 default decision rule with the uncertainty zone on both sides of the
    limit T: conformance is proven when |E| <= T - U, non-conformance when |E| > T + U,
    anything between is undecided. E, U and T share one unit; a non-finite input decides
    nothing.

    Examples
    --------
    >>> decide(0.375, 0.125, 0.5), decide(0.625, 0.125, 0.5), decide(0.5, 0.125, 0.5)
    ('pass', 'undecided', 'undecided')
    >>> decide(float("nan"), 0.1, 0.5)
    'not evaluated'
    """
    if not (math.isfinite(value) and math.isfinite(expanded) and math.isfinite(limit)):
        return "not evaluated"
    if abs(value) <= limit - expanded:
        return "pass"
    return "fail" if abs(value) > limit + expanded else "undecided"


#: Exit status of ``scanqa qa --strict`` per verdict (2 stays an error of the input).
EXIT_STATUS = {"PASS": 0, "FAIL": 1, "UNDECIDED": 3, "INCOMPLETE": 3, "NOT EVALUATED": 3}


def verdict(decisions: Iterable[str]) -> dict:
    """Counts of each decision and the verdict (module notes).

    Parameters
    ----------
    decisions : iterable of str
        One of :data:`DECISIONS` per quantity.

    Returns
    -------
    dict
        ``verdict`` and a count per decision.

    Examples
    --------
    >>> verdict(["pass", "pass", "undecided"])["verdict"]
    'UNDECIDED'
    >>> verdict(["pass", "not evaluated"])["verdict"], verdict([])["verdict"]
    ('INCOMPLETE', 'NOT EVALUATED')
    """
    counts = dict.fromkeys(DECISIONS, 0)
    for d in decisions:
        if d not in counts:
            raise MethodError(f"unknown decision {d!r} (known: {', '.join(DECISIONS)})")
        counts[d] += 1
    total = sum(counts.values())
    if counts["fail"]:
        name = "FAIL"
    elif counts["undecided"]:
        name = "UNDECIDED"
    elif counts["pass"] and counts["pass"] == total:
        name = "PASS"
    elif counts["pass"]:
        name = "INCOMPLETE"
    else:
        name = "NOT EVALUATED"
    return {"verdict": name, **counts}
