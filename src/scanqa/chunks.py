"""Bands of image rows, processed on every core (docs/development.rst, "Performance").

The per-pixel hot paths (building and applying the calibration table, annotating a scan)
work on bands of whole image rows of about :data:`CHUNK_PIXELS` pixels: small enough that
their temporaries stay in the core's cache and are recycled by the allocator instead of
being faulted in afresh, large enough that numpy's per-call overhead is amortised. The
bands run on a pool of ``os.cpu_count()`` threads: numpy releases the GIL in its loops.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

#: Pixels per band: measured fastest for annotate and apply on 2448 x 2048 (6 rows); a
#: band's temporaries (~20 float64 arrays of 128 kB) stay in a 2 MB L2 cache.
CHUNK_PIXELS = 16384

T = TypeVar("T")
R = TypeVar("R")


def row_bands(n_rows: int, row_size: int, pixels: int = CHUNK_PIXELS) -> list[tuple[int, int]]:
    """Split ``n_rows`` rows of ``row_size`` items into bands of about ``pixels`` items.

    Parameters
    ----------
    n_rows : int
        Number of rows [-].
    row_size : int
        Items (pixels) per row [-].
    pixels : int
        Target items per band; a band holds at least one row [-].

    Returns
    -------
    list of (int, int)
        Half-open row ranges (start, stop) covering ``range(n_rows)`` in order.

    Examples
    --------
    >>> row_bands(5, 10, pixels=20)
    [(0, 2), (2, 4), (4, 5)]
    """
    step = max(1, pixels // max(row_size, 1))
    return [(r, min(r + step, n_rows)) for r in range(0, n_rows, step)]


def run_bands(work: Callable[[int, int], T], bands: list[tuple[int, int]]) -> list[T]:
    """Call ``work(start, stop)`` for every band on a thread pool.

    Parameters
    ----------
    work : callable
        Processes rows start..stop; bands must not write to shared state other than
        disjoint slices of preallocated outputs.
    bands : list of (int, int)
        Row ranges from :func:`row_bands`.

    Returns
    -------
    list
        The results in band order. The first exception raised by a band propagates.
    """
    workers = min(os.cpu_count() or 1, len(bands))
    if workers <= 1:
        return [work(a, b) for a, b in bands]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(lambda band: work(*band), bands))


def run_bands_with(task: Callable[[], R], work: Callable[[int, int], T],
                   bands: list[tuple[int, int]]) -> tuple[R, list[T]]:
    """:func:`run_bands` with one more task on the same pool, submitted first: one thread
    takes it while the others start on the bands.

    Parameters
    ----------
    task : callable
        Work beside the bands (reads only, or writes what no band touches).
    work : callable
        As for :func:`run_bands`.
    bands : list of (int, int)
        Row ranges from :func:`row_bands`.

    Returns
    -------
    (object, list)
        ``task``'s result and the bands' results in band order. ``task``'s exception
        propagates before any band's.
    """
    with ThreadPoolExecutor(max_workers=max(min(os.cpu_count() or 1, len(bands)), 1)) as pool:
        first = pool.submit(task)
        running = [pool.submit(work, *band) for band in bands]
        return first.result(), [r.result() for r in running]
