"""The Gray code of a capture, read from its frames (part of ``scanqa describe``).

A run of binary frames (:mod:`scanqa.description.frames`) is read as a Gray code: bits
and inverse frames from the anti-correlated pairs (interleaved or grouped), the bit
order from the stripe density (coarse bits first), the inverse frames' place from
which reading gives neighbouring cells to neighbouring pixels; the cell width from the
projector size, the bits and the cells seen (:func:`cell_width`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from scanqa.decoding.coding import GrayCodeSet
from scanqa.description import frames as fr


@dataclass(frozen=True)
class GrayRun:
    """A Gray run read as a code: bit frames MSB first, inverse frames, layout."""

    run: fr.Run
    bits: int
    inverse: str
    order: tuple  # frame indices in the file order the decoder reads
    code: str = "reflected"  # or "binary": the likelier reading (decoding checks both)


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
    """The Gray code's cells, read in the smoothest of up to four ways: each bit before
    or after its inverse frame, as a reflected Gray code or a plain binary number
    (``code = "binary"``); a later reading must be clearly smoother (by 0.05) to be
    taken. Describe then decodes both codes to choose."""
    readings = [gray]
    if gray.inverse != "none":
        plain, inv = _bit_frames(gray)
        order = ([k for pair in zip(inv, plain, strict=True) for k in pair]
                 if gray.inverse == "interleaved" else inv + plain)
        readings.append(replace(gray, order=tuple(order)))
    best, cells, score = gray, None, -1.0
    for reading in readings:
        for code in ("reflected", "binary"):
            got = _gray_cells(data, norm, reading, code == "binary")
            smooth = _smoothness(got, axis)
            if cells is None or smooth > score + 0.05:
                best, cells, score = replace(reading, code=code), got, smooth
    if best.order != gray.order:
        group.notes.append("each Gray bit's inverse frame comes before the bit (the "
                           "code reads as neighbouring cells only that way)")
    return best, cells


def slope_sign(cells: np.ndarray, lit: np.ndarray, axis: int) -> float:
    """+1 when the cell index grows along the camera axis, -1 when it falls."""
    d = np.diff(cells, axis=axis)
    d = d[np.isfinite(d) & (np.abs(d) <= 2)]
    return 1.0 if d.sum() >= 0 else -1.0



def cells_seen(cells: np.ndarray, count: int) -> int:
    """Index of the last well-populated cell (a cell index that exists on the panel)."""
    codes = cells[np.isfinite(cells)].astype(np.int64)
    if codes.size == 0:
        return 0
    hist = np.bincount(codes, minlength=count)
    typical = float(np.median(hist[hist > 0]))
    return int(np.flatnonzero(hist >= 0.1 * typical).max())


def panel_edge_seen(cells: np.ndarray, top: int, axis: int) -> bool:
    """True when the light ends at the panel's far edge in view: the last (or first)
    lit pixel of 90 % of the image lines along ``axis`` lies in cell ``top`` - a
    straight line in projector coordinates, where an object's silhouette cuts the
    cells anywhere."""
    c = np.moveaxis(cells, axis, -1).reshape(-1, cells.shape[axis])
    lit = np.isfinite(c)
    lines = lit.any(axis=1)
    if lines.sum() < 10:
        return False
    c, lit = c[lines], lit[lines]
    n = lit.shape[1]
    last = n - 1 - np.argmax(lit[:, ::-1], axis=1)
    first = np.argmax(lit, axis=1)
    rows = np.arange(c.shape[0])
    return bool(max(np.mean(c[rows, last] == top), np.mean(c[rows, first] == top)) >= 0.9)


def cell_range(width: int, bits: int, top: int, edge: bool = False) -> tuple[float, float]:
    """Cell widths [px] that need every bit to cover ``width`` (``2**bits`` cells
    cover it, ``2**(bits-1)`` do not) and put cell ``top`` on the panel: [lo, hi);
    with the panel's far edge seen in cell ``top``, the cells that end there."""
    lo, hi = width / 2 ** bits, width / 2 ** (bits - 1)
    if top > 0:
        hi = min(hi, width / top * 1.001)
        if edge:
            lo = max(lo, width / (top + 1) * 0.999)
    return lo, hi


def roundness(value: int) -> int:
    """Trailing zeros of a whole number in decimal [-] (100 is rounder than 96)."""
    count = 0
    while value and value % 10 == 0:
        value //= 10
        count += 1
    return count


def rank_cells(ranges: list[tuple[int, tuple[float, float]]]) -> list[int]:
    """Whole-pixel cell widths that fit every (width, range) given, likeliest first.

    The same cell is assumed in every direction given (one tool setting). Cells that
    divide every coded width (the cells fill the panel, as a DLP's or OpenCV's step)
    come first, the finest of them first; then the roundest (a tool's setting such as
    100 px), then the finest.
    """
    lo = max(r[0] for _, r in ranges)
    hi = min(r[1] for _, r in ranges)
    whole = [c for c in range(max(1, math.ceil(lo - 1e-9)), math.ceil(hi - 1e-9))
             if lo - 1e-9 <= c < hi]

    def key(c):
        divides = all(w % c == 0 for w, _ in ranges)
        return (not divides, 0 if divides else -roundness(c), c)
    return sorted(whole, key=key)


def simple_ratio(ratio: float, tolerance: float = 0.004) -> float:
    """``ratio`` snapped to the nearest fraction p/q with q <= 8 within ``tolerance``
    (relative), else unchanged (a period of 2/3 of a cell: 66.667 px for 100 px)."""
    best = ratio
    for q in range(1, 9):
        p = round(ratio * q)
        if p and abs(p / q / ratio - 1) <= tolerance:
            return p / q
    return best


def edge_offsets(zs: list, signs: list, cells: np.ndarray, cell: float, periods: tuple,
                 axis: int) -> tuple:
    """Phase start of each phase set relative to the Gray code [rad]: the phase
    measured where the cell index steps by one between neighbouring pixels (at
    ``x = c cell - 1/2``, the edge of cell c) less the phase a set starting at x = 0
    has there, averaged as unit phasors (each edge of the code weighing the same,
    however many pixels see it); snapped to a multiple of pi / 6 within 0.1 rad (a
    projector's gamma biases the phase by a few hundredths), or of pi / 12 within
    0.04 rad. The decoder's phase of a set is ``2 pi x / P + offset``."""
    ok, m = cell_edges(cells, axis)
    if ok.sum() < 20:
        return tuple(0.0 for _ in zs)
    edge = m * cell - 0.5
    counts = np.bincount(m.astype(np.int64))
    weight = np.where(counts[m.astype(np.int64)] >= 10, 1.0 / counts[m.astype(np.int64)], 0.0)
    out = []
    for z, sign, period in zip(zs, signs, periods, strict=True):
        psi = sign * np.angle(_edge_phasor(z, ok, axis))
        theta = float(np.angle(np.sum(weight * np.exp(1j * (psi - 2 * np.pi * edge
                                                           / period)))))
        out.append(snapped(theta))
    return tuple(out)


def cue_offsets(zs: list, signs: list, periods: tuple, width: int, usable: np.ndarray,
                memo: dict | None = None) -> tuple:
    """Phase start of each phase set relative to a cue [rad], for phase sets without a
    Gray code: the coarsest set, when its period covers the coded width, starts at 0
    (it defines x = 0: nothing in the frames tells its own start) and gives each pixel
    x; a finer set's start is its phase less ``2 pi x / P`` there, averaged as unit
    phasors over the usable pixels (a whole number of its periods fits the cue's, so
    the cue's wrap does not matter), snapped as :func:`edge_offsets` snaps. Zeros
    without a cue, or where the average is weak (resultant below 0.5).

    ``memo``, a dict shared by the calls for one ``zs``, ``signs`` and ``usable`` (the
    candidate periods of one direction), keeps the unit phasors and each start once
    computed: a start depends on the periods only through the cue and its ratio."""
    if not zs or usable.sum() < 20:
        return tuple(0.0 for _ in zs)
    cue = int(np.argmax(periods))
    if periods[cue] < width:
        return tuple(0.0 for _ in zs)
    memo = {} if memo is None else memo
    if "unit" not in memo:
        memo["unit"] = [np.exp(1j * sign * np.angle(z[usable]))
                        for z, sign in zip(zs, signs, strict=True)]
    unit = memo["unit"]
    out = []
    for i, period in enumerate(periods):
        ratio = periods[cue] / period
        if i == cue or abs(ratio - round(ratio)) > 1e-6:
            out.append(0.0)
            continue
        key = (i, cue, round(ratio))
        if key not in memo:
            diff = unit[i] * np.conj(unit[cue]) ** round(ratio)
            mean = np.mean(diff)
            memo[key] = (snapped(float(np.angle(mean)), _spread(diff, unit[cue]))
                         if abs(mean) >= 0.5 else 0.0)
        out.append(memo[key])
    return tuple(out)


def _spread(diff: np.ndarray, cue: np.ndarray, parts: int = 4) -> float:
    """How far the start measured on each quarter of the cue's period strays from the
    whole's [rad]: the cue's own distortion (a projector's gamma on one wide period)
    biases each part differently, and a start no larger than that is not told apart
    from the nearest usual one."""
    whole = np.angle(np.mean(diff))
    order = np.argsort(np.angle(cue))
    return max(abs(float(np.angle(np.mean(diff[p]) * np.exp(-1j * whole))))
               for p in np.array_split(order, parts) if p.size)


def snapped(theta: float, spread: float = 0.0, within: float = 0.1) -> float:
    """A phase start snapped to a multiple of pi / 6 within ``within`` [rad] (0.1: a
    projector's gamma biases the phase at the cell edges by a few hundredths) or within
    ``spread`` [rad], what the parts of the measurement disagree by, or of pi / 12
    within 0.04 rad (or ``within``, if less), else rounded to 1 mrad; 0 for a start
    within 1e-12 of it."""
    for step, near in ((np.pi / 6, max(within, spread)), (np.pi / 12, min(0.04, within))):
        snap = round(theta / step) * step
        if abs(snap - theta) <= near:  # the usual starts: multiples of 30 degrees
            theta = snap
            break
    else:
        theta = round(theta, 3)
    return 0.0 if abs(theta) < 1e-12 else theta


def cell_edges(cells: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour pairs along ``axis`` whose cell index steps by one, and the index of
    the cell to the right of each edge (the edge lies at ``m cell - 1/2``)."""
    c = np.moveaxis(cells, axis, -1)
    a, b = c[..., :-1], c[..., 1:]
    ok = np.isfinite(a) & np.isfinite(b) & (np.abs(b - a) == 1)
    return ok, np.maximum(a, b)[ok]


def _edge_phasor(z: np.ndarray, ok: np.ndarray, axis: int) -> np.ndarray:
    """Unit phasors of the two pixels of each edge pair, added."""
    zz = np.moveaxis(z, axis, -1)
    za, zb = zz[..., :-1][ok], zz[..., 1:][ok]
    return za / np.maximum(np.abs(za), 1e-9) + zb / np.maximum(np.abs(zb), 1e-9)


def refine_ratio(z: np.ndarray, cells: np.ndarray, axis: int, guess: float) -> float:
    """A phase set's period in Gray cells [cells], refined from the phase at the cell
    edges: the period whose fringes best line up with the edges (the largest
    ``|sum exp(i (phi_e -+ 2 pi m_e / r))|`` over r within 15 % of ``guess``, either
    sign of the shifts); ``guess`` when there are too few edges.

    The score of every r is first summed per cell edge (the edges of one cell share
    ``m_e``: ``sum_m exp(-2 pi i m / r) sum_(e in m) exp(i phi_e)``, a few hundred terms
    for tens of thousands); the edge-by-edge sum is then computed for the r that come
    within a rounding margin of the best, and the first best of those taken, so the
    result is the edge-by-edge search's to the last bit.
    """
    ok, m = cell_edges(cells, axis)
    if ok.sum() < 20 or not guess > 0:
        return guess
    if m.size > 20000:
        pick = np.linspace(0, m.size - 1, 20000).astype(int)
    else:
        pick = slice(None)
    phi = np.angle(_edge_phasor(z, ok, axis))[pick]
    mm = m[pick].astype(np.int64)
    counts = np.bincount(mm)
    weight = np.where(counts[mm] >= 10, 1.0 / counts[mm], 0.0)  # each edge counts once
    if np.count_nonzero(counts >= 10) < 3:
        return guess

    def exact(r, sign):
        return abs(np.sum(weight * np.exp(1j * (sign * phi - 2 * np.pi * mm / r))))

    # per edge: the weighted sum of its pixels' unit phasors, for either sign
    edges = np.flatnonzero(counts >= 10)
    per_edge = (np.bincount(mm, np.cos(phi), edges[-1] + 1)[edges]
                + 1j * np.bincount(mm, np.sin(phi), edges[-1] + 1)[edges]) / counts[edges]
    both = np.stack([per_edge, np.conj(per_edge)], axis=1)  # sign +1, -1
    margin = 1e-7 * edges.size  # far above the two sums' rounding apart
    best, score = guess, -1.0
    for grid in (guess * np.linspace(0.85, 1.15, 601), None):
        if grid is None:
            grid = np.linspace(best * 0.9995, best * 1.0005, 41)
        fast = np.abs(np.exp(-2j * np.pi * edges[None, :] / grid[:, None]) @ both).ravel()
        if not np.all(np.isfinite(fast)):  # no shortcut: every r edge by edge
            near = range(fast.size)
        else:
            near = np.flatnonzero(fast >= fast.max() - 2 * margin)
        for i in near:  # in grid order, +1 before -1: the first best kept
            r = grid[i // 2]
            v = exact(r, 1.0 if i % 2 == 0 else -1.0)
            if v > score:
                best, score = float(r), v
    return best


def confidence_line(best, share: float, tried: list, asked: int) -> str:
    """How sure a description is, in one line: "sure" (it decodes, nothing else fits),
    "likely" (it decodes, but a question is open) or "unsure" (it decodes little).

    ``best`` is the chosen PatternDescription, ``share`` its decoded share [-], ``tried``
    every (description, share) checked, ``asked`` the count of open questions.
    """
    others = [got for d, got in tried if d.sets != best.sets and periods_differ(d, best)]
    runner = max(others, default=-1.0)
    word = ("unsure" if share < 0.6 else "sure" if not asked and runner < 0.9 * share
            else "likely")
    said = f"{word}: {100 * share:.0f} % of the lit pixels of the sample decode"
    if runner >= 0:
        said += (f"; the next candidate checked ({len(tried)} in all) "
                 f"{100 * runner:.0f} %")
    return said + (f"; {asked} question(s) open" if asked else "")


def periods_differ(a, b) -> bool:
    """Another scale: a period or the cell width of description ``a`` differs from
    ``b``'s by more than 0.1 %."""
    pa = [s.period_px for s in a.phase_sets] + [a.gray_cell_px]
    pb = [s.period_px for s in b.phase_sets] + [b.gray_cell_px]
    return len(pa) != len(pb) or any(abs(x - y) > 1e-3 * max(abs(y), 1e-9)
                                      for x, y in zip(pa, pb, strict=True))


def with_code(desc):
    """The description with its Gray set read as the other code (reflected Gray or
    plain binary)."""
    other = {"reflected": "binary", "binary": "reflected"}
    return replace(desc, sets=tuple(replace(s, code=other[s.code])
                                    if isinstance(s, GrayCodeSet) else s
                                    for s in desc.sets))


def code_note(best, tried: list, gray: GrayRun, notes: list) -> None:
    """A note (appended to ``notes``) on how the Gray frames were read, reflected Gray or
    plain binary, with the share of the lit pixels each reading decoded (``tried``:
    (description, share) of every candidate)."""
    code = best.gray_set.code
    shares = {}
    for d, got in tried:
        c = d.gray_set.code
        shares[c] = max(shares.get(c, -1.0), got)
    first, last = gray.run.frames[0], gray.run.frames[-1]
    names = {"binary": "plain binary", "reflected": "reflected Gray"}
    both = " and ".join(f"{100 * max(v, 0):.0f} % as {names[c]}"
                        for c, v in sorted(shares.items()))
    if code == "binary":
        notes.append(f"frames {first}..{last} (indices) read as a plain binary code "
                     f"(code = \"binary\"), not a reflected Gray code: the lit pixels "
                     f"decode {both}")
    elif gray.code == "binary":
        notes.append(f"frames {first}..{last} (indices) read smoother as plain binary "
                     f"but decode better as a reflected Gray code ({both})")
