"""The smooth shear of a calibration table's phase axis: s = x_p - x_shear(u, v).

A table's third axis is the phase relative to a reference that follows the projector
column seen by each pixel at mid-sweep. The reference must be one smooth function used
identically when the table is built and when it is applied: interpolated bilinearly
between nodes, its curvature (x_p(u) is projective) reappears as a depth error of
~x_uu h^2 / 8 dZ/dx_p between nodes. A low-order polynomial in normalised pixel
coordinates fitted to the nodes' reference phases has no such error; how far it misses
the exact reference does not matter (it only moves the origin of s), as long as the miss
is smooth.
"""

from __future__ import annotations

import numpy as np

#: Degree of the shear polynomial in (u, v).
DEGREE = 4


def _terms(degree: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]


#: Number of coefficients of a shear (monomials of total degree <= DEGREE).
N_TERMS = len(_terms(DEGREE))


def _normalised(u: np.ndarray, v: np.ndarray, size: tuple[int, int]
                ) -> tuple[np.ndarray, np.ndarray]:
    width, height = size
    return (2.0 * np.asarray(u, float) / max(width - 1, 1) - 1.0,
            2.0 * np.asarray(v, float) / max(height - 1, 1) - 1.0)


def fit_shear(u: np.ndarray, v: np.ndarray, x_ref: np.ndarray, size: tuple[int, int],
              degree: int = DEGREE) -> np.ndarray:
    """Least-squares polynomial through the finite reference phases of the nodes.

    Parameters
    ----------
    u, v : (n_v, n_u) float
        Node coordinates [camera px].
    x_ref : (n_v, n_u) float
        Reference phase at each node, NaN where the node has none [projector px].
    size : (int, int)
        Camera width and height [px].
    degree : int
        Total degree of the polynomial.

    Returns
    -------
    (k,) ndarray
        Coefficients, in the order of the monomials u^i v^j, i + j <= degree.
    """
    ok = np.isfinite(x_ref)
    # small tables: a polynomial that interpolates a few node rows exactly swings wildly
    # between and beyond them; keep at least two node rows and columns per degree
    spread = min(np.unique(u[ok]).size, np.unique(v[ok]).size)
    degree = max(1, min(degree, spread // 2))
    terms = _terms(degree)
    while 2 * len(terms) > ok.sum() and degree > 1:
        degree -= 1
        terms = _terms(degree)
    un, vn = _normalised(u[ok], v[ok], size)
    design = np.stack([un**i * vn**j for i, j in terms], -1)
    coef, *_ = np.linalg.lstsq(design, x_ref[ok], rcond=None)
    full = np.zeros(len(_terms(DEGREE)))
    index = {t: k for k, t in enumerate(_terms(DEGREE))}
    for k, t in enumerate(terms):
        full[index[t]] = coef[k]
    return full


def eval_shear(coef: np.ndarray, u: np.ndarray, v: np.ndarray, size: tuple[int, int]
               ) -> np.ndarray:
    """The shear x_shear(u, v) [projector px] at pixel coordinates ``u``, ``v``."""
    un, vn = _normalised(u, v, size)
    out = np.zeros(np.broadcast(un, vn).shape)
    for c, (i, j) in zip(coef, _terms(DEGREE), strict=True):
        if c:
            out += c * un**i * vn**j
    return out
