"""The decoded phase map of a scan: projector coordinate, modulation, mask and noise.

:class:`PhaseMap` is what the decoder returns and what every later stage reads;
:func:`load_phase_map` / :func:`save_phase_map` store it as a ``phase.npz``
(:mod:`scanqa.io.phasemap` is the file format).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanqa.chunks import row_bands, run_bands
from scanqa.errors import InputError
from scanqa.io import phasemap as phasemap_file

#: Mask reason codes stored in ``PhaseMap.mask`` (uint8).
MASK_VALID = 0
#: A sample of a phase set reached the saturation level.
MASK_SATURATED = 1
#: Modulation too low for a reliable phase: below the floor, too noisy to unwrap, or
#: undecidable Gray-code bits (dark pixels land here; the one undecidable bit between two
#: neighbouring cells of a Gray code decoded alone gives their edge instead, and a phase
#: the Gray code orders decides wherever the cells left open are narrower than its period).
MASK_LOW_MODULATION = 2
#: Sets (or the Gray code) disagree by more than the accepted unwrapping residual.
MASK_INCONSISTENT = 3
#: The unwrapped coordinate lies outside the coded range [-0.5, width - 0.5).
MASK_OUT_OF_RANGE = 4
#: Fringe directions: "vertical" fringes code x_p, "horizontal" ones y_p.
ORIENTATIONS = ("vertical", "horizontal")
#: Name of each reason code.
MASK_REASONS = {MASK_VALID: "valid", MASK_SATURATED: "saturated",
                MASK_LOW_MODULATION: "low_modulation", MASK_INCONSISTENT: "inconsistent",
                MASK_OUT_OF_RANGE: "out_of_range"}
#: Pixels per band of the validation of a map (:meth:`PhaseMap._consistent`) [-].
VALIDATE_PIXELS = 1 << 18


def value_rules(sigma_xp: np.ndarray, modulation: np.ndarray, offset: np.ndarray,
                valid: np.ndarray) -> tuple:
    """The rules of a map's per-pixel values, stated once for the banded check and the
    error: (name, where broken, rule) of sigma_xp [projector px], modulation and offset
    [DN] over the same pixels, ``valid`` where the mask is 0."""
    return (("sigma_xp", np.isinf(sigma_xp) | (sigma_xp < 0),
             "must be >= 0 [projector px] (NaN where masked), never negative or infinite"),
            ("modulation", np.isinf(modulation) | (modulation < 0)
             | (valid & np.isnan(modulation)),
             "must be finite and >= 0 [DN] where the pixel is valid"),
            ("offset", np.isinf(offset) | (valid & np.isnan(offset)),
             "must be finite [DN] where the pixel is valid"))


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
        if not self._consistent():
            self._check_consistency()  # raises the one clear error

    def _consistent(self) -> bool:
        """True when every rule of :meth:`_check_consistency` holds, checked in bands of
        rows on every core (the arrays of a 5 MP map are read once, in parallel)."""
        if self.orientation not in ORIENTATIONS or \
                not (np.isfinite(self.period_px) and self.period_px > 0):
            return False
        height, width = self.xp.shape
        parts = run_bands(self._band_consistent, row_bands(height, width, VALIDATE_PIXELS))
        if not all(ok for ok, _ in parts):
            return False
        counts = np.sum([n for _, n in parts], axis=0) if parts else np.zeros(256, int)
        return not np.setdiff1d(np.flatnonzero(counts), list(MASK_REASONS)).size

    def _band_consistent(self, r0: int, r1: int) -> tuple[bool, np.ndarray]:
        """Whether rows r0..r1 keep the rules, and their count of each mask code."""
        mask = self.mask[r0:r1]
        valid = mask == MASK_VALID
        bad = (np.isfinite(self.xp[r0:r1]) != valid).any() or any(
            broken.any() for _, broken, _ in value_rules(
                self.sigma_xp[r0:r1], self.modulation[r0:r1], self.offset[r0:r1], valid))
        return not bad, np.bincount(mask.ravel(), minlength=256)

    def _check_consistency(self) -> None:
        mask = self.mask
        codes = np.flatnonzero(np.bincount(mask.ravel())) if mask.dtype == np.uint8 \
            else np.unique(mask)  # a count of 256 codes is ~10x faster than a hash
        unknown = np.setdiff1d(codes, list(MASK_REASONS))
        if unknown.size:
            raise InputError(f"PhaseMap.mask holds unknown reason codes {unknown.tolist()} "
                             f"(known: {MASK_REASONS})")
        finite, valid = np.isfinite(self.xp), self.mask == MASK_VALID
        if (finite != valid).any():  # one pass; which way, only when it fails
            if (finite & ~valid).any():
                raise InputError("PhaseMap.xp must be NaN where mask != 0 (masked pixels "
                                 "carry no coordinate)")
            raise InputError("PhaseMap.xp must be finite where mask == 0; mask the pixel")
        if not (np.isfinite(self.period_px) and self.period_px > 0):
            raise InputError(f"PhaseMap.period_px must be > 0 [px], got {self.period_px!r}")
        self._check_values(valid)

    def _check_values(self, valid: np.ndarray) -> None:
        """The one validation of the per-pixel values, for a decoded map and a read one:
        sigma_xp >= 0 and never infinite (NaN: no prediction), modulation and offset
        finite where valid and modulation >= 0, a known orientation."""
        if self.orientation not in ORIENTATIONS:
            raise InputError(f"PhaseMap.orientation must be one of {', '.join(ORIENTATIONS)}"
                             f", got {self.orientation!r}")
        for name, bad, rule in value_rules(self.sigma_xp, self.modulation, self.offset,
                                           valid):
            if bad.any():
                where = np.argwhere(bad)[0]
                value = float(getattr(self, name)[tuple(where)])
                raise InputError(f"PhaseMap.{name} {rule}: {int(bad.sum())} pixels are not "
                                 f"(first at row {where[0]}, column {where[1]}: {value:.6g}); "
                                 "decode the images again")

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
        return count_reasons(self.mask)

    def summary(self) -> str:
        """The decode summary: counts, then what the decode found out.

        The first line gives the valid pixel count and the count of each mask reason;
        a freshly decoded map adds lines for the noise source, how x_p was formed, the
        disagreement between periods, a misstated coding, warnings (what the captures
        say against their description: :mod:`scanqa.decoding.checks`), notes, and -
        when most pixels are masked - the dominant reason with the key that would
        change it.
        """
        counts = self.counts()
        total = self.mask.size
        why = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "valid")
        pct = 100.0 * counts["valid"] / total if total else 0.0
        first = f"{counts['valid']} of {total} pixels valid ({pct:.1f} %); masked: {why}"
        info = self.provenance.get("decode") if isinstance(self.provenance, dict) else None
        if not isinstance(info, dict) or "noise" not in info:
            return first
        return "\n".join([first, *_summary_lines(info)])


def count_reasons(mask: np.ndarray) -> dict[str, int]:
    """Number of pixels per mask reason, keyed by reason name.

    Parameters
    ----------
    mask : (H, W) uint8
        Reason codes (:data:`MASK_REASONS`).
    """
    mask = np.asarray(mask)  # one comparison per code: no int64 copy of a 5 MP mask
    return {name: int(np.count_nonzero(mask == code)) for code, name in MASK_REASONS.items()}


def _summary_lines(info: dict) -> list[str]:
    """Lines after the first of a decode summary, from ``provenance["decode"]``."""
    lines = [f"noise: {info['noise']['source']} (read noise "
             f"{info['noise']['read_noise_dn']:.3g} DN, sigma_I "
             f"{info['noise']['sigma_dn_at_100dn']:.3g} DN at 100 DN)",
             f"x_p: {info['working']}"]
    for row in info.get("disagreement", []):
        lines.append(f"period disagreement: {row['set']!r} - x_p median "
                     f"{row['median_px']:+.3g} px, spread {row['spread_px']:.3g} px "
                     f"(robust std; 90 % within {row['p05_px']:+.3g}..{row['p95_px']:+.3g} "
                     f"px, {row['samples']} samples)")
    for row in info.get("misstated", []):
        lines.append(f"warning: misstated coding? step {row['step']!r} rejected "
                     f"{100 * row['rejected_share']:.0f} % of {row['checked']} pixels, as "
                     f"unrelated patterns would ({100 * row['uniform_share']:.0f} %): check "
                     "period_px, cell_px and projector_width_px; every pixel is masked")
    lines += [f"warning: {text}" for text in info.get("warnings", [])]
    lines += [note for note in info.get("notes", []) if note]
    if info.get("hint"):
        lines.append(info["hint"])
    return lines


def save_phase_map(path: str | os.PathLike, phase_map: PhaseMap) -> Path:
    """Write a phase map to an ``.npz`` file atomically (:mod:`scanqa.io.phasemap`).

    Parameters
    ----------
    path : str or PathLike
        Output file (conventionally ``phase.npz``); its folder must exist.
    phase_map : PhaseMap
        The map to store.

    Returns
    -------
    Path
        The written file.
    """
    arrays = {name: getattr(phase_map, name) for name in phasemap_file.ARRAYS}
    return phasemap_file.write_phase_file(
        path, arrays, period_px=phase_map.period_px, orientation=phase_map.orientation,
        projector_width_px=phase_map.projector_width_px, provenance=phase_map.provenance)


def load_phase_map(path: str | os.PathLike) -> PhaseMap:
    """Read a phase map written by :func:`save_phase_map`.

    Parameters
    ----------
    path : str or PathLike
        The ``.npz`` file.

    Returns
    -------
    PhaseMap
        The map, with validated shapes, mask codes and NaN convention.

    Raises
    ------
    InputError
        When the file is missing or unreadable, of another format version, lacks an
        entry, or its arrays are inconsistent.
    """
    arrays, scalars = phasemap_file.read_phase_file(path)
    try:
        return PhaseMap(**arrays, **scalars)
    except InputError as err:
        raise InputError(f"phase map {path}: {err}") from None
