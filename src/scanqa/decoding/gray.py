"""Gray-code bits to cell indices, with a per-pixel threshold and decidability.

Each bit frame is compared with a threshold that is measured at the same pixel: its
inverse frame, the mid level of the white and black reference frames, or the offset A
of the phase set it orders. The difference must exceed ``gray_min_contrast_sigma``
times its predicted noise, else the bit - and the pixel - is undecidable (dark, in
shadow, or on a cell edge blurred to grey). Bits come most significant first and are
decoded as the reflected binary code: ``b_i = b_(i-1) xor g_i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanqa.decoding.coding import GrayCodeSet, ReferenceSet, SensorModel
from scanqa.decoding.demodulate import sample_variance


@dataclass(frozen=True, eq=False)
class GrayDecode:
    """Decoded Gray code of a chunk of pixels.

    Attributes
    ----------
    cell : (M,) int64
        Cell index [-].
    undecidable : (M,) bool
        Some bit's contrast is below the noise threshold.
    mid_dn : (M,) float64
        Threshold level (mid grey) [DN].
    contrast_dn : (M,) float64
        Half the contrast of the weakest bit, |bit - threshold| [DN].
    """

    cell: np.ndarray
    undecidable: np.ndarray
    mid_dn: np.ndarray
    contrast_dn: np.ndarray


def reference_levels(ref: ReferenceSet, frames: np.ndarray, sensor: SensorModel,
                     quantised: bool) -> tuple[np.ndarray, np.ndarray]:
    """Mid level of white and black, and its variance, per pixel.

    Parameters
    ----------
    ref : ReferenceSet
        Says which frame is white and which black.
    frames : (n, M) array
        The reference frames of a chunk [DN].
    sensor : SensorModel
        Resolved noise model.
    quantised : bool
        Integer images.

    Returns
    -------
    mid, variance : (M,) float64
        ``(mean white + mean black) / 2`` [DN] and its variance [DN^2].
    """
    f = frames.astype(np.float64)
    white = np.array([v == "white" for v in ref.levels])
    w, b = f[white].mean(axis=0), f[~white].mean(axis=0)
    var = (sample_variance(w, sensor, quantised) / white.sum()
           + sample_variance(b, sensor, quantised) / (~white).sum()) / 4.0
    return 0.5 * (w + b), var


def decode_gray(gray: GrayCodeSet, frames: np.ndarray, sensor: SensorModel,
                quantised: bool, min_sigma: float,
                threshold: tuple[np.ndarray, np.ndarray] | None = None) -> GrayDecode:
    """Cell index of every pixel of a chunk.

    Parameters
    ----------
    gray : GrayCodeSet
        Bits and frame layout.
    frames : (frames, M) array
        The set's frames [DN].
    sensor : SensorModel
        Resolved noise model.
    quantised : bool
        Integer images.
    min_sigma : float
        Smallest accepted contrast of a bit in noise standard deviations [-].
    threshold : (mid, variance), optional
        Per-pixel threshold [DN] and its variance [DN^2]; required unless the set has
        inverse frames (which are then the threshold).

    Returns
    -------
    GrayDecode
        Cells, undecidable pixels, threshold and weakest contrast.
    """
    f = frames.astype(np.float64)
    plain, inverse = gray.frame_order()
    bits = f[plain]
    var = sample_variance(bits, sensor, quantised)
    if inverse is not None:
        diff = bits - f[inverse]
        var = var + sample_variance(f[inverse], sensor, quantised)
        mid = 0.5 * (bits + f[inverse]).mean(axis=0)
    else:
        mid, mid_var = threshold
        diff = bits - mid
        var = var + mid_var
    undecidable = (diff * diff < min_sigma * min_sigma * var).any(axis=0)
    return GrayDecode(_cells(diff > 0), undecidable, mid, np.abs(diff).min(axis=0))


def _cells(bits: np.ndarray) -> np.ndarray:
    """(M,) cell index of reflected-Gray bit planes (bits, M), most significant first."""
    binary = np.zeros(bits.shape[1], bool)
    cell = np.zeros(bits.shape[1], np.int64)
    for bit in bits:
        binary ^= bit
        cell = (cell << 1) | binary
    return cell
