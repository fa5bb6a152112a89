"""Camera defocus of the virtual scanner: a depth-dependent disc blur by layers.

Each supersample spreads over its own disc (docs/simulator.rst, step 4): the samples are
split between the two nearest diameters of a fine ladder (linear weights), each layer is
convolved with its disc convolved with the Airy PSF, and the layers are summed. There is
no partial occlusion of the aperture at depth edges. The pixel integration (the mean of
the s x s supersamples of a pixel) follows the blur.

How the sum is computed (the result is the same convolution either way, to float32
rounding):

* samples that share one blur diameter (a face perpendicular to the camera axis: every
  sample has the same ladder position, to 1e-7 of a step) are one item whose kernel is
  the ladder's interpolated kernel ``(1 - f) k_l + f k_(l+1)``: one transform instead of
  one per ladder layer; the other samples go to their two ladder layers as above;
* an item that covers much of the tile is transformed at the tile's size and its
  spectrum, times the kernel's, is added to one sum (one forward FFT per item and
  frame); the pixel integration and the decimation to camera pixels are done on that
  sum in the frequency domain (a box filter, then the spectrum folded s times per
  axis), so the one inverse FFT per frame is at the camera's resolution, s**2 times
  smaller than the supersampled tile;
* an item on a small part of the tile (a block's top, a strip of a wall) is convolved on
  its own bounding box at the supersampled resolution, and its pixel means are added.

Only the tile's core (without its halo) is needed: a kernel no wider than the halo
cannot wrap round into the core, so the tile-size transform needs no padding then.
Images are float32 (a blurred level of 2e4 e- carries a rounding error of ~1e-3 e-
against a shot noise of ~140 e-). Kernel spectra are cached across the tiles of a scan.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.fft import irfft2, next_fast_len, rfft2

from scanqa.simulator.optics_kernels import camera_kernel
from scanqa.simulator.raykernels import add_pixel_means, ladder_groups

#: Blur-diameter ladder: linear steps up to _D_LIN, then geometric [supersamples].
_D_STEP, _D_LIN, _D_RATIO = 0.5, 4.0, 1.06
#: An item whose own transform would cost more than this fraction of a tile-size
#: transform joins the spectral sum [-] (its forward FFT then costs the tile size, its
#: inverse nothing more).
_SUM_FRACTION = 0.5
#: Largest spread of the ladder position within one ladder step for its samples to be
#: blurred as one item with the interpolated kernel [ladder steps]: the kernel of a
#: sample then differs from its own by at most 1e-7 of two neighbouring kernels'
#: difference (about 1e-4 e- on 2e4 e-, below float32 rounding).
_SAME_DIAMETER = 1e-7


def layer_coord(d: np.ndarray) -> np.ndarray:
    """Continuous index of a blur diameter on the ladder [-]."""
    lin = _D_LIN / _D_STEP
    with np.errstate(divide="ignore"):
        geo = lin + np.log(np.maximum(d, _D_LIN) / _D_LIN) / np.log(_D_RATIO)
    return np.where(d <= _D_LIN, d / _D_STEP, geo)


def layer_diameter(i: int) -> float:
    """Blur diameter of ladder layer i [supersamples]."""
    lin = _D_LIN / _D_STEP
    return i * _D_STEP if i <= lin else _D_LIN * _D_RATIO ** (i - lin)


@dataclass(frozen=True)
class _Crop:
    """An item convolved on its own bounding box: weights and its kernel's FFT."""

    rows: slice
    cols: slice
    weight: np.ndarray
    half: int
    fft_shape: tuple[int, int]
    kernel_fft: np.ndarray


@dataclass(frozen=True)
class BlurPlan:
    """The items of one tile, ready to blur every frame of it.

    ``summed`` holds (weight over the tile, kernel spectrum at ``fft_shape`` with the
    kernel's centre at the origin, times the pixel integration's box) of the items
    summed in the frequency domain; ``crops`` the items convolved on their bounding box;
    ``core`` the part of the tile (supersamples) whose pixel values are returned;
    ``supersampling`` the supersamples per pixel and axis.
    """

    shape: tuple[int, int]
    core: tuple[slice, slice]
    fft_shape: tuple[int, int]
    summed: list
    crops: list
    supersampling: int = 1


def _groups(diameter: np.ndarray, hit: np.ndarray
            ) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(ladder index l, flat sample indices, fractions f) of the samples in [l, l + 1).

    :func:`layer_coord` of every hit sample and a stable sort by layer, in one compiled
    pass (:func:`scanqa.simulator.raykernels.ladder_groups`).
    """
    flat, frac, levels, start, stop = ladder_groups(
        np.ascontiguousarray(diameter, np.float64).ravel(), np.ascontiguousarray(hit).ravel(),
        _D_STEP, _D_LIN, float(np.log(_D_RATIO)))
    return [(lev, flat[a:b], frac[a:b])
            for lev, a, b in zip(levels.tolist(), start, stop, strict=True)]


def _items(diameter: np.ndarray, hit: np.ndarray
           ) -> list[tuple[tuple[int, float], np.ndarray, np.ndarray]]:
    """((ladder index, fraction), flat sample indices, weights) of every item.

    A group of samples that share one ladder position (to :data:`_SAME_DIAMETER`) is one
    item with the kernel interpolated at that position; the others are split between
    their two ladder layers (fraction 0), as the ladder defines.
    """
    parts: dict[tuple[int, float], list] = {}
    for lev, idx, frac in _groups(diameter, hit):
        lo, hi = float(frac.min()), float(frac.max())
        if hi - lo <= _SAME_DIAMETER:
            f = 0.5 * (lo + hi)
            key = (lev, 0.0) if f <= _SAME_DIAMETER else (lev, f)
            parts.setdefault(key, []).append((idx, np.ones(idx.size)))
            continue
        parts.setdefault((lev, 0.0), []).append((idx, 1.0 - frac))
        parts.setdefault((lev + 1, 0.0), []).append((idx, frac))
    out = []
    for key in sorted(parts):
        idx = np.concatenate([p[0] for p in parts[key]])
        w = np.concatenate([p[1] for p in parts[key]])
        keep = w > 1e-12
        if keep.any():
            out.append((key, idx[keep], w[keep]))
    return out


@lru_cache(maxsize=256)
def _ladder_kernel(level: int, airy_key: bytes, airy_side: int) -> np.ndarray:
    """Kernel of ladder layer ``level`` (disc convolved with the Airy PSF) [-]."""
    airy = np.frombuffer(airy_key).reshape(airy_side, airy_side)
    return camera_kernel(layer_diameter(level), airy)


def item_kernel(key: tuple[int, float], airy: np.ndarray) -> np.ndarray:
    """Kernel of an item: ``(1 - f) k_l + f k_(l+1)`` for key (l, f), centred, odd [-]."""
    level, f = key
    airy_key = (np.ascontiguousarray(airy, np.float64).tobytes(), airy.shape[0])
    k0 = _ladder_kernel(level, *airy_key)
    if f == 0.0:
        return k0
    k1 = _ladder_kernel(level + 1, *airy_key)
    if k1.shape[0] < k0.shape[0]:  # never on the ladder (diameters grow); kept general
        k0, k1, f = k1, k0, 1.0 - f
    pad = (k1.shape[0] - k0.shape[0]) // 2
    out = f * k1
    out[pad:pad + k0.shape[0], pad:pad + k0.shape[1]] += (1.0 - f) * k0
    return out


def blur_plan(diameter: np.ndarray, hit: np.ndarray, airy: np.ndarray, margin: int,
              supersampling: int = 1) -> BlurPlan:
    """Split the samples of a tile between blur items and prepare their kernels.

    Parameters
    ----------
    diameter : (H, W) float
        Blur diameter of every supersample [supersamples].
    hit : (H, W) bool
        Samples that see the scene (the others carry no light).
    airy : (k, k) float
        Diffraction PSF on the supersample grid.
    margin : int
        Width of the halo around the tile's core, a multiple of ``supersampling``
        [supersamples].
    supersampling : int
        Supersamples per camera pixel and axis, s [-]; H and W are multiples of it.

    Returns
    -------
    BlurPlan
    """
    s = int(supersampling)
    shape = hit.shape
    n_rows, n_cols = shape
    items = [(key, item_kernel(key, airy), idx, w) for key, idx, w in _items(diameter, hit)]
    half_max = max([k.shape[0] // 2 for _, k, _, _ in items], default=0)
    pad = max(0, half_max - margin)
    fft_shape = tuple(s * next_fast_len(-(-(n + pad) // s), real=True) for n in shape)
    tile_cost = _fft_cost(fft_shape)
    airy_key = (np.ascontiguousarray(airy, np.float64).tobytes(), airy.shape[0])
    summed, crops = [], []
    for key, kern, idx, w in items:
        rr, cc = np.divmod(idx, n_cols)
        rows = slice(int(rr.min()), int(rr.max()) + 1)
        cols = slice(int(cc.min()), int(cc.max()) + 1)
        crop_shape = tuple(next_fast_len(n + kern.shape[0] - 1, real=True)
                           for n in (rows.stop - rows.start, cols.stop - cols.start))
        if _fft_cost(crop_shape) > _SUM_FRACTION * tile_cost:
            weight = np.zeros(shape, np.float32)
            weight.ravel()[idx] = w  # a view: half the CPU of .flat (measured)
            summed.append((weight, _pixel_kernel_fft(key, *airy_key, fft_shape, s)))
        else:
            weight = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.float32)
            weight[rr - rows.start, cc - cols.start] = w
            crops.append(_Crop(rows, cols, weight, kern.shape[0] // 2, crop_shape,
                               rfft2(kern.astype(np.float32), s=crop_shape)))
    core = (slice(margin, n_rows - margin), slice(margin, n_cols - margin))
    return BlurPlan(shape, core, fft_shape, summed, crops, s)


def _fft_cost(shape: tuple[int, int]) -> float:
    """Relative cost of a real 2-D FFT of ``shape`` (n log n) [-]."""
    n = float(shape[0] * shape[1])
    return n * np.log2(max(n, 2.0))


@lru_cache(maxsize=24)
def _pixel_kernel_fft(key: tuple[int, float], airy_key: bytes, airy_side: int,
                      fft_shape: tuple[int, int], s: int) -> np.ndarray:
    """Spectrum of an item's kernel centred at index (0, 0), times the pixel box.

    The box is the mean over ``s`` supersamples forwards along each axis (a pixel's
    supersamples start at a multiple of s), and carries the 1/s of each axis's fold
    (:func:`_fold_to_pixels`), so that the folded spectrum's inverse FFT is the pixel
    mean. complex64, (fft_shape[0], fft_shape[1] // 2 + 1) [-].
    """
    airy = np.frombuffer(airy_key).reshape(airy_side, airy_side)
    kern = item_kernel(key, airy)
    half = kern.shape[0] // 2
    padded = np.zeros(fft_shape, np.float64)
    padded[:kern.shape[0], :kern.shape[1]] = kern
    spectrum = rfft2(np.roll(padded, (-half, -half), axis=(0, 1)))
    n0, n1 = fft_shape
    box0 = np.exp(2j * np.pi * np.outer(np.arange(n0), np.arange(s)) / n0).sum(1) / s ** 2
    box1 = np.exp(2j * np.pi * np.outer(np.arange(n1 // 2 + 1), np.arange(s)) / n1).sum(1) / s ** 2
    return (spectrum * box0[:, None] * box1[None, :]).astype(np.complex64)


@lru_cache(maxsize=8)
def _fold_indices(fft_shape: tuple[int, int], s: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gather indices of the axis-1 fold: columns, direct mask, reversed rows."""
    m0, m1 = fft_shape[0] // s, fft_shape[1] // s
    half = fft_shape[1] // 2
    idx = np.arange(m1 // 2 + 1)[None, :] + m1 * np.arange(s)[:, None]  # (s, m1//2 + 1)
    direct = idx <= half
    cols = np.where(direct, idx, fft_shape[1] - idx)
    rows_rev = (-np.arange(m0)) % m0
    return cols, direct, rows_rev


def _fold_to_pixels(spectrum: np.ndarray, fft_shape: tuple[int, int], s: int
                    ) -> np.ndarray:
    """Decimate a (box-filtered) tile spectrum by s per axis; inverse FFT [camera px].

    The DFT of every s-th sample of a sequence of length n is the mean of the s
    aliases ``Z[j + r n / s]`` of its spectrum (the 1/s is in the kernel's spectrum).
    Along the half-spectrum axis an alias beyond n / 2 is the conjugate of the mirrored
    bin, at the mirrored row.
    """
    n0, n1 = fft_shape
    m0, m1 = n0 // s, n1 // s
    rows = spectrum.reshape(s, m0, spectrum.shape[1]).sum(axis=0)
    if s == 1:
        return irfft2(rows, s=(m0, m1))
    cols, direct, rows_rev = _fold_indices(fft_shape, s)
    mirrored = np.conj(rows[rows_rev])
    folded = np.zeros((m0, cols.shape[1]), np.complex64)
    for r in range(s):
        folded += np.where(direct[r], rows[:, cols[r]], mirrored[:, cols[r]])
    return irfft2(folded, s=(m0, m1))


def blur(radiance: np.ndarray, plan: BlurPlan) -> np.ndarray:
    """Depth-dependent disc blur (scatter) of a supersampled radiance image, then the
    pixel integration (mean of each pixel's s x s supersamples).

    Parameters
    ----------
    radiance : (H, W) float32
        Light leaving every supersample of the tile with its halo [e-].
    plan : BlurPlan
        The tile's items (:func:`blur_plan`).

    Returns
    -------
    ((H - 2 margin) / s, (W - 2 margin) / s) float32
        The blurred image's pixel means on the tile's core [e-].
    """
    rows, cols = plan.core
    s = plan.supersampling
    r0, c0 = rows.start // s, cols.start // s
    n_rows, n_cols = (rows.stop - rows.start) // s, (cols.stop - cols.start) // s
    if plan.summed:
        spectrum = None
        for weight, kernel_fft in plan.summed:
            term = rfft2(radiance * weight, s=plan.fft_shape)
            term *= kernel_fft
            spectrum = term if spectrum is None else spectrum.__iadd__(term)
        out = _fold_to_pixels(spectrum, plan.fft_shape, s)[r0:r0 + n_rows, c0:c0 + n_cols]
        out = np.ascontiguousarray(out, np.float32)
    else:
        out = np.zeros((n_rows, n_cols), np.float32)
    if plan.crops:
        fine = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.float32)
        for crop in plan.crops:
            _add_crop(fine, radiance, crop, rows.start, cols.start)
        add_pixel_means(out, fine, s)
    return out


def _add_crop(out: np.ndarray, radiance: np.ndarray, crop: _Crop, r_core: int,
              c_core: int) -> None:
    """Convolve one bounding-box item and add what falls on the core into ``out``."""
    src = radiance[crop.rows, crop.cols] * crop.weight
    h = crop.half
    conv = irfft2(rfft2(src, s=crop.fft_shape) * crop.kernel_fft, s=crop.fft_shape)
    r0, c0 = crop.rows.start - h - r_core, crop.cols.start - h - c_core
    n_rows, n_cols = src.shape[0] + 2 * h, src.shape[1] + 2 * h
    rs = slice(max(r0, 0), min(r0 + n_rows, out.shape[0]))
    cs = slice(max(c0, 0), min(c0 + n_cols, out.shape[1]))
    if rs.start < rs.stop and cs.start < cs.stop:
        out[rs, cs] += conv[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0]
