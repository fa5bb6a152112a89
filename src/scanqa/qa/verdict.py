"""The overall verdict of a QA report from its ISO 14253-1 decisions.

PASS when every decision is a pass; FAIL when any is a fail; otherwise UNDECIDED when
a decision falls in an uncertainty zone, INCOMPLETE when some quantities passed and the
rest could not be evaluated, and NOT EVALUATED when nothing was decided (no MPE or
tolerance, or nothing measurable). The counts travel with the verdict so that a report
shows what it rests on.
"""

from __future__ import annotations

from collections.abc import Iterable

#: The decisions a verdict counts.
DECISIONS = ("pass", "fail", "undecided", "not evaluated")
#: The verdicts, worst first.
VERDICTS = ("FAIL", "UNDECIDED", "INCOMPLETE", "NOT EVALUATED", "PASS")


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
            raise ValueError(f"unknown decision {d!r} (known: {', '.join(DECISIONS)})")
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
