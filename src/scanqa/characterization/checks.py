"""What a noise characterisation refuses before it fits: inputs that fit nothing.

``scanqa characterize board`` and ``characterize repeats`` fit a law to whatever they are
given; these checks make sure that what they are given is what the law means:

* board poses are named by their folder (``pose1/phase.npz`` is pose ``pose1``), and a
  pose given twice, or two poses of one name, are refused;
* a calibration whose scale disagrees with the config (its baseline against the
  config's projector position: a board calibrated with the wrong square size) is
  refused, since every micrometre of the law's systematic term would scale with it;
* repeats must be the same static scene: the same folder twice, copies of one capture,
  a frame much darker than the same frame of the other repeats (a black or missing
  frame), a repeat that decodes far fewer pixels, or one whose x_p differs from the
  first repeat's by more than their noise allows (moved, shifted, another scene) are
  refused, each with one line naming the repeat or the frame;
* after a scan is annotated with a characterised sigma, that sigma is held against the
  scan's own image-based one (:func:`evidence_check`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from scanqa.calibration.base import Calibration
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig
from scanqa.numeric import robust_std

#: The calibration's baseline may differ from the config's by this factor [-].
SCALE_TOLERANCE = 1.25
#: A frame darker than this share of the same frame of the other repeats is refused [-].
DARK_FRAME_SHARE = 0.5
#: A repeat decoding less than this share of the first repeat's pixels is refused [-].
DECODED_SHARE = 0.5
#: Repeats whose x_p differs by more than this many times their predicted noise (robust
#: std, or median offset) are not the same scene [-].
SAME_SCENE_FACTOR = 3.0
#: Largest camera shift searched when naming how far a repeat moved [px].
SHIFT_SEARCH_PX = 3


def pose_keys(paths: list[str]) -> dict[str, str]:
    """The name of each board pose: its folder's (``pose1/`` and ``pose1/phase.npz``
    are both ``pose1``); a file not called ``phase.npz`` keeps its stem.

    Raises
    ------
    InputError
        A pose given twice (the same folder or file), or two poses with one name.
    """
    keys: dict[str, str] = {}
    seen: dict[str, str] = {}
    for text in paths:
        path = Path(text)
        real = os.path.realpath(path)
        if real in seen:
            raise InputError(f"pose {text} is given twice (the same capture as {seen[real]}): "
                             "give each board pose once")
        seen[real] = text
        name = Path(real).name if path.is_dir() else (
            Path(real).parent.name if path.name == "phase.npz" else path.stem)
        if name in keys:
            raise InputError(f"poses {keys[name]} and {text} are both named {name!r} (a pose "
                             "is named by its folder): give each pose its own folder name")
        keys[name] = text
    return keys


def check_scale(calibration: Calibration, config: ScannerConfig, where: str = "") -> None:
    """Refuse a parametric calibration whose baseline disagrees with the config's.

    The baseline is the length of the projector's translation from the camera [mm]; the
    config's is the length of ``[projector] position_mm`` (the camera at the origin).
    A table calibration carries no baseline and is not checked.
    """
    translation = getattr(calibration, "translation", None)
    if translation is None:
        return
    have = float(np.linalg.norm(translation))
    want = float(np.linalg.norm(config.projector.position_mm))
    if not (have > 0 and want > 0):
        return
    ratio = have / want
    if 1 / SCALE_TOLERANCE <= ratio <= SCALE_TOLERANCE:
        return
    raise InputError(
        f"{where or 'the calibration'}: its baseline is {have:.4g} mm, {ratio:.3g}x the "
        f"{want:.4g} mm of [projector] position_mm in {config.source or 'the config'} - a "
        "board calibrated with the wrong square size? (it sets a calibration's scale); "
        "recalibrate with the board's true square size, or correct position_mm")


def frame_levels(files: list[str]) -> list[float]:
    """Mean level of each image file [DN] (a frame of a repeat)."""
    from scanqa.io.images import read_image

    return [float(np.mean(read_image(f)[::4, ::4])) for f in files]


def check_repeats(scans: list[PhaseMap], names: list[str],
                  frames: list[list[tuple[str, float]]] | None = None) -> None:
    """Refuse repeats that are not captures of one static scene.

    Parameters
    ----------
    scans : list of PhaseMap
        The decoded repeats.
    names : list of str
        What the user gave for each (a folder or phase.npz).
    frames : list of list of (file, mean level [DN]), optional
        Each repeat's frames in pattern order (:func:`frame_levels`), for naming a dark
        frame; None for decoded phase maps without their images.

    Raises
    ------
    InputError
        The first problem found, in one line naming the repeat or the frame.
    """
    real = [os.path.realpath(n) for n in names]
    for k, path in enumerate(real):
        if path in real[:k]:
            raise InputError(f"repeat {names[k]} is given twice (the same capture as "
                             f"{names[real.index(path)]}): repeats must be separate captures")
    if frames is not None:
        _check_frames(frames, names)
    if not scans:
        return
    first = scans[0]
    decoded0 = float(np.isfinite(first.xp).mean())
    for k, scan in enumerate(scans[1:], 1):
        decoded = float(np.isfinite(scan.xp).mean())
        if decoded < DECODED_SHARE * decoded0 or decoded0 < DECODED_SHARE * decoded:
            dark = names[k] if decoded < decoded0 else names[0]
            raise InputError(
                f"repeat {dark} decodes {100 * min(decoded, decoded0):.1f} % of the pixels "
                f"against {100 * max(decoded, decoded0):.1f} % in the other: black or "
                "missing frames, or not the same scene")
        if np.array_equal(scan.xp, first.xp, equal_nan=True):
            raise InputError(f"repeats {names[0]} and {names[k]} hold the same images "
                             "(x_p identical at every pixel): copies of one capture have no "
                             "temporal noise; capture the pose again")
        _check_same_scene(first, scan, names[0], names[k])


def _check_frames(frames: list[list[tuple[str, float]]], names: list[str]) -> None:
    counts = {len(f) for f in frames}
    if len(counts) > 1:
        listed = ", ".join(f"{n}: {len(f)}" for n, f in zip(names, frames, strict=True))
        raise InputError(f"the repeats have different numbers of frames ({listed}): they "
                         "must be captures of one pattern sequence")
    for i in range(len(frames[0])):
        levels = np.array([f[i][1] for f in frames])
        ref = float(levels.max() if levels.size == 2 else np.median(levels))
        for k, level in enumerate(levels):
            if level < DARK_FRAME_SHARE * ref:
                raise InputError(
                    f"{frames[k][i][0]}: mean level {level:.3g} DN against {ref:.3g} DN in "
                    f"the same frame of the other repeats (a black or missing frame?); "
                    f"repeat {names[k]} cannot be used")


def _check_same_scene(first: PhaseMap, scan: PhaseMap, name0: str, name: str) -> None:
    both = np.isfinite(first.xp) & np.isfinite(scan.xp)
    d = (scan.xp - first.xp)[both]
    if d.size == 0:
        raise InputError(f"repeat {name} shares no decoded pixel with {name0}: not the same "
                         "scene")
    med = float(np.median(d))
    spread = robust_std(d, centre=med)
    noise = float(np.nanmedian(np.hypot(first.sigma_xp[both], scan.sigma_xp[both])))
    if not math.isfinite(noise) or noise <= 0:
        return
    if spread <= SAME_SCENE_FACTOR * noise and abs(med) <= SAME_SCENE_FACTOR * noise:
        return
    dy, dx = _best_shift(first.offset, scan.offset)
    moved = f"; its image matches {name0}'s best shifted by (dy, dx) = ({dy}, {dx}) px" \
        if (dy, dx) != (0, 0) else ""
    raise InputError(
        f"repeat {name} is not the same scene as {name0}: x_p differs by a robust std of "
        f"{spread:.3g} px (median {med:+.3g} px) where their noise predicts {noise:.3g} px"
        f"{moved}; repeats must be captures of one static pose (nothing moved)")


def _best_shift(a: np.ndarray, b: np.ndarray) -> tuple[int, int]:
    """The whole-pixel shift of ``b`` that best matches ``a`` (mean absolute difference
    over the central half of the image, at most :data:`SHIFT_SEARCH_PX`)."""
    a, b = np.nan_to_num(np.asarray(a, float)), np.nan_to_num(np.asarray(b, float))
    h, w = a.shape
    s = SHIFT_SEARCH_PX
    r0, r1, c0, c1 = h // 4, 3 * h // 4, w // 4, 3 * w // 4
    if r1 - r0 <= 2 * s or c1 - c0 <= 2 * s:
        return 0, 0
    ref = a[r0:r1, c0:c1]
    best, where = math.inf, (0, 0)
    for dy in range(-s, s + 1):
        for dx in range(-s, s + 1):
            cost = float(np.mean(np.abs(b[r0 + dy:r1 + dy, c0 + dx:c1 + dx] - ref)))
            if cost < best - 1e-12:
                best, where = cost, (dy, dx)
    return where


#: The characterised random sigma may differ from the images' by this factor before a
#: scan warns that the characterisation does not fit it [-].
EVIDENCE_FACTOR = 2.0


def evidence_check(origin: dict, attributes: dict) -> dict:
    """The characterised random sigma against the one the scan's own images give.

    Returns
    -------
    dict
        For a characterised source: ``ratio_to_images`` (median characterised random sigma
        over the median image-based sigma, both [um] over the scan's points) and, where
        it leaves [1 / EVIDENCE_FACTOR, EVIDENCE_FACTOR], a ``warning`` naming both;
        otherwise {}.
    """
    if origin.get("kind") != "characterised":
        return {}
    random = np.asarray(attributes["sigma_random_um"], float)
    images = np.asarray(attributes["sigma_phase_um"], float)
    ok = np.isfinite(random) & np.isfinite(images) & (images > 0)
    if not ok.any():
        return {}
    char, img = float(np.median(random[ok])), float(np.median(images[ok]))
    ratio = char / img if img > 0 else math.inf
    out = {"ratio_to_images": ratio}
    if not 1 / EVIDENCE_FACTOR <= ratio <= EVIDENCE_FACTOR:
        out["warning"] = (
            f"the characterised random sigma has a median of {char:.3g} um over this scan "
            f"where the scan's own images give {img:.3g} um ({ratio:.2g}x, outside "
            f"[{1 / EVIDENCE_FACTOR:g}, {EVIDENCE_FACTOR:g}]): the characterisation "
            f"({origin.get('detail', '')}) does not fit this scan - another scanner, "
            "exposure or setting? Check it, or leave characterised_by out to take the "
            "images' sigma")
    return out
