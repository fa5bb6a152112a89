"""What the frames say beyond their sets, for ``scanqa describe``.

:mod:`scanqa.description.inference` measures sets, ratios and cells; what is left open
(the absolute scale, the fringe counts) it settles here:

* the decoding check: each candidate description is decoded on a sample of the frames
  (:func:`check`), and candidates that decode nearly as well are reported
  (:func:`alternatives`);
* the fringes' profile (:func:`fringe_profile`): a set whose phase clusters at a few
  values was projected as binary (square-wave) fringes, which a projector can only
  shift by whole pixels - of the cell widths the Gray bits allow, those whose periods
  shift by whole pixels come first (:func:`whole_shift_first`); the profile is stated;
* the view's extent (:func:`fewest_fringes`): the coarsest set's phase, unwrapped along
  the image lines, runs through as many cycles as the object shows of it - the set has
  at least that many fringes over the panel, which rules out the fewer counts that fit
  the same period ratios (9, 8 and 1 for 45, 40 and 5).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.decoder import decoded_valid
from scanqa.decoding.waveform import fringe_shape
from scanqa.description.gray import snapped
from scanqa.errors import ScanQAError

#: Rows and columns the decoding check reads at most (every n-th of a larger frame) [-].
CHECK_ROWS, CHECK_COLUMNS = 200, 400
#: Lit pixels the fringe profile is read from at most [-].
PROFILE_PIXELS = 60000
#: Noise models of the profile's pixel selection (the decoder's check keeps pixels whose
#: phase noise is below 0.05 rad by the model): the decoder's default camera (4 e-/DN,
#: 8 e-: only strong fringes, the least blurred ones, count) and a quiet one (0.5 DN:
#: a real DLP capture's 45-DN fringes count). The profile is named when either finds it.
PROFILE_SENSORS = (SensorModel(gain_e_per_dn=4.0, read_noise_e=8.0),
                   SensorModel(gain_e_per_dn=1e6, read_noise_e=5e5))


def row_step(rows: int) -> int:
    """Every how many rows the decoding check reads a frame of ``rows`` rows [-]."""
    return max(1, rows // CHECK_ROWS)


def column_step(columns: int) -> int:
    """Every how many columns the decoding check reads a frame [-]."""
    return max(1, columns // CHECK_COLUMNS)


def sample_stacks(images: np.ndarray, lists: list) -> list:
    """Stacks of the frames ``lists`` (indices per set) at every ``row_step``-th row and
    ``column_step``-th column."""
    step, cstep = row_step(images.shape[1]), column_step(images.shape[2])
    return [np.ascontiguousarray(images[idx][:, ::step, ::cstep]) for idx in lists]


def check(desc: PatternDescription, stacks: list, lit: np.ndarray) -> float:
    """Share of the lit pixels (of the sample) that decode valid [-]; -1 when the
    decoder refuses the description."""
    quiet = logging.getLogger(decoded_valid.__module__)
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # a candidate's warnings are not the capture's
    try:
        valid = decoded_valid(desc, stacks)  # decode_images' valid pixels, no summary
    except ScanQAError:
        return -1.0
    finally:
        quiet.setLevel(level)
    lit_rows = lit[::row_step(lit.shape[0]), ::column_step(lit.shape[1])]
    return float(np.count_nonzero(valid & lit_rows) / max(np.count_nonzero(lit_rows), 1))


def alternatives(best: PatternDescription, tried: list, share: float,
                 questions: list) -> None:
    """Candidates that decode nearly as well as the chosen one become a question
    (appended to ``questions``)."""
    def periods(d):
        return ", ".join(f"{s.period_px:g}" for s in d.sets if isinstance(s, PhaseSet))

    def differ(d):  # by more than the 0.1 % a period is stated to
        return any(abs(a.period_px / b.period_px - 1) > 1e-3 for a, b in
                   zip(d.sets, best.sets, strict=True) if isinstance(a, PhaseSet))

    close = [d for d, got in tried if d is not best and got >= 0.9 * share and share > 0
             and differ(d)]
    for d in close[:2]:
        questions.append(f"periods {periods(d)} px decode nearly as many pixels as the "
                         f"chosen {periods(best)} px: which were projected?")
    if share < 0.3:
        questions.append(f"only {100 * max(share, 0):.0f} % of the lit pixels decode: is a "
                         "set missing or misread?")


@dataclass(frozen=True)
class FringeProfile:
    """How far a phase set's fringes are from sine waves.

    Attributes
    ----------
    staircase : bool
        The phase clusters at a few values: binary (square-wave) fringes, or clipping.
    peak_cycles, rms_cycles : float
        Peak and rms of the phase error the profile causes [cycles of the period].
    """

    staircase: bool
    peak_cycles: float
    rms_cycles: float

    def note(self, name: str, steps: int, period_px: float) -> str:
        """One sentence naming the profile and its x_p error [px]."""
        what = (f"its {steps}-step phase clusters at a few values - 50 % square waves "
                "(binary fringes, as a DLP projects them) or hard clipping" if self.staircase
                else f"its {steps}-step phase ripples {steps} times per period - a "
                "projector's gamma or saturation")
        return (f"the fringes of {name} are not sine waves: {what}; x_p errs by up to "
                f"+-{self.peak_cycles * period_px:.2g} px (rms "
                f"{self.rms_cycles * period_px:.2g} px), which scanqa decode adds to "
                "sigma_xp")


def fringe_profile(frames: np.ndarray, shifts: tuple, lit: np.ndarray
                   ) -> FringeProfile | None:
    """The profile of one phase set's fringes from its frames, or None for sine waves
    (or too few clean pixels to tell), as the decoder's check reads it
    (:func:`scanqa.decoding.waveform.fringe_shape`, here per cycle), with the larger
    error of the pixels the two ``PROFILE_SENSORS`` select.

    Parameters
    ----------
    frames : (N, H, W) array
        The set's frames [DN].
    shifts : tuple of float
        Their shifts [rad] (the sign measured; the start does not matter).
    lit : (H, W) bool
        Pixels to read.
    """
    idx = np.flatnonzero(lit)
    if idx.size > PROFILE_PIXELS:
        idx = idx[:: idx.size // PROFILE_PIXELS + 1]
    values = frames.reshape(frames.shape[0], -1)[:, idx].astype(np.float64)
    pset = PhaseSet("set", 1.0, frames.shape[0], tuple(shifts))
    found = [fringe_shape(pset, values, sensor.resolved(frames.dtype),
                          frames.dtype.kind in "ui") for sensor in PROFILE_SENSORS]
    found = [f for f in found if f is not None]
    if not found:
        return None
    shape = max(found, key=lambda f: f.peak_px)
    return FringeProfile(shape.staircase, shape.peak_px, shape.rms_px)


def whole_shift_first(choices: list, periods_in_cells: list, steps: list,
                      width_px: int) -> list:
    """The cell widths [px], likeliest first, with those that divide the coded width
    and whose periods (``cell * ratio``) shift by whole projector pixels (``P / N``
    whole for every set) ahead of the other dividing ones, the order kept otherwise:
    binary fringes are shifted by whole pixels (a DLP's 3-step set of 114 px moves by
    38 px; of the 76, 95 and 114-px cells that 4 bits over 1140 px allow and that
    divide it, only 114 does)."""
    def whole(cell):
        return all(abs(cell * r / n - round(cell * r / n)) < 1e-6
                   for r, n in zip(periods_in_cells, steps, strict=True))
    return sorted(choices, key=lambda c: (width_px % c != 0, width_px % c == 0
                                          and not whole(c)))


def fewest_fringes(z: np.ndarray, axis: int, usable: np.ndarray) -> float:
    """Cycles a phase set's phase runs through along the image lines (``axis``), a
    lower bound of its count of fringes over the panel [-].

    The phase is unwrapped along each line over runs of usable pixels (neighbour
    differences added up) and its range taken per run; the 90th percentile of the
    lines' largest range is returned (a noisy step that slips a cycle in one line does
    not count), 0 when fewer than 10 lines hold a run.
    """
    zz, ok = np.moveaxis(z, axis, -1), np.moveaxis(usable, axis, -1)
    step = np.angle(zz[..., 1:] * np.conj(zz[..., :-1])) / (2 * math.pi)
    step = step.reshape(-1, step.shape[-1])
    good = (ok[..., 1:] & ok[..., :-1]).reshape(step.shape)
    # runs of good neighbour pairs (row-major, so the ends pair with the starts)
    edge = np.diff(np.pad(good.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    line, start = np.nonzero(edge == 1)
    end = np.nonzero(edge == -1)[1]
    long = end - start >= 8
    line, start, length = line[long], start[long], (end - start)[long]
    if np.unique(line).size < 10:
        return 0.0
    ranges = np.empty(length.size)
    size = 1 << (int(length.max()) - 1).bit_length()
    while size >= 8:  # runs of (size/2, size] pixels together, padded with zeros
        part = np.flatnonzero((length <= size) & (length > size // 2))
        if part.size:
            j = np.arange(size)
            take = start[part, None] + np.minimum(j, length[part, None] - 1)
            steps = np.where(j < length[part, None], step[line[part, None], take], 0)
            path = np.cumsum(steps, axis=1)  # each run's phase from its start, in
            # sequence as each run's own sum; the padding repeats its last value
            ranges[part] = (np.maximum(path.max(axis=1), 0.0).astype(np.float64)
                            - np.minimum(path.min(axis=1), 0.0))
        size //= 2
    best = np.full(step.shape[0], -np.inf)
    np.maximum.at(best, line, ranges)
    return float(np.percentile(best[np.isfinite(best)], 90))


def noise_note(desc: PatternDescription) -> str:
    """One loud line when the described frames hold none of the noise sources the
    decoder estimates the camera noise from (:mod:`scanqa.decoding.noise`: a phase set
    of 4 or more steps, two phase sets of one direction, white and black frames, a Gray
    code with inverses), else ""."""
    phase = desc.phase_sets
    gray = desc.gray_set
    if any(s.steps >= 4 for s in phase) or len(phase) >= 2 or \
            desc.reference_set is not None or (gray is not None and gray.inverse != "none"):
        return ""
    return ("NO NOISE SOURCE in these frames (no white and black pair, no 4-step set, no "
            "second set, no Gray inverses): scanqa decode will ASSUME every sigma from a "
            "default camera - add a [sensor] table with gain_e_per_dn and read_noise_e "
            "(the camera's data sheet, or a photon-transfer measurement) before trusting "
            "sigma_xp")


#: Bins of the wrapped phase in :func:`straightened` [-].
PHASE_BINS = 360


def straightened(z: np.ndarray, sign: float, steps: int, lit: np.ndarray) -> np.ndarray:
    """A phase set's phasors with the error its fringe profile causes taken out.

    Binary fringes' phase is a staircase (a 3-step set of square waves reads 6 values,
    off by up to 1/12 of a period); where the Gray code's cell edges fall on one point
    of the staircase, the phase start measured there is off by as much (x_p then errs
    by that everywhere). Over many periods the true phase is spread evenly, so the
    measured phase's cumulative distribution F gives the error ``e = psi - F(psi)``
    (as :mod:`scanqa.decoding.waveform` reads it); its harmonics at multiples of N, the
    profile's (a mean of zero: the plateaus' centres read true), are subtracted,
    ``psi - e(psi)``, on the lit pixels of at least the median modulation.

    Parameters
    ----------
    z : (H, W) complex
        The set's phasors (:func:`scanqa.description.frames.phasor`).
    sign : float
        The sign of its shifts (the phase is ``sign * angle(z)``).
    steps : int
        N [-].
    lit : (H, W) bool
        Pixels to read.

    Returns
    -------
    (H, W) complex
        Phasors of the same modulation and the corrected phase.
    """
    phase = (sign * np.angle(z) / (2 * math.pi)) % 1.0
    strong = lit & (np.abs(z) >= np.median(np.abs(z)[lit]))
    if strong.sum() < 1000:
        return z
    hist = np.bincount((phase[strong] * PHASE_BINS).astype(np.intp) % PHASE_BINS,
                       minlength=PHASE_BINS)
    edges = np.arange(1, PHASE_BINS + 1) / PHASE_BINS
    spectrum = np.fft.rfft(edges - np.cumsum(hist) / strong.sum())
    k = np.arange(spectrum.size)
    error = np.fft.irfft(np.where((k > 0) & (k % steps == 0), spectrum, 0), PHASE_BINS)
    # the error sampled at the bins' upper edges: interpolated periodically
    grid = np.concatenate([[edges[-1] - 1.0], edges])
    table = np.concatenate([[error[-1]], error])
    fixed = phase - np.interp(phase, grid, table)
    return np.abs(z) * np.exp(1j * sign * 2 * math.pi * fixed)


#: How much more of the lit pixels a candidate must decode to be taken over a likelier
#: one [-]: another shape (periods in cells, phase starts, code), or only another scale.
MARGIN, SCALE_MARGIN = 0.02, 0.05


def scale_only(a: PatternDescription | None, b: PatternDescription | None) -> bool:
    """True when two candidates differ only by their scale: other Gray cells, the same
    periods in cells (within 0.2 %), phase starts (0.05 rad) and code. Such candidates
    decode alike - x_p scales with the cell - and the sample's noise, not the capture,
    tells their shares apart by a per cent or two."""
    if a is None or b is None or a.gray_set is None or b.gray_set is None:
        return False
    ca, cb = a.gray_set.cell_px, b.gray_set.cell_px
    if ca == cb or a.gray_set.code != b.gray_set.code:
        return False
    for p, q in zip(a.phase_sets, b.phase_sets, strict=True):
        if abs((p.period_px / ca) / (q.period_px / cb) - 1) > 2e-3 or \
                abs(math.remainder(p.shifts_rad[0] - q.shifts_rad[0], 2 * math.pi)) > 0.05:
            return False
    return True


#: How near a usual start (a multiple of pi / 6) a start measured over whole cells is
#: snapped to it [rad]: such a measurement is good to a few mrad (1.7 mrad on a DLP's
#: simulated square waves, where the edges alone erred by 0.25 rad).
CELL_SNAP_RAD = 0.02


def cell_offsets(z: np.ndarray, sign: float, cells: np.ndarray, cell: float,
                 period: float, axis: int) -> float | None:
    """Phase start of a set relative to the Gray code [rad], from every pixel of the
    cells seen whole, not from their edges alone; None when fewer than 20 cells are.

    Within a cell seen whole along an image line - a run of one cell index between its
    two neighbours' - x is taken to grow linearly from the cell's left edge
    (``c cell - 1/2``) to its right edge, the pixel at ``(j + 1/2) / L`` of the run's L
    pixels; the start is the phase less ``2 pi x / P``, averaged as unit phasors. The
    error of a non-sine profile averages out over a whole period (a square wave's
    staircase reads its plateaus' centres: its error is a sawtooth of mean zero), where
    at the edges alone it is one value of the sawtooth - up to 1/12 of a period for a
    3-step set, whose sharp plateaus no straightening can open.
    """
    cc = np.moveaxis(cells, axis, -1)
    psi = sign * np.angle(np.moveaxis(z, axis, -1))
    cc, psi = cc.reshape(-1, cc.shape[-1]), psi.reshape(-1, psi.shape[-1])
    ok = np.isfinite(cc)
    value = np.where(ok, cc, -10.0)
    # runs of one value along each line (of 8 or more lit pixels), not a line's first
    # or last, of a cell whose left and right neighbours are the cells before and after
    change = np.diff(value, axis=1) != 0
    line, a = np.nonzero(change)
    a = a + 1
    nxt = np.append(a[1:], value.shape[1])
    b = np.where(np.append(line[1:] == line[:-1], False), nxt, value.shape[1])
    keep = (ok.sum(axis=1) >= 8)[line] & (b < value.shape[1])
    line, a, b = line[keep], a[keep], b[keep]
    idx = value[line, a]
    keep = ((idx >= 0) & (b - a >= 6) & (value[line, a - 1] == idx - 1)
            & (value[line, np.minimum(b, value.shape[1] - 1)] == idx + 1))
    line, a, b, idx = line[keep], a[keep], b[keep], idx[keep]
    if line.size < 20:
        return None
    length = b - a
    means = np.empty(line.size, complex)
    for n in np.unique(length):  # runs of one length summed together, each as alone
        part = np.flatnonzero(length == n)
        j = np.arange(n)
        x = idx[part, None] * cell - 0.5 + (j + 0.5) / n * cell
        phase = psi[line[part, None], a[part, None] + j]
        means[part] = np.sum(np.exp(1j * (phase - 2 * np.pi * x / period)), axis=1) / n
    total = 0j
    for m in means.tolist():  # in the lines' order, as the runs were found
        total += m
    return snapped(float(np.angle(total)), within=CELL_SNAP_RAD)
