"""Part "real" of docs/studies/calibration_covariance.py: SLStudio's board poses and skull.

scanqa's board calibration of poses 1, 3-6 (model corners, lens model "k1", what
``scanqa calibrate --board 9x13 --square-mm 10`` does) against SLStudio's
calibration.xml on skull_2x3 (every 7th valid pixel): median |dXYZ|, its line-of-sight
part, the median calibration sigma and their ratio; and the five calibrations that each
left one pose out: their spread at the skull's points (the std over the five of the
line-of-sight position, times sqrt(n - 1) for the jackknife's inflation, and the RMS
of each minus the full calibration) against the predicted sigma.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
from tests.realdata import SLSTUDIO, SLSTUDIO_SHIFTS, slstudio_board_patterns

from scanqa.calibration.board import Board, decode_pose
from scanqa.calibration.board_fit import calibrate_board
from scanqa.calibration.parametric import from_opencv, load_opencv_calibration
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.decoding.parsing import load_patterns
from scanqa.io.patterns import dumps_patterns

BOARD = Board(rows=9, columns=13, square_mm=10.0)
PANEL = (1824, 1140)
POSES = (1, 3, 4, 5, 6)


def skull_points(folder: Path):
    frames = [str(SLSTUDIO / "skull_2x3" / f"frameSeq_{i:02d}.bmp") for i in range(6)]
    (folder / "patterns.toml").write_text(dumps_patterns({
        "format": "scanqa-patterns/2", "projector_width_px": 1824, "set": [
            {"kind": "phase", "name": "p114", "period_px": 114.0, "steps": 3,
             "shifts_rad": SLSTUDIO_SHIFTS, "files": frames[:3]},
            {"kind": "phase", "name": "p1824", "period_px": 1824.0, "steps": 3,
             "shifts_rad": SLSTUDIO_SHIFTS, "files": frames[3:]}]}))
    pm = decode_pattern_dir(folder)
    v, u = (a[::7] for a in np.nonzero(pm.valid))
    return u, v, pm.xp[v, u]


def run_real() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cols, rows = (load_patterns(p) for p in slstudio_board_patterns(Path(tmp)))
        poses = [decode_pose(SLSTUDIO / "calibration" / f"calseq{k}", cols, rows, BOARD)
                 for k in POSES]
        u, v, xp = skull_points(Path(tmp))
    result = calibrate_board(poses, BOARD, PANEL, "k1")
    ours = from_opencv(result.data)
    ref = load_opencv_calibration(SLSTUDIO / "calibration" / "calibration.xml")
    p_ours = ours.apply(u, v, xp).xyz
    p_ref = ref.apply(u, v, xp).xyz
    ray = p_ours / np.linalg.norm(p_ours, axis=1, keepdims=True)
    sigma = ours.calibration_sigma_mm(u, v, xp)
    d = p_ours - p_ref
    ok = np.isfinite(d).all(1) & np.isfinite(sigma)
    out = {"joint_fit": result.bundle["noise_px"],
           "model_terms": result.bundle["model_terms"],
           "median_abs_dxyz_um": 1e3 * float(np.median(np.linalg.norm(d[ok], axis=1))),
           "median_abs_dlos_um": 1e3 * float(np.median(np.abs(np.sum(d * ray, 1)[ok]))),
           "median_sigma_um": 1e3 * float(np.median(sigma[ok])),
           "sigma_range_um": [1e3 * float(np.percentile(sigma[ok], 5)),
                              1e3 * float(np.percentile(sigma[ok], 95))]}
    out["ratio_dxyz"] = out["median_abs_dxyz_um"] / out["median_sigma_um"]
    out["ratio_dlos"] = out["median_abs_dlos_um"] / out["median_sigma_um"]
    loo = []
    for k in range(len(poses)):
        sub = calibrate_board(poses[:k] + poses[k + 1:], BOARD, PANEL, "k1")
        loo.append(np.sum((from_opencv(sub.data).apply(u, v, xp).xyz - p_ours) * ray, 1))
    loo = np.array(loo)
    n = len(poses)
    spread = np.sqrt((n - 1) / n * np.sum((loo - loo.mean(0)) ** 2, axis=0))  # jackknife
    out["loo_jackknife_sigma_median_um"] = 1e3 * float(np.median(spread[ok]))
    out["loo_rms_shift_median_um"] = 1e3 * float(np.median(np.sqrt(np.mean(loo**2, 0))[ok]))
    out["loo_jackknife_over_predicted"] = out["loo_jackknife_sigma_median_um"] / out[
        "median_sigma_um"]
    print(json.dumps(out, indent=1, default=float))
    return out
