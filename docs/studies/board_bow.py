"""Measurement: a bowed board (z = a x^2 + b y^2 + c xy) with the model's corners, once.

docs/calibration.rst, section "From a board: a parametric calibration" gives the numbers.

The camera fits the bow: its RMS is minimised over (a, b, c) [mm, the bow's height at the
board's edges, x and y scaled to -1..1 over the corner grid]; the bowed board is then
given to the projector's fit and to the stereo fit (intrinsics held). Poses 1, 3-6 of
SLStudio's example data (real; the folder of tests/realdata.py), lens model "k1",
compared with SLStudio's calibration.xml; then each pose left out (bow refitted on the
other four). Not part of the library and not a test: measured once.

Run: .venv/bin/python docs/studies/board_bow.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.realdata import SLSTUDIO, slstudio_board_patterns  # noqa: E402

from scanqa.calibration.board import Board, decode_pose  # noqa: E402
from scanqa.calibration.board_fit import _flags, _points, compare  # noqa: E402
from scanqa.decoding.parsing import load_patterns  # noqa: E402
from scanqa.io.opencv import OpenCVCalibration, read_opencv_calibration  # noqa: E402

BOARD = Board(rows=9, columns=13, square_mm=10.0)
PANEL = (1824, 1140)
CALIBRATION = SLSTUDIO / "calibration"


def bowed(abc) -> np.ndarray:
    """The board's corners with the bow's z [mm]."""
    pts = BOARD.object_points.astype(float).copy()
    x = pts[:, 0] - pts[:, 0].mean()
    y = pts[:, 1] - pts[:, 1].mean()
    x, y = x / np.abs(x).max(), y / np.abs(y).max()
    a, b, c = abc
    pts[:, 2] = a * x ** 2 + b * y ** 2 + c * x * y
    return pts.astype(np.float32)


def _pad(dist) -> np.ndarray:
    return np.pad(np.ravel(dist)[:5], (0, 5))[:5]


def fit(poses, abc0=(0.0, 0.0, 0.0)):
    """Bow fitted by the camera, then projector and stereo on the bowed board."""
    import cv2
    from scipy.optimize import minimize

    cam_flags, proj_flags = _flags()["k1"]
    obj, cam, proj = _points(poses, BOARD)
    size = poses[0].camera_size
    _, kc0, dc0, *_ = cv2.calibrateCamera(obj, cam, size, None, None, flags=cam_flags)
    _, kp0, dp0, *_ = cv2.calibrateCamera(obj, proj, PANEL, None, None, flags=proj_flags)
    guess = cv2.CALIB_USE_INTRINSIC_GUESS

    def camera(abc):
        board = [bowed(abc)] * len(cam)
        return cv2.calibrateCamera(board, cam, size, kc0.copy(), dc0.copy(),
                                   flags=cam_flags | guess)

    res = minimize(lambda p: camera(p)[0], np.asarray(abc0, float), method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 400})
    board = [bowed(res.x)] * len(cam)
    e_c, kc, dc = camera(res.x)[:3]
    e_p, kp, dp = cv2.calibrateCamera(board, proj, PANEL, kp0.copy(), dp0.copy(),
                                      flags=proj_flags | guess)[:3]
    e_s, *_, rot, trans, _, _ = cv2.stereoCalibrate(board, cam, proj, kc, dc, kp, dp, size,
                                                    flags=cv2.CALIB_FIX_INTRINSIC)
    data = OpenCVCalibration(kc, _pad(dc), kp, _pad(dp), rot, trans.ravel(),
                             sizes={"frameWidth": size[0], "frameHeight": size[1],
                                    "screenResX": PANEL[0], "screenResY": PANEL[1]},
                             errors={"cam_error": float(e_c), "proj_error": float(e_p),
                                     "stereo_error": float(e_s)})
    return res.x, data


def show(label, abc, data, ref):
    d = compare(data, ref)
    e = data.errors
    print(f"{label}: a b c = {abc[0]:+.3f} {abc[1]:+.3f} {abc[2]:+.3f} mm; RMS camera "
          f"{e['cam_error']:.3f} projector {e['proj_error']:.3f} stereo "
          f"{e['stereo_error']:.3f} px; f {100 * d['camera_focal_rel']:+.2f} % / "
          f"{100 * d['projector_focal_rel']:+.2f} %; rotation {d['rotation_deg']:.3f} deg;"
          f" baseline {d['baseline_deg']:.3f} deg, {100 * d['baseline_rel']:+.2f} %",
          flush=True)


def main() -> None:
    tmp = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("/tmp")
    cols, rows = (load_patterns(p) for p in slstudio_board_patterns(tmp))
    poses = [decode_pose(CALIBRATION / f"calseq{k}", cols, rows, BOARD.square_mm,
                         corner_method="model") for k in (1, 3, 4, 5, 6)]
    ref = read_opencv_calibration(CALIBRATION / "calibration.xml")
    show("flat board", (0, 0, 0), _flat(poses), ref)
    abc, data = fit(poses)
    show("bow, poses 1,3-6", abc, data, ref)
    for k, pose in enumerate(poses):
        abc_k, data_k = fit(poses[:k] + poses[k + 1:], abc)
        show(f"without {pose.name}", abc_k, data_k, ref)


def _flat(poses):
    from scanqa.calibration.board_fit import calibrate_board

    return calibrate_board(poses, BOARD, PANEL, covariance=False).data


if __name__ == "__main__":
    main()
