"""Numerical blur kernels of the virtual scanner: disc quadrature, disc and Airy kernels.

None of these uses the Bessel closed form of Eq. 11/12: the projector's disc average
is a quadrature over the disc, the camera's disc kernel is the pixel-coverage of a
disc, and the Airy pattern (which is a Bessel function by nature) is only the
diffraction PSF of the camera lens.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.signal import fftconvolve
from scipy.special import j1


@lru_cache(maxsize=8)
def disc_quadrature(n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic equal-area quadrature of the unit disc, symmetric under x -> -x.

    Rings at radii sqrt((i + 1/2) / n_rings), each of an even number of points at
    angles (j + 1/2) 2 pi / k_i, every ring carrying weight 1 / n_rings.

    Parameters
    ----------
    n_points : int
        Approximate number of points [-].

    Returns
    -------
    x, weight : (n,) float
        x coordinate of each point on the unit disc [-] and its weight (sum 1) [-].
    """
    n_rings = max(2, round(np.sqrt(n_points / np.pi)))
    xs, ws = [], []
    for i in range(n_rings):
        rho = np.sqrt((i + 0.5) / n_rings)
        k = max(2, 2 * round(np.pi * (2 * i + 1) * n_points / (2 * np.pi * n_rings ** 2)))
        theta = (np.arange(k) + 0.5) * 2 * np.pi / k
        xs.append(rho * np.cos(theta))
        ws.append(np.full(k, 1.0 / (n_rings * k)))
    return np.concatenate(xs), np.concatenate(ws)


@lru_cache(maxsize=4)
def disc_average(n_points: int) -> DiscAverage:
    """Cached :class:`DiscAverage` for ``n_points`` quadrature points."""
    return DiscAverage(n_points)


class DiscAverage:
    """Average of exp(i u x) over the unit disc by quadrature, tabulated in u.

    The pattern of a vertical-fringe set depends on the panel column only, so the
    average of ``cos(2 pi (x_p + d/2 x) / P + delta)`` over a panel disc of diameter d
    is ``Re(M(pi d / P) exp(i (2 pi x_p / P + delta)))`` with M the quadrature average
    of ``exp(i u x)``. M is tabulated on a fine grid of u and interpolated linearly
    (error < 1e-6).

    Parameters
    ----------
    n_points : int
        Number of quadrature points on the disc [-].
    u_max : float
        Largest argument tabulated, pi d / P [rad].
    """

    def __init__(self, n_points: int, u_max: float = 40.0) -> None:
        x, w = disc_quadrature(n_points)
        self.u = np.linspace(0.0, u_max, 40001)
        self.m = np.cos(np.outer(self.u, x)) @ w  # the sine part vanishes by symmetry

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """M(u) [-]; u beyond the table is clipped to its end (contrast ~0 there)."""
        return np.interp(u, self.u, self.m)


@lru_cache(maxsize=512)
def disc_kernel(diameter: float, oversample: int = 8) -> np.ndarray:
    """Normalised disc kernel: the area fraction of each cell inside the disc.

    Parameters
    ----------
    diameter : float
        Disc diameter [cells].
    oversample : int
        Sub-samples per cell and axis used to measure the coverage [-].

    Returns
    -------
    (k, k) float
        Kernel summing to 1, k odd.
    """
    r = diameter / 2.0
    half = int(np.ceil(r + 0.5))
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    grid = (np.arange(-half, half + 1)[:, None] + sub[None, :]).ravel()
    inside = (grid[:, None] ** 2 + grid[None, :] ** 2) <= r * r
    k = inside.reshape(2 * half + 1, oversample, 2 * half + 1, oversample).mean(axis=(1, 3))
    if k.sum() == 0:  # a disc smaller than a sub-sample: a delta
        k[half, half] = 1.0
    return k / k.sum()


@lru_cache(maxsize=16)
def airy_kernel(wavelength_mm: float, f_number: float, cell_mm: float,
                zeros: int = 5, oversample: int = 5) -> np.ndarray:
    """Normalised Airy PSF (2 J1(x) / x)^2 sampled on a grid, truncated at a dark ring.

    Parameters
    ----------
    wavelength_mm : float
        Wavelength lambda [mm].
    f_number : float
        Camera f-number N [-].
    cell_mm : float
        Grid spacing on the sensor [mm].
    zeros : int
        Truncation at this dark ring (x = 3.83, 7.02, 10.17, 13.32, 16.47) [-].

    Returns
    -------
    (k, k) float
        Kernel summing to 1; the first dark ring has diameter 2.44 lambda N (Eq. 15).
    """
    x_zero = (3.8317, 7.0156, 10.1735, 13.3237, 16.4706)[zeros - 1]
    r_max = x_zero * wavelength_mm * f_number / np.pi / cell_mm
    half = int(np.ceil(r_max))
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    grid = (np.arange(-half, half + 1)[:, None] + sub[None, :]).ravel() * cell_mm
    rho = np.hypot(grid[:, None], grid[None, :])
    x = np.pi * rho / (wavelength_mm * f_number)
    safe = np.where(x > 1e-9, x, 1.0)
    psf = np.where(x > 1e-9, (2 * j1(safe) / safe) ** 2, 1.0)
    psf = np.where(x <= x_zero, psf, 0.0)
    k = psf.reshape(2 * half + 1, oversample, 2 * half + 1, oversample).mean(axis=(1, 3))
    return k / k.sum()


def camera_kernel(diameter: float, airy: np.ndarray) -> np.ndarray:
    """Defocus disc of ``diameter`` cells convolved with the diffraction PSF."""
    k = fftconvolve(disc_kernel(diameter), airy, mode="full")
    k = np.clip(k, 0.0, None)
    return k / k.sum()
