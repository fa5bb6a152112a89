"""Synthetic captures of a blurred projector for the decoder's closed loops (issue 26).

The images are made here from the formulas of the patterns, independently of the
decoder's own pattern definitions: a reflected Gray code of the projector columns (cells
of ``cell`` columns, bits most significant first, each followed by its inverse as
OpenCV's ``GrayCodePattern`` lays them out), a white and a black frame, and 3-step phase
sets ``0.5 (1 + cos(2 pi x / P + 2 pi k / 3))``. The projector's optics blur every
pattern by a Gaussian of ``blur`` projector px (the exact integral of each panel column
for the Gray code, the attenuation ``exp(-2 pi^2 blur^2 / P^2)`` for a sinusoid); the
camera adds Gaussian and shot noise and writes 8 bits. The scene is a smooth surface: x
grows along the camera rows, as in a scanner whose projector sits beside the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, PhaseSet, ReferenceSet

THREE = (0.0, 2 * math.pi / 3, 4 * math.pi / 3)


@dataclass(frozen=True)
class Rig:
    """What the synthetic scanner projects and how sharply [projector px, DN]."""

    width: int = 1000
    bits: int = 10
    cell: float = 1.0
    periods: tuple = (100.0, 66.667)
    blur: float = 1.2
    white: float = 200.0
    black: float = 20.0
    noise_dn: float = 1.5
    shape: tuple = (80, 320)
    box: float = 0.0  # width of a box blur of defocus [px]; 0: the Gaussian alone
    jump: float = 0.0  # a depth edge at the middle column: x_p jumps by this [px]
    albedo: float = 1.0  # the darkest row's reflectance, rising linearly to 1 [-]


def truth(rig: Rig, seed: int) -> np.ndarray:
    """(H, W) projector coordinate of a smooth, tilted surface with a bump [px]."""
    rng = np.random.default_rng(seed)
    h, w = rig.shape
    v, u = np.mgrid[0:h, 0:w].astype(float)
    span = rig.width - 40.0
    bump = rng.uniform(5.0, 25.0) * np.sin(2 * np.pi * (v / h + rng.uniform()))
    x = 20.0 + span * u / (w - 1) + bump * np.sin(np.pi * u / (w - 1))
    return np.clip(x, 0.0, rig.width - 1.0)


def gray_panels(rig: Rig) -> np.ndarray:
    """(2 bits, width) panel rows in {0, 1}: each bit then its inverse."""
    c = (np.arange(rig.width) // rig.cell).astype(np.int64)
    code = c ^ (c >> 1)
    rows = []
    for b in range(rig.bits):
        bit = ((code >> (rig.bits - 1 - b)) & 1).astype(float)
        rows += [bit, 1.0 - bit]
    return np.array(rows)


def blurred(panels: np.ndarray, x: np.ndarray, blur: float) -> np.ndarray:
    """(rows, *x.shape) panel values seen at x through a Gaussian of ``blur`` px."""
    reach = math.ceil(6 * blur) + 1
    out = np.zeros((panels.shape[0], *x.shape))
    for offset in range(-reach, reach + 1):
        j = np.floor(x).astype(int) + offset
        weight = ndtr((j + 0.5 - x) / blur) - ndtr((j - 0.5 - x) / blur)
        out += panels[:, np.clip(j, 0, panels.shape[1] - 1)] * weight
    return out


def boxed(panels: np.ndarray, x: np.ndarray, width: float) -> np.ndarray:
    """(rows, *x.shape) panel values averaged over [x - width/2, x + width/2]: a defocus
    whose spread is flat, which turns the contrast of fine stripes over [px]."""
    n = panels.shape[1]
    cum = np.concatenate([np.zeros((panels.shape[0], 1)), np.cumsum(panels, axis=1)], axis=1)

    def integral(t: np.ndarray) -> np.ndarray:  # of the panel from -1/2 to t
        s = np.clip(t + 0.5, 0.0, n - 1e-9)
        j = np.floor(s).astype(int)
        return cum[:, j] + (s - j) * panels[:, j]

    return (integral(x + width / 2) - integral(x - width / 2)) / width


def capture(rig: Rig, seed: int) -> tuple[dict, np.ndarray]:
    """Noisy 8-bit frames by kind ("reference", "gray", and each period) and the truth.

    With ``rig.jump`` the pixels right of the middle column see x + jump, and the edge
    column a mix of both (the truth there is the side it sees more of); with
    ``rig.albedo`` < 1 the rows darken towards the top.
    """
    rng = np.random.default_rng(seed + 1000)
    near = truth(rig, seed)
    h, w = rig.shape
    shade = np.linspace(rig.albedo, 1.0, h)[:, None]
    lo, hi = rig.black * shade, rig.white * shade
    mix = np.zeros((1, w))
    far = near
    if rig.jump:
        mix = np.clip(np.arange(w) + 0.5 - (w / 2 + 0.37), 0.0, 1.0)[None, :]
        far = np.clip(near + rig.jump, 0.0, rig.width - 1.0)

    def seen(pattern) -> np.ndarray:  # each pixel integrates what its two sides see
        out = pattern(near)
        return out if not rig.jump else (1 - mix) * out + mix * pattern(far)

    def camera(p: np.ndarray) -> np.ndarray:
        i = lo + (hi - lo) * p
        i = i + rng.normal(0.0, 1.0, i.shape) * np.sqrt(rig.noise_dn ** 2 + i / 10.0)
        return np.clip(np.rint(i), 0, 255).astype(np.uint8)

    ones = np.ones_like(near)
    frames = {"reference": camera(np.stack([ones, 0 * ones])),
              "gray": camera(seen(lambda x: _optics(rig, gray_panels(rig), x)))}
    for period in rig.periods:
        damp = math.exp(-2 * math.pi ** 2 * rig.blur ** 2 / period ** 2)
        if rig.box:
            damp *= np.sinc(rig.box / period)
        frames[period] = camera(seen(lambda x, p=period, a=damp: np.stack(
            [0.5 + 0.5 * a * np.cos(2 * np.pi * x / p + d) for d in THREE])))
    return frames, np.where(mix >= 0.5, far, near)


def _optics(rig: Rig, panels: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Panels through the Gaussian blur and, if any, the box of defocus."""
    seen = blurred(panels, x, rig.blur)
    if not rig.box:
        return seen
    grid = np.arange(rig.width, dtype=float)
    boxed_panels = boxed(panels, grid, rig.box)  # box first, on the panel columns
    return blurred(boxed_panels, x, rig.blur)


def description(rig: Rig, *, periods=None, shifts=THREE, levels=("white", "black"),
                inverse="interleaved", bits=None, cell=None, phase=True,
                reference=True, gray=True) -> tuple[PatternDescription, list]:
    """The coding as a user would state it (each keyword a possible misstatement), and
    the keys of ``capture``'s frames in set order."""
    sets, keys = [], []
    if reference:
        sets.append(ReferenceSet("wb", tuple(levels)))
        keys.append("reference")
    if gray:
        stated_bits = rig.bits if bits is None else bits
        sets.append(GrayCodeSet("gray", stated_bits, inverse=inverse, threshold="inverse",
                                cell_px=rig.cell if cell is None else cell))
        keys.append("gray")
    if phase:
        for i, (true, stated) in enumerate(zip(rig.periods, periods or rig.periods,
                                               strict=True)):
            sets.append(PhaseSet(f"p{i}", float(stated), 3, shifts_rad=tuple(shifts)))
            keys.append(true)
    return PatternDescription(rig.width, tuple(sets)), keys


def stacks(frames: dict, keys: list) -> list[np.ndarray]:
    """The frames of each set, in the description's order."""
    return [frames[k] for k in keys]


def order_errors(pm, x: np.ndarray, period: float) -> tuple[float, float]:
    """(valid fraction, share of valid pixels off the truth by a quarter period or more)."""
    valid = pm.valid
    if not valid.any():
        return 0.0, 0.0
    wrong = np.abs(pm.xp[valid] - x[valid]) >= period / 4
    return float(valid.mean()), float(wrong.mean())
