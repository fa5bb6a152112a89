"""The joint fit of a board calibration and its covariance (bundle adjustment).

OpenCV's calibration (:mod:`scanqa.calibration.board_fit`) fits the camera, then the
projector, then their relative pose with both lenses held. Here every parameter is
refined at once from that start: the free lens parameters of both devices (the lens
model's, :data:`FREE`), the projector's pose (Rp as a rotation vector, Tp) and the
board's pose in the camera for every board pose (6 each). The residuals are the
reprojection errors of the corners in the camera and in the projector, each divided by
its device's corner noise s_c, s_p measured in the fit itself (the RMS of that device's
residuals, corrected for the parameters spent, Eq. 1; iterated once):

    s_d^2 = sum_i r_d,i^2 / (m_d - p m_d / m)                                      (1)

with m_d the device's residuals, m all of them and p the parameters. With J the
Jacobian of the scaled residuals at the solution (analytic: OpenCV's projection with its
derivatives, chained through the projector's pose; the solver uses it too), the covariance
of all parameters is (J^T J)^-1 (Eq. 2; [1]_, Sec. 9), and that of the calibration's 24
(:data:`scanqa.io.opencv.COVARIANCE_PARAMETERS`) its block, the board poses'
uncertainty carried in:

    C_fit = [(J^T J)^-1]_theta theta                                               (2)

Model errors the data show, as stated terms: what the model holds fixed, but the board
poses can measure - the board's departure from a plane (a quadric z = b_x x'^2 + b_y y'^2
+ b_xy x' y' over the board, x', y' in units of half its size [mm]) and the lens terms
the model leaves out (k2 of both devices for "k1", the camera's principal point for
"k1" too, k3 for "k1k2"). Each such nuisance parameter eta is estimated with its std
sigma_eta by adding its columns J_eta to the fit (one Gauss-Newton step from the
solution); ignoring it biases the calibration by G eta with G = (J^T J)^-1 J^T J_eta,
so its contribution, with max(eta_hat^2 - sigma_eta^2, 0) (an unbiased estimate of
eta^2) for what the calibration assumed to be zero, is

    C = C_fit + G diag(max(eta_hat^2 - sigma_eta^2, 0)) G^T                        (3)

Eq. 3 states an estimated bias as a zero-mean variance: where it dominates (corner
noise of a few hundredths of a pixel, as Gray-code poses give, against a principal point
pixels off), the error at every point of the volume is that one bias, about one sigma
everywhere, and the share within 2 sigma is near 1 rather than 0.95, on every seed. With
``release``: the corner noise of Eq. 1 is measured on the residuals the nuisances' step
leaves (Eq. 4: model error is not counted as noise too), and a left-out term whose
estimate lies beyond :data:`RELEASE_STD` of its std is fitted, not stated (Eq. 5): it
becomes a free parameter, started at its Eq. 3 estimate, the fit is run to convergence,
and its uncertainty enters C_fit; the other left-out terms stay Eq. 3's.

A left-out term can be significant without being identified: on real poses it can take
up model errors the lens model does not name (on SLStudio's board poses the camera's c_y
comes out 17 px off at 14 std, and the five fits that each leave a pose out put it
anywhere from -20.8 to -14.5 px). Released, such a term moves the calibration by far more
than its covariance says. Eq. 6 is the guard: with the estimates eta_k of the n fits
that each leave one pose out, the term is identified when their jackknife spread agrees
with its std sigma_eta in the fit of all poses,

    (n - 1)/n sum_k (eta_k - mean eta)^2 <= sigma_eta^2 chi2_{n-1}(1 - p) / (n - 1)    (6)

at level p = :data:`GUARD_P`; :func:`scanqa.calibration.board_fit.calibrate_board`
releases only identified terms (three poses or more; fewer: none).

The calibrations that leave one pose out (the jackknife) remain a check
(:func:`scanqa.calibration.uncertainty.jackknife_covariance`); with five poses their
spread has 4 degrees of freedom and carries the board's bow as if it were noise.

References
----------
.. [1] B. Triggs, P. McLauchlan, R. Hartley and A. Fitzgibbon, "Bundle adjustment - a
   modern synthesis", Vision Algorithms: Theory and Practice, LNCS 1883 (2000), Sec. 9
   (covariance of the estimate, gauge).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scanqa.errors import InputError
from scanqa.io.opencv import OpenCVCalibration

#: Lens parameters free in each model, per device (camera, projector), by name of the
#: 9-vector (f_x f_y c_x c_y k1 k2 p1 p2 k3); "f" is f_x and f_y tied at their ratio.
FREE = {"k1": (("f", "k1"), ("f", "cx", "cy", "k1")),
        "k1k2": (("fx", "fy", "cx", "cy", "k1", "k2"),) * 2,
        "full": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),) * 2}
#: Lens terms a model leaves out that enter Eq. 3 as stated model errors, per device.
LEFT_OUT = {"k1": (("cx", "cy", "k2"), ("k2",)), "k1k2": (("k3",), ("k3",)),
            "full": ((), ())}
#: A left-out lens term whose estimate lies beyond this many of its std is released
#: (Eq. 5) [-].
RELEASE_STD = 2.0
#: Eq. 6's level: a left-out term is refused release when its leave-one-pose-out
#: estimates scatter beyond this tail of the chi-square their stated std predicts [-].
GUARD_P = 0.001
#: Board-shape terms of Eq. 3: the quadric's coefficients [mm].
BOW_TERMS = ("bow_x", "bow_y", "bow_xy")
_LENS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class BundleResult:
    """The joint fit (module notes).

    Attributes
    ----------
    data : OpenCVCalibration
        The refined calibration, its ``covariance`` Eq. 3's.
    noise_px : dict
        s_c, s_p of Eq. 1: ``camera``, ``projector`` [px].
    fit_covariance : (24, 24) float
        Eq. 2 alone [px, -, rad, mm squared].
    model_terms : dict
        Each stated nuisance: its estimate, std [mm, px, -] and its share of the trace
        of the camera-frame translation covariance.
    rvecs, tvecs : list of (3,) float
        The board poses in the camera [rad, mm].
    """

    data: OpenCVCalibration
    noise_px: dict
    fit_covariance: np.ndarray
    model_terms: dict = field(default_factory=dict)
    rvecs: list = field(default_factory=list)
    tvecs: list = field(default_factory=list)


def _basis(matrix: np.ndarray, names) -> np.ndarray:
    """(9, q) columns: how the device's 9-vector moves per free parameter."""
    cols = []
    for name in names:
        col = np.zeros(9)
        if name == "f":
            col[0], col[1] = 1.0, matrix[1, 1] / matrix[0, 0]
        else:
            col[_LENS.index(name)] = 1.0
        cols.append(col)
    return np.array(cols).T.reshape(9, len(cols))


def _lens9(matrix: np.ndarray, dist: np.ndarray) -> np.ndarray:
    d = np.pad(np.ravel(dist)[:5], (0, 5))[:5]
    return np.array([matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], *d], float)


def _kd(lens: np.ndarray, skew: float) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([[lens[0], skew, lens[2]], [0.0, lens[1], lens[3]], [0.0, 0.0, 1.0]]),
            np.asarray(lens[4:9], float))


class _Problem:
    """The scaled residuals of the joint fit as a function of one parameter vector."""

    def __init__(self, data: OpenCVCalibration, obj: list, cam: list, proj: list,
                 terms: tuple, rvecs: list, tvecs: list, extent: np.ndarray) -> None:
        self.obj, self.cam, self.proj = obj, cam, proj
        self.lens0 = (_lens9(data.Kc, data.kc), _lens9(data.Kp, data.kp))
        self.skew = (float(data.Kc[0, 1]), float(data.Kp[0, 1]))
        self.free, self.left = terms
        self.basis = [_basis(m, f) for m, f in zip((data.Kc, data.Kp), self.free,
                                                    strict=True)]
        self.nuis_basis = [_basis(m, f) for m, f in zip((data.Kc, data.Kp), self.left,
                                                         strict=True)]
        q = [b.shape[1] for b in self.basis]
        self.sizes = (q[0], q[1], 6, len(BOW_TERMS), 6 * len(obj))
        import cv2

        self.x0 = np.concatenate([np.zeros(q[0] + q[1]), cv2.Rodrigues(data.Rp)[0].ravel(),
                                  np.ravel(data.Tp), np.zeros(len(BOW_TERMS)),
                                  *[np.r_[np.ravel(r), np.ravel(t)]
                                                       for r, t in zip(rvecs, tvecs,
                                                                       strict=True)]])
        self.n_nuis = sum(b.shape[1] for b in self.nuis_basis)
        centre = (extent.max(axis=0) + extent.min(axis=0)) / 2
        half = np.maximum((extent.max(axis=0) - extent.min(axis=0)) / 2, 1e-9)
        self.shape = [np.column_stack([((o[:, 0] - centre[0]) / half[0]) ** 2,
                                       ((o[:, 1] - centre[1]) / half[1]) ** 2,
                                       (o[:, 0] - centre[0]) * (o[:, 1] - centre[1])
                                       / (half[0] * half[1])]) for o in obj]
        self.scale = np.ones(2)

    @property
    def n(self) -> int:
        return len(self.x0)

    def lenses(self, x: np.ndarray, eta: np.ndarray | None = None) -> list[np.ndarray]:
        out, k = [], 0
        for dev in range(2):
            q = self.basis[dev].shape[1]
            out.append(self.lens0[dev] + self.basis[dev] @ x[k:k + q])
            k += q
        if eta is not None:
            k = 0
            for dev in range(2):
                q = self.nuis_basis[dev].shape[1]
                out[dev] = out[dev] + self.nuis_basis[dev] @ eta[k:k + q]
                k += q
        return out

    def residuals(self, x: np.ndarray, eta: np.ndarray | None = None,
                  split: bool = False):
        import cv2

        lens = self.lenses(x, eta)
        kc_m, kc = _kd(lens[0], self.skew[0])
        kp_m, kp = _kd(lens[1], self.skew[1])
        k = self.sizes[0] + self.sizes[1]
        rot = cv2.Rodrigues(x[k:k + 3])[0]
        tp = x[k + 3:k + 6]
        bow = x[k + 6:k + 9]
        k += len(BOW_TERMS)
        res_c, res_p = [], []
        for i, (o, c, p) in enumerate(zip(self.obj, self.cam, self.proj, strict=True)):
            j = k + 6 + 6 * i
            rvec, tvec = x[j:j + 3], x[j + 3:j + 6]
            pts = o.copy()
            pts[:, 2] = pts[:, 2] + self.shape[i] @ bow
            res_c.append((cv2.projectPoints(pts, rvec, tvec, kc_m, kc)[0].reshape(-1, 2)
                          - c).ravel())
            r2 = cv2.Rodrigues(rot @ cv2.Rodrigues(rvec)[0])[0]
            res_p.append((cv2.projectPoints(pts, r2, rot @ tvec + tp, kp_m, kp)[0]
                          .reshape(-1, 2) - p).ravel())
        rc, rp = np.concatenate(res_c), np.concatenate(res_p)
        if split:
            return rc, rp
        return np.concatenate([rc / self.scale[0], rp / self.scale[1]])

    def with_jacobian(self, x: np.ndarray, eta: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scaled residuals (as :meth:`residuals`) and their Jacobians d/d x and
        d/d eta (the left-out lens terms), analytic: ``cv2.projectPoints`` gives each
        corner's image derivatives by its pose, focal lengths, principal point and
        distortion; the projector's pose (Rp R, Rp t + Tp) is chained by
        ``cv2.composeRT``, and the bow moves a corner along the board's normal,
        d/d z = d/d t R e_z."""
        import cv2

        lens = self.lenses(x, eta)
        kc_m, kc = _kd(lens[0], self.skew[0])
        kp_m, kp = _kd(lens[1], self.skew[1])
        q0, q1 = self.sizes[:2]
        k = q0 + q1
        rvec_p, tp = x[k:k + 3], x[k + 3:k + 6]
        rot = cv2.Rodrigues(rvec_p)[0]
        bow = x[k + 6:k + 9]
        first = k + 6 + len(BOW_TERMS)
        rows = 2 * sum(len(o) for o in self.obj)
        res = np.empty(2 * rows)
        jac = np.zeros((2 * rows, self.n))
        jn = np.zeros((2 * rows, self.n_nuis))
        nq0 = self.nuis_basis[0].shape[1]
        top = 0
        for i, (o, c, p) in enumerate(zip(self.obj, self.cam, self.proj, strict=True)):
            j = first + 6 * i
            rvec, tvec = x[j:j + 3], x[j + 3:j + 6]
            pts = o.copy()
            pts[:, 2] = pts[:, 2] + self.shape[i] @ bow
            shape = np.repeat(self.shape[i], 2, axis=0)
            cam_rows = slice(top, top + 2 * len(o))
            proj_rows = slice(rows + top, rows + top + 2 * len(o))
            top += 2 * len(o)
            pix, d = cv2.projectPoints(pts, rvec, tvec, kc_m, kc)
            res[cam_rows] = (pix.reshape(-1, 2) - c).ravel()
            jac[cam_rows, :q0] = d[:, 6:15] @ self.basis[0]
            jn[cam_rows, :nq0] = d[:, 6:15] @ self.nuis_basis[0]
            jac[cam_rows, j:j + 6] = d[:, :6]
            r1 = cv2.Rodrigues(rvec)[0]
            jac[cam_rows, k + 6:first] = (d[:, 3:6] @ r1[:, 2])[:, None] * shape
            r2 = cv2.Rodrigues(rot @ r1)[0]
            pix, d = cv2.projectPoints(pts, r2, rot @ tvec + tp, kp_m, kp)
            res[proj_rows] = (pix.reshape(-1, 2) - p).ravel()
            chain = cv2.composeRT(rvec, tvec, rvec_p, tp)
            jac[proj_rows, q0:k] = d[:, 6:15] @ self.basis[1]
            jn[proj_rows, nq0:] = d[:, 6:15] @ self.nuis_basis[1]
            jac[proj_rows, j:j + 3] = d[:, :3] @ chain[2]
            jac[proj_rows, j + 3:j + 6] = d[:, 3:6] @ chain[7]
            jac[proj_rows, k:k + 3] = d[:, :3] @ chain[4] + d[:, 3:6] @ chain[8]
            jac[proj_rows, k + 3:k + 6] = d[:, 3:6]
            jac[proj_rows, k + 6:first] = ((d[:, 3:6] @ cv2.Rodrigues(r2)[0][:, 2])[:, None]
                                           * shape)
        weight = np.repeat(1.0 / self.scale, rows)
        return res * weight, jac * weight[:, None], jn * weight[:, None]

    def step(self, x: np.ndarray) -> np.ndarray:
        """A typical small change of each parameter (the solver's ``x_scale`` is 1000 of
        them) [px, -, rad, mm]."""
        h = np.full(len(x), 1e-6)
        lens_steps = np.concatenate([np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-6, 1e-6, 1e-7,
                                               1e-7, 1e-6]) @ np.abs(b) for b in self.basis])
        h[:len(lens_steps)] = lens_steps
        k = self.sizes[0] + self.sizes[1]
        h[k + 3:k + 9] = 1e-4
        k += len(BOW_TERMS)
        for i in range(len(self.obj)):
            h[k + 6 + 6 * i + 3:k + 12 + 6 * i] = 1e-4
        return h

    def to_24(self) -> np.ndarray:
        """(24, n_theta) map from the free calibration parameters to the 24."""
        q0, q1 = self.sizes[:2]
        out = np.zeros((24, q0 + q1 + 6))
        out[0:9, :q0] = self.basis[0]
        out[9:18, q0:q0 + q1] = self.basis[1]
        out[18:24, q0 + q1:] = np.eye(6)
        return out

    def nuisance_24(self) -> np.ndarray:
        """(24, n_nuis) map from the left-out lens terms to the 24."""
        out = np.zeros((24, self.n_nuis))
        q0, q1 = (b.shape[1] for b in self.nuis_basis)
        out[0:9, :q0] = self.nuis_basis[0]
        out[9:18, q0:q0 + q1] = self.nuis_basis[1]
        return out

    def calibration(self, x: np.ndarray, like: OpenCVCalibration,
                    eta: np.ndarray | None = None) -> OpenCVCalibration:
        import cv2

        lens = self.lenses(x, eta)
        kc_m, kc = _kd(lens[0], self.skew[0])
        kp_m, kp = _kd(lens[1], self.skew[1])
        k = self.sizes[0] + self.sizes[1]
        return OpenCVCalibration(kc_m, kc, kp_m, kp, cv2.Rodrigues(x[k:k + 3])[0],
                                 x[k + 3:k + 6].copy(), sizes=dict(like.sizes),
                                 errors=dict(like.errors), source=like.source)


def _noise(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """Eq. 1: s_c, s_p [px]."""
    rc, rp = problem.residuals(x, split=True)
    m = len(rc) + len(rp)
    return np.array([np.sqrt(np.sum(r**2) / max(len(r) - problem.n * len(r) / m, 1.0))
                     for r in (rc, rp)])


def _solve(jac: np.ndarray, res: np.ndarray, strict: bool = True
           ) -> tuple[np.ndarray, np.ndarray]:
    """(J^T J)^-1 and the Gauss-Newton step -(J^T J)^-1 J^T r of scaled residuals
    (not ``strict``: the pseudo-inverse where J^T J is singular)."""
    try:
        inverse = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        if not strict:
            inverse = np.linalg.pinv(jac.T @ jac)
            return inverse, -(inverse @ (jac.T @ res))
        raise InputError("the board poses do not fix the calibration (a singular joint "
                         "fit): are two poses the same? use poses that tilt the board "
                         "differently") from None
    return inverse, -(inverse @ (jac.T @ res))


def _extended_noise(res: np.ndarray, jac: np.ndarray, jn: np.ndarray, scale: np.ndarray,
                    counts: list[int]) -> np.ndarray:
    """Eq. 4: s_c, s_p [px], Eq. 1 on the residuals left after one Gauss-Newton step of
    the fit with the nuisances' columns added, their parameters counted too.

    ``res``, ``jac``, ``jn``: the residuals and Jacobians scaled by ``scale`` (s_c, s_p
    of Eq. 1), ``counts`` the camera's and the projector's number of residuals."""
    full = np.hstack([jac, jn])
    left = (res + full @ np.linalg.lstsq(full, -res, rcond=None)[0]) * np.repeat(scale,
                                                                                counts)
    m, p = len(left), full.shape[1]
    return np.array([np.sqrt(np.sum(r**2) / max(len(r) - p * len(r) / m, 1.0))
                     for r in np.split(left, [counts[0]])])


def identified(estimates: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Eq. 6: which left-out lens terms the board poses identify - the leave-one-pose-out
    estimates agree within the full fit's std (module notes).

    Parameters
    ----------
    estimates : (n, k) float
        Each term's estimate from the n fits that each left one pose out.
    std : (k,) float
        Each term's std in the fit of all poses.

    Returns
    -------
    (k,) bool
    """
    from scipy.stats import chi2

    estimates = np.asarray(estimates, float)
    n = len(estimates)
    jack = np.sqrt((n - 1) / n * np.sum((estimates - estimates.mean(axis=0)) ** 2, axis=0))
    limit = np.sqrt(chi2.ppf(1 - GUARD_P, n - 1) / (n - 1))
    return jack <= limit * np.asarray(std, float)


def bundle_adjust(data: OpenCVCalibration, obj: list, cam: list, proj: list, model: str,
                  extent: np.ndarray, refine: bool = True, release=False) -> BundleResult:
    """Refine a board calibration jointly and give its covariance (Eqs. 1-5).

    Parameters
    ----------
    data : OpenCVCalibration
        The start (OpenCV's sequential fit).
    obj, cam, proj : list of (n_i, 2 or 3) float
        Per pose: board corners [mm] (Z = 0), their camera and projector images [px].
    model : str
        The lens model (:data:`FREE`).
    extent : (m, 3) float
        The board's corners, to scale the bow terms [mm].
    refine : bool
        Refine the parameters (else the covariance at ``data`` as it is).
    release : bool or collection of str
        Eqs. 4-5 (module notes) for these left-out terms (names as in ``model_terms``,
        e.g. ``"camera_cy"``; True: all of them): those the data show beyond
        :data:`RELEASE_STD` of their std are fitted, not stated, and the corner noise is
        measured after the nuisances. :func:`scanqa.calibration.board_fit.calibrate_board`
        passes the terms Eq. 6 finds identified.

    Returns
    -------
    BundleResult
    """
    if model not in FREE:
        raise InputError(f"lens model must be one of {FREE.keys()}, got {model!r}")
    names = [f"{dev}_{n}" for dev, left in zip(("camera", "projector"), LEFT_OUT[model],
                                               strict=True) for n in left]
    allowed = set(names) if release is True else set(release or ())
    first, est, std, stepped = _adjust(data, obj, cam, proj, (FREE[model], LEFT_OUT[model]),
                                       extent, refine, bool(allowed))
    shown = [n for n, e, s in zip(names, est, std, strict=True)
             if n in allowed and abs(e) > RELEASE_STD * s]
    if not shown:
        return first
    # Eq. 5: the shown terms become free parameters, started at their Eq. 3 estimates,
    # and the fit is run to convergence
    free = tuple(f + tuple(n for n in left if f"{dev}_{n}" in shown)
                 for dev, f, left in zip(("camera", "projector"), FREE[model],
                                         LEFT_OUT[model], strict=True))
    left = tuple(tuple(n for n in lo if f"{dev}_{n}" not in shown)
                 for dev, lo in zip(("camera", "projector"), LEFT_OUT[model], strict=True))
    start = stepped(np.isin(names, shown))
    out = _adjust(start, obj, cam, proj, (free, left), extent, refine, True)[0]
    lens0 = np.r_[_lens9(data.Kc, data.kc), _lens9(data.Kp, data.kp)]
    lens = np.r_[_lens9(out.data.Kc, out.data.kc), _lens9(out.data.Kp, out.data.kp)]
    terms = dict(out.model_terms)
    for name in shown:
        dev, lens_name = name.split("_", 1)
        k = _LENS.index(lens_name) + (9 if dev == "projector" else 0)
        terms[name] = {"estimate": float(lens[k] - lens0[k]),
                       "std": float(np.sqrt(max(out.fit_covariance[k, k], 0.0))),
                       "released": True}
    return BundleResult(out.data, out.noise_px, out.fit_covariance,
                        {k: terms[k] for k in (*names, *BOW_TERMS) if k in terms},
                        out.rvecs, out.tvecs)


def _adjust(data: OpenCVCalibration, obj: list, cam: list, proj: list, terms: tuple,
            extent: np.ndarray, refine: bool, after: bool
            ) -> tuple:
    """Eqs. 1-4 with the lens parameters ``terms`` = (free, left out), each per device
    (Eq. 4 when ``after``). Also returns every left-out term's estimate and std and the
    calibration one Gauss-Newton step takes with all of them added [px, -]."""
    import cv2
    from scipy.optimize import least_squares

    obj = [np.asarray(o, float).reshape(-1, 3) for o in obj]
    cam = [np.asarray(c, float).reshape(-1, 2) for c in cam]
    proj = [np.asarray(p, float).reshape(-1, 2) for p in proj]
    rvecs, tvecs = [], []
    for o, c in zip(obj, cam, strict=True):
        _, r, t = cv2.solvePnP(o, c, data.Kc, data.kc)
        rvecs.append(r.ravel())
        tvecs.append(t.ravel())
    problem = _Problem(data, obj, cam, proj, terms, rvecs, tvecs, np.asarray(extent, float))
    x = problem.x0.copy()
    problem.scale = _noise(problem, x)
    for _ in range(2 if refine else 0):
        x = least_squares(problem.residuals, x, jac=lambda y: problem.with_jacobian(y)[1],
                          x_scale=problem.step(x) * 1e3, method="lm").x
        problem.scale = _noise(problem, x)
    _, jac, jn = problem.with_jacobian(x)
    if after:  # Eq. 4: the corner noise from what the nuisances leave
        counts = [len(r) for r in problem.residuals(x, split=True)]
        noise = _extended_noise(problem.residuals(x), jac, jn, problem.scale, counts)
        ratio = np.repeat(problem.scale / noise, counts)
        jac, jn = jac * ratio[:, None], jn * ratio[:, None]
        problem.scale = noise
    res = problem.residuals(x)
    n_theta = sum(problem.sizes[:3])
    # Eq. 3: the nuisances, estimated by one Gauss-Newton step with their columns added
    inverse, _ = _solve(jac, res)
    full_inv, full_step = _solve(np.hstack([jac, jn]), res, strict=False)
    est, std = full_step[jac.shape[1]:], np.sqrt(np.clip(np.diag(full_inv)[jac.shape[1]:],
                                                         0, None))

    def stepped(keep: np.ndarray) -> OpenCVCalibration:
        return problem.calibration(x, data, np.where(keep, est, 0.0))

    to_all = np.zeros((24, inverse.shape[0]))
    to_all[:, :n_theta] = problem.to_24()
    fit_cov = to_all @ inverse @ to_all.T
    shift = to_all @ (inverse @ (jac.T @ jn)) - problem.nuisance_24()
    stated = np.clip(est**2 - std**2, 0.0, None)
    model_cov = shift @ np.diag(stated) @ shift.T
    names = [f"camera_{n}" for n in problem.left[0]] + [f"projector_{n}"
                                                        for n in problem.left[1]]
    model_terms = {name: {"estimate": float(e), "std": float(s),
                          "tz_std_mm": float(abs(shift[-1, k]) * np.sqrt(var))}
                   for k, (name, e, s, var) in enumerate(zip(names, est, std, stated,
                                                             strict=True))}
    k = n_theta
    for name, value, var in zip(BOW_TERMS, x[k:k + 3], np.diag(inverse)[k:k + 3],
                                strict=True):
        model_terms[name] = {"estimate": float(value), "std": float(np.sqrt(max(var, 0.0))),
                             "fitted": True}
    out = problem.calibration(x, data)
    cov = fit_cov + model_cov
    out = OpenCVCalibration(**{**out.__dict__, "covariance": (cov + cov.T) / 2})
    k = n_theta + len(BOW_TERMS)
    result = BundleResult(out, {"camera": float(problem.scale[0]),
                                "projector": float(problem.scale[1])}, fit_cov, model_terms,
                          [x[k + 6 * i:k + 6 * i + 3] for i in range(len(obj))],
                          [x[k + 6 * i + 3:k + 6 * i + 6] for i in range(len(obj))])
    return result, est, std, stepped
