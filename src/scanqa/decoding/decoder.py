"""Decoding a scan: fringe images to the unwrapped projector coordinate of every pixel.

Every phase set is demodulated (:mod:`scanqa.decoding.demodulate`) and, with a
projector response, corrected for the projector's nonlinearity
(:mod:`scanqa.decoding.response`); temporal unwrapping follows the planned chain
(:mod:`scanqa.decoding.chain`, :mod:`scanqa.decoding.unwrap`). x_p is the finest set's
coordinate; the coarser sets and the Gray code only decide its fringe order (unless
``fuse_periods``), and their systematic disagreement with x_p is measured and reported.
The camera noise comes from ``[sensor]`` or from the images
(:mod:`scanqa.decoding.noise`). The work runs on chunks of rows that fit the CPU cache.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from scanqa.chunks import row_bands, run_bands_with
from scanqa.decoding import checks, consistency, diagnostics, framecheck, waveform
from scanqa.decoding.coding import PatternDescription, SensorModel
from scanqa.decoding.demodulate import demodulate_sample
from scanqa.decoding.noise import NoiseEstimate, resolve_noise
from scanqa.decoding.parsing import load_patterns
from scanqa.decoding.patternset import lossy_image_note, read_pattern_images
from scanqa.decoding.phasemap import MASK_VALID, PhaseMap, count_reasons, load_phase_map
from scanqa.decoding.response import ProjectorResponse, load_response, measure_tables
from scanqa.decoding.unwrap import (
    ChainStats,
    UnwrapPlan,
    defers_orders,
    ripple_bin,
    unwrap_rows,
)
from scanqa.errors import InputError, ScanQAError

log = logging.getLogger(__name__)

_CHUNK_PIXELS = 32768  # pixels per chunk: measured fastest on 2448 x 2048 (cache-sized)


def decode_images(desc: PatternDescription, images: Sequence[np.ndarray], *,
                  chunk_rows: int | None = None,
                  progress: Callable[[str], None] | None = None,
                  response: ProjectorResponse | None = None,
                  notes: Sequence[str] = ()) -> PhaseMap:
    """Decode a pattern set into a :class:`PhaseMap`.

    Parameters
    ----------
    desc : PatternDescription
        What was projected, the sensor noise model, the thresholds and options.
    images : sequence of (N, H, W) arrays
        One stack per set, in ``desc.sets`` order [DN]. Integer stacks are treated as
        quantised (the 1/12 DN^2 term enters the noise).
    chunk_rows : int, optional
        Rows decoded at a time [px]; default: about 32k pixels per chunk, which keeps
        the temporaries in the CPU cache and bounds the working memory.
    progress : callable, optional
        Receives short progress messages.
    response : ProjectorResponse, optional
        Phase-error tables of the projector, applied to every phase set.
    notes : sequence of str
        Remarks for the summary (e.g. about the image files).

    Returns
    -------
    PhaseMap
        x_p (or y_p) [projector px], modulation and offset of the finest set [DN],
        mask with reasons, predicted sigma_xp [projector px] and provenance (with the
        noise source, the period disagreement and hints, see ``summary()``).

    Raises
    ------
    InputError
        On a wrong number of stacks or frames, mismatched sizes, or NaN in the images.
    """
    t0 = time.perf_counter()
    run = _decode(desc, images, chunk_rows, response, keep_sets=False)
    out = run.out
    if progress:
        progress(f"decoded {out['xp'].shape[0]} x {out['xp'].shape[1]} px in "
                 f"{time.perf_counter() - t0:.2f} s")
    return _phase_map(desc, run, response, images, notes)


def decoded_valid(desc: PatternDescription, images: Sequence[np.ndarray]) -> np.ndarray:
    """(H, W) bool: where :func:`decode_images` gives a valid x_p - the same decode and
    the same guards, without the map's diagnostics, warnings and provenance (``scanqa
    describe`` checks its candidate descriptions with it).

    Raises
    ------
    InputError
        As :func:`decode_images`.
    """
    run = _decode(desc, images, None, None, keep_sets=False)
    if diagnostics.misstated_steps(desc, run.stats) or run.contradicted:
        diagnostics.apply_guard(run.out)
    return run.out["mask"] == MASK_VALID


@dataclass(frozen=True, eq=False)
class _Run:
    """A decode's outputs (dict of arrays), counts, noise model and plan, the sample of
    rows the checks read, and what the checks found (``pairs``: the residual test of
    every cue set against the finer sets)."""

    out: dict
    stats: ChainStats
    noise: NoiseEstimate
    plan: UnwrapPlan
    sample: list
    notes: list
    warnings: list
    pairs: list
    contradicted: bool = False


def _decode(desc: PatternDescription, images: Sequence[np.ndarray], chunk_rows: int | None,
            response: ProjectorResponse | None, keep_sets: bool, check: bool = True) -> _Run:
    """Decode, with the checks of the description on a sample of rows first."""
    stacks = _checked_stacks(desc, images)
    quantised = stacks[0].dtype.kind in "ui"
    noise = resolve_noise(desc, stacks, desc.sensor.resolved(stacks[0].dtype), quantised)
    sample = checks.sample_rows(stacks)
    # the plan reads the Gray bits only: every other check of the sample runs in the
    # band pool, beside the bands, and is joined before its findings are used
    bits, notes = checks.gray_bits(desc, sample, noise.sensor, quantised) if check \
        else (None, [])
    plan = UnwrapPlan.build(desc, noise.sensor, quantised, response, gray_bits=bits)
    if defers_orders(plan):
        plan = replace(plan, systematic=_systematic(plan, desc, sample))
    height, width = stacks[0].shape[1:]
    out = _allocate(height, width, [p.name for p in plan.phase] if keep_sets else [])
    by_name = {s.name: st for s, st in zip(desc.sets, stacks, strict=True)}
    step = max(int(chunk_rows or _CHUNK_PIXELS // max(width, 1)), 1)

    def band(r0: int, r1: int) -> ChainStats:  # disjoint rows of the outputs: thread-safe
        part = ChainStats()
        unwrap_rows(plan, {k: v[:, r0:r1] for k, v in by_name.items()},
                    {k: v[r0:r1] for k, v in out.items()}, part)
        return part

    # the sample's checks beside the bands; a check's error first, as when the checks
    # ran before the bands
    found, parts = run_bands_with(
        lambda: _sample_checks(desc, sample, noise.sensor, quantised, response, check),
        band, row_bands(height, width, step * width))
    shapes, pairs, warnings, contradicted = found
    stats = ChainStats()
    for part in parts:
        stats.merge(part)
    warnings += _carry_shapes(desc, shapes, out)
    return _Run(out, stats, noise, plan, sample, notes, warnings, pairs, contradicted)


def _sample_checks(desc: PatternDescription, sample: list, sensor: SensorModel, quantised: bool,
                   response: ProjectorResponse | None, check: bool
                   ) -> tuple[list, list, list[str], bool]:
    """The description's checks on the sample rows (all but the Gray bits): the sets
    whose fringes are not sine waves, the pairs' consistency, the warnings, and whether
    the sets contradict one another."""
    if not check:
        return [], [], [], False
    corrected = () if response is None else \
        tuple(s.name for s in desc.phase_sets if response.table_for(s) is not None)
    demods = demodulate_sample(desc.sets, sample, sensor, quantised)  # once
    shapes = [s for s in waveform.fringe_shapes(desc, sample, sensor, quantised, demods)
              if s.name not in corrected]
    pairs = consistency.set_consistency(desc, sample, sensor, quantised, demods)
    repeated = consistency.repeated_frames(desc, sample)
    broken = framecheck.broken_frames(desc, sample, sensor, quantised)
    contradicted = bool(repeated or broken) or any(p.contradicted for p in pairs)
    warnings = [*broken, *checks.reference_swapped(desc, sample, sensor, quantised),
                *checks.inverse_layout(desc, sample, sensor, quantised),
                *repeated, *consistency.consistency_warnings(pairs)]
    return shapes, pairs, warnings, contradicted


def _carry_shapes(desc: PatternDescription, shapes: list, out: dict) -> list[str]:
    """Warnings for sets whose fringes are not sine waves; the rms x_p error of the set
    that gives x_p (without ``fuse_periods``) is added to sigma_xp in quadrature."""
    finest = desc.phase_sets[-1].name if desc.phase_sets and \
        not desc.options.fuse_periods else None
    steps = {s.name: s.steps for s in desc.phase_sets}
    for shape in shapes:
        if shape.name == finest:
            sigma = out["sigma_xp"]
            np.sqrt(sigma * sigma + np.float32(shape.rms_px ** 2), out=sigma)
    return [shape.warning(steps[shape.name], shape.name == finest) for shape in shapes]


#: Share of the sampled pixels whose disagreement between two sets, once its ripple is
#: taken out, bounds the rest (:func:`_systematic`) [-].
SYSTEMATIC_QUANTILE = 0.99
#: Bins of the wrapped phase in the ripple tables of :func:`_systematic` [-].
RIPPLE_BINS = 32


def _systematic(plan: UnwrapPlan, desc: PatternDescription, sample: list) -> dict:
    """The systematic disagreement between the Gray-ordered set and the step that
    decides the orders the Gray code leaves open, measured on the sample rows.

    A projector's gamma distorts each set's phase by a ripple that is a function of its
    own wrapped phase, which the noise model does not predict (object1 of kamino410's
    captures: +-7.5 px on its 100 px set). Over the sample's valid pixels (whose orders
    every margin decided) the disagreement d = x_first - x_step is fitted as
    ``e1(f_first) - e2(f_step)``, two tables of ``RIPPLE_BINS`` bins of the wrapped
    phases (alternating bin means); what the tables leave, its ``SYSTEMATIC_QUANTILE``
    quantile (noise included, which errs on the safe side), bounds the rest.

    Returns
    -------
    dict
        ``{step name: (e1 [px], e2 [px], bound [cycles of the step])}``, or empty when
        the sample holds too few valid pixels.
    """
    first, step = plan.steps[0], plan.steps[1]
    if not (first.is_set and step.is_set):
        return {}
    frames = {s.name: st for s, st in zip(desc.sets, sample, strict=True)}
    height, width = sample[0].shape[1:]
    out = _allocate(height, width, [first.name, step.name])
    unwrap_rows(plan, frames, out, ChainStats())
    x1, x2 = out[f"x:{first.name}"], out[f"x:{step.name}"]
    d = x1 - x2
    keep = (out["mask"] == 0) & (np.abs(d - np.nanmedian(d)) < 0.25 * step.period_px)
    if np.count_nonzero(keep) < 50 * RIPPLE_BINS:
        return {}
    d = d[keep]
    b1 = ripple_bin(x1[keep] / first.period_px, RIPPLE_BINS)
    b2 = ripple_bin(x2[keep] / step.period_px, RIPPLE_BINS)
    e1, e2 = np.zeros(RIPPLE_BINS), np.zeros(RIPPLE_BINS)
    for _ in range(4):
        e1 = _bin_mean(b1, d + e2[b2], e1)
        e2 = _bin_mean(b2, e1[b1] - d, e2)
    rest = d - (e1[b1] - e2[b2])
    bound = np.quantile(np.abs(rest - np.median(rest)), SYSTEMATIC_QUANTILE)
    return {step.name: (e1, e2, float(bound) / step.period_px)}


def _bin_mean(bins: np.ndarray, values: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Mean of ``values`` per bin (``old`` where a bin is empty)."""
    n = np.bincount(bins, minlength=RIPPLE_BINS)
    total = np.bincount(bins, values, minlength=RIPPLE_BINS)
    return np.where(n > 0, total / np.maximum(n, 1), old)


def _phase_map(desc: PatternDescription, run: _Run, response: ProjectorResponse | None,
               images: Sequence[np.ndarray], notes: Sequence[str]) -> PhaseMap:
    """Apply the guard, gather the diagnostics and warnings, and build the map."""
    out, stats = run.out, run.stats
    # the spread of every set against x_p reads the counts alone: a second thread
    # summarises it while this one checks the decoded map
    with ThreadPoolExecutor(max_workers=1) as pool:
        spread = pool.submit(diagnostics.disagreement, stats)
        misstated = diagnostics.misstated_steps(desc, stats)
        warnings = [*([run.noise.warning] if run.noise.warning else []), *run.warnings]
        if misstated:
            diagnostics.apply_guard(out)
            warnings += checks.likely_cause(desc, run.sample, _trips_guard)
        else:
            warnings += _decoded_checks(desc, run)
        if run.contradicted:  # the sets disagree before any mask: no pixel is trusted
            diagnostics.apply_guard(out)
        counts = count_reasons(out["mask"])
        info = _decode_info(desc, run, response, misstated, [*run.notes, *notes],
                            counts["valid"], spread.result())
    for text in warnings:
        log.warning(text)
    arrays = {k: v for k, v in out.items() if not k.startswith("x:")}
    info["warnings"] = warnings
    info["hint"] = diagnostics.mask_hint(desc, counts, stats,
                                         contradicted=bool(misstated) or run.contradicted)
    period = desc.working_period_px if desc.phase_sets else run.plan.gray_cell_px
    return PhaseMap(**arrays, period_px=period, orientation=desc.orientation,
                    projector_width_px=desc.projector_width_px,
                    provenance=_provenance(desc, run.noise, np.asarray(images[0]), info))


def _decoded_checks(desc: PatternDescription, run: _Run) -> list[str]:
    """Warnings from the decoded map: a drift between sets, a mirrored decode."""
    stats = run.stats
    samples = {k: np.concatenate(v) for k, v in stats.disagreement.items() if v}
    positions = {k: np.concatenate(v) for k, v in stats.positions.items() if v}
    valid = run.out["mask"] == 0
    return [*checks.period_drift(desc, samples, positions),
            *checks.mirrored(run.out["xp"], valid, desc.orientation)]


def _trips_guard(desc: PatternDescription, sample: list) -> bool:
    """True when a decode of the sample rows trips the misstatement guard."""
    try:
        run = _decode(desc, sample, None, None, keep_sets=False, check=False)
    except ScanQAError:
        return True
    return bool(diagnostics.misstated_steps(desc, run.stats))


def _decode_info(desc: PatternDescription, run: _Run, response: ProjectorResponse | None,
                 misstated: list, notes: Sequence[str], valid: int,
                 spread: list[dict]) -> dict:
    phase, stats, noise = desc.phase_sets, run.stats, run.noise
    if not phase:
        working = _gray_working(run.plan.gray_cell_px, sum(stats.edges.values()), valid)
    elif desc.options.fuse_periods:
        working = ("inverse-variance fusion of every phase set (decode.fuse_periods = true): "
                   "systematic differences between periods bias x_p")
    else:
        working = (f"finest set {phase[-1].name!r} alone (period {phase[-1].period_px:g} "
                   "px); coarser sets and the Gray code decide its fringe order only")
    notes = [*notes]
    if response is not None:
        done = [s.name for s in phase if response.table_for(s) is not None]
        left = [s.name for s in phase if s.name not in done]
        notes.append(f"projector response {response.source or '(given)'} corrects "
                     f"{', '.join(done)}" + (f"; no table for {', '.join(left)} (they "
                                             "only decide fringe orders)" if left else ""))
    return {"noise": noise.as_dict(), "working": working,
            "chain": [s.name for s in UnwrapPlan.build(desc, noise.sensor, False).steps],
            "disagreement": spread, "misstated": misstated,
            "consistency": [p.as_dict() for p in run.pairs],
            "gray_edge_pixels": int(sum(stats.edges.values())),
            "low_modulation_reasons": {diagnostics.LOW_REASONS[b]: int(n)
                                       for b, n in stats.low.items() if n},
            "steps": {k: {"checked": int(v), "rejected": int(stats.rejected[k]),
                          "noisy": int(stats.noisy.get(k, 0))}
                      for k, v in stats.checked.items()},
            "notes": notes}


def _gray_working(cell_px: float, edges: int, valid: int) -> str:
    """How x_p is formed from a Gray code alone, with the count of edge pixels."""
    share = 100.0 * edges / valid if valid else 0.0
    return (f"Gray-code cell centres (cells of {cell_px:g} px; sigma_xp is the "
            f"quantisation, cell / sqrt(12) = {cell_px / 12 ** 0.5:.3g} px); {edges} edge "
            f"pixels ({share:.1f} % of the valid: one bit undecidable between two "
            "neighbouring cells) take the cell edge, sigma_xp 2 cell / sqrt(12) = "
            f"{2 * cell_px / 12 ** 0.5:.3g} px")


def _allocate(height: int, width: int, set_names: Sequence[str]) -> dict[str, np.ndarray]:
    out = {"xp": np.empty((height, width), np.float64),
           "modulation": np.empty((height, width), np.float32),
           "offset": np.empty((height, width), np.float32),
           "mask": np.empty((height, width), np.uint8),
           "sigma_xp": np.empty((height, width), np.float32)}
    for name in set_names:
        out[f"x:{name}"] = np.empty((height, width), np.float64)
    return out


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


def _provenance(desc: PatternDescription, noise: NoiseEstimate, stack: np.ndarray,
                info: dict) -> dict:
    from scanqa._version import __version__

    return {"software": "scanqa", "version": __version__, "stage": "decode",
            "patterns_file": desc.source, "patterns": desc.to_dict(),
            "sensor_resolved": asdict(noise.sensor), "image_dtype": str(stack.dtype),
            "image_shape": list(stack.shape[1:]), "decode": info,
            "mask_reasons": diagnostics.mask_reason_names()}


def decode_pattern_dir(path: str | os.PathLike,
                       progress: Callable[[str], None] | None = None,
                       response: str | os.PathLike | None = None) -> PhaseMap:
    """Load ``patterns.toml`` and its images from a folder (or file) and decode them.

    Parameters
    ----------
    path : str or PathLike
        Pattern folder, or its patterns.toml.
    progress : callable, optional
        Receives short progress messages.
    response : str or PathLike, optional
        Projector response file; default the one ``[decode] response`` names, if any.

    Returns
    -------
    PhaseMap
        The decoded map.
    """
    desc, stacks = load_pattern_dir(path, progress)
    note = lossy_image_note(desc)
    return decode_images(desc, stacks, progress=progress,
                         response=named_response(desc, response), notes=[note] if note else [])


def load_pattern_dir(path: str | os.PathLike, progress: Callable[[str], None] | None = None
                     ) -> tuple[PatternDescription, list[np.ndarray]]:
    """The description and image stacks of a pattern folder (or its patterns.toml)."""
    t0 = time.perf_counter()
    desc = load_patterns(path)
    stacks = read_pattern_images(desc)
    if progress:
        n = sum(st.shape[0] for st in stacks)
        h, w = stacks[0].shape[1:]
        progress(f"read {n} images of {w} x {h} px ({stacks[0].dtype}) from "
                 f"{desc.source} in {time.perf_counter() - t0:.2f} s")
    return desc, stacks


def named_response(desc: PatternDescription, given: str | os.PathLike | None = None
                   ) -> ProjectorResponse | None:
    """The projector response given (e.g. on the command line) or named by the coding.

    Parameters
    ----------
    desc : PatternDescription
        Its ``[decode] response`` is relative to the patterns.toml folder.
    given : str or PathLike, optional
        A response file that takes precedence.
    """
    if given:
        return load_response(given)
    if desc.options.response:
        folder = Path(desc.source).parent if desc.source else Path(".")
        return load_response(folder / desc.options.response)
    return None


def measure_response(desc: PatternDescription, images: Sequence[np.ndarray],
                     description: str = "") -> tuple[ProjectorResponse, PhaseMap]:
    """Phase-error tables of every phase set, from a decoded capture of a flat.

    Parameters
    ----------
    desc : PatternDescription
        The coding (decoded without a response).
    images : sequence of (N, H, W) arrays
        The capture [DN].
    description : str
        Stored in the response (where and how it was measured).

    Returns
    -------
    response : ProjectorResponse
        One table per phase set (see :func:`scanqa.decoding.response.measure_tables`).
    phase_map : PhaseMap
        The uncorrected decode it was measured on.
    """
    if not desc.phase_sets:
        raise InputError("a projector response is measured on phase sets; this scan has "
                         "none (a Gray code is not affected by the projector's gamma)")
    run = _decode(desc, images, None, None, keep_sets=True)
    pm = _phase_map(desc, run, None, images, ())
    maps = [run.out[f"x:{s.name}"] for s in desc.phase_sets]
    tables = measure_tables(desc.phase_sets, maps, pm.xp, pm.valid)
    return ProjectorResponse(tables, description), pm


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
