"""Decoding a scan: fringe images to the unwrapped projector coordinate of every pixel.

Every phase set is demodulated (:mod:`scanqa.decoding.demodulate`); temporal unwrapping
is hierarchical (coarse to fine periods, or a Gray code ordering the coarsest period;
:mod:`scanqa.decoding.unwrap`), and every unwrapped set is fused by inverse-variance
weighting. The work runs on chunks of rows that fit the CPU cache.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from scanqa.decoding.coding import PatternDescription, SensorModel, load_patterns
from scanqa.decoding.patternset import read_pattern_images
from scanqa.decoding.phasemap import MASK_REASONS, PhaseMap, load_phase_map
from scanqa.decoding.unwrap import UnwrapPlan, unwrap_rows
from scanqa.errors import InputError

_CHUNK_PIXELS = 32768  # pixels per chunk: measured fastest on 2448 x 2048 (cache-sized)


def decode_images(desc: PatternDescription, images: Sequence[np.ndarray], *,
           chunk_rows: int | None = None, progress: Callable[[str], None] | None = None
           ) -> PhaseMap:
    """Decode a pattern set into a :class:`PhaseMap`.

    Parameters
    ----------
    desc : PatternDescription
        What was projected, the sensor noise model and the thresholds.
    images : sequence of (N, H, W) arrays
        One stack per set, in ``desc.sets`` order [DN]. Integer stacks are treated as
        quantised (the 1/12 DN^2 term enters the noise).
    chunk_rows : int, optional
        Rows decoded at a time [px]; default: about 32k pixels per chunk, which keeps
        the temporaries in the CPU cache and bounds the working memory.
    progress : callable, optional
        Receives short progress messages.

    Returns
    -------
    PhaseMap
        x_p (or y_p) [projector px], modulation and offset of the finest set [DN],
        mask with reasons, predicted sigma_xp [projector px] and provenance.

    Raises
    ------
    InputError
        On a wrong number of stacks or frames, mismatched sizes, or NaN in the images.
    """
    t0 = time.perf_counter()
    stacks = _checked_stacks(desc, images)
    sensor = desc.sensor.resolved(stacks[0].dtype)
    plan = UnwrapPlan.build(desc, sensor, quantised=stacks[0].dtype.kind in "ui")
    height, width = stacks[0].shape[1:]
    out = _allocate(height, width)
    by_name = {s.name: st for s, st in zip(desc.sets, stacks, strict=True)}
    step = max(int(chunk_rows or _CHUNK_PIXELS // max(width, 1)), 1)
    for r0 in range(0, height, step):
        rows = slice(r0, min(r0 + step, height))
        unwrap_rows(plan, {k: v[:, rows] for k, v in by_name.items()},
                    {k: v[rows] for k, v in out.items()})
    if progress:
        progress(f"decoded {height} x {width} px in {time.perf_counter() - t0:.2f} s")
    return PhaseMap(**out, period_px=desc.working_period_px, orientation=desc.orientation,
                    projector_width_px=desc.projector_width_px,
                    provenance=_provenance(desc, sensor, stacks[0]))


def _allocate(height: int, width: int) -> dict[str, np.ndarray]:
    return {"xp": np.empty((height, width), np.float64),
            "modulation": np.empty((height, width), np.float32),
            "offset": np.empty((height, width), np.float32),
            "mask": np.empty((height, width), np.uint8),
            "sigma_xp": np.empty((height, width), np.float32)}


def _checked_stacks(desc: PatternDescription, images: Sequence[np.ndarray]
                    ) -> list[np.ndarray]:
    """One (N, H, W) real, finite stack per set, all of one size and dtype."""
    if len(images) != len(desc.sets):
        raise InputError(f"got {len(images)} image stacks for {len(desc.sets)} sets "
                         f"(in {desc.source or 'the pattern description'})")
    stacks = [np.asarray(im) for im in images]
    for pset, st in zip(desc.sets, stacks, strict=True):
        if st.ndim != 3 or st.shape[0] != pset.frames or st.dtype.kind not in "uif":
            raise InputError(f"set {pset.name!r} needs a real ({pset.frames}, H, W) stack, "
                             f"got shape {st.shape} dtype {st.dtype}")
        if st.shape[1:] != stacks[0].shape[1:] or st.dtype != stacks[0].dtype:
            raise InputError(f"mismatched image sizes: set {pset.name!r} is {st.shape[1:]} "
                             f"{st.dtype}, set {desc.sets[0].name!r} is "
                             f"{stacks[0].shape[1:]} {stacks[0].dtype}")
        if st.dtype.kind == "f" and not np.isfinite(st).all():
            raise InputError(f"images of set {pset.name!r} contain NaN or inf")
    return stacks


def _provenance(desc: PatternDescription, sensor: SensorModel, stack: np.ndarray) -> dict:
    from scanqa._version import __version__

    return {"software": "scanqa", "version": __version__, "stage": "decode",
            "patterns_file": desc.source, "patterns": desc.to_dict(),
            "sensor_resolved": asdict(sensor), "image_dtype": str(stack.dtype),
            "image_shape": list(stack.shape[1:]),
            "mask_reasons": {str(k): v for k, v in MASK_REASONS.items()}}


def decode_pattern_dir(path: str | os.PathLike,
                       progress: Callable[[str], None] | None = None) -> PhaseMap:
    """Load ``patterns.toml`` and its images from a folder (or file) and decode them.

    Parameters
    ----------
    path : str or PathLike
        Pattern folder, or its patterns.toml.
    progress : callable, optional
        Receives short progress messages.

    Returns
    -------
    PhaseMap
        The decoded map.
    """
    t0 = time.perf_counter()
    desc = load_patterns(path)
    stacks = read_pattern_images(desc)
    if progress:
        n = sum(st.shape[0] for st in stacks)
        h, w = stacks[0].shape[1:]
        progress(f"read {n} images of {w} x {h} px ({stacks[0].dtype}) from "
                 f"{desc.source} in {time.perf_counter() - t0:.2f} s")
    return decode_images(desc, stacks, progress=progress)


def decode(source: str | os.PathLike,
           progress: Callable[[str], None] | None = None) -> PhaseMap:
    """The phase map of a scan, whatever form it comes in.

    Parameters
    ----------
    source : str or PathLike
        A pattern folder (images and their ``patterns.toml``), the ``patterns.toml``
        itself, or a phase map file (``.npz``) written by :func:`save_phase_map`.
    progress : callable, optional
        Receives short progress messages while decoding.

    Returns
    -------
    PhaseMap
        The decoded (or loaded) map.
    """
    path = Path(source)
    if path.suffix.lower() == ".npz" and path.is_file():
        return load_phase_map(path)
    if not path.exists():
        raise InputError(f"scan {path} does not exist (give a pattern folder with a "
                         "patterns.toml, or a phase.npz written by 'scanqa decode')")
    return decode_pattern_dir(path, progress)

