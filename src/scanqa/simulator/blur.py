"""Camera defocus of the virtual scanner: a depth-dependent disc blur by layers.

Each supersample spreads over its own disc (docs/simulator.rst, step 4): the samples are
split between the two nearest diameters of a fine ladder (linear weights), each layer is
convolved with its disc convolved with the Airy PSF, and the layers are summed. There is
no partial occlusion of the aperture at depth edges.

How the sum is computed (the result is the same convolution either way, to float32
rounding): a layer that covers much of the tile is transformed at the tile's size and
its spectrum, times the kernel's, is added to one sum that one inverse transform brings
back (one forward FFT per layer and frame, one inverse per frame); a layer on a small
part of the tile (a block's top, a strip of a wall) is convolved on its own bounding
box. Only the tile's core (without its halo) is needed: a kernel no wider than the halo
cannot wrap round into the core, so the tile-size transform needs no padding then.
Images are float32 (a blurred level of 2e4 e- carries a rounding error of ~1e-3 e-
against a shot noise of ~140 e-).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.fft import irfft2, next_fast_len, rfft2

from scanqa.simulator.optics_kernels import camera_kernel

#: Blur-diameter ladder: linear steps up to _D_LIN, then geometric [supersamples].
_D_STEP, _D_LIN, _D_RATIO = 0.5, 4.0, 1.06
#: A layer whose own transform would cost more than this fraction of a tile-size
#: transform joins the spectral sum [-] (its forward FFT then costs the tile size, its
#: inverse nothing more).
_SUM_FRACTION = 0.5


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
    """A layer convolved on its own bounding box: weights and its kernel's FFT."""

    rows: slice
    cols: slice
    weight: np.ndarray
    half: int
    fft_shape: tuple[int, int]
    kernel_fft: np.ndarray


@dataclass(frozen=True)
class BlurPlan:
    """The layers of one tile, ready to blur every frame of it.

    ``summed`` holds (weight over the tile, kernel spectrum at ``fft_shape`` with the
    kernel's centre at the origin) of the layers summed in the frequency domain;
    ``crops`` the layers convolved on their bounding box; ``core`` the part of the tile
    whose blurred values are returned.
    """

    shape: tuple[int, int]
    core: tuple[slice, slice]
    fft_shape: tuple[int, int]
    summed: list
    crops: list


def _layer_samples(diameter: np.ndarray, hit: np.ndarray
                   ) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(ladder index, flat sample indices, weights) of every non-empty layer."""
    flat = np.flatnonzero(hit)
    if flat.size == 0:
        return []
    lam = layer_coord(diameter.ravel()[flat])
    i0 = np.floor(lam).astype(np.int64)
    frac = lam - i0
    order = np.argsort(i0.astype(np.int16), kind="stable")  # a radix sort: < 2**15 layers
    flat, i0, frac = flat[order], i0[order], frac[order]
    start = np.flatnonzero(np.diff(i0, prepend=i0[:1] - 1))  # i0 is sorted
    stop = np.append(start[1:], i0.size)
    levels = i0[start]
    parts: dict[int, list] = {}
    for lev, a, b in zip(levels.tolist(), start, stop, strict=True):
        parts.setdefault(lev, []).append((flat[a:b], 1.0 - frac[a:b]))
        parts.setdefault(lev + 1, []).append((flat[a:b], frac[a:b]))
    out = []
    for lev in sorted(parts):
        idx = np.concatenate([p[0] for p in parts[lev]])
        w = np.concatenate([p[1] for p in parts[lev]])
        keep = w > 1e-12
        if keep.any():
            out.append((lev, idx[keep], w[keep]))
    return out


def blur_plan(diameter: np.ndarray, hit: np.ndarray, airy: np.ndarray, margin: int
              ) -> BlurPlan:
    """Split the samples of a tile between ladder layers and prepare their kernels.

    Parameters
    ----------
    diameter : (H, W) float
        Blur diameter of every supersample [supersamples].
    hit : (H, W) bool
        Samples that see the scene (the others carry no light).
    airy : (k, k) float
        Diffraction PSF on the supersample grid.
    margin : int
        Width of the halo around the tile's core [supersamples].

    Returns
    -------
    BlurPlan
    """
    shape = hit.shape
    n_rows, n_cols = shape
    layers = []
    for lev, idx, w in _layer_samples(diameter, hit):
        kern = camera_kernel(layer_diameter(lev), airy)
        layers.append((kern, idx, w))
    half_max = max([k.shape[0] // 2 for k, _, _ in layers], default=0)
    pad = max(0, half_max - margin)
    fft_shape = (next_fast_len(n_rows + pad, real=True), next_fast_len(n_cols + pad, real=True))
    tile_cost = _fft_cost(fft_shape)
    summed, crops = [], []
    for kern, idx, w in layers:
        rr, cc = np.divmod(idx, n_cols)
        rows = slice(int(rr.min()), int(rr.max()) + 1)
        cols = slice(int(cc.min()), int(cc.max()) + 1)
        crop_shape = tuple(next_fast_len(n + kern.shape[0] - 1, real=True)
                           for n in (rows.stop - rows.start, cols.stop - cols.start))
        if _fft_cost(crop_shape) > _SUM_FRACTION * tile_cost:
            weight = np.zeros(shape, np.float32)
            weight.flat[idx] = w
            summed.append((weight, _centred_kernel_fft(kern, fft_shape)))
        else:
            weight = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.float32)
            weight[rr - rows.start, cc - cols.start] = w
            crops.append(_Crop(rows, cols, weight, kern.shape[0] // 2, crop_shape,
                               rfft2(kern.astype(np.float32), s=crop_shape)))
    core = (slice(margin, n_rows - margin), slice(margin, n_cols - margin))
    return BlurPlan(shape, core, fft_shape, summed, crops)


def _fft_cost(shape: tuple[int, int]) -> float:
    """Relative cost of a real 2-D FFT of ``shape`` (n log n) [-]."""
    n = float(shape[0] * shape[1])
    return n * np.log2(max(n, 2.0))


def _centred_kernel_fft(kern: np.ndarray, fft_shape: tuple[int, int]) -> np.ndarray:
    """Spectrum of a kernel placed with its centre at index (0, 0) (wrapped round)."""
    half = kern.shape[0] // 2
    padded = np.zeros(fft_shape, np.float32)
    padded[:kern.shape[0], :kern.shape[1]] = kern
    return rfft2(np.roll(padded, (-half, -half), axis=(0, 1)))


def blur(radiance: np.ndarray, plan: BlurPlan) -> np.ndarray:
    """Depth-dependent disc blur (scatter) of a supersampled radiance image.

    Parameters
    ----------
    radiance : (H, W) float32
        Light leaving every supersample of the tile with its halo [e-].
    plan : BlurPlan
        The tile's layers (:func:`blur_plan`).

    Returns
    -------
    (H - 2 margin, W - 2 margin) float32
        The blurred image on the tile's core [e-].
    """
    rows, cols = plan.core
    if plan.summed:
        spectrum = None
        for weight, kernel_fft in plan.summed:
            term = rfft2(radiance * weight, s=plan.fft_shape)
            term *= kernel_fft
            spectrum = term if spectrum is None else spectrum.__iadd__(term)
        out = irfft2(spectrum, s=plan.fft_shape)[rows, cols]
    else:
        out = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.float32)
    for crop in plan.crops:
        _add_crop(out, radiance, crop, rows.start, cols.start)
    return out


def _add_crop(out: np.ndarray, radiance: np.ndarray, crop: _Crop, r_core: int,
              c_core: int) -> None:
    """Convolve one bounding-box layer and add what falls on the core into ``out``."""
    src = radiance[crop.rows, crop.cols] * crop.weight
    h = crop.half
    conv = irfft2(rfft2(src, s=crop.fft_shape) * crop.kernel_fft, s=crop.fft_shape)
    r0, c0 = crop.rows.start - h - r_core, crop.cols.start - h - c_core
    n_rows, n_cols = src.shape[0] + 2 * h, src.shape[1] + 2 * h
    rs = slice(max(r0, 0), min(r0 + n_rows, out.shape[0]))
    cs = slice(max(c0, 0), min(c0 + n_cols, out.shape[1]))
    if rs.start < rs.stop and cs.start < cs.stop:
        out[rs, cs] += conv[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0]
