"""Small numeric helpers every layer shares, each written once (issue 47).

:func:`robust_std` is the robust spread (1.4826 x the median absolute deviation),
:func:`inclusive_range` and :func:`parse_range` the START:STOP:STEP ranges of stage
positions and range samples, :func:`json_ready` the cleaning of values for JSON (which
has no NaN). ``tests/test_conventions.py`` fails where a second copy appears.
"""

from __future__ import annotations

import math

import numpy as np

#: 1 / Phi^-1(3/4): the median absolute deviation times this is the standard deviation
#: of a normal distribution [-].
MAD_TO_SIGMA = 1.4826


def robust_std(values, centre: float | None = None) -> float:
    """The robust standard deviation: :data:`MAD_TO_SIGMA` x the median absolute
    deviation of the finite values [their unit].

    Parameters
    ----------
    values : array_like
        The sample [any unit]; NaN and inf are left out.
    centre : float, optional
        The value deviations are taken from [same unit]: the sample's median by default;
        0 for residuals whose expected value is zero.

    Returns
    -------
    float
        The spread [same unit]; NaN for a sample without a finite value.
    """
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    c = np.median(v) if centre is None else centre
    return float(MAD_TO_SIGMA * np.median(np.abs(v - c)))


def inclusive_range(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, ...`` up to ``stop`` inclusive (a hair's tolerance) [unit].

    Parameters
    ----------
    start, stop : float
        First and last value [any unit]; ``stop >= start``.
    step : float
        Spacing [same unit], > 0.

    Returns
    -------
    numpy.ndarray
        ``floor((stop - start) / step + 1e-9) + 1`` values [same unit].
    """
    n = int(np.floor((stop - start) / step + 1e-9)) + 1
    return start + step * np.arange(n)


def parse_range(text: str, most: int = 10000) -> list[float]:
    """The values of a ``START:STOP:STEP`` range (inclusive), rounded to 1e-9 [unit].

    Parameters
    ----------
    text : str
        ``START:STOP:STEP`` [any unit], e.g. ``"-30:30:2"``.
    most : int
        Most values the range may hold [-].

    Returns
    -------
    list of float
        The values [same unit].

    Raises
    ------
    ValueError
        When the text is not three numbers, or not finite, STEP <= 0, STOP < START or the
        range holds more than ``most`` values.
    """
    try:
        start, stop, step = (float(t) for t in text.split(":"))
    except ValueError:
        raise ValueError(f"expected START:STOP:STEP, got {text!r}") from None
    if not (math.isfinite(start) and math.isfinite(stop) and step > 0 and stop >= start
            and (stop - start) / step <= most):
        raise ValueError(f"need finite numbers, STEP > 0, STOP >= START and at most {most} "
                         f"positions, got {text!r}")
    return [round(float(v), 9) for v in inclusive_range(start, stop, step)]


def json_ready(value):
    """``value`` ready for strict JSON: NaN and inf become None (null), numpy scalars
    Python numbers, through dicts, lists and tuples; anything else as it is.

    Parameters
    ----------
    value : object
        A number, a container of numbers, or anything JSON takes.

    Returns
    -------
    object
        The same structure with every non-finite float replaced by None.
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_ready(v) for v in value]
    if isinstance(value, tuple):
        return tuple(json_ready(v) for v in value)
    return value
