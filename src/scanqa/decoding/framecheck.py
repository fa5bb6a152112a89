"""Frame-level checks of the phase sets: a zeroed, black, swapped or foreign frame.

A phase set's N frames sample one sinusoid per pixel, I_k = A + B cos(phi - delta_k). A
frame that is not one of them - zeroed or black (a dropped capture), two frames swapped,
a frame of another scene or another set - still decodes: the arctangent returns a phase
for any N numbers, and the noise model, fed the wrong frames, even predicts a smaller
sigma. The frames themselves say it, before anything is decoded:

- *a black frame*: its mean over the sampled rows is below :data:`BLACK_SHARE` of its
  siblings' median mean (a fringe pattern never dims a whole frame so: the darkest frame
  of a one-period cue set is 0.21 of its siblings on the sample scans and SLStudio's
  skull, 0.52-0.75 on its board poses, 0.94-0.99 on kamino410's captures);
- *frames that fit no sinusoid* (N >= 4): the least-squares fit of A, B cos, B sin to
  the N frames leaves residuals that noise cannot explain; at the well-modulated pixels
  the median ratio of the residual's RMS to B exceeds :data:`MISFIT_SHARE` where a
  correct set leaves noise only, or the residuals follow the phase's 0th and 1st
  harmonics across the pixels (:data:`COHERENT_SHARE`), as one frame of a wrong level,
  shift or scene makes them, where a projector's gamma adds a 2nd harmonic only - and
  by more than the scan's noise leaves in one pixel (measured on the scan's other
  phase sets, at least the sensor's): noise correlated over the pixels (scene- and
  projector-side noise in few cells of a small window, widened by a defocused camera's
  blur) is not averaged out of the harmonics' fit, and as a share of a modulation that
  defocus has cut it exceeds :data:`COHERENT_SHARE` on correct sets. (With
  N = 3 the fit is exact for any frames; only the black-frame test applies. With N = 4
  the residual has one degree of freedom, shared by all frames: the set is named, not
  the frame.)

Each finding is a warning naming the set, the frame (its file when known) and the fix,
and the decode trusts no pixel of the scan (:mod:`scanqa.decoding.decoder`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.demodulate import ShiftFit, sample_variance

#: A frame darker than this share of its siblings' median mean is black or zeroed [-].
BLACK_SHARE = 0.05
#: Median residual RMS over modulation above which a set's frames fit no sinusoid [-].
#: Correct simulated sets leave 0.005-0.014 (the sample sweeps and gauge scans); an
#: uncorrected projector gamma leaves its second harmonic, b2/b1 = 0.29 at gamma 2.2 and
#: 0.40 at 3.0 (about 0.7 of that as the median residual); one zeroed or two swapped
#: frames of four leave 0.6.
MISFIT_SHARE = 0.4
#: RMS share of the residuals that follows the phase's 0th and 1st harmonics (a frame of
#: a wrong shift or scene) above which the frames are broken [-]; correct sets leave noise
#: averaged over the pixels, and a projector's gamma its 2nd harmonic, which is fitted:
#: at most 0.0015 on every 4-step set of the sample sweeps and gauge scans, also with a
#: gamma of 2.2 applied; a frame of another scene leaves 0.014-0.31 (tuned on those
#: simulated scans; no real 4-step capture was at hand). Noise correlated over a small
#: window exceeds it on correct sets - 0.0101 on the 5 px set of a 40 px window 24 mm
#: behind the camera's focus (noise 0.031 of the blurred modulation), 0.0102 on a 7 px
#: set of a 24 px window at focus (scene noise 0.026 of it) - hence the noise floor of
#: :func:`_misfit`.
COHERENT_SHARE = 0.01
#: Fewest well-modulated sampled pixels for the misfit test [-].
MIN_PIXELS = 200
#: Most pixels the sinusoid fit reads (every k-th of a larger sample, evenly spread):
#: its medians and its five-term harmonic fit are as well determined by 40 000 pixels
#: as by the 157 000 of 64 rows of a 2448-px camera, at a quarter of the cost [-].
MAX_FIT_PIXELS = 40000


def _frame_name(pset: PhaseSet, k: int) -> str:
    return f"frame {k} ({pset.files[k]})" if k < len(pset.files) else f"frame {k}"


def broken_frames(desc: PatternDescription, sample: Sequence[np.ndarray],
                  sensor: SensorModel, quantised: bool) -> list[str]:
    """Warnings for phase-set frames that are black or fit no sinusoid (module notes).

    Parameters
    ----------
    desc : PatternDescription
        The scan's description.
    sample : sequence of (N, h, W) arrays
        Sampled rows of each set's frames, in ``desc.sets`` order [DN].
    sensor : SensorModel
        The sensor noise model.
    quantised : bool
        Integer images (quantisation noise added).

    Returns
    -------
    list of str
        One warning per broken set.
    """
    out = []
    flat = {pset.name: np.asarray(frames, np.float64).reshape(frames.shape[0], -1)
            - sensor.black_level_dn
            for pset, frames in zip(desc.sets, sample, strict=True)
            if isinstance(pset, PhaseSet)}
    stride = max(1, -(-next(iter(flat.values())).shape[1] // MAX_FIT_PIXELS)) if flat else 1
    fits = {pset.name: _fit(pset, flat[pset.name][:, ::stride], sensor, quantised)
            for pset in desc.sets if isinstance(pset, PhaseSet)}
    noise = {name: _noise_dn(fit) for name, fit in fits.items() if fit is not None}
    for pset in desc.sets:
        if not isinstance(pset, PhaseSet):
            continue
        f = flat[pset.name]
        means = f.mean(axis=1)
        black = [k for k in range(len(means))
                 if (sib := np.median(np.delete(means, k))) > 0
                 and means[k] < BLACK_SHARE * sib]
        if black:
            k = black[0]
            out.append(f"set {pset.name!r}: {_frame_name(pset, k)} is black or zeroed (mean "
                       f"{means[k]:.3g} DN against {np.median(np.delete(means, k)):.3g} DN "
                       "of the other frames): capture it again, or correct the set's frame "
                       "list; no pixel of this decode is trusted")
            continue
        others = [v for k, v in noise.items() if k != pset.name]
        share = _misfit(fits[pset.name], min(others, default=0.0))
        if share is not None:
            files = f" ({', '.join(pset.files)})" if pset.files else ""
            out.append(f"set {pset.name!r}: its {pset.steps} frames{files} fit no sinusoid "
                       f"(residual {100 * share:.0f} % of the modulation, where noise and a "
                       "projector's gamma leave < 30 %): a frame zeroed, swapped, out of "
                       "order or of another scene - check the set's files and shifts_rad; no "
                       "pixel of this decode is trusted")
    return out


def _fit(pset: PhaseSet, f: np.ndarray, sensor: SensorModel, quantised: bool):
    """The least-squares sinusoid fit of a set's frames at its well-modulated unclipped
    pixels: (residuals, modulation, (cos phi, sin phi), sensor noise std [DN]) there, N;
    or None (N < 4, or fewer than :data:`MIN_PIXELS` such pixels)."""
    n = f.shape[0]
    if n < 4:
        return None
    fit = ShiftFit.from_shifts(pset.shifts_rad)  # the pseudo-inverse: one small matmul
    coef = fit.rows @ f
    modulation = np.hypot(coef[1], coef[2])
    var = sample_variance(np.clip(coef[0], 0, None) + sensor.black_level_dn, sensor, quantised)
    # clipped pixels (saturated, masked by the decoder) are no sinusoid either: left out
    top = sensor.saturation_dn - sensor.black_level_dn if sensor.saturation_dn else f.max()
    lit = (modulation > 10.0 * np.sqrt(var)) & (f < 0.99 * top).all(axis=0)
    if np.count_nonzero(lit) < MIN_PIXELS:
        return None
    coef, m = coef[:, lit], modulation[lit]
    resid = f[:, lit] - fit.design @ coef
    return (resid, m, (coef[1] / m, coef[2] / m), np.sqrt(var[lit])), n


def _noise_dn(fit) -> float:
    """A set's intensity noise per frame as its residuals measure it (median over the
    pixels; the fit leaves N - 3 of N degrees of freedom) [DN]."""
    (resid, _, _, _), n = fit
    return float(np.median(np.sqrt(np.mean(resid ** 2, axis=0) * n / (n - 3))))


def _misfit(fit, other_noise_dn: float) -> float | None:
    """The median residual RMS / modulation when above :data:`MISFIT_SHARE`, else the
    coherent share when above both :data:`COHERENT_SHARE` and what noise leaves in one
    pixel (``other_noise_dn``, the other sets' :func:`_noise_dn`, or the sensor's when
    larger), else None."""
    if fit is None:
        return None
    (resid, modulation, phi, sensor_std), n = fit
    rms = np.sqrt(np.mean(resid ** 2, axis=0))
    share = float(np.median(rms / modulation))
    if share > MISFIT_SHARE:
        return share
    coherent = _coherent_share(resid / modulation, phi)
    # all of one pixel's residual noise, were it shared by every pixel, would pass for
    # coherent: the most that noise correlated over the window leaves
    floor = float(np.median(np.maximum(sensor_std, other_noise_dn) / modulation)
                  * np.sqrt((n - 3) / n))
    return coherent if coherent > max(COHERENT_SHARE, floor) else None


def _coherent_share(q: np.ndarray, phase: tuple[np.ndarray, np.ndarray]) -> float:
    """The RMS share of the residuals (over modulation) that follows the phase's 0th and
    1st harmonics across the pixels - what a frame of a wrong shift, scene or level
    leaves - with the 2nd harmonic (a projector's gamma, harmless to the phase with 4
    steps) fitted alongside; 0 when the pixels' phases cover too little of the circle to
    tell the harmonics apart (a cue set of one period).

    ``phase`` is (cos phi, sin phi) of every pixel. The five-term least-squares fit is
    solved by its normal equations (the basis is well conditioned wherever it is used,
    condition number <= 10), and the fitted 0th/1st-harmonic part's mean square is the
    quadratic form of its coefficients with the Gram matrix - no (M, 5) product."""
    c, s = phase
    basis = np.stack([np.ones_like(c), c, s, c * c - s * s, 2.0 * c * s])  # (5, M)
    gram = basis @ basis.T
    eig = np.linalg.eigvalsh(gram)
    if not eig[0] > 0 or np.sqrt(eig[-1] / eig[0]) > 10.0:
        return 0.0
    coef = np.linalg.solve(gram, basis @ q.T)  # (5, N)
    low = coef[:3]
    total = float(np.einsum("ik,ij,jk->", low, gram[:3, :3], low))
    return float(np.sqrt(max(total, 0.0) / (q.shape[0] * q.shape[1])))
