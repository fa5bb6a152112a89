"""Projector nonlinearity: phase-error tables, their measurement and their correction.

A projector whose emitted light is not linear in the pattern value (gamma) adds
harmonics to every fringe. An N-step fit aliases some of them into the fundamental,
so the wrapped phase carries a periodic error ``e(phi)`` that depends only on the
measured phase, the shifts and the harmonics' strength at that period - a ripple of
N cycles per fringe for equal shifts [1]_. It is systematic: averaging periods does not
remove it, and it makes periods disagree.

Measurement (:func:`measure_tables`) needs a decoded capture:

- coarser sets: the error is ``(x_set - x_p) 2 pi / P`` with x_p the finest set's
  coordinate, whose own error is smaller by the period ratio - any scene will do;
- the finest set: its error is the residual of x_p from a smooth surface (a cubic in
  the camera coordinates), which holds for a flat target; the table is measured on
  the flat and stored.

Both are binned over the measured wrapped phase (median per bin, ``bins`` bins), so the
correction is a look-up ``phi - e(phi)`` of the measured phase, interpolated
periodically. The tables belong to one projector and pattern set (period, steps,
shifts); ambient light and albedo do not change them, defocus weakens the harmonics of
fine periods (measure near the working distance).

References
----------
.. [1] S. Zhang, P. S. Huang, "Phase error compensation for a 3-D shape measurement
   system based on the phase-shifting method", Opt. Eng. 46(6), 063601, 2007.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanqa.decoding.coding import PhaseSet
from scanqa.errors import ConfigError
from scanqa.io.response import read_response_file, write_response_file
from scanqa.numeric import robust_std

#: Bins of a measured table over one cycle of the wrapped phase.
DEFAULT_BINS = 64
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, eq=False)
class PhaseErrorTable:
    """Phase error of one pattern set as a function of its measured wrapped phase.

    Attributes
    ----------
    period_px : float
        Period of the set [projector px].
    steps : int
        Frames of the set [-].
    shifts_rad : tuple of float
        Shifts of the set [rad].
    error_rad : (n,) float64
        Mean error (measured - true phase) at measured phase ``(i + 1/2) 2 pi / n`` [rad].
    """

    period_px: float
    steps: int
    shifts_rad: tuple
    error_rad: np.ndarray
    _grid: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        err = np.asarray(self.error_rad, dtype=np.float64).ravel()
        if err.size < 4 or not np.isfinite(err).all() or np.abs(err).max() >= math.pi / 2:
            raise ConfigError(f"phase_error_rad of the period {self.period_px:g} px table "
                              "must be >= 4 finite values of magnitude < pi/2 [rad]")
        n = err.size
        centres = (np.arange(n) + 0.5) / n
        slope = (np.roll(err, -1) - np.roll(err, 1)) * (n / 2.0) / _TWO_PI  # d e / d phi
        grid = (np.concatenate([[centres[-1] - 1.0], centres, [centres[0] + 1.0]]),
                np.concatenate([[err[-1]], err, [err[0]]]) / _TWO_PI,
                np.concatenate([[slope[-1]], slope, [slope[0]]]))
        object.__setattr__(self, "error_rad", err)
        object.__setattr__(self, "shifts_rad", tuple(float(s) for s in self.shifts_rad))
        object.__setattr__(self, "_grid", grid)

    def matches(self, pset: PhaseSet) -> bool:
        """True when the table was measured for this set's period, steps and shifts."""
        return (math.isclose(self.period_px, pset.period_px, rel_tol=1e-6)
                and self.steps == pset.steps
                and np.allclose(self.shifts_rad, pset.shifts_rad, atol=1e-6))

    def correct(self, frac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corrected wrapped phase of a measured one, and how it scales the noise.

        Parameters
        ----------
        frac : (...) float
            Measured wrapped phase [cycles in [0, 1)].

        Returns
        -------
        corrected : (...) float64
            ``frac - e(frac)`` [cycles in [0, 1)].
        gain : (...) float64
            ``|1 - de/dphi|``: where the projector compresses the phase, the correction
            stretches it back, and the noise with it [-].
        """
        centres, error, slope = self._grid
        out = frac - np.interp(frac, centres, error)
        return out - np.floor(out), np.abs(1.0 - np.interp(frac, centres, slope))

    @property
    def rms_rad(self) -> float:
        """RMS of the error over the cycle [rad]."""
        return float(np.sqrt(np.mean(self.error_rad ** 2)))


@dataclass(frozen=True)
class ProjectorResponse:
    """The phase-error tables of one projector (a response file).

    Attributes
    ----------
    tables : tuple of PhaseErrorTable
        One per measured pattern set.
    description : str
        Free text (how and where it was measured).
    source : str
        The file it was read from.
    """

    tables: tuple
    description: str = ""
    source: str = ""

    def table_for(self, pset: PhaseSet) -> PhaseErrorTable | None:
        """The table of a phase set, or None when the response has none for it."""
        return next((t for t in self.tables if t.matches(pset)), None)

    def check_covers(self, sets: Sequence[PhaseSet]) -> None:
        """Raise unless the response has a table for the finest of ``sets``.

        The finest set gives x_p; coarser sets only decide fringe orders, so a table
        missing for them leaves them uncorrected (the decode summary says which).
        """
        finest = sets[-1]
        if self.table_for(finest) is None:
            have = ", ".join(f"{t.period_px:g} px x {t.steps}" for t in self.tables) or "none"
            raise ConfigError(
                f"projector response {self.source or '(given)'} has no table for the finest "
                f"set {finest.name!r} (period {finest.period_px:g} px, {finest.steps} "
                f"steps; it has: {have}); measure one on a flat with this pattern set, or "
                "decode without the response")


def load_response(path: str | os.PathLike) -> ProjectorResponse:
    """Read and validate a projector response file (:mod:`scanqa.io.response`).

    Parameters
    ----------
    path : str or PathLike
        The TOML file.
    """
    data = read_response_file(path)
    try:
        tables = tuple(PhaseErrorTable(float(t["period_px"]), int(t["steps"]),
                                       tuple(t["shifts_rad"]), np.array(t["phase_error_rad"]))
                       for t in data.get("set", []))
    except (KeyError, TypeError, ValueError) as err:
        raise ConfigError(f"projector response {path}: every [[set]] needs period_px, "
                          f"steps, shifts_rad and phase_error_rad ({err})") from None
    except ConfigError as err:
        raise ConfigError(f"projector response {path}: {err}") from None
    return ProjectorResponse(tables, str(data.get("description", "")), str(path))


def save_response(path: str | os.PathLike, response: ProjectorResponse) -> Path:
    """Write a projector response file atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; its folder must exist.
    response : ProjectorResponse
        The tables.
    """
    sets = [{"period_px": t.period_px, "steps": t.steps, "shifts_rad": list(t.shifts_rad),
             "phase_error_rad": [round(float(e), 7) for e in t.error_rad]}
            for t in response.tables]
    return write_response_file(path, {"description": response.description, "set": sets})


# ------------------------------------------------------------------------ measuring

def smooth_surface(xp: np.ndarray, valid: np.ndarray, degree: int = 3,
                   max_samples: int = 200000) -> np.ndarray:
    """Robust least-squares polynomial surface through the valid pixels of a map.

    Parameters
    ----------
    xp : (H, W) float
        Coordinate map [projector px].
    valid : (H, W) bool
        Pixels to fit.
    degree : int
        Total degree of the polynomial in the camera coordinates [-].
    max_samples : int
        Pixels used at most (an even subsample) [-].

    Returns
    -------
    (H, W) float64
        The surface at every pixel [projector px].
    """
    h, w = xp.shape
    v, u = np.nonzero(valid)
    step = max(1, u.size // max_samples)
    u, v = u[::step], v[::step]
    powers = [(i, d - i) for d in range(degree + 1) for i in range(d + 1)]
    norm = max(h, w) / 2.0
    design = np.column_stack([((u - w / 2) / norm) ** a * ((v - h / 2) / norm) ** b
                              for a, b in powers])
    target = xp[v, u]
    keep = np.ones(target.size, bool)
    for _ in range(4):
        coef = np.linalg.lstsq(design[keep], target[keep], rcond=None)[0]
        res = target - design @ coef
        scale = robust_std(res[keep], centre=0.0) + 1e-12
        keep = np.abs(res) < 4 * scale
    vv, uu = np.mgrid[0:h, 0:w]
    return sum(c * ((uu - w / 2) / norm) ** a * ((vv - h / 2) / norm) ** b
               for c, (a, b) in zip(coef, powers, strict=True))


def binned_error(phase_frac: np.ndarray, error_rad: np.ndarray,
                 bins: int = DEFAULT_BINS) -> np.ndarray:
    """Median error per bin of the measured wrapped phase, empty bins interpolated.

    Parameters
    ----------
    phase_frac : (n,) float
        Measured wrapped phase [cycles in [0, 1)].
    error_rad : (n,) float
        Its error [rad].
    bins : int
        Number of bins over one cycle [-].

    Returns
    -------
    (bins,) float64
        Median error per bin [rad].
    """
    index = np.minimum((phase_frac * bins).astype(np.int64), bins - 1)
    order = np.argsort(index, kind="stable")
    edges = np.searchsorted(index[order], np.arange(bins + 1))
    med = np.full(bins, np.nan)
    for i in range(bins):
        chunk = error_rad[order[edges[i]:edges[i + 1]]]
        if chunk.size >= 10:
            med[i] = np.median(chunk)
    ok = np.isfinite(med)
    if ok.sum() < bins // 2:
        raise ConfigError(f"too few valid pixels to measure a phase-error table ({ok.sum()} "
                          f"of {bins} phase bins filled); use a larger, well-lit flat")
    centres = np.arange(bins) + 0.5
    return np.interp(centres, centres[ok], med[ok], period=bins)


def measure_tables(sets: Sequence[PhaseSet], set_maps: Sequence[np.ndarray],
                   xp: np.ndarray, valid: np.ndarray, bins: int = DEFAULT_BINS
                   ) -> tuple[PhaseErrorTable, ...]:
    """Phase-error tables of every phase set of a decoded flat.

    Parameters
    ----------
    sets : sequence of PhaseSet
        The phase sets, coarsest first (the last is the finest).
    set_maps : sequence of (H, W) float
        Each set's own unwrapped coordinate, uncorrected [projector px].
    xp : (H, W) float
        The decoded coordinate (the finest set's) [projector px].
    valid : (H, W) bool
        Valid pixels.
    bins : int
        Bins over one cycle [-].

    Returns
    -------
    tuple of PhaseErrorTable
        In the order of ``sets``, leaving out coarse sets whose phase the capture does
        not cover over enough of a cycle (they only decide fringe orders).

    Raises
    ------
    ConfigError
        When the finest set's table cannot be measured.
    """
    surface = smooth_surface(xp, valid)
    out = []
    for i, (pset, xs) in enumerate(zip(sets, set_maps, strict=True)):
        finest = i == len(sets) - 1
        ref = surface if finest else xp
        frac = np.mod(xs[valid] / pset.period_px, 1.0)
        err = (xs[valid] - ref[valid]) * (_TWO_PI / pset.period_px)
        try:
            table = binned_error(frac, err, bins)
        except ConfigError:
            if finest:
                raise
            continue
        out.append(PhaseErrorTable(pset.period_px, pset.steps, pset.shifts_rad, table))
    return tuple(out)
