"""Where the marker-derived geometry's error comes from (simulated): oracle experiments.

On the acceptance sweep of ``acceptance_calibration.py`` (whose simulator truth is
known), the sweep geometry (:mod:`scanqa.calibration.sweep_fit`) is fitted with parts of it
replaced by the truth, and each variant's target-plane points (the X, Y, Z the table is
built with) are compared with the simulator's truth maps of the sweep: RMS in the camera
frame, after one rigid registration (as the acceptance) and the range of the mean
line-of-sight error over the positions (trend). A last part propagates white corner noise
of the measured size through the fit (linearised) to the registered error.

``--radial-bias`` needs no sweep: it renders the acceptance sweep's 27 marker frames
(2 mm squares) without noise (no scene noise, the sensor's mean signal as float) and fits
the camera to the corners found with the corner refinement's window as the detector sets
it and with a fixed window (sigma, half window [px]); the fit's f and k2 against the
simulator's camera are the detector's bias alone (docs/calibration.rst, "The marker fit's
radial bias"). ``--seed N`` renders the frames with noise instead (stream N).

``--frames K --seed N`` renders the marker frames with noise streams N .. N + K - 1,
averages the K frames of each position as ``calibrate`` does, fits, and prints the
target rotation's error against the simulator's truth and its std, with the registered
error the fit's covariance implies (Eq. 4 of :mod:`scanqa.calibration.uncertainty`) and
its distribution for 1-8 frames per position
(docs/calibration.rst, "How many marker frames"). Streams 1000 and up are the
marker-only draws (no acceptance seed).

Usage::

    python docs/studies/diagnose_marker_geometry.py [--sweep DIR]
    python docs/studies/diagnose_marker_geometry.py --radial-bias [--seed N]
    python docs/studies/diagnose_marker_geometry.py --frames K --seed N

DIR defaults to ``acceptance_calibration_data/sweep`` (simulate it with
``acceptance_calibration.py --simulate-only``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import acceptance_calibration as acc

from scanqa.calibration import sweep_fit as sf
from scanqa.calibration import target as tg
from scanqa.calibration.parametric import Lens
from scanqa.io.images import read_image
from scanqa.io.sweep import load_sweep
from scanqa.simulator import devices, texture

NAMES = ("f", "cx", "cy", "k1", "k2", "p1", "p2", "r1", "r2", "r3", "tx", "ty", "tz",
         "ax", "ay")
ALL = np.ones(15, bool)
PP_HELD = ALL & ~np.isin(np.arange(15), (1, 2))
INTRINSICS, POSES = np.arange(15) < 7, np.arange(15) >= 7


def _pack(f, pp, dist, rotation, origin, axis) -> np.ndarray:
    """Camera, target rotation (target -> camera), origin and stage axis as the 15 fit
    parameters of :mod:`scanqa.calibration.sweep_fit` (the inverse of its ``_unpack``)."""
    import cv2

    return np.array([f, *pp, *dist, *cv2.Rodrigues(np.asarray(rotation, float))[0].ravel(),
                     *origin, math.atan2(axis[0], axis[2]), math.atan2(axis[1], axis[2])])


class Setup:
    """The sweep, its truth, the detected and the exact corners."""

    def __init__(self, folder: Path) -> None:
        self.cfg = acc.scanner()
        self.sweep = load_sweep(folder)
        self.stage = [p.z_mm for p in self.sweep.positions]
        self.ref = 0.5 * (min(self.stage) + max(self.stage))
        self.size = (self.cfg.camera.width_px, self.cfg.camera.height_px)
        spec = tg.ChessboardSpec(float(self.sweep.target["square_mm"]))
        self.detected = [tg.detect_chessboard(read_image(p.marker_frames[0]), spec)
                         for p in self.sweep.positions]
        self.exact = [tg.Detection(self.true_uv(d.target_points, s), d.target_points)
                      for d, s in zip(self.detected, self.stage, strict=True)]
        self.truth = []
        for i in range(len(self.stage)):
            with np.load(folder / "truth" / f"p{i:03d}.npz") as t:
                self.truth.append((np.stack([t["X"], t["Y"], t["Z"]], -1), t["valid"]))

    def true_uv(self, xy: np.ndarray, stage: float) -> np.ndarray:
        frame = texture.target_frame(self.cfg, stage)
        u, v = devices.project_to_camera(self.cfg, devices.camera_pose(), frame.to_world(xy))
        return np.stack([u, v], -1)

    def oracle(self) -> np.ndarray:
        """The simulator's camera, target pose and stage axis as fit parameters."""
        cam = self.cfg.camera
        frame = texture.target_frame(self.cfg, self.ref)
        return _pack(cam.principal_distance_px, devices.camera_principal_point(self.cfg),
                     devices.distortion(self.cfg, "camera"), frame.axes.T, frame.origin,
                     texture.stage_axis(self.cfg))

    def arrays(self, dets):
        xy = np.concatenate([d.target_points for d in dets])
        uv = np.concatenate([d.image_points for d in dets])
        st = np.concatenate([np.full(len(d.target_points), s - self.ref)
                             for d, s in zip(dets, self.stage, strict=True)])
        return xy, st, uv

    def fit(self, dets, free, start=None) -> tuple[np.ndarray, np.ndarray]:
        """Fit the free parameters (others at ``start``, default the truth)."""
        p0 = self.oracle() if start is None else start.copy()
        fit = sf._solve(p0, free, (*self.arrays(dets), self.size))
        return fit.p, fit.std()

    def params(self, g: sf.SweepGeometry) -> np.ndarray:
        """A fitted geometry as the 15 fit parameters (stage reference as here)."""
        k = g.camera.matrix
        return _pack(k[0, 0], k[:2, 2], g.camera.distortion[:4], g.rotation,
                     g.translation(self.ref), g.axis)

    def geometry(self, p) -> sf.SweepGeometry:
        k, dist, rot, t0, axis = sf._unpack(p)
        return sf.SweepGeometry(Lens(k, dist, *self.size), rot, np.asarray(t0), axis,
                                self.ref, 0.0)

    def points(self, p, step: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g, src, dst, idx = self.geometry(p), [], [], []
        for i, s in enumerate(self.stage):
            q = np.stack(g.plane_points(s, *self.size), -1)[::step, ::step]
            t, ok = self.truth[i][0][::step, ::step], self.truth[i][1][::step, ::step]
            ok = ok & np.isfinite(q).all(-1)
            src.append(q[ok])
            dst.append(t[ok])
            idx.append(np.full(int(ok.sum()), i))
        return np.concatenate(src), np.concatenate(dst), np.concatenate(idx)

    def error(self, p) -> dict:
        """Plane points against truth: camera frame, registered, trend [um]."""
        a, b, idx = self.points(p)
        ca, cb = a.mean(0), b.mean(0)
        uu, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
        rot = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ uu.T))]) @ uu.T
        e = (a - ca) @ rot.T + cb - b
        los = np.einsum("ni,ni->n", e, b / np.linalg.norm(b, axis=1, keepdims=True))
        per = [los[idx == i].mean() for i in range(len(self.stage))]
        return {"camera_frame_um": 1e3 * float(np.sqrt(np.mean(np.sum((a - b)**2, -1)))),
                "registered_um": 1e3 * float(np.sqrt(np.mean(np.sum(e**2, -1)))),
                "trend_um": 1e3 * float(np.ptp(per))}


def detection_error(s: Setup) -> dict:
    """Detected corners against the exact ones: RMS and the pixel-locking term [px]."""
    err = np.concatenate([d.image_points - e.image_points
                          for d, e in zip(s.detected, s.exact, strict=True)])
    uv = np.concatenate([e.image_points for e in s.exact])
    frac = uv - np.round(uv)
    amp = [float(np.linalg.lstsq(np.column_stack([np.ones(len(f)), np.sin(2 * np.pi * f)]),
                                 e, rcond=None)[0][1]) for f, e in zip(frac.T, err.T,
                                                                        strict=True)]
    locked = err - np.outer(np.ones(len(err)), amp) * np.sin(2 * np.pi * frac)
    return {"rms_px": float(np.sqrt(np.mean(np.sum(err**2, 1)))),
            "mean_px": err.mean(0).tolist(), "locking_amplitude_px": amp,
            "rest_rms_per_coord_px": float(locked.std(0).mean()), "n": len(err)}


def experiments(s: Setup) -> dict:
    """The fit variants and their plane-point errors (module notes)."""
    held = {k: PP_HELD & ~np.isin(np.arange(15), v) for k, v in
            (("k2", (4,)), ("p", (5, 6)))}
    runs = {"oracle geometry": None,
            "exact corners, pp held": (s.exact, PP_HELD),
            "exact corners, pp free": (s.exact, ALL),
            "detected, pp held (the earlier calibrate)": (s.detected, PP_HELD),
            "detected, pp free": (s.detected, ALL),
            "detected, pp held, k2 = 0": (s.detected, held["k2"]),
            "detected, pp held, p1 = p2 = 0": (s.detected, held["p"]),
            "detected, true intrinsics, fitted poses": (s.detected, POSES),
            "detected, fitted intrinsics, true poses": (s.detected, INTRINSICS)}
    out, truth = {}, s.oracle()
    for name, run in runs.items():
        p, std = (truth, np.zeros(15)) if run is None else s.fit(*run)
        row = s.error(p)
        row["params"] = {n: [float(v), float(e), float(t)] for n, v, e, t in
                         zip(NAMES, p, std, truth, strict=True) if e > 0}
        out[name] = row
    geo = sf.fit_sweep_geometry(s.detected, s.stage, s.cfg, *s.size)
    fitted = s.params(geo)
    out["as calibrate (fit_sweep_geometry)"] = s.error(fitted)
    for name, idx in (("target rotation", slice(7, 10)), ("f, k1, k2", [0, 3, 4])):
        swapped = fitted.copy()
        swapped[idx] = truth[idx]
        out[f"as calibrate, its {name} set to the truth (not refitted)"] = s.error(swapped)
    main, _ = s.fit(s.detected, PP_HELD)
    mixed = truth.copy()
    mixed[:7] = main[:7]
    out["intrinsics of the calibrate fit, true poses"] = s.error(mixed)
    return out


def propagation(s: Setup, sigma_px: float) -> dict:
    """Registered plane-point RMS from white corner noise through the linearised fit [um]."""
    p0 = s.oracle()
    free = np.nonzero(PP_HELD)[0]
    xy, st, uv = s.arrays(s.exact)
    base_r = sf._residuals(p0, xy, st, uv, s.size)
    base_f, _, _ = s.points(p0, step=8)
    n = len(base_f)
    rigid = []
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        rigid += [np.tile(e, n), np.cross(e, base_f - base_f.mean(0)).ravel()]
    q, _ = np.linalg.qr(np.array(rigid).T)
    jac, field = [], []
    for k in free:
        p = p0.copy()
        h = 1e-6 * max(1.0, abs(p0[k]) * 1e-2)
        p[k] += h
        jac.append((sf._residuals(p, xy, st, uv, s.size) - base_r) / h)
        f = ((s.points(p, step=8)[0] - base_f) / h).ravel()
        field.append(f - q @ (q.T @ f))
    jac, field = np.array(jac).T, np.array(field).T
    out = {}
    for name, sel in (("pp held", free >= 0), ("intrinsics known", free >= 7)):
        cov = np.linalg.inv(jac[:, sel].T @ jac[:, sel]) * sigma_px**2
        g = field[:, sel]
        out[name] = 1e3 * float(np.sqrt(np.trace(cov @ (g.T @ g)) / n))
    return out


def marker_frames(cfg, seed: int | None = None) -> list[np.ndarray]:
    """The acceptance sweep's marker frames, noise-free (``seed`` None) or with the
    simulator's noise of stream ``seed`` [DN]."""
    from scanqa.simulator import experiments, render

    sensor = render._sensor
    if seed is None:
        cfg = cfg.replace_simulator(scene_noise_rel=0.0)
        render._sensor = lambda config, e, rng: (e / config.simulator.gain_e_per_dn
                                                 ).astype(np.float32)
    else:
        cfg = cfg.replace_simulator(seed=seed)
    try:
        frames = []
        for pos in experiments.build_positions("calibration-sweep", cfg, acc.SWEEP_Z):
            win = devices.sensor_window(cfg)
            images = [np.zeros((1, win.height, win.width), np.float32)]
            render._render_tiles(cfg, experiments.acquisition(cfg, pos, 0,
                                                              "calibration-sweep"),
                                 None, win, images)
            frames.append(images[0][0])
    finally:
        render._sensor = sensor
    return frames


def radial_bias(seed: int | None) -> dict:
    """The marker fit's f, k2 and target tilt against the truth, per refinement window."""
    cfg = acc.scanner(square_mm=2.0)
    frames, spec = marker_frames(cfg, seed), tg.ChessboardSpec(2.0)
    size = (cfg.camera.width_px, cfg.camera.height_px)
    out, rule = {}, tg.refine_window
    for name, window in (("as the detector sets it", None), ("fixed 1.5 / 5", (1.5, 5))):
        tg.refine_window = rule if window is None else (lambda square, w=window: w)
        try:
            dets = [tg.detect_chessboard(f, spec) for f in frames]
        finally:
            tg.refine_window = rule
        g = sf.fit_sweep_geometry(dets, acc.SWEEP_Z, cfg, *size)
        out[name] = {"f_error_px": float(g.camera.matrix[0, 0]
                                         - cfg.camera.principal_distance_px),
                     "f_std_px": g.std["focal_px"], "k2": float(g.camera.distortion[1]),
                     "k2_std": g.std["k2"],
                     "k1_error": float(g.camera.distortion[0] - cfg.simulator.camera_k1),
                     "target_tilt_error_deg": g.target_tilt_deg - cfg.simulator.target_tilt_deg,
                     "rms_px": g.rms_px}
    return {"simulated": True, "noise": "none" if seed is None else f"seed {seed}", **out}


def averaged_frames(seed: int, frames: int) -> dict:
    """The marker fit of K averaged noisy frames per position against the truth, and
    what its covariance predicts (module notes)."""
    from scanqa.calibration import uncertainty as un

    cfg = acc.scanner(square_mm=2.0)
    spec, size = tg.ChessboardSpec(2.0), (cfg.camera.width_px, cfg.camera.height_px)
    draws = [marker_frames(cfg, seed + k) for k in range(frames)]
    dets = [tg.detect_chessboard(np.mean([d[i].astype(float) for d in draws], axis=0), spec)
            for i in range(len(acc.SWEEP_Z))]
    g = sf.fit_sweep_geometry(dets, acc.SWEEP_Z, cfg, *size)
    ref = 0.5 * (min(acc.SWEEP_Z) + max(acc.SWEEP_Z))
    truth = texture.target_frame(cfg, ref).axes.T[:, 2]
    normal = g.rotation[:, 2] * np.sign(g.rotation[2, 2]) - truth
    spread = un.registered_error_spread(g, acc.SWEEP_Z)
    per_n = {n: {"median_um": 1e3 * un.registered_error_mm(spread, 0.5, frames / n),
                 "q95_um": 1e3 * un.registered_error_mm(spread, 0.95, frames / n)}
             for n in (1, 2, 3, 4, 5, 6, 8)}
    return {"simulated": True, "streams": [seed, seed + frames - 1], "frames": frames,
            "rotation_error_deg": [math.degrees(float(v)) for v in normal[:2]],
            "rotation_std_deg": [g.std["target_normal_x_deg"], g.std["target_normal_y_deg"]],
            "spread_um2": [1e6 * float(v) for v in spread[:3]],
            "predicted_per_frames": per_n,
            "marker_error": un.marker_error_summary(g, acc.SWEEP_Z, frames, 0.75e-3)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sweep", default="acceptance_calibration_data/sweep")
    parser.add_argument("--radial-bias", action="store_true",
                        help="the detector's bias of f and k2 from rendered marker frames")
    parser.add_argument("--seed", type=int, default=None,
                        help="with --radial-bias: frames with noise of this stream; with "
                             "--frames: the first stream")
    parser.add_argument("--frames", type=int, default=None,
                        help="marker frames averaged per position (needs --seed)")
    args = parser.parse_args(argv)
    if args.frames:
        print(json.dumps(averaged_frames(args.seed or 1001, args.frames), indent=1))
        return 0
    if args.radial_bias:
        print(json.dumps(radial_bias(args.seed), indent=1))
        return 0
    s = Setup(Path(args.sweep))
    det = detection_error(s)
    result = {"simulated": True, "detection": det, "experiments": experiments(s),
              "white_noise_prediction_um": propagation(s, det["rms_px"] / math.sqrt(2))}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
