"""The digital filters of flattening (Sect. 5.2 of [1]_): a bank of disc kernels, what
a filter does to the two noise sources and to the fringe, and its application to the
quadrature components of a phase set, and the sampling error of a std measured on a
field the filter (and the scene's correlated noise) has correlated.

A pixel's filter is a blend of two neighbouring discs of the bank, indexed by a
continuous level t; the blend's noise-equivalent area NEA = 1 / sum(K^2), second moment
and transfer at a fringe period follow exactly from those of the two discs.
:mod:`scanqa.annotation.flattening` chooses the level of every pixel.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal, special, stats

from scanqa.chunks import row_bands, run_bands
from scanqa.decoding.demodulate import TWO_PI, ShiftFit
from scanqa.decoding.phasemap import MASK_INCONSISTENT, MASK_OUT_OF_RANGE, PhaseMap
from scanqa.io.opencv import opencv_available
from scanqa.model import optics
from scanqa.model.config import ScannerConfig

#: Diameters of the disc filters in the bank [camera px]; a pixel between two of them
#: gets the blend of the two, whose noise-equivalent area and transfer are exact.
LEVEL_DIAMETERS_PX = (0.0, 1.2, 1.6, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0,
                      12.0, 14.0, 16.0)
#: Mask reasons that concern the fringe order only (the sets disagree, or the unwrapped
#: coordinate is off the panel): the working set's quadrature components of such a pixel
#: are as good as a valid pixel's, so they take part in the filter. Leaving them out
#: would shift the phase of every neighbour: the fringe turns across the kernel, so a
#: missing sample off the centre moves the phase of the kernel's sum.
ORDER_ONLY_REASONS = (MASK_INCONSISTENT, MASK_OUT_OF_RANGE)


def disc_kernel(diameter_px: float, oversample: int = 8) -> np.ndarray:
    """A disc of the given diameter on the pixel grid, anti-aliased, of unit sum.

    Parameters
    ----------
    diameter_px : float
        Disc diameter [camera px]; 0 gives the identity [[1]].
    oversample : int
        Sub-samples per pixel and axis for the coverage [-].

    Returns
    -------
    (k, k) float64
        Each cell's share of the disc's area, k odd [-].

    Examples
    --------
    >>> float(disc_kernel(0.0).sum()), disc_kernel(3.0).shape
    (1.0, (3, 3))
    """
    if not diameter_px > 0:
        return np.ones((1, 1))
    half = int(np.ceil(diameter_px / 2.0 - 0.5))
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    cells = np.arange(-half, half + 1)
    u = (cells[:, None] + sub[None, :]).ravel()
    inside = (u[:, None] ** 2 + u[None, :] ** 2 <= diameter_px ** 2 / 4.0).astype(float)
    n = cells.size
    cover = inside.reshape(n, oversample, n, oversample).sum(axis=(1, 3))
    return cover / cover.sum()


@dataclass(frozen=True)
class FilterBank:
    """The disc filters and their exact properties, indexed by a continuous level t.

    t in [0, L - 1]; between levels k and k + 1 the kernel is (1 - w) K_k + w K_{k+1}
    with w = t - k, whose sum of squares, second moment and transfer follow exactly.
    """

    diameters_px: tuple
    kernels: tuple
    sum_sq: np.ndarray
    cross: np.ndarray
    moments: np.ndarray

    @classmethod
    def build(cls, diameters_px: Sequence[float] = LEVEL_DIAMETERS_PX) -> FilterBank:
        kernels = tuple(disc_kernel(d) for d in diameters_px)
        size = max(k.shape[0] for k in kernels)
        padded = [np.pad(k, (size - k.shape[0]) // 2) for k in kernels]
        x = np.arange(size) - size // 2
        sum_sq = np.array([(k * k).sum() for k in padded])
        cross = np.array([(a * b).sum() for a, b in itertools.pairwise(padded)])
        moment = np.array([(k * x[None, :] ** 2).sum() for k in padded])
        return cls(tuple(float(d) for d in diameters_px), kernels, sum_sq, cross, moment)

    @property
    def top(self) -> float:
        """The largest level index [-]."""
        return float(len(self.kernels) - 1)

    def _split(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.top)
        k = np.minimum(np.floor(t).astype(int), len(self.kernels) - 2)
        return k, t - k

    def nea_px2(self, t: np.ndarray) -> np.ndarray:
        """Noise-equivalent area 1 / sum(K^2) of the blended kernel [px^2]."""
        k, w = self._split(t)
        sq = (1 - w) ** 2 * self.sum_sq[k] + 2 * w * (1 - w) * self.cross[k] \
            + w ** 2 * self.sum_sq[k + 1]
        return 1.0 / sq

    def moment_px2(self, t: np.ndarray) -> np.ndarray:
        """Per-axis second moment of the blended kernel [px^2]."""
        k, w = self._split(t)
        return (1 - w) * self.moments[k] + w * self.moments[k + 1]

    def transfer(self, t: np.ndarray, period_px: np.ndarray) -> np.ndarray:
        """Amplitude transfer of the blended kernel for a fringe of ``period_px`` along
        an image axis (the disc is isotropic to the sampling) [-]."""
        k, w = self._split(t)
        p = np.asarray(period_px, dtype=float)
        return (1 - w) * self.level_transfer(k, p) + w * self.level_transfer(k + 1, p)

    def level_transfer(self, k: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Transfer of the bank's kernels ``k`` (int) at fringe periods ``p`` [px] [-]."""
        out = np.empty(np.broadcast_shapes(np.shape(k), np.shape(p)))
        k, p = np.broadcast_arrays(k, p)
        for level in np.unique(k):
            kern = self.kernels[level]
            x = np.arange(kern.shape[0]) - kern.shape[0] // 2
            line = kern.sum(axis=0)
            sel = k == level
            out[sel] = (line[None, :] * np.cos(TWO_PI * x[None, :] / p[sel][:, None])).sum(1)
        return out


@functools.lru_cache(maxsize=1)
def default_bank() -> FilterBank:
    """The bank of :data:`LEVEL_DIAMETERS_PX`, built once."""
    return FilterBank.build()


def reduction(noise_area_px2: np.ndarray, period_cam_px: np.ndarray, t: np.ndarray,
              config: ScannerConfig, bank: FilterBank | None = None, transfer: bool = False,
              z_mm: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Factors by which the filter at level t scales the scene and sensor parts [-].

    Parameters
    ----------
    noise_area_px2 : array_like
        Noise-equivalent area of the camera's own kernel N_o
        (:func:`scanqa.model.readings.camera_noise_area`) [px^2].
    period_cam_px : array_like
        Fringe period in the image [camera px] (or, with ``transfer``, the filter's
        transfer m_f [-]).
    t : array_like
        Level index in the filter bank [-].
    config : ScannerConfig
        Its ``[model] gamma``: the scene noise's correlation area is gamma^2 [px^2].
    bank : FilterBank, optional
        Default :func:`default_bank`.
    transfer : bool
        ``period_cam_px`` is already the filter's transfer m_f [-].
    z_mm : array_like, optional
        Range of the points along the camera axis [mm]: with the smooth floor the
        correlation cell is fixed on the object (:func:`scanqa.model.optics.correlation_gamma`);
        without it gamma is taken as at focus.

    Returns
    -------
    scene, sensor : ndarray
        sqrt((g^2 + N_o) / (g^2 + N_o + NEA - 1)) / m_f and 1 / (sqrt(NEA) m_f) [-].

    Notes
    -----
    With the smooth floor and ``z_mm`` given, the scene factor is
    :func:`scene_gain`: the exact second-order variance of the scene cells (squares of
    side gamma, :func:`scanqa.model.optics.correlation_gamma`) through the pixel, the
    defocus disc, the Airy pattern and the digital filter. Otherwise: noise correlated
    over an area g^2 and filtered by kernels of noise-equivalent areas that add (second
    moments of near-Gaussian kernels add, docs/noise_model.rst) keeps the variance share
    g^2 / (g^2 + N); the digital filter adds NEA - 1 to N (the pixel is already in N_o).
    This is the smooth form of F^2 = max(1, N / g^2) that the sum form of Eq. 17
    floors; it is 1-3 % off where the defocus disc and the filter are of a size (two
    discs' noise-equivalent areas do not add), docs/flattening.rst, "Bias and chance".
    """
    bank = bank or default_bank()
    nea = bank.nea_px2(t)
    m_f = period_cam_px if transfer else bank.transfer(t, period_cam_px)
    n_o = np.asarray(noise_area_px2, dtype=float)
    if z_mm is not None and config.model.filter_floor == "smooth":
        with np.errstate(divide="ignore", invalid="ignore"):
            return scene_gain(z_mm, t, config, bank) / m_f, 1.0 / (np.sqrt(nea) * m_f)
    gamma = config.model.gamma if z_mm is None else optics.correlation_gamma(
        config.model.gamma, z_mm, config, config.model.filter_floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        scene = (optics.filter_factor(n_o, 0.0, gamma, "smooth", "sum")
                 / optics.filter_factor(n_o + nea - 1.0, 0.0, gamma, "smooth", "sum"))
        return scene / m_f, 1.0 / (np.sqrt(nea) * m_f)


#: Sub-samples per camera pixel and axis of the kernels in :func:`scene_gain` [-].
_FINE = 4
#: Spacing of the range nodes :func:`scene_gain` tabulates, at least [mm], and the
#: largest number of nodes (a wider range gets a coarser spacing).
_NODE_MM, _MAX_NODES = 0.5, 121


def scene_gain(z_mm: np.ndarray, t: np.ndarray, config: ScannerConfig,
               bank: FilterBank | None = None) -> np.ndarray:
    """The factor by which the filter at level t scales the scene part, to second
    order exactly [-].

    Parameters
    ----------
    z_mm : array_like
        Range of the points along the camera axis [mm].
    t : array_like
        Level index in the filter bank [-].
    config : ScannerConfig
        Camera optics and ``[model] gamma`` (the cell side at focus) [px].
    bank : FilterBank, optional
        Default :func:`default_bank`.

    Returns
    -------
    ndarray
        sqrt(V(t) / V(0)), broadcast over ``z_mm`` and ``t`` [-].

    Notes
    -----
    The scene noise is i.i.d. per square cell of side gamma Z_focus / Z_c px
    (:func:`scanqa.model.optics.correlation_gamma`); the camera's kernel h is that cell
    convolved with the pixel (a 1 px box), the defocus disc (diameter c_c, Eq. 2) and the
    Airy pattern (Eq. 15, to its fifth dark ring), so the pixels' scene noise has the
    autocovariance R = h * h sampled at whole-pixel lags, and the filter K gives the
    variance V(K) = sum_lag (K * K)(lag) R(lag) (a blend of two discs by its three
    cross terms). Tabulated at range nodes (:data:`_NODE_MM`) and interpolated.
    Unlike the smooth law's areas that add, this holds for any kernel shapes: on the
    paper's f/11 scanner a defocus disc and a filter disc of a size reduce the noise
    0.5-3 % less than the law says, and near the far end about 1 % more. NaN ranges
    give NaN.

    Examples
    --------
    >>> from scanqa.model.config import load_config
    >>> cfg = load_config("calib/paper_scanner.toml", profile="f11").replace_model(
    ...     gamma=2.1, filter_floor="smooth")
    >>> round(float(scene_gain(450.0, 0.0, cfg)), 3), bool(np.isnan(scene_gain(np.nan, 9.0, cfg)))
    (1.0, True)
    """
    bank = bank or default_bank()
    z = np.asarray(z_mm, dtype=float)
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        return np.full(np.broadcast_shapes(z.shape, np.shape(t)), np.nan)
    lo, hi = float(finite.min()), float(finite.max())
    step = _NODE_MM * 2.0 ** max(0, math.ceil(math.log2(max(
        (hi - lo) / (_MAX_NODES - 2) / _NODE_MM, 1e-12))))  # nodes shared between calls
    nodes = step * np.arange(math.floor(lo / step), math.ceil(hi / step) + 1)
    table = np.array([_level_variances(float(n), config, bank) for n in nodes])
    k, w = bank._split(t)
    zi = np.interp(z, nodes, np.arange(nodes.size)) if nodes.size > 1 else np.zeros_like(z)
    zi = np.where(np.isfinite(z), zi, 0.0)
    i = np.minimum(np.floor(zi).astype(int), max(nodes.size - 2, 0))
    f = zi - i

    def at(col: np.ndarray) -> np.ndarray:
        lower = table[i, col]
        upper = table[np.minimum(i + 1, nodes.size - 1), col]
        return (1 - f) * lower + f * upper

    n = len(bank.kernels)
    var = (1 - w) ** 2 * at(k) + 2 * w * (1 - w) * at(n + k) + w ** 2 * at(k + 1)
    return np.where(np.isfinite(z), np.sqrt(var), np.nan)


def _level_variances(z_mm: float, config: ScannerConfig, bank: FilterBank) -> np.ndarray:
    """V of every level's kernel, then of every neighbouring pair's cross term, over V
    of no filter, at range ``z_mm`` (:func:`scene_gain`) [-]."""
    cam, model = config.camera, config.model
    key = (round(z_mm, 6), cam.focal_mm, cam.focus_mm, cam.aperture_mm, cam.pixel_um,
           cam.f_number, model.gamma, model.wavelength_nm, model.filter_floor, bank.diameters_px)
    if key not in _VARIANCES:
        if len(_VARIANCES) > 4096:
            _VARIANCES.clear()
        _VARIANCES[key] = _compute_level_variances(z_mm, config, bank)
    return _VARIANCES[key]


#: :func:`_level_variances` computed so far, by range, optics, gamma and bank.
_VARIANCES: dict = {}


def _compute_level_variances(z_mm: float, config: ScannerConfig, bank: FilterBank
                             ) -> np.ndarray:
    cam = config.camera
    pixel = cam.pixel_um * 1e-3
    cell = float(optics.correlation_gamma(config.model.gamma, z_mm, config,
                                          config.model.filter_floor))
    c_px = float(optics.image_blur_diameter(z_mm, cam.focal_mm, cam.focus_mm,
                                            cam.aperture_mm)) / pixel
    airy = optics.airy_diameter(config.model.wavelength_nm * 1e-6, cam.f_number) / pixel
    h = _box(cell)
    for part in (_box(1.0), disc_kernel(c_px * _FINE, oversample=4), _airy(airy)):
        h = signal.fftconvolve(h, part)
    auto = signal.fftconvolve(h, h[::-1, ::-1])
    centre = np.array(auto.shape) // 2
    reach = bank.kernels[-1].shape[0] - 1
    lags = np.arange(-reach, reach + 1)
    rows, cols = centre[0] + _FINE * lags, centre[1] + _FINE * lags
    inside = (rows >= 0) & (rows < auto.shape[0]), (cols >= 0) & (cols < auto.shape[1])
    r = np.zeros((lags.size, lags.size))
    r[np.ix_(*inside)] = auto[np.ix_(rows[inside[0]], cols[inside[1]])]
    return _pair_correlations(bank) @ r.ravel() / r[reach, reach]


#: :func:`_pair_correlations` by the bank's diameters.
_PAIRS: dict = {}


def _pair_correlations(bank: FilterBank) -> np.ndarray:
    """K_a * K_b of every level (a = b) and neighbouring pair (b = a + 1), flattened,
    one row each [-]."""
    if bank.diameters_px not in _PAIRS:
        _PAIRS[bank.diameters_px] = _correlate_pairs(bank)
    return _PAIRS[bank.diameters_px]


def _correlate_pairs(bank: FilterBank) -> np.ndarray:
    size = bank.kernels[-1].shape[0]
    padded = [np.pad(kern, (size - kern.shape[0]) // 2) for kern in bank.kernels]
    pairs = [(a, a) for a in padded] + list(itertools.pairwise(padded))
    return np.array([signal.correlate(a, b).ravel() for a, b in pairs])


def _box(width_px: float) -> np.ndarray:
    """A square of side ``width_px`` on the fine grid, its edges' cells partly
    covered, of unit sum [-]."""
    n = width_px * _FINE
    full = int(np.floor(n))
    edge = (n - full) / 2.0
    line = np.ones(full + (2 if edge > 0 else 0))
    if edge > 0:
        line[0] = line[-1] = edge
    return np.outer(line, line) / line.sum() ** 2


def _airy(diameter_px: float) -> np.ndarray:
    """The Airy pattern (2 J1(x) / x)^2 whose first dark ring has ``diameter_px``, to
    its fifth dark ring, on the fine grid, of unit sum (Eq. 15) [-]."""
    x_zero, x_fifth = 3.8317, 16.4706
    radius = diameter_px / 2.0 * _FINE * x_fifth / x_zero
    half = int(np.ceil(radius))
    u = np.arange(-half, half + 1)
    rho = np.hypot(u[:, None], u[None, :]) / (diameter_px / 2.0 * _FINE) * x_zero
    safe = np.where(rho > 1e-9, rho, 1.0)
    psf = np.where(rho > 1e-9, (2 * special.j1(safe) / safe) ** 2, 1.0)
    psf = np.where(rho <= x_fifth, psf, 0.0)
    return psf / psf.sum()


def camera_noise_area_px2(z_mm: np.ndarray, config: ScannerConfig) -> np.ndarray:
    """The camera kernel's noise-equivalent area N_o at range ``z_mm`` (pixel, defocus
    disc, Airy disc; :func:`scanqa.model.readings.camera_noise_area`) [px^2]."""
    cam, model = config.camera, config.model
    pixel = cam.pixel_um * 1e-3
    b_d = optics.diffraction_blur_area(
        optics.airy_diameter(model.wavelength_nm * 1e-6, cam.f_number), pixel)
    c_image = optics.image_blur_diameter(z_mm, cam.focal_mm, cam.focus_mm, cam.aperture_mm)
    return optics.camera_noise_area(c_image, pixel, b_d)


def optics_moment_px2(z_mm: np.ndarray, config: ScannerConfig) -> np.ndarray:
    """Per-axis second moment of the camera's own kernel at range ``z_mm``: pixel box
    1/12, defocus disc c_c^2 / 16 and Airy disc d^2 / 16 [px^2]."""
    cam, model = config.camera, config.model
    pixel = cam.pixel_um * 1e-3
    c_image = optics.image_blur_diameter(z_mm, cam.focal_mm, cam.focus_mm, cam.aperture_mm)
    airy = optics.airy_diameter(model.wavelength_nm * 1e-6, cam.f_number)
    return 1.0 / 12.0 + ((c_image / pixel) ** 2 + (airy / pixel) ** 2) / 16.0


def filter_phase(stack: np.ndarray, shifts_rad: Sequence[float], phase_map: PhaseMap,
                 level: np.ndarray, bank: FilterBank | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """x_p with the working set's quadrature components filtered at each pixel's level.

    Parameters
    ----------
    stack : (N, H, W) array
        The working set's frames [DN].
    shifts_rad : sequence of float
        Their phase shifts [rad].
    phase_map : PhaseMap
        The unfiltered decode (its x_p gives the fringe order; its mask the pixels that
        take part: the valid ones and those masked for their fringe order only,
        :data:`ORDER_ONLY_REASONS`).
    level : (H, W) float
        Filter level per pixel, NaN to leave a pixel alone [-].
    bank : FilterBank, optional
        Default :func:`default_bank`.

    Returns
    -------
    xp : (H, W) float64
        Filtered x_p [projector px].
    gain : (H, W) float
        The sensor-noise factor 1 / (sqrt(NEA) m_f) with m_f measured as the fall of the
        modulation, for ``sigma_xp`` [-].
    """
    bank = bank or default_bank()
    n, height, width = stack.shape
    fit = ShiftFit.from_shifts(shifts_rad)
    rows = fit.rows[1:].astype(np.float32)
    c, s = (rows @ stack.reshape(n, -1).astype(np.float32)).reshape(2, height, width)
    use = phase_map.valid & np.isfinite(phase_map.xp)
    part = use | np.isin(phase_map.mask, ORDER_ONLY_REASONS)
    weighted = np.stack([part.astype(np.float32), c * part, s * part])
    todo = np.flatnonzero(use & (level > 0))  # NaN > 0 is False
    t = level.flat[todo]
    k = np.minimum(t.astype(np.int8), len(bank.kernels) - 2)  # floor: t >= 0
    w = (t - k).astype(np.float32)
    order = np.argsort(k, kind="stable")  # a radix sort of small integers
    bounds = np.searchsorted(k[order], np.arange(len(bank.kernels) + 1))
    # each pixel takes (1 - w) of level k (``below``) and w of level k + 1 (``above``):
    # every level writes its own pixels of each, so the levels run on every core, and
    # below + above is the sum the levels added one after another
    below, above = (np.zeros((2, todo.size), np.float32) for _ in range(2))

    def one_level(lev: int, _: int) -> None:
        lower = order[bounds[lev]:bounds[lev + 1]]  # k == lev: weight 1 - w
        upper = order[bounds[lev - 1]:bounds[lev]] if lev else order[:0]  # k + 1 == lev
        sel = np.concatenate([lower, upper])
        if sel.size:
            share = np.concatenate([1 - w[lower], w[upper]])
            part = share * _filtered_at(weighted, bank.kernels[lev], todo[sel], width)
            below[:, lower] = part[:, :lower.size]
            above[:, upper] = part[:, lower.size:]

    run_bands(one_level, [(lev, lev + 1) for lev in range(len(bank.kernels))])
    cs = below + above
    xp = phase_map.xp.copy()
    gain = np.ones((height, width))
    grid = np.linspace(0.0, bank.top, 64 * int(bank.top) + 1)
    nea = bank.nea_px2(grid)

    def finish(a: int, b: int) -> None:  # element by element: disjoint slices of todo
        at, cs_ab = todo[a:b], cs[:, a:b]
        c0, s0 = c.flat[at], s.flat[at]
        shift = (np.arctan2(-cs_ab[1], cs_ab[0]) - np.arctan2(-s0, c0)) / TWO_PI
        xp.flat[at] += (shift - np.rint(shift)) * phase_map.period_px
        with np.errstate(invalid="ignore", divide="ignore"):
            fall = np.hypot(cs_ab[0], cs_ab[1]) / np.hypot(c0, s0)
            gain.flat[at] = 1.0 / (np.sqrt(np.interp(t[a:b], grid, nea)) * fall)

    run_bands(finish, row_bands(todo.size, 1, 1 << 20))
    return xp, gain


def _filtered_at(weighted: np.ndarray, kernel: np.ndarray, index: np.ndarray, width: int
                 ) -> np.ndarray:
    """Normalised convolution (C w * K / w * K, S w * K / w * K) at the flat ``index``,
    computed on the band of rows that holds them [-]."""
    r = kernel.shape[0] // 2
    r0, r1 = int(index.min()) // width, int(index.max()) // width + 1
    b0, b1 = max(r0 - r, 0), min(r1 + r, weighted.shape[1])
    local = index - b0 * width
    den, cw, sw = (convolve_reflected(np.ascontiguousarray(x[b0:b1]), kernel).ravel()[local]
                   for x in weighted)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([cw / den, sw / den])


def convolve_reflected(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``image`` (float32) correlated with ``kernel``, edges reflected (fedcba|abcdef):
    ``cv2.filter2D`` (BORDER_REFLECT) when OpenCV is installed (the calib extra; 1.4 x
    less CPU in flattening), else :func:`correlate_reflected`, equal to float32 rounding."""
    if kernel.size == 1:
        return image
    if opencv_available():
        import cv2

        return cv2.filter2D(image, cv2.CV_32F, kernel.astype(np.float32),
                            borderType=cv2.BORDER_REFLECT)
    return correlate_reflected(image, kernel)


def correlate_reflected(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """:func:`convolve_reflected` in scipy: float64 sums, float32 out; direct up to
    :data:`DIRECT_KERNEL_SIZE` taps, by FFT over the image padded numpy's 'symmetric'
    way above (tests/test_opencv_twins.py holds it to ``cv2.filter2D``)."""
    k = np.asarray(kernel, dtype=float)
    if k.size <= DIRECT_KERNEL_SIZE:
        from scipy.ndimage import correlate

        return correlate(image.astype(float), k, mode="reflect").astype(np.float32)
    (ry, rx), (sy, sx) = np.array(k.shape) // 2, np.array(k.shape) - 1 - np.array(k.shape) // 2
    padded = np.pad(image.astype(float), ((ry, sy), (rx, sx)), mode="symmetric")
    return signal.fftconvolve(padded, k[::-1, ::-1], mode="valid").astype(np.float32)


#: Largest kernel (taps) :func:`convolve_reflected` sums directly; larger ones go through FFTs.
DIRECT_KERNEL_SIZE = 49


#: Largest lag of the autocorrelation summed by :func:`effective_pixels` [camera px]:
#: the largest disc of the bank (16 px) correlates pixels up to 16 px apart, and the
#: camera's defocus disc (about 10 px at 436 and 463 mm on the paper's f/11 scanner) adds.
MAX_LAG_PX = 24


def effective_pixels(field: np.ndarray, max_lag_px: int = MAX_LAG_PX) -> tuple[int, float]:
    """The number of finite pixels of a noise field and its effective number of
    independent pixels for the variance.

    Parameters
    ----------
    field : (H, W) float
        A zero-mean noise field (e.g. the difference of two scans' x_p or range), NaN
        where not measured [any unit].
    max_lag_px : int
        Largest lag along each axis summed [px].

    Returns
    -------
    n : int
        Finite pixels [-].
    n_eff : float
        n^2 / sum_(i,j) rho_ij^2 [-], with rho the field's autocorrelation measured on
        it (every lag within ``max_lag_px``), so that the sample variance has the
        relative variance 2 / n_eff.

    Notes
    -----
    For a Gaussian field, var(s^2) = (2 / n^2) sum_(i,j) cov_ij^2 (Isserlis), so
    var(s^2) / sigma^4 = 2 / n_eff with n_eff = n^2 / sum_lag C(lag) rho(lag)^2, C(lag)
    the pixel pairs at that lag. White noise gives n_eff = n; noise filtered by a kernel
    K gives n / sum_lag rho^2 with rho = (K * K) / sum(K^2), about n / 20 for a 7 px disc.
    Each lag's estimated rho^2 is biased up by about S / C(lag), S = sum_lag rho^2
    (Bartlett's variance of an autocorrelation estimate), so the measured sum
    D = sum_lag C rho^2 is about S (n + L) over L lags besides the zero lag, and
    n_eff = n (n + L) / D.
    """
    ok = np.isfinite(field)
    n = int(ok.sum())
    if n < 2:
        return n, float(n)
    z = np.where(ok, field - np.mean(field[ok]), 0.0)
    m = ok.astype(float)
    h, w = z.shape
    shape = (2 * h, 2 * w)
    fz, fm = np.fft.rfft2(z, shape), np.fft.rfft2(m, shape)
    lags = np.r_[0:max_lag_px + 1, -max_lag_px:0]
    acov = np.fft.irfft2(fz * np.conj(fz), shape)[np.ix_(lags, lags)]
    pairs = np.rint(np.fft.irfft2(fm * np.conj(fm), shape)[np.ix_(lags, lags)])
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = acov / np.maximum(pairs, 1.0) / (acov[0, 0] / n)
        terms = np.where(pairs > 0, pairs * rho ** 2, 0.0)
    lags = int((pairs[1:, :] > 0).sum() + (pairs[0, 1:] > 0).sum())
    return n, float(n * (n + lags) / max(terms.sum(), n + lags))


def std_interval(std: float, n_eff: float, level: float = 0.95) -> tuple[float, float]:
    """Confidence interval of the true std behind a measured one.

    Parameters
    ----------
    std : float
        The measured std [any unit].
    n_eff : float
        Effective independent pixels of the field it was measured on
        (:func:`effective_pixels`) [-].
    level : float
        Confidence level [-].

    Returns
    -------
    low, high : float
        The interval [unit of ``std``]: n_eff s^2 / sigma^2 taken as chi-square with
        n_eff degrees of freedom (the same relative variance 2 / n_eff).

    Examples
    --------
    >>> [round(v, 3) for v in std_interval(1.0, 1000.0)]
    [0.958, 1.046]
    """
    a = (1.0 - level) / 2.0
    q_hi, q_lo = stats.chi2.ppf([1.0 - a, a], n_eff)
    return std * math.sqrt(n_eff / q_hi), std * math.sqrt(n_eff / q_lo)
