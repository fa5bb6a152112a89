"""The expected range of Gaussian residuals: the predicted form error PF and F.

Predicted form error (PF and F) from the per-point sigmas. The residuals are Gaussian
with standard deviations sigma_i (a mixture when they differ); S(q) = mean_i
2 Phi_c(q / sigma_i) is the fraction of |residuals| above q and T(x) its inverse, the
level exceeded by a fraction x. In the tail, the points ordered by decreasing |residual|
arrive as a Poisson process in tau = N S(q) with unit rate, each on either side with
probability 1/2. Dropping the k largest leaves the (k+1)-th, at tau ~ Gamma(k + 1), as
one end of the kept range; the other end is the next arrival on the other side, a gap
E ~ exponential of mean 2 later. Hence the kept range is

    PF = T(tau / N) + T((tau + E) / N),   tau ~ Gamma(k + 1),  E ~ Exp(mean 2),

whose mean (the prediction) and standard deviation (u_s) are computed by quadrature over
tau and E. For equal sigmas and large N with k = 0.3 % of N this is the range of the
central 99.7 % of a Gaussian, about 2 x 2.968 sigma; with k = 0 it is the sum of two
independent extremes (the Gumbel case). The prediction covers noise only: the
artefact's own form and any systematic error add to the measured range. The tests check
it against Monte Carlo draws of the residuals.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaincinv, ndtr

#: Quadrature nodes per variable of the range prediction [-].
_NODES = 64


def predicted_range(sigma, n_dropped: int = 0) -> tuple[float, float]:
    """Expected range of Gaussian residuals after dropping the largest |r|, and its std.

    Parameters
    ----------
    sigma : (n,) float
        Standard deviation of each residual, all n points before dropping [mm].
    n_dropped : int
        Points with the largest |residual| removed before the range [-].

    Returns
    -------
    predicted : float
        Expected range of the kept residuals [mm] (module notes); NaN when there are
        fewer than 2 sigmas, a sigma is not finite and > 0, or ``n_dropped`` leaves
        fewer than 2 points (no prediction, never a number).
    u : float
        Its standard deviation over repeated scans [mm]; NaN with ``predicted``.

    Notes
    -----
    PF = T(tau / N) + T((tau + E) / N), tau ~ Gamma(k + 1), E ~ Exp(mean 2), T the inverse
    of S(q) = mean_i 2 Phi_c(q / sigma_i); mean and standard deviation by quadrature on
    64 x 64 equal-probability nodes. scanqa's own derivation (module notes,
    docs/artefacts.rst), checked against Monte Carlo draws in the tests.
    """
    s = np.asarray(sigma, dtype=float).ravel()
    n, k = s.size, int(n_dropped)
    if n < 2 or not np.all(np.isfinite(s) & (s > 0)) or not 0 <= k < n - 1:
        return math.nan, math.nan
    level = _tail_level(s)
    p = (np.arange(_NODES) + 0.5) / _NODES  # equal-probability nodes of tau and E
    tau = gammaincinv(k + 1, p)[:, None]
    gap = -2.0 * np.log1p(-p)[None, :]
    r = level(tau / n) + level((tau + gap) / n)
    return float(r.mean()), float(r.std())


def _tail_level(s: np.ndarray):
    """The |residual| level q at which a fraction x of the points is expected above:
    S(q) = mean_i 2 Phi_c(q / sigma_i) = x, as a vectorised function of x."""
    reps = np.quantile(s, (np.arange(256) + 0.5) / 256) if s.size > 256 else s
    q = np.linspace(0.0, 14.0 * float(s.max()), 4001)
    tail = 2.0 * np.mean(ndtr(-q[:, None] / reps[None, :]), axis=1)
    log_tail = np.log(np.maximum(tail, 1e-300))[::-1]
    return lambda x: np.interp(np.log(x), log_tail, q[::-1])
