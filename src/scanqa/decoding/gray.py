"""Gray-code bits to cell indices, with a per-pixel threshold and decidability.

Each bit frame is compared with a threshold that is measured at the same pixel: its
inverse frame, the mid level of the white and black reference frames, or the offset A
of the phase set it orders. The difference must exceed ``gray_min_contrast_sigma``
times its predicted noise, else the bit is undecidable (dark, in shadow, or on a cell
edge blurred to grey). Bits come most significant first and are decoded as the
reflected binary code, ``b_i = b_(i-1) xor g_i``, or as a plain binary number
(``code = "binary"``).

The edge rule. Every physical edge between two neighbouring cells flips exactly one bit
of a reflected Gray code, so a pixel that sees such an edge blurred to grey has exactly
one undecidable bit, and its two candidate codes (that bit 0 or 1) are the adjacent
cells k and k + 1. Such a pixel is an *edge pixel*: it lies in cell k or k + 1, and the
decoder (:mod:`scanqa.decoding.unwrap`) puts it on their shared edge. Any other pixel
with an undecidable bit - several undecidable bits (dark, shadow), or one whose two
candidates are not neighbours (the bit's grey level is not explained by an edge at
this pixel) - is undecidable.
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
        Cell index [-]; for an edge pixel the lower of its two cells, k.
    undecidable : (M,) bool
        Some bit's contrast is below the noise threshold, and the pixel is not an
        edge pixel.
    edge : (M,) bool
        Edge pixel: exactly one bit undecidable, and its two candidate cells are
        ``cell`` and ``cell + 1``; the pixel lies in one of the two, x_p at their edge.
    mid_dn : (M,) float64
        Threshold level (mid grey) [DN].
    contrast_dn : (M,) float64
        Half the contrast of the weakest bit the cell rests on, |bit - threshold|
        (an edge pixel's undecidable bit left out) [DN].
    span : (M,) int64
        Number of cells the pixel may lie in, starting at ``first`` [-]: 1 where every
        bit is decided, 2 for an edge pixel, else the aligned block of ``2**(j + 1)``
        cells that the undecidable bits can reach (j the most significant undecidable
        bit, counted from the least significant one: flipping reflected-Gray bit j
        changes the cell within that block only).
    first : (M,) int64
        First cell of the span [-].
    """

    cell: np.ndarray
    undecidable: np.ndarray
    edge: np.ndarray
    mid_dn: np.ndarray
    contrast_dn: np.ndarray
    span: np.ndarray
    first: np.ndarray


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
        Cells, undecidable and edge pixels, threshold and weakest contrast.
    """
    diff, var, mid = _bit_contrast(gray, frames, sensor, quantised, threshold)
    weak = diff * diff < min_sigma * min_sigma * var
    cell, edge = _edge_rule(diff > 0, weak, gray.code == "binary")
    magnitude = np.abs(diff)
    contrast = np.where(weak & edge, np.inf, magnitude).min(axis=0)
    contrast = np.where(np.isfinite(contrast), contrast, magnitude.min(axis=0))
    first, span = _spans(cell, edge, weak)
    return GrayDecode(cell, weak.any(axis=0) & ~edge, edge, mid, contrast, span, first)


def _bit_contrast(gray: GrayCodeSet, frames: np.ndarray, sensor: SensorModel,
                  quantised: bool, threshold) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each bit frame against its inverse (or the reference threshold): the difference
    [DN], its variance [DN^2] and the mid level [DN] per pixel."""
    f = frames.astype(np.float64)
    plain, inverse = gray.frame_order()
    bits = f[plain]
    var = sample_variance(bits, sensor, quantised)
    if inverse is not None:
        var = var + sample_variance(f[inverse], sensor, quantised)
        return bits - f[inverse], var, 0.5 * (bits + f[inverse]).mean(axis=0)
    mid, mid_var = threshold
    return bits - mid, var + mid_var, mid


def _spans(cell: np.ndarray, edge: np.ndarray, weak: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """First cell and number of cells each pixel may lie in, from its undecidable bits.

    The decided bits above the most significant undecidable bit j (counted from the
    least significant, 0) fix the aligned block ``cell >> (j + 1)`` of ``2**(j + 1)``
    cells; the bits below it do not leave the block. An edge pixel's span is its two
    neighbouring cells.
    """
    n = weak.shape[0]
    anyweak = weak.any(axis=0)
    j = np.where(anyweak, n - 1 - np.argmax(weak, axis=0), -1).astype(np.int64)
    first = (cell >> (j + 1)) << (j + 1)
    span = np.left_shift(np.int64(1), j + 1)
    return np.where(edge, cell, first), np.where(edge, 2, span)


def _edge_rule(bits: np.ndarray, weak: np.ndarray, binary: bool = False
               ) -> tuple[np.ndarray, np.ndarray]:
    """(M,) cells and edge pixels of bit planes (bits, M) with undecidable bits ``weak``.

    An edge pixel has one weak bit, and its cell with that bit flipped is a neighbour;
    its cell is then the lower of the two. Flipping Gray bit i (most significant first)
    flips binary bit i and all below it, so the two candidates are neighbours only where
    those binary bits read 10...0 or 01...1 (always for the least significant bit). In a
    plain binary code (``binary``) only the least significant bit's flip gives a
    neighbour; the edges where several bits flip at once leave several bits weak, and
    such pixels keep the span of cells those bits reach (:func:`_spans`).
    """
    cell = _cells(bits, binary)
    single = np.flatnonzero(weak.sum(axis=0) == 1)
    other = _cells(bits[:, single] ^ weak[:, single], binary)
    adjacent = np.abs(other - cell[single]) == 1
    single, other = single[adjacent], other[adjacent]
    cell[single] = np.minimum(cell[single], other)
    edge = np.zeros(cell.shape, bool)
    edge[single] = True
    return cell, edge


def _cells(bits: np.ndarray, plain: bool = False) -> np.ndarray:
    """(M,) cell index of reflected-Gray bit planes (bits, M), most significant first;
    of plain binary bit planes with ``plain``."""
    binary = np.zeros(bits.shape[1], bool)
    cell = np.zeros(bits.shape[1], np.int64)
    for bit in bits:
        if plain:
            binary = bit
        else:
            binary ^= bit
        cell = (cell << 1) | binary
    return cell


#: Share of lit pixels at which a bit must be decidable to be kept: in a Gray code that
#: orders a phase (the phase gives the precision, a barely resolved bit only adds
#: readings of noise), and in a Gray code decoded alone (a bit is kept while it decides
#: anything: each pixel it decides gets half the cell) [-].
RESOLVED_SHARE = {"ordering": 0.5, "alone": 0.05}


def bit_resolution(gray: GrayCodeSet, frames: np.ndarray, sensor: SensorModel,
                   quantised: bool, min_sigma: float,
                   threshold: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """How well the optics resolve every bit, over the lit pixels.

    Parameters
    ----------
    gray, frames, sensor, quantised, min_sigma, threshold
        As for :func:`decode_gray` (a sample of the pixels is enough).

    Returns
    -------
    share : (bits,) float64
        Share of the lit pixels (the most significant bit decidable) where the bit is
        decidable: its contrast exceeds ``min_sigma`` noise standard deviations [-].
    contrast : (bits,) float64
        Median contrast ``|bit - threshold|`` relative to the most significant bit's [-].
        Both NaN where no pixel is lit.

    Notes
    -----
    The most significant bit's stripes are half the panel wide, so no projector blur
    greys them; a finer bit's contrast falls with its stripe width as the blur's
    transfer function does, and where it falls below the noise the bit reads noise.
    """
    diff, var, _ = _bit_contrast(gray, frames, sensor, quantised, threshold)
    decidable = diff * diff > min_sigma * min_sigma * var
    lit = decidable[0]
    if not lit.any():
        return np.full(gray.bits, np.nan), np.full(gray.bits, np.nan)
    magnitude = np.median(np.abs(diff[:, lit]), axis=1)
    return decidable[:, lit].mean(axis=1), magnitude / magnitude[0]


def resolved_bits(share: np.ndarray, least: float) -> int:
    """How many of the most significant bits to decode: the finest bits decidable at
    fewer than ``least`` of the lit pixels (:func:`bit_resolution`) are dropped [-]."""
    keep = len(share)
    while keep > 1 and share[keep - 1] < least:
        keep -= 1
    return keep
