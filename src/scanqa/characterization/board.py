"""The noise of a real scanner from its calibration board: no stage needed.

Every pose of a chessboard board is a plane seen through bright and dark squares, so the
scatter of the triangulated points about that plane, square by square, is the scanner's
real random error at that pose's depth and at two fringe contrasts. This module splits
each pose's residual about its fitted plane into

* a smooth part: a polynomial surface of degree :data:`SMOOTH_DEGREE` in the board's
  plane (board flatness and calibration error; one pose cannot tell them apart);
* a phase-locked ripple: harmonics 1-3 of the working fringe's phase (a projector
  response that is not a pure sine, which 3-step shifting folds into the phase);
* the random part, which the per-point sigma must predict;

and fits the noise law of the phase that each pixel's own fringe offset ``A`` and
modulation ``B`` give (:func:`scanqa.decoding.imagenoise.phase_sigma_px`)::

    sigma_xp^2 = (P / 2 pi)^2 (2 / N) (a + b A) / B^2

(``a`` [DN^2]: read noise and quantisation; ``b`` [DN]: shot noise, 1 / gain) to the
random part of every square of every pose. Bright and dark squares at one depth differ
several-fold in ``B``: the two terms scale differently with it, which is what pins both.

The defocus model's filtering is not identified by a board at a few nearby depths (its
blur ratios are small there); it is reported as such, and sigma takes the attenuation
from the measured ``B`` of each pixel.
"""

from __future__ import annotations

import hashlib
import itertools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from scanqa.calibration.base import Calibration
from scanqa.calibration.board import Board, find_corners
from scanqa.characterization.boardshape import board_coordinates, split_smooth
from scanqa.decoding.imagenoise import phase_sigma_px, working_steps
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.numeric import robust_std

#: Degree of the polynomial surface taken as the smooth part [-].
SMOOTH_DEGREE = 4
#: Harmonics of the fringe phase taken as the phase-locked ripple [-].
RIPPLE_HARMONICS = 3
#: Each square's quadrilateral is shrunk to this fraction about its centre (so the
#: colour edges, blurred by both lenses, stay out) [-].
SQUARE_SHRINK = 0.6
#: Fewest points of a square used in the fit [-].
MIN_SQUARE_POINTS = 200
#: Points per pose sampled for the board-shape / calibration split [-].
SHAPE_SAMPLES = 4000
#: Format tag of the summary written by :func:`characterize_board`.
SUMMARY_FORMAT = "scanqa-board-noise/1"


def find_board_corners(image: np.ndarray, inner: tuple[int, int]) -> np.ndarray | None:
    """Inner corners of a chessboard in an image, (rows, cols, 2) [camera px] or None
    (:func:`scanqa.calibration.board.find_corners`, either orientation).

    Parameters
    ----------
    image : (H, W) float
        A frame showing the board (e.g. the fringe offset A) [DN].
    inner : (int, int)
        Inner corners (saddle points) per row and per column of the board [-].
    """
    for cols, rows in (inner, inner[::-1]):
        corners = find_corners(image, Board(rows=rows, columns=cols, square_mm=1.0))
        if corners is not None:
            return corners.reshape(rows, cols, 2)
    return None


def fill_convex(image: np.ndarray, polygon: np.ndarray, value: int) -> None:
    """Set to ``value`` the pixels of ``image`` inside a convex polygon of whole-pixel
    vertices or on its edges' lines (``cv2.fillConvexPoly`` on them, to a pixel of the
    edges where the two draw lines apart; tests/test_opencv_twins.py).

    Parameters
    ----------
    image : (H, W) array
        Written in place.
    polygon : (n, 2) array_like
        Vertices (x, y) in order (either sense) [px].
    value : int
        The label written.
    """
    poly = np.asarray(polygon, dtype=float)
    lo = np.maximum(np.floor(poly.min(axis=0)).astype(int), 0)
    hi = np.minimum(np.ceil(poly.max(axis=0)).astype(int) + 1, image.shape[::-1])
    if np.any(hi <= lo):
        return
    y, x = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
    edges = np.roll(poly, -1, axis=0) - poly
    cross = (edges[:, 0, None, None] * (y - poly[:, 1, None, None])
             - edges[:, 1, None, None] * (x - poly[:, 0, None, None]))
    # OpenCV includes the pixels its edge lines pass through: those within half a pixel
    # of an edge along its minor axis (cross product / the edge's larger extent)
    sense = np.sign(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1)
                           * poly[:, 1])) or 1.0
    reach = 0.5 * np.maximum(np.abs(edges).max(axis=1), 1e-12)[:, None, None]
    inside = np.all(sense * cross >= -reach, axis=0)
    image[lo[1]:hi[1], lo[0]:hi[0]][inside] = value


def square_labels(corners: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Label image of the board's squares between its inner corners, and their colours.

    Returns
    -------
    labels : (H, W) int
        Square index + 1 inside each square's shrunk quadrilateral, 0 elsewhere [-].
    bright : (n_squares,) bool
        True for the bright squares (the parity class with the higher median offset).
    """
    labels = np.zeros(offset.shape, np.int32)
    rows, cols = corners.shape[:2]
    parity = []
    for i in range(rows - 1):
        for j in range(cols - 1):
            quad = np.array([corners[i, j], corners[i, j + 1], corners[i + 1, j + 1],
                             corners[i + 1, j]])
            centre = quad.mean(axis=0)
            quad = centre + SQUARE_SHRINK * (quad - centre)
            fill_convex(labels, np.round(quad), len(parity) + 1)
            parity.append((i + j) % 2)
    parity = np.array(parity)
    level = np.array([np.nanmedian(v) for v in _by_label(labels.ravel(), offset.ravel(),
                                                         parity.size)])
    even_bright = np.nanmedian(level[parity == 0]) > np.nanmedian(level[parity == 1])
    return labels, (parity == 0) == even_bright


@dataclass(frozen=True)
class PoseResidual:
    """One pose's residual about its plane, split into parts.

    Attributes
    ----------
    name : str
        The pose (its folder).
    normal : (3,) float
        Unit normal of the fitted plane, towards the camera [-].
    depth_mm : float
        Median Z of the board's points [mm].
    smooth_rms_um, ripple_amplitude_um : float
        RMS of the smooth part and amplitude (half peak-to-peak) of the phase-locked
        ripple over the board [um].
    squares : dict
        Per square (arrays over squares): ``bright`` (bool), ``n`` points,
        ``var_random_mm2`` and ``var_plane_mm2`` (robust variance of the random part and
        of the whole residual about the plane [mm^2]), ``read_term``, ``shot_term``
        (mean over the square's points of the law's two regressors [mm^2/DN^2],
        [mm^2/DN]) and ``sigma_images_mm`` (median sigma along the normal from the
        decoder's own noise estimate [mm]).
    """

    name: str
    normal: np.ndarray
    depth_mm: float
    smooth_rms_um: float
    ripple_amplitude_um: float
    squares: dict = field(repr=False)
    #: robust std of the whole residual about the plane over all points of the bright
    #: and of the dark squares (smooth part and ripple included) [um]
    about_plane_um: dict = field(default_factory=dict)
    #: sampled points for splitting the smooth part (:func:`scanqa.characterization.boardshape.
    #: split_smooth`): board and image coordinates, plane coordinates, smooth part
    shape_samples: dict = field(default_factory=dict, repr=False)


def pose_residual(name: str, phase_map: PhaseMap, calibration: Calibration,
                  inner: tuple[int, int]) -> PoseResidual:
    """Split one board pose's residual about its plane (module docstring)."""
    corners = find_board_corners(phase_map.offset.astype(float), inner)
    if corners is None:
        raise InputError(f"{name}: no {inner[0]} x {inner[1]} chessboard found in the "
                         "fringe offset image; check the board given (inner corners per "
                         "row and column) and that the whole board is in view")
    labels, bright = square_labels(corners, phase_map.offset)
    look = calibration.apply_image(phase_map.xp)
    on = labels > 0
    on[on] = np.isfinite(look.xyz[on]).all(axis=-1)  # the board's pixels only
    xyz = look.xyz[on]
    normal, resid = _plane(xyz)
    ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    cos = np.abs(ray @ normal)
    theta = 2 * math.pi * phase_map.xp[on] / phase_map.period_px
    parts, keep, plane_st = _split(xyz, normal, resid, theta)
    smooth, ripple = parts
    random = resid - smooth - ripple
    lab = labels[on]
    s_t = np.linalg.norm(look.slope[on], axis=-1)  # look.s_t[on], of the board only
    terms = _law_terms(phase_map, s_t, cos, on)
    sig_img = s_t * phase_map.sigma_xp[on] * cos
    squares = _per_square(lab, bright, keep, random, resid, terms, sig_img)
    is_bright = bright[lab - 1]
    pooled = {"bright": 1e3 * robust_std(resid[is_bright]),
              "dark": 1e3 * robust_std(resid[~is_bright])}
    pick = np.flatnonzero(keep)[::max(1, int(keep.sum()) // SHAPE_SAMPLES)]
    rows, cols = (i[pick] for i in np.nonzero(on))
    board_u, board_v = board_coordinates(corners, rows, cols)
    samples = {"board_u": board_u, "board_v": board_v, "image_u": cols.astype(float),
               "image_v": rows.astype(float), "s": plane_st[0][pick], "t": plane_st[1][pick],
               "smooth": smooth[pick]}
    return PoseResidual(name, normal, float(np.median(xyz[:, 2])),
                        1e3 * float(np.sqrt(np.mean(smooth[keep] ** 2))),
                        1e3 * 0.5 * float(np.ptp(np.percentile(ripple[keep], [1, 99]))),
                        squares, pooled, samples)


def _plane(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane with 4-sigma rejection: unit normal towards the camera and the
    signed residual of every point [mm]."""
    keep = np.ones(len(xyz), bool)
    for _ in range(3):
        centre = xyz[keep].mean(axis=0)
        normal = np.linalg.svd(xyz[keep][::7] - centre, full_matrices=False)[2][2]
        resid = (xyz - centre) @ normal
        keep = np.abs(resid - np.median(resid)) < 4 * robust_std(resid)
    if normal @ centre > 0:
        normal, resid = -normal, -resid
    return normal, resid


def _split(xyz: np.ndarray, normal: np.ndarray, resid: np.ndarray, theta: np.ndarray
           ) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, tuple]:
    """Smooth part and ripple of ``resid`` (joint least squares with 4-sigma rejection),
    the points kept and their plane coordinates [mm, mm, bool, (-, -)]."""
    e1 = np.cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    centre = xyz.mean(axis=0)
    s, t = (xyz - centre) @ e1, (xyz - centre) @ e2
    span = max(np.ptp(s), np.ptp(t)) / 2
    s, t = s / span, t / span
    smooth_cols = [s**i * t**j for i in range(SMOOTH_DEGREE + 1)
                   for j in range(SMOOTH_DEGREE + 1 - i)]
    ripple_cols = [f(k * theta) for k in range(1, RIPPLE_HARMONICS + 1)
                   for f in (np.cos, np.sin)]
    design = np.stack(smooth_cols + ripple_cols, axis=1)
    keep = np.ones(resid.size, bool)
    for _ in range(3):
        coef = np.linalg.lstsq(design[keep][::3], resid[keep][::3], rcond=None)[0]
        rest = resid - design @ coef
        keep = np.abs(rest) < 4 * robust_std(rest)
    n = len(smooth_cols)
    return (design[:, :n] @ coef[:n], design[:, n:] @ coef[n:]), keep, (s, t)


def _law_terms(phase_map: PhaseMap, s_t: np.ndarray, cos: np.ndarray, on: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """The noise law's two regressors per point, along the plane normal: the variance
    for a = 1 DN^2, b = 0 and for a = 0, b = 1 DN [mm^2/DN^2, mm^2/DN]."""
    steps = working_steps(phase_map)
    unit = phase_sigma_px(phase_map.modulation[on], phase_map.offset[on], 1.0, 0.0,
                          phase_map.period_px, steps)
    scale = (s_t * cos) ** 2
    read = scale * unit**2
    return read, read * np.maximum(phase_map.offset[on].astype(float), 0.0)


def _by_label(labels: np.ndarray, values: np.ndarray, n: int) -> list[np.ndarray]:
    """``[values[labels == k] for k in 1..n]`` in their order, from one stable sort."""
    order = np.argsort(labels, kind="stable")
    ends = np.searchsorted(labels[order], np.arange(1, n + 2))
    return [values[order[a:b]] for a, b in itertools.pairwise(ends)]


def _per_square(lab, bright, keep, random, resid, terms, sig_img) -> dict:
    """Per-square statistics (see :class:`PoseResidual`)."""
    out = {k: [] for k in ("bright", "n", "var_random_mm2", "var_plane_mm2", "read_term",
                           "shot_term", "sigma_images_mm")}
    for k, square in enumerate(_by_label(lab, np.arange(lab.size), bright.size)):
        sel = square[keep[square]]
        if sel.size < MIN_SQUARE_POINTS:
            continue
        out["bright"].append(bool(bright[k]))
        out["n"].append(int(sel.size))
        out["var_random_mm2"].append(robust_std(random[sel]) ** 2)
        out["var_plane_mm2"].append(robust_std(resid[square]) ** 2)
        out["read_term"].append(float(np.mean(terms[0][sel])))
        out["shot_term"].append(float(np.mean(terms[1][sel])))
        out["sigma_images_mm"].append(float(np.nanmedian(sig_img[sel])))
    return {k: np.array(v) for k, v in out.items()}


@dataclass(frozen=True)
class NoiseLaw:
    """The per-pixel phase-noise law ``var = a + b A`` [DN^2] fitted to board data.

    Attributes
    ----------
    read_var_dn2 : float
        ``a``: read noise and quantisation, per frame [DN^2].
    shot_dn : float
        ``b``: shot-noise slope, the inverse gain [DN].
    interval : dict
        95 % intervals of both from a bootstrap over poses.
    """

    read_var_dn2: float
    shot_dn: float
    interval: dict = field(default_factory=dict)


def fit_noise_law(poses: list[PoseResidual], bootstrap: int = 200, seed: int = 0
                  ) -> NoiseLaw:
    """Fit ``a`` and ``b`` to the random part of every square of ``poses`` (non-negative
    least squares on relative errors), with a bootstrap over poses for the intervals."""
    if not poses:
        raise InputError("no board pose to fit the noise law to")
    a, b = _nnls_law(poses)
    rng = np.random.default_rng(seed)
    draws = [_nnls_law([poses[i] for i in rng.integers(0, len(poses), len(poses))])
             for _ in range(bootstrap if len(poses) > 1 else 0)]
    interval = {}
    if draws:
        d = np.array(draws)
        interval = {"read_var_dn2": [float(x) for x in np.percentile(d[:, 0], [2.5, 97.5])],
                    "shot_dn": [float(x) for x in np.percentile(d[:, 1], [2.5, 97.5])]}
    return NoiseLaw(a, b, interval)


def _nnls_law(poses: list[PoseResidual]) -> tuple[float, float]:
    sq = [p.squares for p in poses]
    y = np.concatenate([s["var_random_mm2"] for s in sq])
    x = np.stack([np.concatenate([s["read_term"] for s in sq]),
                  np.concatenate([s["shot_term"] for s in sq])], axis=1)
    coef = nnls(x / y[:, None], np.ones(y.size))[0]
    return float(coef[0]), float(coef[1])


def law_sigma_mm(law: NoiseLaw, square: dict) -> np.ndarray:
    """Predicted sigma along the normal of each square of a pose [mm]."""
    return np.sqrt(law.read_var_dn2 * square["read_term"] + law.shot_dn * square["shot_term"])


def cell_table(pose: PoseResidual, law: NoiseLaw | None, smooth_um: float = 0.0) -> list:
    """Measured against predicted per colour of one pose: rows with the robust std of the
    random part (per square, pooled) and of all the colour's points about the plane, the
    median predicted sigma along the normal (from ``law``, or from the decoder's image
    estimate when ``law`` is None), and that sigma with the systematic term ``smooth_um``
    [um]."""
    sq = pose.squares
    rows = []
    for colour, sel in (("bright", sq["bright"]), ("dark", ~sq["bright"])):
        if not sel.any():
            continue
        w = sq["n"][sel]
        meas = 1e3 * math.sqrt(np.average(sq["var_random_mm2"][sel], weights=w))
        plane = pose.about_plane_um.get(colour, math.nan)
        pred_sq = (law_sigma_mm(law, sq) if law is not None else sq["sigma_images_mm"])[sel]
        pred = 1e3 * float(np.median(pred_sq))
        rows.append({"pose": pose.name, "colour": colour, "depth_mm": pose.depth_mm,
                     "squares": int(sel.sum()), "measured_random_um": meas,
                     "measured_about_plane_um": plane, "predicted_um": pred,
                     "predicted_with_systematic_um": math.hypot(pred, smooth_um),
                     "ratio_random": meas / pred,
                     "ratio_about_plane": plane / math.hypot(pred, smooth_um)})
    return rows


def leave_one_out(poses: list[PoseResidual]) -> list[dict]:
    """Each pose predicted by the law fitted to the others (and the smooth part's RMS of
    the others as the systematic term): the rows of :func:`cell_table`, plus the
    dark/bright ratios measured and predicted."""
    rows = []
    for i, pose in enumerate(poses):
        others = poses[:i] + poses[i + 1:]
        law = fit_noise_law(others, bootstrap=0)
        smooth = math.sqrt(np.mean([p.smooth_rms_um**2 for p in others]))
        rows.extend(cell_table(pose, law, smooth))
    return rows


def digest(paths: list[str]) -> str:
    """SHA-256 over the given files' bytes, in order (the data a characterisation used)."""
    h = hashlib.sha256()
    for p in paths:
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def summary(poses: list[PoseResidual], law: NoiseLaw, held_out: list[dict],
            data_sha256: str, sources: list[str]) -> dict:
    """The JSON summary that ``--model`` takes (``noise_law``) with every table."""
    smooth = math.sqrt(np.mean([p.smooth_rms_um**2 for p in poses]))
    split = split_smooth([p.shape_samples for p in poses]) \
        if all(p.shape_samples for p in poses) else {"separable": False}
    if split["separable"]:
        applied = split["calibration_um"]
        what = (f"split: the board's own shape {split['board_shape_um']:.1f} um (the same in "
                f"board coordinates at every pose; not applied to later scans) and the "
                f"calibration error {split['calibration_um']:.1f} um (fixed in the image, "
                "plus each pose's own rest; applied to later scans), canonical correlation "
                f"of the two {split['correlation']:.2f}")
    else:
        applied = smooth
        what = ("not separable with these poses (" + split.get(
            "why", f"the board-fixed and image-fixed surfaces correlate "
                   f"{split.get('correlation', math.nan):.2f}") + "): board shape and "
                "calibration error are applied together to later scans; pose the board "
                "at more different positions and tilts, or add a flat of known form")
    return {"format": SUMMARY_FORMAT, "kind": "board",
            "noise_law": {"read_var_dn2": law.read_var_dn2, "shot_dn": law.shot_dn,
                          "interval_95": law.interval,
                          "systematic_um": applied,
                          "systematic": {"smooth_rms_um": smooth, **split},
                          "data_sha256": data_sha256, "sources": sources},
            "identifiability": {
                "read_var_dn2": "fitted (bright and dark squares differ in B)",
                "shot_dn": "fitted (bright and dark squares differ in B)",
                "systematic (board shape against calibration error)": what,
                "defocus filtering (gamma, sigma_p)": "not identified: the board's poses "
                "span too little depth for the blur to change the noise"},
            "poses": [{"name": p.name, "depth_mm": p.depth_mm,
                       "smooth_rms_um": p.smooth_rms_um,
                       "ripple_amplitude_um": p.ripple_amplitude_um,
                       "squares": int(p.squares["n"].size)} for p in poses],
            "held_out": held_out}


def characterize_board(poses: dict, calibration: Calibration, inner: tuple[int, int],
                       progress=None) -> dict:
    """Characterise a scanner from its board poses.

    Parameters
    ----------
    poses : dict of str to PhaseMap
        Each pose's decoded scan (fringes across the board), by name.
    calibration : Calibration
        The scanner's calibration (parametric or table).
    inner : (int, int)
        Inner corners of the chessboard per row and column [-].
    progress : callable, optional
        Receives a short message per pose.

    Returns
    -------
    dict
        The summary (:func:`summary`) without the data hash: the law fitted to every
        pose, each pose predicted by the law of the others (``held_out``), and the
        image-only prediction per pose (``images_only``).
    """
    if len(poses) < 2:
        raise InputError(f"a board characterisation needs >= 2 poses (one held out at a "
                         f"time), got {len(poses)}")
    residuals = []
    for name, pm in poses.items():
        if progress:
            progress(f"board pose {name}")
        residuals.append(pose_residual(name, pm, calibration, inner))
    law = fit_noise_law(residuals)
    out = summary(residuals, law, leave_one_out(residuals), "", list(poses))
    out["images_only"] = [row for p in residuals for row in cell_table(p, None)]
    return out


#: Groups of pixels (by predicted variance) the repeats' law is fitted to [-].
REPEAT_BINS = 40


def repeat_samples(scans: list[PhaseMap], select: np.ndarray | None = None) -> dict:
    """Temporal variance of x_p over repeated captures of one static scene, grouped.

    Parameters
    ----------
    scans : list of PhaseMap
        Two or more decodes of the same pose (nothing moved between them).
    select : (H, W) bool, optional
        Pixels to use (all decoded ones by default).

    Returns
    -------
    dict
        Per group of pixels of similar predicted noise (arrays over groups):
        ``var_px2`` (mean of the per-pixel sample variances, ddof 1 [px^2]), ``read_term``
        and ``shot_term`` (mean law regressors [px^2/DN^2], [px^2/DN]), ``n`` (pixels).
    """
    if len(scans) < 2:
        raise InputError(f"repeats need >= 2 captures of one pose, got {len(scans)}")
    xp = np.stack([s.xp for s in scans])
    ok = np.isfinite(xp).all(axis=0) if select is None else \
        np.isfinite(xp).all(axis=0) & select
    var = xp[:, ok].var(axis=0, ddof=1)
    first = scans[0]
    mod = np.mean([s.modulation[ok] for s in scans], axis=0)
    off = np.mean([s.offset[ok] for s in scans], axis=0)
    unit = phase_sigma_px(mod, off, 1.0, 0.0, first.period_px, working_steps(first)) ** 2
    read, shot = unit, unit * np.maximum(off, 0.0)
    order = np.argsort(first.sigma_xp[ok])
    groups = [g for g in np.array_split(order, REPEAT_BINS) if g.size]
    return {"var_px2": np.array([var[g].mean() for g in groups]),
            "read_term": np.array([read[g].mean() for g in groups]),
            "shot_term": np.array([shot[g].mean() for g in groups]),
            "n": np.array([g.size for g in groups])}


def fit_repeat_law(samples: dict) -> NoiseLaw:
    """``a`` and ``b`` of the law fitted to grouped temporal variances (non-negative
    least squares on relative errors; :func:`repeat_samples`)."""
    y = samples["var_px2"]
    x = np.stack([samples["read_term"], samples["shot_term"]], axis=1)
    coef = nnls(x / y[:, None], np.ones(y.size))[0]
    return NoiseLaw(float(coef[0]), float(coef[1]))


def characterize_repeats(scans: list[PhaseMap]) -> dict:
    """Characterise a scanner from repeated captures of one pose: the law fitted to the
    even image rows, checked on the odd ones (held out), then fitted to all.

    Returns
    -------
    dict
        The summary --model takes (``noise_law``, no systematic term: repeats see only
        the random part) with the held-out check per group of the odd rows.
    """
    rows = np.zeros(scans[0].xp.shape, bool)
    rows[::2] = True
    law = fit_repeat_law(repeat_samples(scans, rows))
    held = repeat_samples(scans, ~rows)
    pred = law.read_var_dn2 * held["read_term"] + law.shot_dn * held["shot_term"]
    ratio = np.sqrt(held["var_px2"] / pred)
    full = fit_repeat_law(repeat_samples(scans))
    return {"format": SUMMARY_FORMAT, "kind": "repeats",
            "noise_law": {"read_var_dn2": full.read_var_dn2, "shot_dn": full.shot_dn,
                          "systematic_um": 0.0, "data_sha256": "", "sources": []},
            "identifiability": {
                "read_var_dn2, shot_dn": "fitted where the scene spans a range of A and B",
                "systematic": "not seen: repeats hold only the temporal random part"},
            "held_out": {"law": {"read_var_dn2": law.read_var_dn2, "shot_dn": law.shot_dn},
                         "ratio_measured_over_predicted": [float(r) for r in ratio],
                         "median_ratio": float(np.median(ratio))}}
