"""The Gray code of a capture, read from its frames (part of ``scanqa describe``).

A run of binary frames (:mod:`scanqa.decoding.frames`) is read as a Gray code: bits
and inverse frames from the anti-correlated pairs (interleaved or grouped), the bit
order from the stripe density (coarse bits first), the inverse frames' place from
which reading gives neighbouring cells to neighbouring pixels; the cell width from the
projector size, the bits and the cells seen (:func:`cell_width`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from scanqa.decoding import frames as fr


@dataclass(frozen=True)
class GrayRun:
    """A Gray run read as a code: bit frames MSB first, inverse frames, layout."""

    run: fr.Run
    bits: int
    inverse: str
    order: tuple  # frame indices in the file order the decoder reads


def gray_layout(norm: fr.Normalised, grays: list, axis: int, group,
                 notes: dict) -> GrayRun:
    """Bits, inverse layout and bit order of the first Gray run."""
    run = grays[0]
    frames = list(run.frames)
    corr = fr.correlations(norm, frames)
    count = len(frames)
    half = count // 2
    inverse = "none"
    if count % 2 == 0 and _paired([corr[2 * i, 2 * i + 1] for i in range(half)]):
        inverse = "interleaved"
    elif count % 2 == 0 and _paired([corr[i, i + half] for i in range(half)]):
        inverse = "grouped"
    bits = count if inverse == "none" else half
    plain = {"none": frames, "interleaved": frames[0::2], "grouped": frames[:half]}[inverse]
    edges = [fr.gradient_energy(norm.n[k], norm.lit)[1 - axis] for k in plain]
    rising = np.polyfit(np.arange(bits), edges, 1)[0] >= 0 if bits > 1 else True
    if not rising:  # least significant bit first: list the files MSB first
        group.notes.append("the Gray bits come least significant first (their stripes get "
                           "coarser frame by frame); the files are listed MSB first")
    order = _gray_order(frames, inverse, rising)
    return GrayRun(run, bits, inverse, tuple(order))


def _paired(corr: list[float]) -> bool:
    """Bits and inverses: every pair anti-correlated, most of them strongly (the finest
    bits may be washed out by the projector's blur)."""
    return bool(max(corr) < -0.2 and np.median(corr) < -0.6)


def _gray_order(frames: list, inverse: str, msb_first: bool) -> list:
    """Frame indices in the decoder's order (MSB first, the layout kept)."""
    half = len(frames) // 2
    if inverse == "none":
        return frames if msb_first else frames[::-1]
    if inverse == "interleaved":
        pairs = [frames[2 * i:2 * i + 2] for i in range(half)]
        pairs = pairs if msb_first else pairs[::-1]
        return [k for p in pairs for k in p]
    plain, inv = frames[:half], frames[half:]
    return plain + inv if msb_first else plain[::-1] + inv[::-1]


def _gray_cells(data: np.ndarray, norm: fr.Normalised, gray: GrayRun,
                binary_code: bool = False) -> np.ndarray:
    """Cell index of every pixel from the Gray frames (NaN where unlit) [cells]; with
    ``binary_code`` the bits are read as a plain binary number instead."""
    plain, inv = _bit_frames(gray)
    if inv is not None:
        bits = [data[p] > data[q] for p, q in zip(plain, inv, strict=True)]
    else:
        bits = [norm.n[p] > 0.5 for p in plain]
    code = np.zeros(data.shape[1:], np.int64)
    binary = np.zeros_like(code)
    for b in bits:  # reflected Gray to binary: b_i = g_i xor b_(i-1)
        binary = b.astype(np.int64) if binary_code else binary ^ b.astype(np.int64)
        code = (code << 1) | binary
    return np.where(norm.lit, code.astype(np.float64), np.nan)


def _bit_frames(gray: GrayRun) -> tuple[list, list | None]:
    """Frame indices of the bits and of their inverses (None without inverses)."""
    order = list(gray.order)
    if gray.inverse == "interleaved":
        return order[0::2], order[1::2]
    if gray.inverse == "grouped":
        return order[:gray.bits], order[gray.bits:]
    return order, None


def _smoothness(cells: np.ndarray, axis: int) -> float:
    """How well the cells follow the camera coordinate along ``axis``: the absolute
    correlation of the two over the lit pixels [-] (about 1 for the right reading, of
    any scene that does not fold back; lower for a misread code, whose cell order is
    scrambled)."""
    coord = np.broadcast_to(np.arange(cells.shape[axis], dtype=float).reshape(
        (-1, 1) if axis == 0 else (1, -1)), cells.shape)
    ok = np.isfinite(cells)
    if ok.sum() < 10 or np.std(cells[ok]) == 0:
        return 0.0
    return float(abs(np.corrcoef(cells[ok], coord[ok])[0, 1]))


def read_gray(data, norm, gray: GrayRun, axis: int, group) -> tuple:
    """The Gray code's cells, with the inverse frames first when that reads smoother;
    a code that reads smoother as plain binary is asked about."""
    cells = _gray_cells(data, norm, gray)
    if gray.inverse != "none":
        plain, inv = _bit_frames(gray)
        order = ([k for pair in zip(inv, plain, strict=True) for k in pair]
                 if gray.inverse == "interleaved" else inv + plain)
        swapped = replace(gray, order=tuple(order))
        other = _gray_cells(data, norm, swapped)
        if _smoothness(other, axis) > _smoothness(cells, axis) + 0.05:
            group.notes.append("each Gray bit's inverse frame comes before the bit (the "
                               "code reads as neighbouring cells only that way)")
            gray, cells = swapped, other
    if _smoothness(_gray_cells(data, norm, gray, True), axis) > \
            _smoothness(cells, axis) + 0.05:
        group.questions.append("the binary frames read more smoothly as a plain binary "
                               "code than as a reflected Gray code, which is all the "
                               "decoder reads: is it a binary code?")
    return gray, cells


def slope_sign(cells: np.ndarray, lit: np.ndarray, axis: int) -> float:
    """+1 when the cell index grows along the camera axis, -1 when it falls."""
    d = np.diff(cells, axis=axis)
    d = d[np.isfinite(d) & (np.abs(d) <= 2)]
    return 1.0 if d.sum() >= 0 else -1.0



def cells_seen(cells: np.ndarray, count: int) -> tuple[int, bool]:
    """Cells up to the last well-populated one, and whether the panel's edge was seen.

    At the panel's far edge the last cell is a full line of pixels across the image (as
    many as a typical cell); at an object's silhouette the last cells thin out.
    """
    codes = cells[np.isfinite(cells)].astype(np.int64)
    if codes.size == 0:
        return count, False
    hist = np.bincount(codes, minlength=count)
    typical = float(np.median(hist[hist > 0]))
    top = int(np.flatnonzero(hist >= 0.1 * typical).max())
    edge = top + 1 < count and hist[max(top - 1, 0):top + 1].sum() >= 0.5 * typical
    return top + 1, bool(edge)


def cell_width(width: int, bits: int, seen: int, edge: bool, group) -> tuple[float, str]:
    """Cell width from the panel size, the bits and the cells seen [px], and why."""
    count = 2 ** bits
    lo, hi = width / count, width / (count / 2)
    whole = [c for c in range(max(1, math.ceil(lo - 1e-9)), math.floor(hi) + 1)
             if lo - 1e-9 <= c < hi and c <= width / seen * 1.02]
    evidence = (f"{bits} bits cover {width} px with cells of {lo:.4g} to {hi:.4g} px; "
                f"cells 0..{seen - 1} seen")
    if edge and width / seen >= lo - 1e-9:
        target = width / seen  # the panel's edge seen: the cells fill the width
        cell = min(whole, key=lambda c: abs(c - target)) if whole else target
        return float(cell), evidence + ", the last one at the panel's edge"
    if not whole:
        return lo, evidence
    cell = float(whole[0])
    if len(whole) > 1:
        others = ", ".join(f"{c:g}" for c in whole[1:])
        group.questions.append(
            f"cell_px = {cell:g} is the finest whole-pixel cell that covers the {width} px "
            f"with {bits} bits; the panel's edge was not seen, and cells of {others} px "
            f"would fit the {seen} cells seen too - which one was projected?")
    return cell, evidence
