"""The smooth part of a board's residuals, split into the board's shape and the scanner's
calibration error where the poses can tell them apart.

Each pose's residual about its fitted plane has a smooth part
(:mod:`scanqa.characterization.board`). Two things make it, and a characterisation must
not mix them up:

* the board's own shape (bow, a warped print): fixed in the board's coordinates, the
  same at every pose; it is no error of the scanner and must not be added to later scans;
* the calibration's error: fixed in the camera's image (and slowly changing with depth),
  wherever the board is; it is the scanner's, and belongs to every later scan.

Across poses the board lies differently in the image, so the two are fitted jointly by
least squares over all poses: per pose a constant and a tilt (the plane fit takes those
out), a surface of degree 2-:data:`DEGREE` in board coordinates shared by all poses, and
one in image coordinates shared by all poses; what neither explains is a pose's own
(depth-dependent calibration error, or what the models miss) and is counted with the
calibration. Whether the poses separate the two is measured, not assumed: the largest
canonical correlation between the two surfaces' columns (after the per-pose terms are
taken out) must stay below :data:`MAX_CORRELATION`, else the split is reported as not
separable and the whole smooth part is applied, as before.
"""

from __future__ import annotations

import math

import numpy as np

#: Highest degree of either shared surface [-] (degree 2 and up: a pose's plane takes
#: the constant and the tilt).
DEGREE = 3
#: Largest canonical correlation of the two surfaces at which they count as separable [-].
MAX_CORRELATION = 0.95


def board_coordinates(corners: np.ndarray, rows: np.ndarray, cols: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Board coordinates (in squares, the first inner corner at 0) of image pixels, through
    the homography that maps the inner corners onto their grid.

    Parameters
    ----------
    corners : (R, C, 2) float
        Inner corners in the image (x, y) [camera px].
    rows, cols : (n,) int
        Pixels to map [camera px].
    """
    r, c = corners.shape[:2]
    gi, gj = np.meshgrid(np.arange(r, dtype=float), np.arange(c, dtype=float), indexing="ij")
    src = corners.reshape(-1, 2).astype(float)
    dst = np.stack([gj.ravel(), gi.ravel()], axis=1)
    shift, scale = src.mean(axis=0), src.std() or 1.0
    s = (src - shift) / scale
    zeros, ones = np.zeros(len(s)), np.ones(len(s))
    a = np.concatenate([
        np.stack([s[:, 0], s[:, 1], ones, zeros, zeros, zeros, -dst[:, 0] * s[:, 0],
                  -dst[:, 0] * s[:, 1], -dst[:, 0]], axis=1),
        np.stack([zeros, zeros, zeros, s[:, 0], s[:, 1], ones, -dst[:, 1] * s[:, 0],
                  -dst[:, 1] * s[:, 1], -dst[:, 1]], axis=1)])
    h = np.linalg.svd(a)[2][-1].reshape(3, 3)
    x = (np.asarray(cols, float) - shift[0]) / scale
    y = (np.asarray(rows, float) - shift[1]) / scale
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w


def _surface(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Monomials u^i v^j of degree 2..DEGREE (columns)."""
    return np.stack([u**i * v**(d - i) for d in range(2, DEGREE + 1) for i in range(d + 1)],
                    axis=1)


def _normalised(x: np.ndarray) -> np.ndarray:
    lo, hi = np.min(x), np.max(x)
    return (x - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-12)


def split_smooth(samples: list[dict]) -> dict:
    """Split the poses' smooth parts into board shape and calibration error.

    Parameters
    ----------
    samples : list of dict
        Per pose, arrays over sampled points: ``board_u``, ``board_v`` (board
        coordinates [squares]), ``image_u``, ``image_v`` [camera px], ``s``, ``t`` (the
        pose's plane coordinates [-]) and ``smooth`` (the smooth part [mm]).

    Returns
    -------
    dict
        ``board_shape_um``, ``calibration_um`` (the image-fixed surface and each pose's
        own rest, RMS over all points [um]), ``pose_own_um`` (that rest alone),
        ``correlation`` (largest canonical correlation of the two surfaces [-]) and
        ``separable`` (bool); with fewer than 3 poses, ``separable`` False only.
    """
    if len(samples) < 3:
        return {"separable": False, "correlation": math.nan,
                "why": "fewer than 3 poses: a board shape and a calibration error cannot "
                       "be told apart"}
    n = [len(p["smooth"]) for p in samples]
    cat = {k: np.concatenate([p[k] for p in samples]) for k in samples[0]}
    board = _surface(_normalised(cat["board_u"]), _normalised(cat["board_v"]))
    image = _surface(_normalised(cat["image_u"]), _normalised(cat["image_v"]))
    pose = np.zeros((sum(n), 3 * len(n)))
    start = 0
    for k, m in enumerate(n):
        sl = slice(start, start + m)
        pose[sl, 3 * k:3 * k + 3] = np.stack([np.ones(m), cat["s"][sl], cat["t"][sl]], axis=1)
        start += m
    q_pose = np.linalg.qr(pose)[0]

    def rest(x: np.ndarray) -> np.ndarray:
        return x - q_pose @ (q_pose.T @ x)

    qb, qi = np.linalg.qr(rest(board))[0], np.linalg.qr(rest(image))[0]
    correlation = float(np.linalg.svd(qb.T @ qi, compute_uv=False)[0])
    y = cat["smooth"]
    design = np.concatenate([pose, board, image], axis=1)
    coef = np.linalg.lstsq(design, y, rcond=None)[0]
    nb = board.shape[1]
    p0 = pose.shape[1]
    shape = rest(board @ coef[p0:p0 + nb])  # each pose's level and tilt are its plane's
    calib = rest(image @ coef[p0 + nb:])
    own = y - design @ coef

    def rms(x: np.ndarray) -> float:
        return 1e3 * float(np.sqrt(np.mean(x**2)))

    return {"board_shape_um": rms(shape), "calibration_um": math.hypot(rms(calib), rms(own)),
            "pose_own_um": rms(own), "correlation": correlation,
            "separable": correlation < MAX_CORRELATION}
