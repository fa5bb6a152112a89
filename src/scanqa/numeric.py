"""Numeric helpers every layer shares, each written once (issue 47; a second copy fails
``tests/test_conventions.py``): the robust spread, START:STOP:STEP ranges, JSON values."""

from __future__ import annotations

import math

import numpy as np

#: Median absolute deviation to the std of a normal distribution, 1 / Phi^-1(3/4) [-].
MAD_TO_SIGMA = 1.4826


def robust_std(values, centre: float | None = None) -> float:
    """:data:`MAD_TO_SIGMA` x the median absolute deviation of the finite values.

    Parameters
    ----------
    values : array_like
        The sample [any unit]; NaN and inf are left out.
    centre : float, optional
        Where deviations are taken from [same unit]: the median by default, 0 for
        residuals expected to be zero.

    Returns
    -------
    float
        The robust std [same unit]; NaN without a finite value.
    """
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    return float(MAD_TO_SIGMA * np.median(np.abs(v - (np.median(v) if centre is None
                                                      else centre))))


def inclusive_range(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, ...`` up to ``stop`` inclusive, within 1e-9 step [unit]
    (``start``, ``stop`` [any unit], ``step`` > 0 [same unit])."""
    return start + step * np.arange(int(np.floor((stop - start) / step + 1e-9)) + 1)


def parse_range(text: str, most: int = 10000) -> list[float]:
    """The values of ``"START:STOP:STEP"`` (inclusive) rounded to 1e-9 [its unit].

    Raises
    ------
    ValueError
        Not three numbers; not finite, STEP <= 0, STOP < START or over ``most`` values.
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
    """``value`` for strict JSON: non-finite floats become None (null) and numpy scalars
    Python ones, through dicts, lists and tuples; anything else is returned as it is."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        out = [json_ready(v) for v in value]
        return tuple(out) if isinstance(value, tuple) else out
    return value


def ill_conditioned(matrices: np.ndarray, limit: float) -> tuple:
    """``~(np.linalg.cond(matrices) < limit)`` per matrix of a (..., k, k) stack, with the
    SVD run only where the cheap bound cond <= ||M||_F ||M^-1||_F does not already put
    the matrix 100x below ``limit`` (an SVD per small matrix costs ~5x an inverse); and
    the inverses that bound needed.

    Parameters
    ----------
    matrices : (..., k, k) float
        Square matrices [any unit].
    limit : float
        Condition number from which a matrix counts as ill-conditioned [-].

    Returns
    -------
    flags : (...,) bool
        True where cond >= ``limit`` or is NaN; the same as computing every cond.
    inverses : (..., k, k) float or None
        ``np.linalg.inv(matrices)``; None when one of them is exactly singular.
    """
    inv = None
    try:
        inv = np.linalg.inv(matrices)
        bound = (np.einsum("...ab,...ab->...", matrices, matrices)
                 * np.einsum("...ab,...ab->...", inv, inv))
        unsure = ~(bound < (limit / 100.0) ** 2)
    except np.linalg.LinAlgError:  # an exactly singular matrix: check every one
        unsure = np.ones(matrices.shape[:-2], bool)
    out = np.zeros(matrices.shape[:-2], bool)
    out[unsure] = ~(np.linalg.cond(matrices[unsure]) < limit)
    return out, inv
