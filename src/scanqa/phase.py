"""Phase decoding: fringe images to unwrapped projector coordinate, modulation and noise.

The image model (shared with the simulator, see :mod:`scanqa.io.patterns`) is, for
frame k of a phase set of period P,

    I_k = A + B cos(phi + delta_k),   phi = 2 pi x_p / P,

so that a least-squares fit of ``I_k = A + C cos delta_k + S sin delta_k`` gives the
offset A, the modulation ``B = hypot(C, S)`` and the wrapped phase
``phi = atan2(-S, C)`` for any N >= 3 shifts (equal shifts reduce to the classical
N-step formulas). Temporal unwrapping is hierarchical (coarse to fine periods, or a
Gray code ordering the coarsest period; :mod:`scanqa.unwrap`), and every unwrapped set
is fused by inverse-variance weighting.

Noise: each sample has variance ``sigma_I^2 = r^2 + 1/12 + (I - black) / g`` [DN^2]
(read noise r [DN], quantisation when the images are integers, shot noise with the gain
g [e-/DN]). First-order propagation through the fit gives the phase variance per pixel
(exact for unequal shifts and for N = 3, where the shot-noise term depends on phi); for
N >= 4 equal shifts it is the familiar ``2 sigma_I^2 / (N B^2)`` [1]_. The projector
coordinate noise is ``sigma_xp = sigma_phi P / (2 pi)``.

References
----------
.. [1] C. Rathjen, "Statistical properties of phase-shift algorithms", J. Opt. Soc. Am.
   A 12(9), 1995.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from scanqa.errors import InputError
from scanqa.io.patterns import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    SensorModel,
    load_patterns,
    read_pattern_images,
)

#: Mask reason codes stored in ``PhaseMap.mask`` (uint8).
MASK_VALID = 0
#: A sample of a phase set reached the saturation level.
MASK_SATURATED = 1
#: Modulation too low for a reliable phase: below the floor, too noisy to unwrap, or an
#: undecidable Gray-code bit (dark pixels land here).
MASK_LOW_MODULATION = 2
#: Sets (or the Gray code) disagree by more than the accepted unwrapping residual.
MASK_INCONSISTENT = 3
#: The unwrapped coordinate lies outside the coded range [-0.5, width - 0.5).
MASK_OUT_OF_RANGE = 4
#: Name of each reason code.
MASK_REASONS = {MASK_VALID: "valid", MASK_SATURATED: "saturated",
                MASK_LOW_MODULATION: "low_modulation", MASK_INCONSISTENT: "inconsistent",
                MASK_OUT_OF_RANGE: "out_of_range"}

_TWO_PI = 2.0 * np.pi
_CHUNK_PIXELS = 32768  # pixels per chunk: measured fastest on 2448 x 2048 (cache-sized)


@dataclass(frozen=True, eq=False)
class PhaseMap:
    """Decoded projector coordinate of every camera pixel, with mask and noise.

    Attributes
    ----------
    xp : (H, W) float64
        Unwrapped projector coordinate along the fringe direction (x_p for vertical
        fringes, y_p for horizontal) [projector px]; NaN where masked.
    modulation : (H, W) float32
        Modulation B of the working (finest) phase set [DN].
    offset : (H, W) float32
        Offset A of the working phase set [DN].
    mask : (H, W) uint8
        Reason code, ``MASK_VALID`` (0) where xp is valid (see ``MASK_REASONS``).
    sigma_xp : (H, W) float32
        Predicted standard deviation of xp [projector px]; NaN where masked.
    period_px : float
        Working (finest) fringe period [projector px].
    orientation : str
        "vertical" (xp is x_p) or "horizontal" (xp is y_p).
    projector_width_px : int
        Coded range along the fringe direction [projector px].
    provenance : dict
        JSON-serialisable description of how the map was made.
    """

    xp: np.ndarray
    modulation: np.ndarray
    offset: np.ndarray
    mask: np.ndarray
    sigma_xp: np.ndarray
    period_px: float
    orientation: str = "vertical"
    projector_width_px: int = 0
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        arrays = {"xp": np.float64, "modulation": np.float32, "offset": np.float32,
                  "mask": np.uint8, "sigma_xp": np.float32}
        shape = np.shape(self.xp)
        for name, dtype in arrays.items():
            arr = np.asarray(getattr(self, name), dtype=dtype).view()  # no copy
            if arr.ndim != 2 or arr.shape != shape:
                raise InputError(f"PhaseMap.{name} must be a 2-D array of the shape of xp "
                                 f"{shape}, got {arr.shape}")
            arr.flags.writeable = False  # on the view only: the caller's array is untouched
            object.__setattr__(self, name, arr)
        self._check_consistency()

    def _check_consistency(self) -> None:
        unknown = np.setdiff1d(np.unique(self.mask), list(MASK_REASONS))
        if unknown.size:
            raise InputError(f"PhaseMap.mask holds unknown reason codes {unknown.tolist()} "
                             f"(known: {MASK_REASONS})")
        finite, valid = np.isfinite(self.xp), self.mask == MASK_VALID
        if (finite & ~valid).any():
            raise InputError("PhaseMap.xp must be NaN where mask != 0 (masked pixels carry "
                             "no coordinate)")
        if (valid & ~finite).any():
            raise InputError("PhaseMap.xp must be finite where mask == 0; mask the pixel")
        if not (np.isfinite(self.period_px) and self.period_px > 0):
            raise InputError(f"PhaseMap.period_px must be > 0 [px], got {self.period_px!r}")

    @property
    def shape(self) -> tuple[int, int]:
        """Image size (H, W) [px]."""
        return self.xp.shape  # type: ignore[return-value]

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool, True where xp is valid."""
        return self.mask == MASK_VALID

    def counts(self) -> dict[str, int]:
        """Number of pixels per mask reason, keyed by reason name."""
        hist = np.bincount(self.mask.ravel(), minlength=len(MASK_REASONS))
        return {MASK_REASONS[code]: int(hist[code]) for code in MASK_REASONS}

    def summary(self) -> str:
        """One line: valid pixel count and the count of each mask reason."""
        counts = self.counts()
        total = self.mask.size
        why = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "valid")
        pct = 100.0 * counts["valid"] / total if total else 0.0
        return f"{counts['valid']} of {total} pixels valid ({pct:.1f} %); masked: {why}"


@dataclass(frozen=True, eq=False)
class WrappedPhase:
    """Result of demodulating one phase set.

    Attributes
    ----------
    phase_rad : (H, W) float64
        Wrapped phase phi in [0, 2 pi) [rad].
    offset_dn : (H, W) float64
        Offset A [DN].
    modulation_dn : (H, W) float64
        Modulation B [DN].
    sigma_phase_rad : (H, W) float64
        Predicted standard deviation of phi [rad].
    """

    phase_rad: np.ndarray
    offset_dn: np.ndarray
    modulation_dn: np.ndarray
    sigma_phase_rad: np.ndarray


@dataclass(frozen=True, eq=False)
class _ShiftFit:
    """Constants of the least-squares fit for one set of shifts.

    ``rows`` maps the N samples to (A, C, S); the other fields are the coefficients of
    the phase variance polynomial (see :func:`_phase_variance`).
    """

    rows: np.ndarray
    quad: tuple[float, float, float]
    cubic: tuple[float, float, float, float]

    @classmethod
    def from_shifts(cls, shifts_rad: Sequence[float]) -> _ShiftFit:
        d = np.asarray(shifts_rad, dtype=np.float64)
        c, s = np.cos(d), np.sin(d)
        rows = np.linalg.pinv(np.column_stack([np.ones_like(d), c, s]))
        p1, p2 = rows[1], rows[2]
        quad = (float(p1 @ p1), float(p1 @ p2), float(p2 @ p2))
        cubic = (float(p1 ** 2 @ s), float(p1 ** 2 @ c - 2 * (p1 * p2) @ s),
                 float(p2 ** 2 @ s - 2 * (p1 * p2) @ c), float(p2 ** 2 @ c))
        if max(abs(t) for t in cubic) < 1e-12:
            cubic = (0.0, 0.0, 0.0, 0.0)
        return cls(rows, quad, cubic)


def sample_variance(intensity_dn: np.ndarray, sensor: SensorModel,
                    quantised: bool) -> np.ndarray:
    """Variance of one intensity sample from the sensor noise model.

    Parameters
    ----------
    intensity_dn : (...) float
        Expected sample value [DN].
    sensor : SensorModel
        Gain [e-/DN], read noise [e-] and black level [DN].
    quantised : bool
        Add the quantisation variance 1/12 [DN^2] (integer images).

    Returns
    -------
    (...) float64
        ``r^2 + q + max(I - black, 0) / g`` [DN^2].

    Examples
    --------
    >>> float(sample_variance(np.float64(100.0), SensorModel(gain_e_per_dn=4.0,
    ...       read_noise_e=8.0), quantised=False))
    29.0
    """
    floor = sensor.read_noise_dn ** 2 + (1.0 / 12.0 if quantised else 0.0)
    signal = np.maximum(np.asarray(intensity_dn, dtype=np.float64) - sensor.black_level_dn, 0)
    return floor + signal / sensor.gain_e_per_dn


def _fit_rows(fit: _ShiftFit, frames: np.ndarray) -> np.ndarray:
    """(3, M) float64 least-squares (A, C, S) of (N, M) samples."""
    return fit.rows @ frames.astype(np.float64)


def _phase_variance(fit: _ShiftFit, a: np.ndarray, c: np.ndarray, s: np.ndarray,
                    b2: np.ndarray, sensor: SensorModel, quantised: bool) -> np.ndarray:
    """Variance of phi = atan2(-S, C) to first order, per pixel [rad^2].

    ``dphi/dI_k = (S p1_k - C p2_k) / B^2`` and ``var I_k = e + (C cos d_k + S sin d_k)
    / g`` with ``e = var(A)`` of the noise model; the sum over k is a polynomial in C, S
    whose constant coefficients come from the fit rows p1, p2.
    """
    q11, q12, q22 = fit.quad
    quad = q11 * s * s - 2.0 * q12 * s * c + q22 * c * c
    var = sample_variance(a, sensor, quantised) * quad
    if any(fit.cubic):
        t1, t2, t3, t4 = fit.cubic
        var += (((t1 * s + t2 * c) * s + t3 * c * c) * s + t4 * c * c * c) \
            / sensor.gain_e_per_dn
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(b2 > 0, var / (b2 * b2), np.inf)


def _demodulate_flat(fit: _ShiftFit, frames: np.ndarray, sensor: SensorModel,
                     quantised: bool) -> tuple[np.ndarray, ...]:
    """Offset, modulation, phase fraction [cycles in [0, 1)] and phase variance."""
    a, c, s = _fit_rows(fit, frames)
    b2 = c * c + s * s
    frac = np.arctan2(-s, c) * (1.0 / _TWO_PI)
    frac += frac < 0
    return a, np.sqrt(b2), frac, _phase_variance(fit, a, c, s, b2, sensor, quantised)


def demodulate(images: np.ndarray, shifts_rad: Sequence[float] | None = None,
               sensor: SensorModel | None = None) -> WrappedPhase:
    """Wrapped phase, offset, modulation and phase noise of one N-step set.

    Parameters
    ----------
    images : (N, H, W) array
        The N frames, N >= 3 [DN].
    shifts_rad : sequence of float, optional
        Phase shift delta_k of each frame [rad]; default ``2 pi k / N``.
    sensor : SensorModel, optional
        Noise model; default :class:`~scanqa.io.patterns.SensorModel()`.

    Returns
    -------
    WrappedPhase
        phi in [0, 2 pi), A, B and sigma_phi of every pixel.

    Examples
    --------
    >>> x = np.array([[0.5, 1.0, 7.25]])
    >>> frames = np.stack([100 + 50 * np.cos(2 * np.pi * x / 8 + 2 * np.pi * k / 4)
    ...                    for k in range(4)])
    >>> (demodulate(frames).phase_rad * 8 / (2 * np.pi)).round(9).tolist()
    [[0.5, 1.0, 7.25]]
    """
    stack = np.asarray(images)
    if stack.ndim != 3 or stack.shape[0] < 3:
        raise InputError(f"images must be an (N, H, W) stack with N >= 3, got {stack.shape}")
    n = stack.shape[0]
    shifts = _TWO_PI * np.arange(n) / n if shifts_rad is None else shifts_rad
    if len(shifts) != n:
        raise InputError(f"got {len(shifts)} shifts_rad for {n} images; give one per image")
    fit = _ShiftFit.from_shifts(shifts)
    quantised = stack.dtype.kind in "ui"
    sensor = SensorModel() if sensor is None else sensor
    with np.errstate(invalid="ignore"):
        a, b, frac, var = _demodulate_flat(fit, stack.reshape(n, -1), sensor, quantised)
    shape = stack.shape[1:]
    return WrappedPhase(_TWO_PI * frac.reshape(shape), a.reshape(shape), b.reshape(shape),
                        np.sqrt(var).reshape(shape))


# ------------------------------------------------------------------------- decoding

def decode(desc: PatternDescription, images: Sequence[np.ndarray], *,
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
    from scanqa.unwrap import UnwrapPlan, unwrap_rows

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
    from scanqa import __version__

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
    return decode(desc, stacks, progress=progress)


__all__ = ["MASK_INCONSISTENT", "MASK_LOW_MODULATION", "MASK_OUT_OF_RANGE", "MASK_REASONS",
           "MASK_SATURATED", "MASK_VALID", "GrayCodeSet", "PhaseMap", "PhaseSet",
           "WrappedPhase", "decode", "decode_pattern_dir", "demodulate", "sample_variance"]
