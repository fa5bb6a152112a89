"""The local scatter of a range image: each pixel minus the median of its window, where
the whole window is valid (test_flattening_real.py, test_realdata_noise.py)."""

from __future__ import annotations

import numpy as np

#: Pixels whose windows are copied at once (~36 MB for 15 x 15 windows of float64).
CHUNK = 20_000


def window_medians(z: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the ``size`` x ``size`` window centred on a pixel (NaN beyond the image) is
    finite throughout, and the window's median there.

    The same numbers as ``sliding_window_view(np.pad(z, size // 2, constant_values=nan),
    (size, size)).reshape(h, w, size**2)``, ``np.isfinite(...).all(axis=2)`` and
    ``np.median(windows[full], axis=1)``, without copying every pixel's window at once
    (4 GB for 15 x 15 windows of a 2.3 MP image): the windows are counted finite by
    summed-area table and their medians taken a chunk of pixels at a time.

    Parameters
    ----------
    z : (H, W) float
        The image, NaN where invalid.
    size : int
        The window's side (odd) [px].

    Returns
    -------
    full : (H, W) bool
        The pixels whose windows are finite throughout.
    medians : (n,) float64
        Their windows' medians, in the order of ``z[full]``.
    """
    half = size // 2
    padded = np.pad(z, half, constant_values=np.nan)
    table = np.zeros((padded.shape[0] + 1, padded.shape[1] + 1), np.int64)
    table[1:, 1:] = np.isfinite(padded).cumsum(axis=0).cumsum(axis=1)
    counts = (table[size:, size:] - table[:-size, size:] - table[size:, :-size]
              + table[:-size, :-size])
    full = counts == size * size
    windows = np.lib.stride_tricks.sliding_window_view(padded, (size, size))
    rows, cols = np.nonzero(full)
    medians = np.empty(rows.size)
    for start in range(0, rows.size, CHUNK):
        part = slice(start, start + CHUNK)
        medians[part] = np.median(windows[rows[part], cols[part]].reshape(-1, size * size),
                                  axis=1)
    return full, medians
