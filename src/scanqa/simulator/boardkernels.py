"""Compiled per-pixel loops of the board renderers (numba), and their numpy twins.

The Gray-code board renderer (:func:`scanqa.simulator.boardposes.gray_frames`) and the
phase-shift one (:func:`scanqa.simulator.boardfringes.frames`) spent their time in numpy
passes over million-pixel float64 images: the ray meeting the bowed board (five passes a
step, three steps, nine points a pixel), the squares' reflectance, and per frame the
image, OpenCV's Gaussian blur (scipy's two ``correlate1d`` passes), the noise, the
rounding and the clipping. Here each is one loop over the pixels that repeats numpy's
and scipy's arithmetic in their order (every product and sum rounded once, no fused
multiply-add: numba contracts none without fastmath; the blur of a pixel is scipy's
symmetric-kernel sum ``x w_0 + sum_(j = R..1) (x_(-j) + x_(+j)) w_j`` with the mirrored
border of ``mode="mirror"``), so the 8-bit frames are the same bytes as the numpy
passes give (``tests/test_boardkernels.py`` compares them with operation-count
tolerances, never bit for bit).

Without numba (:mod:`scanqa.compiled`) the ``*_numpy`` twins below run instead: the
numpy expressions the loops replaced.
"""

from __future__ import annotations

import numpy as np

from scanqa import compiled
from scanqa.compiled import njit


def gaussian_weights(sigma_px: float) -> np.ndarray:
    """One half of the kernel of :func:`scanqa.simulator.boardposes.gaussian_blur`:
    weights w_0 .. w_R of the offsets 0 .. R (OpenCV's radius round(4 sigma), sampled
    and normalised as scipy does) [-]; ``[1.0]`` for sigma 0 (no blur)."""
    if sigma_px <= 1e-15:  # scipy skips the axis: the image itself
        return np.ones(1)
    radius = (int(np.rint(sigma_px * 8 + 1)) | 1) // 2
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma_px * sigma_px) * x ** 2)
    phi /= phi.sum()
    return np.ascontiguousarray(phi[radius:])


@njit(cache=True, nogil=True, inline="always")
def _mirror(i: int, n: int) -> int:
    """Index i reflected into 0 .. n - 1 about the end samples (reflect-101)."""
    if n == 1:
        return 0
    period = 2 * (n - 1)
    i = abs(i) % period
    return period - i if i >= n else i


@njit(cache=True, nogil=True)
def _blur_row(image: np.ndarray, r: int, w: np.ndarray, column: np.ndarray,
              padded: np.ndarray, out: np.ndarray) -> None:
    """Row r of the separable blur of ``image`` (rows first, as scipy) into ``out``;
    ``column`` (W,) and ``padded`` (W + 2R,) are scratch."""
    height, width = image.shape
    radius = w.shape[0] - 1
    src = image[r]
    for c in range(width):
        column[c] = src[c] * w[0]
    for j in range(radius, 0, -1):
        a, b, wj = image[_mirror(r - j, height)], image[_mirror(r + j, height)], w[j]
        for c in range(width):
            column[c] += (a[c] + b[c]) * wj
    for c in range(width):
        padded[c + radius] = column[c]
    for j in range(1, radius + 1):  # the mirrored border
        padded[radius - j] = column[_mirror(-j, width)]
        padded[radius + width - 1 + j] = column[_mirror(width - 1 + j, width)]
    mid = padded[radius:radius + width]  # slices, as the rows above: numba vectorises
    for c in range(width):                # these loops, not indices shifted by j (3 x)
        out[c] = mid[c] * w[0]
    for j in range(radius, 0, -1):
        a, b = padded[radius - j:radius - j + width], padded[radius + j:radius + j + width]
        wj = w[j]
        for c in range(width):
            out[c] += (a[c] + b[c]) * wj


@njit(cache=True, nogil=True)
def blur(image: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The separable blur of a float64 image with the symmetric kernel of half ``w``
    (:func:`gaussian_weights`), mirrored border: scipy's ``correlate1d`` along the rows,
    then along the columns, (H, W) float64 [units of image]."""
    height, width = image.shape
    out = np.empty((height, width))
    column, padded = np.empty(width), np.empty(width + 2 * (w.shape[0] - 1))
    for r in range(height):
        _blur_row(image, r, w, column, padded, out[r])
    return out


@njit(cache=True, nogil=True, inline="always")
def _to_uint8(x: float) -> np.uint8:
    """``np.clip(np.round(x), 0, 255).astype(np.uint8)`` of one value."""
    return np.uint8(min(max(np.rint(x), 0.0), 255.0))


@njit(cache=True, nogil=True)
def fringe_shot(dark: float, gain: np.ndarray, light: np.ndarray, w: np.ndarray,
                noise: np.ndarray, read_var_dn2: float, shot_dn: float) -> np.ndarray:
    """One board frame: ``dark + gain * light`` blurred, plus noise of variance
    ``read_var_dn2 + shot_dn max(I, 0)`` (``noise`` the standard normal draws), rounded
    and clipped to 8 bits, (H, W) uint8 [DN]. A Gray-code frame's constant noise is
    ``read_var_dn2 = noise_dn ** 2``, ``shot_dn = 0`` (the square root of a square is
    the number itself in IEEE arithmetic, so the frame is ``noise_dn * noise`` exactly).
    """
    height, width = gain.shape
    image = np.empty((height, width))
    for r in range(height):
        for c in range(width):
            image[r, c] = dark + gain[r, c] * light[r, c]
    out = np.empty((height, width), np.uint8)
    column, padded = np.empty(width), np.empty(width + 2 * (w.shape[0] - 1))
    row = np.empty(width)
    for r in range(height):
        _blur_row(image, r, w, column, padded, row)
        for c in range(width):
            level = row[c]
            sigma = np.sqrt(read_var_dn2 + shot_dn * max(level, 0.0))
            out[r, c] = _to_uint8(level + sigma * noise[r, c])
    return out


@njit(cache=True, nogil=True)
def board_points(nx: np.ndarray, ny: np.ndarray, normal: np.ndarray, origin: np.ndarray,
                 rot: np.ndarray, depth0: float, bow: np.ndarray, centre: np.ndarray,
                 half: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays (nx, ny, 1) meet the bowed board: camera-frame points and board
    coordinates, (n, 3) each [mm].

    The plane ``normal . p = depth0`` first, then ``steps`` fixed-point steps onto the
    sag (:func:`scanqa.simulator.boardposes.sag_mm` with ``bow``, ``centre``, ``half``)
    along the ray; board coordinates are ``rot^T (p - origin)``.
    """
    n = nx.shape[0]
    pts = np.empty((n, 3))
    local = np.empty((n, 3))
    for i in range(n):
        x, y = nx[i], ny[i]
        along = (x * normal[0] + y * normal[1]) + normal[2]
        depth = depth0
        for step in range(steps + 1):
            scale = depth / along
            p0, p1 = x * scale, y * scale
            r0, r1, r2 = p0 - origin[0], p1 - origin[1], scale - origin[2]
            l0 = (r0 * rot[0, 0] + r1 * rot[1, 0]) + r2 * rot[2, 0]
            l1 = (r0 * rot[0, 1] + r1 * rot[1, 1]) + r2 * rot[2, 1]
            l2 = (r0 * rot[0, 2] + r1 * rot[1, 2]) + r2 * rot[2, 2]
            if step < steps:
                sx, sy = (l0 - centre[0]) / half[0], (l1 - centre[1]) / half[1]
                depth = depth0 + ((bow[0] * (sx * sx) + bow[1] * (sy * sy))
                                  + bow[2] * sx * sy)
        pts[i, 0], pts[i, 1], pts[i, 2] = p0, p1, scale
        local[i, 0], local[i, 1], local[i, 2] = l0, l1, l2
    return pts, local


@njit(cache=True, nogil=True, inline="always")
def _square(coordinate: float, square_mm: float) -> int:
    """``floor(coordinate / square) + 1`` as numpy's int cast gives it; far off (or NaN)
    the board: a square index that is outside every test."""
    q = np.floor(coordinate / square_mm)
    if not abs(q) < 2.0 ** 62:  # numpy's cast: the int64 minimum
        return -(2 ** 62)
    return int(q) + 1


@njit(cache=True, nogil=True)
def board_reflectance(local: np.ndarray, square_mm: float, columns: int, rows: int,
                      white: float, black: float, beyond: float) -> np.ndarray:
    """Reflectance at board coordinates ``local`` (n, 3) [mm]: black and white squares,
    a white margin of one square, ``beyond`` past it, (n,) [-]."""
    n = local.shape[0]
    out = np.empty(n)
    for i in range(n):
        s0, s1 = _square(local[i, 0], square_mm), _square(local[i, 1], square_mm)
        value = beyond
        if -1 <= s0 <= columns + 1 and -1 <= s1 <= rows + 1:
            value = white
        if 0 <= s0 <= columns and 0 <= s1 <= rows and (s0 + s1) % 2 == 0:
            value = black
        out[i] = value
    return out


# --------------------------------------------------------------- numpy twins (no numba)

def fringe_shot_numpy(dark: float, gain: np.ndarray, light: np.ndarray, w: np.ndarray,
                      noise: np.ndarray, read_var_dn2: float, shot_dn: float
                      ) -> np.ndarray:
    """:func:`fringe_shot` in numpy passes and scipy's blur [DN]."""
    image = blur_numpy(dark + gain * light, w)
    image = image + np.sqrt(read_var_dn2 + shot_dn * np.maximum(image, 0.0)) * noise
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def blur_numpy(image: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`blur` by scipy's ``correlate1d`` [units of image]."""
    from scipy.ndimage import correlate1d

    if w.shape[0] == 1:
        return image.copy()
    kernel = np.concatenate([w[:0:-1], w])
    out = correlate1d(image, kernel, axis=0, mode="mirror")
    return correlate1d(out, kernel, axis=1, mode="mirror")


def board_points_numpy(nx: np.ndarray, ny: np.ndarray, normal: np.ndarray,
                       origin: np.ndarray, rot: np.ndarray, depth0: float, bow: np.ndarray,
                       centre: np.ndarray, half: np.ndarray, steps: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`board_points` in numpy passes, column by column [mm]."""
    along = nx * normal[0] + ny * normal[1] + normal[2]

    def at(depth):
        scale = depth / along
        pts = np.column_stack([nx * scale, ny * scale, scale])
        rel = pts - origin
        # column by column: numpy's (n, 3) @ (3, 3) is ~5x slower for a million rows
        return pts, np.column_stack([rel[:, 0] * rot[0, j] + rel[:, 1] * rot[1, j]
                                     + rel[:, 2] * rot[2, j] for j in range(3)])

    pts, local = at(np.full(len(along), depth0))
    for _ in range(steps):
        x, y = (local[:, 0] - centre[0]) / half[0], (local[:, 1] - centre[1]) / half[1]
        pts, local = at(depth0 + (bow[0] * x**2 + bow[1] * y**2 + bow[2] * x * y))
    return pts, local


def board_reflectance_numpy(local: np.ndarray, square_mm: float, columns: int, rows: int,
                            white: float, black: float, beyond: float) -> np.ndarray:
    """:func:`board_reflectance` in numpy passes [-]."""
    with np.errstate(invalid="ignore"):
        sq = np.floor(local[:, :2] / square_mm).astype(int) + 1
    inside = ((sq[:, 0] >= -1) & (sq[:, 0] <= columns + 1) & (sq[:, 1] >= -1)
              & (sq[:, 1] <= rows + 1))
    grid_in = (sq[:, 0] >= 0) & (sq[:, 0] <= columns) & (sq[:, 1] >= 0) & (sq[:, 1] <= rows)
    out = np.where(inside, white, beyond)
    return np.where(grid_in & ((sq[:, 0] + sq[:, 1]) % 2 == 0), black, out)


#: The compiled loops and their numpy twins, by name.
NUMPY_TWINS = {"blur": blur_numpy,
               "fringe_shot": fringe_shot_numpy, "board_points": board_points_numpy,
               "board_reflectance": board_reflectance_numpy}

if not compiled.HAVE_NUMBA:  # a Python loop over every pixel would be far too slow
    globals().update(NUMPY_TWINS)
