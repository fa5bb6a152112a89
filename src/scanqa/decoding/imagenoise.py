"""Phase noise of one pixel from its own fringe offset and modulation.

For an N-step phase set with equally spaced shifts, least-squares demodulation of
``I_k = A + B cos(phi + d_k)`` with independent intensity noise of variance ``s^2`` per
frame gives ``var(phi) = 2 s^2 / (N B^2)``; the intensity noise of a camera is
``s^2 = a + b A`` (read noise and quantisation ``a`` [DN^2], shot noise ``b`` [DN], the
inverse gain), taken at the mean level A of the frames. In projector pixels:

    sigma_xp = P / (2 pi) sqrt(2 (a + b A) / (N B^2))

This is the law that a board characterisation (:mod:`scanqa.characterization.board`) fits and that
:func:`scanqa.annotation.points.annotate` applies per pixel.
"""

from __future__ import annotations

import math

import numpy as np

from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError


def phase_sigma_px(modulation: np.ndarray, offset: np.ndarray, read_var_dn2: float,
                   shot_dn: float, period_px: float, steps: int) -> np.ndarray:
    """Phase noise of each pixel in projector pixels.

    Parameters
    ----------
    modulation : (...) float
        Fringe modulation B [DN].
    offset : (...) float
        Fringe offset A, the mean level [DN].
    read_var_dn2 : float
        Intensity variance at zero signal, ``a`` [DN^2].
    shot_dn : float
        Shot-noise slope ``b`` [DN].
    period_px : float
        Fringe period P of the working set [projector px].
    steps : int
        Phase steps N [-].

    Returns
    -------
    (...) float
        sigma_xp [projector px]; NaN where B <= 0 or not finite.

    Examples
    --------
    >>> float(phase_sigma_px(50.0, 60.0, 1.0, 0.0, 2 * math.pi, 2))
    0.02
    """
    b = np.asarray(modulation, dtype=float)
    a = np.maximum(np.asarray(offset, dtype=float), 0.0)
    var = read_var_dn2 + shot_dn * a
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = period_px / (2 * math.pi) * np.sqrt(2.0 * var / steps) / b
    return np.where(b > 0, sigma, np.nan)


def working_steps(phase_map: PhaseMap) -> int:
    """Phase steps N of the working (finest) phase set of a decoded scan [-]."""
    prov = phase_map.provenance
    chain = prov.get("decode", {}).get("chain", [])
    sets = {s.get("name"): s for s in prov.get("patterns", {}).get("set", [])}
    working = sets.get(chain[-1]) if chain else None
    if working is None or "steps" not in working:
        raise InputError("the phase map does not say how many phase steps its working set "
                         "has (its provenance lacks the decode chain): decode the pattern "
                         "folder with this version of scanqa")
    return int(working["steps"])
