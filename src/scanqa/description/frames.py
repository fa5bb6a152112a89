"""What each captured frame is: the frame analysis behind ``scanqa describe``.

Camera frames of an unknown coding are split into runs that form one set each, from
the frames alone (:mod:`scanqa.description.inference` turns the runs into a
``patterns.toml``):

* every frame is normalised per pixel, ``n = (I - lo) / (hi - lo)`` with ``lo``, ``hi``
  the darkest and brightest sample of the pixel over all frames (over the black and
  white frames once they are known), which removes the albedo;
* uniform frames - nearly 1 or nearly 0 everywhere - at the start or the end of the
  sequence are the references (a black frame alone too), or, when those lack a level,
  a white and a black frame side by side inside it (a lone Gray bit, or a bit and its
  inverse, may look uniform on a small object);
* a run of N >= 3 frames whose mean is uniform while each frame is not, and whose
  frame-to-frame correlations follow ``cos(2 pi (j - k) / N)``, is an N-step phase set
  (the offsets ``A`` of its frames add up, the fringes cancel);
* what is left are Gray-code frames, split where their orientation changes; a bit and
  its inverse are anti-correlated (their sum is uniform).

Frames are assumed to be grouped by set (in the order given, or sorted by name); a set
whose frames are spread among other sets is not recognised.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from scanqa.errors import InputError

#: Largest number of steps searched for a phase set [-].
MAX_STEPS = 16
#: Mean-to-frame fringe ratio below which a run of frames sums to a uniform image [-].
UNIFORM_RATIO = 0.35
#: Largest departure of a frame-pair correlation from cos(2 pi (j - k) / N) [-] (lenient:
#: a coarse set seen over a fraction of its period correlates less than a full cycle).
CORRELATION_TOLERANCE = 0.5
#: Correlation below which two frames are a pattern and its inverse [-].
INVERSE_CORRELATION = -0.9
#: A frame is a white (black) reference when this share of its lit pixels is above
#: 1 - LEVEL_MARGIN (below LEVEL_MARGIN) in normalised units [-].
LEVEL_SHARE, LEVEL_MARGIN = 0.95, 0.3


@dataclass(frozen=True)
class Normalised:
    """Frames normalised per pixel, and where they are lit.

    Attributes
    ----------
    n : (K, H, W) float32
        ``(I - lo) / (hi - lo)``, 0.5 where unlit [-].
    lit : (H, W) bool
        Pixels whose brightest and darkest sample differ well above the noise.
    """

    n: np.ndarray
    lit: np.ndarray


@dataclass(frozen=True)
class Run:
    """A run of frames that forms one set.

    Attributes
    ----------
    kind : str
        "phase", "gray" or "reference".
    frames : tuple of int
        Frame indices in the sequence, in the given order.
    orientation : str
        "vertical" (fringes vary along the camera rows: projector columns) or
        "horizontal"; empty for references.
    anisotropy : float
        Ratio of the fringe gradient along the orientation to that across it [-]
        (how clearly the orientation was seen; 1 means undecided).
    order : tuple of int
        For a phase set, the step m_k of each frame (its shift is 2 pi m_k / N up to
        the sign); empty for frames in step order.
    """

    kind: str
    frames: tuple
    orientation: str = ""
    anisotropy: float = 1.0
    order: tuple = ()


def normalise(images: np.ndarray, lo: np.ndarray | None = None,
              hi: np.ndarray | None = None, out: np.ndarray | None = None) -> Normalised:
    """Per-pixel normalised frames and the lit mask.

    Parameters
    ----------
    images : (K, H, W) float
        Camera frames [DN].
    lo, hi : (H, W) float, optional
        Dark and bright level of each pixel [DN]; default the darkest and brightest
        sample over the frames.
    out : (K, H, W) float32, optional
        An array no longer needed (an earlier ``Normalised.n`` of the same frames) to
        write the result into when the arithmetic is float32 anyway: a new array of a
        few hundred MB costs more in page faults than the arithmetic.

    Returns
    -------
    Normalised
        The frames in [0, 1] (about) and the lit pixels.
    """
    lo = images.min(axis=0) if lo is None else lo
    hi = images.max(axis=0) if hi is None else hi
    span = (hi - lo).astype(np.float32)
    top = float(np.percentile(span, 99.5))
    if not top > 0:
        raise InputError("the frames do not change: every pixel has the same value in "
                         "every frame (is this a pattern sequence?)")
    lit = span > max(0.15 * top, 1e-6)
    reuse = (out is not None and out.shape == images.shape
             and np.result_type(images, lo) == out.dtype == np.float32)
    n = np.subtract(images, lo, out=out if reuse else None)  # then in place
    scale = np.where(lit, span, 1.0)
    if np.result_type(n, scale) == n.dtype:
        np.divide(n, scale, out=n)
    else:  # integer frames: the quotient is a new float array
        n = n / scale
    np.copyto(n, 0.5, where=~lit)
    return Normalised(n.astype(np.float32, copy=False), lit)


def frame_level(norm: Normalised, k: int) -> str:
    """"white", "black" or "" for frame k (uniform frames only)."""
    values = norm.n[k][norm.lit]
    if np.mean(values > 1 - LEVEL_MARGIN) >= LEVEL_SHARE:
        return "white"
    if np.mean(values < LEVEL_MARGIN) >= LEVEL_SHARE:
        return "black"
    return ""


def reference_frames(norm: Normalised) -> tuple[int, ...]:
    """Indices of the uniform reference frames (white, black, or black or white alone).

    Runs of uniform frames at the start or the end of the sequence are the references
    (a real tool puts them there); only when those do not hold both levels, a run
    holding both a white and a black frame inside the sequence is taken too. A lone
    uniform frame inside the sequence is taken for a Gray bit that a small object sees
    on one side of its edges (and so is a pair of them, a bit and its inverse, when
    the ends already hold both levels).
    """
    count = norm.n.shape[0]
    levels = [frame_level(norm, k) for k in range(count)]
    ends: list[int] = []
    inner: list[list[int]] = []
    k = 0
    while k < count:
        if not levels[k]:
            k += 1
            continue
        end = k
        while end + 1 < count and levels[end + 1]:
            end += 1
        run = list(range(k, end + 1))
        if k == 0 or end == count - 1:
            ends.extend(run)
        elif {levels[i] for i in run} == {"white", "black"}:
            inner.append(run)
        k = end + 1
    if {levels[i] for i in ends} != {"white", "black"} and inner:
        ends.extend(inner[0])
    ends = [k for k in ends if not _pattern_among_references(norm, k, ends, levels)]
    if len(ends) == count:  # every frame uniform: nothing is coded
        return ()
    return tuple(sorted(ends))


def _pattern_among_references(norm: Normalised, k: int, ends: list, levels: list) -> bool:
    """True for a frame that looks uniform but is a pattern: another reference frame
    has its level, and it is on the other side of the mid level at more than 0.1 % of
    the lit pixels and ten times as many as the cleanest of them (a Gray code's coarsest
    bit whose one edge is barely in view, next to the black frame; the per-pixel
    normalisation puts a true reference at the extreme of every pixel)."""
    same = [j for j in ends if levels[j] == levels[k]]
    if len(same) < 2:
        return False

    def other_side(j):
        values = norm.n[j][norm.lit]
        return float(np.mean(values > 0.5 if levels[j] == "black" else values < 0.5))
    share = other_side(k)
    return share > 1e-3 and share > 10 * min(other_side(j) for j in same)


def _sample(norm: Normalised, frames, limit: int = 400_000) -> np.ndarray:
    """(len(frames), S) normalised values at up to ``limit`` lit pixels."""
    idx = np.flatnonzero(norm.lit)
    if idx.size > limit:
        idx = idx[:: idx.size // limit + 1]
    return np.stack([norm.n[k].ravel()[idx] for k in frames]).astype(np.float64)


def covariance(norm: Normalised) -> np.ndarray:
    """(K, K) covariance of the normalised frames over (a sample of) the lit pixels [-]."""
    values = _sample(norm, range(norm.n.shape[0]))
    values -= values.mean(axis=1, keepdims=True)
    return (values @ values.T) / values.shape[1]


def correlations(norm: Normalised, frames, cov: np.ndarray | None = None) -> np.ndarray:
    """(F, F) correlation of the normalised frames over the lit pixels [-].

    ``cov`` is :func:`covariance` of ``norm`` when already computed.
    """
    c = (covariance(norm) if cov is None else cov)[np.ix_(list(frames), list(frames))]
    scale = np.sqrt(np.diag(c))
    return c / np.outer(scale, scale).clip(1e-12)


def uniform_ratio(norm: Normalised, frames, cov: np.ndarray | None = None) -> float:
    """Fringe contrast of the mean of ``frames`` relative to that of one frame [-].

    Near 0 when the frames' fringes cancel in their sum (a phase set, a bit and its
    inverse), near 1 for unrelated frames: ``std(mean_J n) / mean_J std(n_j)``, from
    the covariance (``var(mean) = sum_jk C_jk / N**2``).
    """
    idx = list(frames)
    c = (covariance(norm) if cov is None else cov)[np.ix_(idx, idx)]
    spread = math.sqrt(max(c.sum(), 0.0)) / len(idx)
    return float(spread / max(np.sqrt(np.diag(c)).mean(), 1e-12))


def is_phase_run(norm: Normalised, frames, cov: np.ndarray | None = None,
                 order=None) -> bool:
    """True when ``frames`` look like one N-step phase set (N = len(frames) >= 3) whose
    frames have the steps ``order`` (default 0, 1, ..., N - 1)."""
    steps = len(frames)
    cov = covariance(norm) if cov is None else cov
    if steps < 3 or uniform_ratio(norm, frames, cov) > UNIFORM_RATIO:
        return False
    return _order_misfit(correlations(norm, frames, cov), order) <= CORRELATION_TOLERANCE


def _order_misfit(corr: np.ndarray, order=None) -> float:
    """Largest departure of the correlations from cos(2 pi (m_j - m_k) / N) [-] (inf
    when two frames are a pattern and its inverse but not half a cycle apart)."""
    steps = corr.shape[0]
    m = np.arange(steps) if order is None else np.asarray(order)
    expected = np.cos(2 * np.pi * (m[:, None] - m[None, :]) / steps)
    if ((corr < INVERSE_CORRELATION) & (expected > -0.99)).any():  # a bit and its inverse
        return math.inf
    return float(np.abs(corr - expected).max())


def step_order(norm: Normalised, frames, cov: np.ndarray) -> tuple | None:
    """Steps of 4 to 6 frames whose fringes cancel but come in another order than their
    shifts (e.g. 0, pi, pi/2, 3 pi/2): the order whose correlations fit best, the first
    frame at step 0 and the second at a step below N/2 (the other sign is the same
    order mirrored, left to the phase slope), if the frames are not binary and do not
    come as pattern-inverse pairs (0, pi, pi/2, 3 pi/2 cannot be told from two Gray
    bits with their inverses); None when none fits."""
    steps = len(frames)
    if not 4 <= steps <= 6 or uniform_ratio(norm, frames, cov) > UNIFORM_RATIO:
        return None
    corr = correlations(norm, frames, cov)
    best = min((p for p in itertools.permutations(range(1, steps))
                if p[0] <= steps / 2), key=lambda p: _order_misfit(corr, (0, *p)))
    order = (0, *best)
    if _order_misfit(corr, order) > CORRELATION_TOLERANCE:
        return None
    # Gray bits with interleaved inverses correlate the same way (b0, ~b0, b1, ~b1 as
    # steps 0, 2, 1, 3) - and two blurred bits of a Gray code are a quadrature pair:
    # such an order is left to the Gray code. Binary frames are not a phase set either
    # (a third of a sinusoid's samples lie in the middle half of its range, a few per
    # cent of a binary frame's)
    if all((order[2 * j] - order[2 * j + 1]) % steps == steps // 2
           for j in range(steps // 2)):
        return None
    values = _sample(norm, frames)
    middle = float(np.mean((values > 0.25) & (values < 0.75)))
    return order if middle > 0.15 else None


def gradient_energy(frame: np.ndarray, lit: np.ndarray) -> tuple[float, float]:
    """Mean absolute difference between neighbours along rows and along columns [-],
    on the frame averaged over blocks of f x f pixels (f = 1 up to 300 px, about
    1/150 of the smaller side beyond): in a large frame, a stripe edge every hundred
    pixels is otherwise lost in the noise of neighbouring pixels."""
    f = max(1, min(frame.shape) // 150) if min(frame.shape) > 300 else 1
    if f > 1:
        h, w = (frame.shape[0] // f) * f, (frame.shape[1] // f) * f
        frame = frame[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))
        lit = lit[:h, :w].reshape(h // f, f, w // f, f).all(axis=(1, 3))
    du = np.abs(np.diff(frame, axis=1))[lit[:, 1:] & lit[:, :-1]]
    dv = np.abs(np.diff(frame, axis=0))[lit[1:] & lit[:-1]]
    return float(du.mean()) if du.size else 0.0, float(dv.mean()) if dv.size else 0.0


def phasor(images: np.ndarray, order=()) -> np.ndarray:
    """Temporal DFT bin 1 of an N-step set, ``sum_k I_k exp(-2 pi i m_k / N)`` [DN].

    Its angle is the fringe phase for shifts +2 pi m_k / N (minus the phase for shifts
    -2 pi m_k / N); its magnitude is N B / 2. ``order`` gives the steps m_k (default
    0, 1, ..., N - 1).
    """
    steps = images.shape[0]
    m = np.asarray(order) if len(order) else np.arange(steps)
    weights = np.exp(-2j * np.pi * m / steps).astype(np.complex64)
    return np.tensordot(weights, images.astype(np.float32, copy=False), axes=1)


def phase_frequency(z: np.ndarray, axis: int) -> float:
    """Mean fringe frequency of a phasor map along a camera axis [rad/camera px].

    The angle of ``sum z[i + 1] conj(z[i])`` along ``axis`` (1: rows, u; 0: columns,
    v): a modulation-weighted mean of the local frequency, signed (positive where the
    phase grows with the camera coordinate).
    """
    a = np.moveaxis(z, axis, -1)
    return float(np.angle(np.sum(a[..., 1:] * np.conj(a[..., :-1]))))


def orientation_of(du: float, dv: float) -> tuple[str, float]:
    """"vertical" when the fringes vary along the rows more than along the columns."""
    if du >= dv:
        return "vertical", du / max(dv, 1e-12)
    return "horizontal", dv / max(du, 1e-12)


def phase_orientation(z: np.ndarray) -> tuple[str, float]:
    """Orientation of a phase set from its phase slope along u and along v."""
    return orientation_of(abs(phase_frequency(z, 1)), abs(phase_frequency(z, 0)))


def split_runs(images: np.ndarray, norm: Normalised, references: tuple) -> list[Run]:
    """The sequence as runs of phase sets, Gray frames and the references.

    Parameters
    ----------
    images : (K, H, W) float
        Camera frames [DN].
    norm : Normalised
        The frames normalised (by the references when there are).
    references : tuple of int
        Indices of the white and black frames.

    Returns
    -------
    list of Run
        In sequence order (the reference run first); Gray runs are split where the
        orientation changes.
    """
    runs = [Run("reference", tuple(references))] if references else []
    rest = [k for k in range(images.shape[0]) if k not in references]
    cov = covariance(norm)
    parts: list = []  # phase Runs and lists of loose frames, in sequence order
    loose: list[int] = []
    i = 0
    while i < len(rest):
        steps, order = _phase_at(norm, rest[i:], cov)
        if not steps:
            loose.append(rest[i])
            i += 1
            continue
        parts.append(loose)
        loose = []
        frames = tuple(rest[i:i + steps])
        z = phasor(images[list(frames)], order)
        orient, aniso = phase_orientation(z)
        parts.append((Run("phase", frames, orient, aniso, order), _phase_angle(z)))
        i += steps
    parts.append(loose)
    angles: dict = {}  # the fringes' direction of each orientation's phase sets
    for part in parts:
        if isinstance(part, tuple):
            angles.setdefault(part[0].orientation, []).append(part[1])
    directions = {o: 0.5 * math.atan2(np.mean(np.sin(2 * np.array(a))),
                                      np.mean(np.cos(2 * np.array(a))))
                  for o, a in angles.items()}
    for part in parts:
        runs.extend([part[0]] if isinstance(part, tuple) else
                    _gray_runs(norm, part, directions))
    return runs


def _phase_angle(z: np.ndarray) -> float:
    """Direction of a phase set's phase gradient from the camera's u axis [rad]."""
    return math.atan2(phase_frequency(z, 0), phase_frequency(z, 1))


def edge_direction(frame: np.ndarray, lit: np.ndarray) -> tuple[float, float]:
    """Direction of a frame's stripes and how clear it is.

    The structure tensor of the frame's gradient over the lit pixels (on blocks as
    :func:`gradient_energy` averages them): the angle of its main axis from the camera's
    u axis [rad, in (-pi/2, pi/2]], and the square root of the ratio of its eigenvalues
    [-] (1 for no direction); the frame is smoothed by a 1-px Gaussian first, or the
    steps of a pixelated oblique edge bias the angle (35 degrees for 30). Unlike the
    gradient energies along u and v, neither depends on how the camera is rolled
    against the projector.
    """
    f = max(1, min(frame.shape) // 150) if min(frame.shape) > 300 else 1
    if f > 1:
        h, w = (frame.shape[0] // f) * f, (frame.shape[1] // f) * f
        frame = frame[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))
        lit = lit[:h, :w].reshape(h // f, f, w // f, f).all(axis=(1, 3))
    frame = gaussian_filter(frame.astype(np.float64), 1.0)  # a pixelated edge's steps
    ok = lit[1:-1, 2:] & lit[1:-1, :-2] & lit[2:, 1:-1] & lit[:-2, 1:-1]
    gu = (frame[1:-1, 2:] - frame[1:-1, :-2])[ok].astype(np.float64)  # central differences:
    gv = (frame[2:, 1:-1] - frame[:-2, 1:-1])[ok].astype(np.float64)  # both at the pixel
    a, b, c = float(gu @ gu), float(gv @ gv), float(gu @ gv)
    if a + b <= 0:
        return 0.0, 1.0
    disc = math.hypot((a - b) / 2, c)
    low = max((a + b) / 2 - disc, 1e-12 * (a + b))
    return 0.5 * math.atan2(2 * c, a - b), math.sqrt(((a + b) / 2 + disc) / low)


def _angle_apart(a: float, b: float) -> float:
    """Angle between two undirected directions [rad, 0..pi/2]."""
    return abs(math.remainder(a - b, math.pi))


def _stripe_orientation(angle: float, directions: dict) -> str:
    """The orientation of stripes at ``angle``: that of the phase sets whose fringes run
    nearest (one orientation's sets only: theirs within 45 degrees, else the other),
    else "vertical" within 45 degrees of the u axis."""
    if len(directions) == 2:
        return min(directions, key=lambda o: _angle_apart(angle, directions[o]))
    if len(directions) == 1:
        (o, d), = directions.items()
        other = "horizontal" if o == "vertical" else "vertical"
        return o if _angle_apart(angle, d) < math.pi / 4 else other
    return "vertical" if _angle_apart(angle, 0.0) < math.pi / 4 else "horizontal"


def _phase_at(norm: Normalised, rest: list, cov: np.ndarray) -> tuple[int, tuple]:
    """Steps and step order of the phase set that starts ``rest`` ((0, ()) for none)."""
    for n in range(3, min(MAX_STEPS, len(rest)) + 1):
        frames = rest[:n]
        if not _contiguous(frames):
            break
        if is_phase_run(norm, frames, cov):
            return n, ()
        order = step_order(norm, frames, cov)
        if order is not None:
            return n, order
    return 0, ()


def _contiguous(frames) -> bool:
    return all(b == a + 1 for a, b in itertools.pairwise(frames))


def _gray_runs(norm: Normalised, frames: list[int], directions: dict | None = None
               ) -> list[Run]:
    """Gray frames split into runs of one orientation (uncertain frames join a run).

    A frame's orientation is that of its stripes' direction (:func:`edge_direction`)
    against the phase sets' fringes (``directions``: their angle per orientation
    [rad]), so a rolled camera's oblique stripes are read right; a frame whose
    direction is unclear (a coarse bit with an edge or none in view) joins its coarser
    neighbour - the next bit of its own code, whether the bits come coarse or fine
    first, where the neighbour across a code's boundary is the other code's finest.
    """
    if not frames:
        return []
    seen = [edge_direction(norm.n[k], norm.lit) for k in frames]
    energy = [sum(gradient_energy(norm.n[k], norm.lit)) for k in frames]
    clear = [_stripe_orientation(a, directions or {}) if r > 1.5 else "" for a, r in seen]
    for i in sorted(range(len(frames)), key=lambda j: energy[j], reverse=True):
        if not clear[i]:  # the finer unclear frames first: a coarser one may follow them
            near = [j for j in (i - 1, i + 1) if 0 <= j < len(frames) and clear[j]
                    and abs(frames[j] - frames[i]) == 1]
            coarser = min(near, key=lambda j: energy[j], default=None)
            clear[i] = clear[coarser] if coarser is not None else \
                _stripe_orientation(seen[i][0], directions or {})
    runs, start = [], 0
    for i in range(1, len(frames) + 1):
        if i == len(frames) or clear[i] != clear[start] or frames[i] != frames[i - 1] + 1:
            part = frames[start:i]
            aniso = math.exp(np.mean([math.log(max(seen[j][1], 1e-12))
                                      for j in range(start, i)]))
            runs.append(Run("gray", tuple(part), clear[start], aniso))
            start = i
    return runs


def frequency_ratio(z_fine: np.ndarray, z_coarse: np.ndarray, axis: int,
                    usable: np.ndarray, steps: int = 3) -> tuple[float, float]:
    """Ratio of the coarse set's phase slope to the fine set's, on the same segments.

    Over segments of L pixels along ``axis`` (L about 1/``steps`` of a coarse fringe, so
    that the phase error a nonlinear projector leaves, periodic in 2 pi / steps, cancels
    between the segment's ends),
    the coarse phase change is compared with the fine phase unwrapped along the segment
    (its neighbour differences added up); segments crossing an unlit or a masked pixel
    are left out, and segments whose ratio departs by more than 10 % from the median
    (a depth step on the way) too. Same segments, same weights: no bias from where the
    modulation is high.

    Parameters
    ----------
    z_fine, z_coarse : (H, W) complex
        Phasors of the two sets (:func:`phasor`).
    axis : int
        1 along the rows (u), 0 along the columns (v).
    usable : (H, W) bool
        Pixels whose phasors are trusted.

    Returns
    -------
    ratio : float
        Coarse over fine phase slope, i.e. fine period over coarse period [-] (NaN when
        too few segments).
    spread : float
        Relative standard deviation of the ratio between four bands of the image
        across ``axis`` (a measure of its uncertainty, systematic effects included) [-].
    """
    zf, zc, ok = (np.moveaxis(a, axis, -1) for a in (z_fine, z_coarse, usable))
    pair_ok = ok[..., 1:] & ok[..., :-1]
    slope = abs(phase_frequency(z_coarse, axis))
    cycle = 2 * math.pi / steps / max(slope, 1e-9)  # the error's period [camera px]
    length = int(np.clip(round(cycle * math.ceil(16 / cycle)), 8, zf.shape[-1] // 3))
    fine, coarse = (_unwrapped_change(z, length) for z in (zf, zc))
    bad = np.concatenate([np.zeros((*pair_ok.shape[:-1], 1)), np.cumsum(~pair_ok, -1)], -1)
    clean = (bad[..., length:] - bad[..., :-length]) == 0
    keep = clean & (np.abs(fine) > 1.0)
    if keep.sum() < 50:
        return math.nan, math.nan
    med = np.median(coarse[keep] / fine[keep])
    keep &= np.abs(coarse - med * fine) <= 0.1 * abs(med * fine)
    ratio = float(coarse[keep].sum() / fine[keep].sum())
    bands = [b for b in np.array_split(np.arange(keep.shape[0]), 4)
             if keep[b].sum() >= 20]
    parts = [coarse[b][keep[b]].sum() / fine[b][keep[b]].sum() for b in bands
             if abs(fine[b][keep[b]].sum()) > 0]
    spread = float(np.std(parts) / abs(ratio)) if len(parts) > 1 and ratio else 0.05
    if not math.isfinite(ratio):
        return math.nan, math.nan
    return ratio, max(spread, 1e-4)


def _unwrapped_change(z: np.ndarray, length: int) -> np.ndarray:
    """Phase change over ``length`` pixels along the last axis, neighbour steps added
    (the end-point difference where no step slips) [rad]."""
    step = np.angle(z[..., 1:] * np.conj(z[..., :-1]))
    csum = np.concatenate([np.zeros((*step.shape[:-1], 1)), np.cumsum(step, -1)], -1)
    return csum[..., length:] - csum[..., :-length]
