"""Acceptance of the marked-target calibration (simulated): three calibrations of one sweep.

A simulated scanner with what real hardware has - camera distortion of 5 px at the
sensor corners, projector distortion, a stage axis tilted 1 deg against the camera axis,
a target tilted 2 deg, a printed marked chessboard - scans a plane sweep (27 positions,
2 repeats, with a marker frame each), 9 hold-out planes between the calibrated ones
(4 repeats) and the gauge-block artefact (6 repeats). Side by side:

(a) the table with the marker-derived lateral geometry (``scanqa calibrate``);
(b) a pinhole + distortion parametric calibration of the same sweep: the camera as
    fitted to the marker corners (:mod:`scanqa.calibration.sweep_fit`), the projector fitted
    to the decoded x_p at the corners (pinhole + k1 k2 p1 p2, by least squares on
    ``cv2.projectPoints``), triangulated by :mod:`scanqa.calibration.parametric`;
(c) the table with today's lateral: the config's ideal pinhole, Z = the stage reading
    (``scanqa calibrate --no-markers``).

Errors against the simulator's truth, repeats averaged with the noise floor removed
(as ``tests/test_closed_loop.py``): in the camera frame as estimated, and after one rigid
registration of each calibration's frame onto the truth (6 parameters fitted on the
calibration's own sweep positions with the true phase), since any calibration knows
the scanner frame only up to a rigid motion; trend = change of the mean signed error
along the line of sight over the hold-out range.

Usage::

    python docs/studies/acceptance_calibration.py [--out DIR] [--quick]
        [--config calib/paper_scanner.toml --profile f11] [--square-mm MM] [--seed N]
        [--marker-frames N]   # default 5, the capture the docs advise

Simulation results are cached in DIR (default ``acceptance_calibration_data``). At the
paper's full resolution (``--config calib/paper_scanner.toml --profile f11``) a scan
takes about 4 min to simulate: ``--quick`` (26 scans) is then under 2 h.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from scipy.ndimage import binary_erosion, maximum_filter, minimum_filter  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from scanqa.calibration.parametric import Lens, ParametricCalibration  # noqa: E402
from scanqa.calibration.sweep import calibrate, marker_geometry  # noqa: E402
from scanqa.calibration.sweep_fit import SweepGeometry, plane_to_camera  # noqa: E402
from scanqa.decoding.decoder import decode  # noqa: E402
from scanqa.io.manifest import read_manifest  # noqa: E402
from scanqa.io.sweep import Sweep, load_sweep  # noqa: E402
from scanqa.model.config import ScannerConfig, load_config  # noqa: E402
from scanqa.simulator.experiments import run_experiment  # noqa: E402

SAMPLE = ROOT / "sample_data" / "sample_scanner.toml"
SWEEP_Z = [float(z) for z in np.arange(424.0, 477.0, 2.0)]
HOLDOUT_Z = [425.0, 431.0, 437.0, 443.0, 449.0, 455.0, 461.0, 467.0, 475.0]
REALISM = {"camera_k1": -2.6, "projector_k1": -0.05, "projector_p1": 2e-4,
           "camera_cx_offset_px": 5.0, "camera_cy_offset_px": -3.0,
           "stage_tilt_deg": 1.0, "stage_tilt_azimuth_deg": 30.0, "target_tilt_deg": 2.0,
           "target": "chessboard", "target_square_mm": 4.0}


def scanner(config: Path = SAMPLE, profile: str | None = "sample",
            square_mm: float | None = None) -> ScannerConfig:
    """The scanner with the realism above: by default the sample camera (306 x 256 px of
    64 um, f/11); ``calib/paper_scanner.toml#f11`` is the paper's 2448 x 2048 px of 8 um.
    ``square_mm`` replaces the chessboard's square (4 mm)."""
    realism = dict(REALISM, **({"target_square_mm": square_mm} if square_mm else {}))
    return load_config(config, profile=profile).replace_simulator(**realism)


def simulate(out: Path, quick: bool, cfg: ScannerConfig, seed: int = 0,
             marker_frames: int = 1) -> dict[str, Path]:
    """Simulate (or reuse) the sweep, the hold-out planes and the gauge scans; ``seed``
    > 0 gives all three fresh noise (a second, independent run of the same scanner);
    the sweep takes ``marker_frames`` marker frames per position (the hold-out planes,
    whose markers are not used, one)."""
    zs = SWEEP_Z[::2] if quick else SWEEP_Z
    shift = 10 * seed
    runs = {"sweep": ("calibration-sweep", cfg.replace_simulator(
                seed=cfg.simulator.seed + shift), zs, 1 if quick else 2),
            "holdout": ("calibration-sweep", cfg.replace_simulator(seed=901 + shift),
                        HOLDOUT_Z[1::3] if quick else HOLDOUT_Z, 2 if quick else 4),
            "gauge": ("gauge-blocks", cfg.replace_simulator(seed=902 + shift), None,
                      2 if quick else 6)}
    done = {}
    for key, (name, config, positions, repeats) in runs.items():
        folder = out / key
        if not (folder / "manifest.toml").is_file():
            t0 = time.time()
            run_experiment(name, config, folder, positions=positions, repeats=repeats,
                           progress=True,
                           marker_frames=marker_frames if key == "sweep" else 1)
            print(f"simulated {key} in {time.time() - t0:.0f} s", file=sys.stderr)
        done[key] = folder
    return done


# ------------------------------------------------------------ (b) the parametric one


def _xp_at(xp: np.ndarray, uv: np.ndarray, half: int = 3) -> np.ndarray:
    """x_p at sub-pixel points by a local plane fit over (2 half + 1)^2 px [px]."""
    out = np.full(len(uv), np.nan)
    dv, du = np.mgrid[-half:half + 1, -half:half + 1]
    for n, (u, v) in enumerate(uv):
        iu, iv = round(float(u)), round(float(v))
        if not (half <= iu < xp.shape[1] - half and half <= iv < xp.shape[0] - half):
            continue
        patch = xp[iv - half:iv + half + 1, iu - half:iu + half + 1]
        ok = np.isfinite(patch)
        if ok.sum() < 12:
            continue
        a = np.column_stack([np.ones(ok.sum()), du[ok], dv[ok]])
        coef = np.linalg.lstsq(a, patch[ok], rcond=None)[0]
        out[n] = coef[0] + coef[1] * (u - iu) + coef[2] * (v - iv)
    return out


def projector_observations(sweep: Sweep, geometry: SweepGeometry
                           ) -> tuple[np.ndarray, np.ndarray]:
    """3-D corners in the camera frame and the decoded x_p there (repeats averaged)."""
    pts, xps = [], []
    xy = np.array([[i, j] for i in range(-20, 21) for j in range(-20, 21)], float) * 4.0
    for pos in sweep.positions:
        uv = geometry.project(xy, pos.z_mm)
        inside = (uv[:, 0] > 5) & (uv[:, 0] < geometry.camera.width_px - 6) & \
            (uv[:, 1] > 5) & (uv[:, 1] < geometry.camera.height_px - 6)
        maps = [decode(src).xp for src in pos.sources]
        xp = np.nanmean([_xp_at(m, uv[inside]) for m in maps], axis=0)
        p3 = plane_to_camera(xy[inside], geometry.rotation, geometry.translation(pos.z_mm))
        pts.append(p3[np.isfinite(xp)])
        xps.append(xp[np.isfinite(xp)])
    return np.concatenate(pts), np.concatenate(xps)


def fit_parametric(sweep: Sweep, geometry: SweepGeometry, cfg: ScannerConfig
                   ) -> tuple[ParametricCalibration, float]:
    """Pinhole + distortion projector fitted to x_p at the corners; the camera is the
    marker fit's. Only x_p is observed (vertical fringes), so f_y = f_x and c_y is the
    panel centre (neither enters the triangulation of x_p)."""
    import cv2

    pts, xp = projector_observations(sweep, geometry)
    proj = cfg.projector
    rot0 = proj.rotation
    t0 = -rot0 @ np.asarray(proj.position_mm, float)
    cy = (proj.height_px - 1) / 2.0

    def model(p: np.ndarray) -> np.ndarray:
        rot = cv2.Rodrigues(p[6:9])[0]
        q = pts @ rot.T + p[9:12]
        lens = Lens(np.array([[p[0], 0, p[1]], [0, p[0], cy], [0, 0, 1]]),
                    np.array([*p[2:6], 0.0]), proj.width_px, proj.height_px)
        return lens.project(q)[0]

    p0 = np.array([proj.principal_distance_px, (proj.width_px - 1) / 2.0, 0, 0, 0, 0,
                   *cv2.Rodrigues(rot0)[0].ravel(), *t0])
    fit = least_squares(lambda p: model(p) - xp, p0, x_scale="jac", method="lm")
    p = fit.x
    projector = Lens(np.array([[p[0], 0, p[1]], [0, p[0], cy], [0, 0, 1]]),
                     np.array([*p[2:6], 0.0]), proj.width_px, proj.height_px)
    cal = ParametricCalibration(geometry.camera, projector, cv2.Rodrigues(p[6:9])[0],
                                p[9:12], "vertical", source="fitted (acceptance)")
    return cal, float(np.sqrt(np.mean(fit.fun**2)))


# ------------------------------------------------------------------------ errors


def _points(cal, u, v, xp) -> np.ndarray:
    look = cal.apply(u, v, xp)
    return np.where(look.in_volume[..., None], look.xyz, np.nan)


def registration(cal, sweep_dir: Path, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (R, t) that best maps the calibration's frame onto the truth, fitted on the
    calibration's own sweep positions with the true phase (Kabsch)."""
    src, dst = [], []
    for npz in sorted((sweep_dir / "truth").glob("p*.npz")):
        with np.load(npz) as t:
            xyz, xp, ok = np.stack([t["X"], t["Y"], t["Z"]], -1), t["xp_true"], t["valid"]
        v, u = np.mgrid[0:xp.shape[0]:step, 0:xp.shape[1]:step]
        sel = ok[v, u]
        p = _points(cal, u[sel], v[sel], xp[v, u][sel])
        good = np.isfinite(p).all(-1)
        src.append(p[good])
        dst.append(xyz[v, u][sel][good])
    a, b = np.concatenate(src), np.concatenate(dst)
    ca, cb = a.mean(0), b.mean(0)
    uu, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ uu.T))
    rot = vt.T @ np.diag([1, 1, d]) @ uu.T
    return rot, cb - rot @ ca


def systematic(errors: np.ndarray) -> dict:
    """(R, n, 3) errors of R repeats -> systematic RMS with the noise floor removed [um]."""
    reps = errors.shape[0]
    mean = errors.mean(0)
    raw2 = float(np.mean(np.sum(mean**2, -1)))
    floor2 = float(np.mean(errors.var(0, ddof=1).sum(-1))) / reps
    return {"sys_um": 1e3 * np.sqrt(max(raw2 - floor2, 0.0)), "raw_um": 1e3 * np.sqrt(raw2),
            "floor_um": 1e3 * np.sqrt(floor2), "n": int(errors.shape[1])}


#: Pixels this close to an edge of the scene are left out of the errors [mm on the object]:
#: 3 px of the sample camera. Held in object space since the simulator's blur halo at a
#: depth edge (docs/simulator.rst) is as wide in mm at any resolution; at the paper's
#: 8 um pixels 3 px left 10 um of halo error in the gauge scan's figure.
EDGE_MARGIN_MM = 0.6


def edge_margin_px(cfg: ScannerConfig) -> int:
    """:data:`EDGE_MARGIN_MM` in camera pixels at the focus distance [px]."""
    cam = cfg.camera
    return int(np.ceil(EDGE_MARGIN_MM * cam.principal_distance_px / cam.focus_mm))


def _clean(valid: np.ndarray, z: np.ndarray, margin: int) -> np.ndarray:
    k = 2 * margin + 1
    zz = np.where(np.isfinite(z), z, 0.0)
    flat = (maximum_filter(zz, size=k) - minimum_filter(zz, size=k)) < 0.05
    return flat & binary_erosion(valid, np.ones((k, k), bool), border_value=0)


def scans(folder: Path) -> list[tuple[dict, list[np.ndarray]]]:
    """(truth arrays, decoded x_p of every repeat) per position of an experiment."""
    manifest = read_manifest(folder)
    out: dict = {}
    for acq in manifest["acquisition"]:
        out.setdefault(acq["truth"], []).append(decode(folder / acq["folder"]).xp)
    result = []
    for truth, maps in out.items():
        with np.load(folder / truth) as t:
            result.append(({k: t[k] for k in ("X", "Y", "Z", "valid")}, maps))
    return result


def errors_of(cal, data, margin: int, reg=None) -> tuple[dict, list[float]]:
    """Pooled systematic error and the mean signed error along the line of sight per
    position [um], ``margin`` px from the scene's edges left out."""
    parts, bias = [], []
    for truth, maps in data:
        ok = _clean(truth["valid"], truth["Z"], margin) & np.all([np.isfinite(m) for m in maps],
                                                                 0)
        v, u = np.nonzero(ok)
        xyz = np.stack([truth[k][ok] for k in ("X", "Y", "Z")], -1)
        pts = np.stack([_points(cal, u, v, m[ok]) for m in maps])
        if reg is not None:
            pts = pts @ reg[0].T + reg[1]
        good = np.isfinite(pts).all(-1).all(0)
        err = pts[:, good] - xyz[good]
        los = xyz[good] / np.linalg.norm(xyz[good], axis=-1, keepdims=True)
        parts.append(err)
        bias.append(1e3 * float(np.mean(np.einsum("rni,ni->n", err, los)) / len(maps)))
    return systematic(np.concatenate(parts, axis=1)), bias


def evaluate(cfg: ScannerConfig, folders: dict[str, Path]) -> dict:
    """The three calibrations and their errors (module notes)."""
    sweep = load_sweep(folders["sweep"])
    t0 = time.time()
    geometry = marker_geometry(sweep, cfg)
    cals = {"a_marker_table": calibrate(sweep, cfg)[0]}
    cals["b_parametric"], proj_rms = fit_parametric(sweep, geometry, cfg)
    cals["c_pinhole_table"] = calibrate(sweep, cfg, use_markers=False)[0]
    print(f"calibrated in {time.time() - t0:.0f} s", file=sys.stderr)
    holdout, gauge = scans(folders["holdout"]), scans(folders["gauge"])
    z_hold = [float(np.nanmedian(t["Z"])) for t, _ in holdout]
    margin = edge_margin_px(cfg)
    focus = int(np.argmin(np.abs(np.array(z_hold) - cfg.camera.focus_mm)))
    result = {"simulated": True, "realism": REALISM,
              "target_square_mm": cfg.simulator.target_square_mm,
              "marker_error": cals["a_marker_table"].provenance["target_geometry"][
                  "marker_error"],
              "geometry": geometry.summary(),
              "projector_fit_rms_px": proj_rms, "edge_margin_px": margin, "calibrations": {}}
    for name, cal in cals.items():
        reg = registration(cal, folders["sweep"])
        row = {"registration_deg": float(np.degrees(np.arccos(np.clip(
            (np.trace(reg[0]) - 1) / 2, -1, 1)))), "registration_mm": reg[1].tolist()}
        for frame, r in (("camera_frame", None), ("registered", reg)):
            hold, bias = errors_of(cal, holdout, margin, r)
            gau, _ = errors_of(cal, gauge, margin, r)
            slope = np.polyfit(z_hold, bias, 1)[0] if len(z_hold) > 1 else 0.0
            row[frame] = {"holdout": hold, "gauge": gau,
                          "trend_um": float(abs(slope) * (max(z_hold) - min(z_hold))),
                          "bias_um_per_plane": bias}
        result["calibrations"][name] = row
    result["in_focus_sigma_um"] = in_focus_sigma(cals["a_marker_table"], holdout[focus], margin)
    return result


def in_focus_sigma(cal, plane, margin: int) -> float:
    """Measured single-point std along the line of sight at the plane nearest focus [um]."""
    truth, maps = plane
    ok = _clean(truth["valid"], truth["Z"], margin) & np.all([np.isfinite(m) for m in maps], 0)
    v, u = np.nonzero(ok)
    pts = np.stack([_points(cal, u, v, m[ok]) for m in maps])
    los = pts[0] / np.linalg.norm(pts[0], axis=-1, keepdims=True)
    d = np.einsum("rni,ni->rn", pts, los)
    return float(1e3 * np.sqrt(np.nanmean(np.nanvar(d, axis=0, ddof=1))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="acceptance_calibration_data")
    parser.add_argument("--quick", action="store_true",
                        help="14 sweep positions x 1, 3 hold-out planes x 2, 2 gauge scans "
                             "(instead of 27 x 2, 9 x 4, 6)")
    parser.add_argument("--simulate-only", action="store_true")
    parser.add_argument("--config", type=Path, default=SAMPLE,
                        help="scanner config (default: the sample scanner)")
    parser.add_argument("--profile", default="sample",
                        help="profile of --config (default 'sample'; 'f11' with "
                             "calib/paper_scanner.toml is the paper's full-resolution camera)")
    parser.add_argument("--square-mm", type=float, default=None,
                        help="the printed chessboard's square [mm] (default 4)")
    parser.add_argument("--marker-frames", type=int, default=5,
                        help="marker frames per sweep position, averaged by calibrate "
                             "(default 5, the capture the docs advise: "
                             "docs/calibration.rst 'How many marker frames')")
    parser.add_argument("--seed", type=int, default=0,
                        help="> 0: fresh noise for sweep, hold-out and gauge scans (an "
                             "independent repetition of the run; default 0)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    cfg = scanner(args.config, args.profile, args.square_mm)
    folders = simulate(out, args.quick, cfg, args.seed, args.marker_frames)
    if args.simulate_only:
        return 0
    result = evaluate(cfg, folders)
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
