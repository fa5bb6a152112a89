"""Does a board calibration's covariance predict its real error? (issue 42)

Part "sim" (simulated, known truth): each seed draws a scanner, a bowed board and board
poses (:mod:`scanqa.simulator.boardposes`: camera and projector with k1 and k2, the
camera's principal point off the image centre, a quadric bow of ~0.15 mm, corner noise
0.03-0.2 px), calibrates with the default lens model "k1" (which leaves the camera's
principal point and both k2 out: model errors the joint fit must state) and compares,
at points spread over the volume (a 7 x 7 grid of camera pixels at three depths over the
poses' range), the calibration's 3-D error along the line of sight with its predicted
sigma (:func:`scanqa.calibration.uncertainty.calibration_sigma_mm` of the joint fit's
covariance). Acceptance: over the held-out seeds, RMS(error / sigma) in [0.75, 1.33] and
the share within 2 sigma in [0.90, 0.99].

The seeds were named here before they were run: TUNING_SEEDS were used while the
method was built (the sign of a term, how a left-out term's variance is stated),
HELD_OUT_SEEDS only once, for the numbers reported.

Part "gray" (simulated): GRAY_SEEDS' poses rendered as images under Gray codes alone
(the layout of public projector-camera calibration tools), decoded (local homographies
on the decoded codes) and calibrated; the same error / sigma at the volume points, and
the focal lengths against the truth's.

Part "other" (simulated; issue 42's held-out class): another scanner's Gray-code-only
board poses (:data:`scanqa.simulator.boardposes.OTHER_SCANNER` and ``OTHER_BOARD``: 10
column and 10 row bits with inverses, white, black - 42 frames a pose), its truth the
reference calibration: the focal lengths against the reference's and the disagreement
at the volume points against the predicted sigma.

Since session 43 the default fit releases the left-out lens terms the poses identify
(Eq. 6 of :mod:`scanqa.calibration.bundle`); ``--release all`` and ``--release none``
give session 42's two variants.

Part "real" (the SLStudio board poses 1, 3-6, model corners, and skull_2x3; needs the
real-data folder): skull_2x3 triangulated with scanqa's board calibration and with
calibration.xml: median |dXYZ| / median calibration sigma; the five leave-one-pose-out
calibrations' spread at the skull's points against the predicted sigma.

Usage::

    python docs/studies/calibration_covariance.py sim [--tuning] [--release all|none]
    python docs/studies/calibration_covariance.py sim --noise-px 0.02,0.02 --seeds ...
    python docs/studies/calibration_covariance.py gray [--tuning] [--release all|none]
    python docs/studies/calibration_covariance.py other
    python docs/studies/calibration_covariance.py real
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
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # calibration_covariance_real

from scanqa.calibration.board_fit import calibrate_board  # noqa: E402
from scanqa.calibration.parametric import from_opencv  # noqa: E402
from scanqa.calibration.uncertainty import calibration_sigma_mm  # noqa: E402
from scanqa.simulator.boardposes import (  # noqa: E402
    BOARD,
    PANEL,
    SCANNER,
    simulate,
    volume_points,
)

#: Seeds the method was built on.
TUNING_SEEDS = tuple(range(1000, 1010))
#: Seeds named before they were run; run once for the reported numbers.
HELD_OUT_SEEDS = tuple(range(2000, 2012))
#: Part "gray": seeds whose poses are rendered as images under Gray codes (10 column and
#: 11 row bits with inverses, white, black; no phase set), decoded and calibrated as
#: ``scanqa calibrate`` does; named before they were run, none tuned on. Seeds 4000-4009
#: were named first and three run with a renderer that lit the bowed board's point off
#: the camera pixel's ray and sampled each pixel's reflectance at its centre only (its
#: corners 0.29 px off the truth, now 0.03 px; ratio of median error to median sigma
#: 1.45, 0.96, 2.64): the renderer was fixed, not the method, and these seeds named
#: afresh.
GRAY_SEEDS = tuple(range(4100, 4110))
#: Session 42 (the coverage of part "gray" was 0.998 on 4100-4106, above 0.99): the
#: seeds its cause was investigated and the method changed on, and the seeds named
#: before that work began and run once after it (none of them run before: 4107-4109
#: were left out, as 4107 had been run once and 4105-4106 reported).
GRAY_TUNING_SEEDS = tuple(range(4100, 4105))
GRAY_HELD_OUT_SEEDS = tuple(range(4110, 4118))
#: Session 42, part "sim" with ``--noise-px 0.02,0.02`` (the corner noise of rendered
#: Gray-code poses, 5 poses): seeds the cause was found on, and seeds named before the
#: ``--release`` variant was run on them.
LOW_NOISE_TUNING_SEEDS = tuple(range(5000, 5008))
LOW_NOISE_HELD_OUT_SEEDS = tuple(range(5100, 5112))


#: Session 43, named before any change and before any of them was run. Part "gray"
#: with the cheaper renderer: 4250-4254 to investigate on (cost, cause, model choice),
#: 4200-4211 held out (run once, for the reported numbers). Part "other" (the held-out
#: class: another scanner, Gray codes alone, its truth as the reference calibration):
#: 4300-4311 held out, never tuned on; 4390 only to see that its renderer runs.
#: Seed 4300 stopped in its first pose: the corner search found the board at half size
#: but not again at full size (scanqa.calibration.board now falls back to the half-size
#: corners); 4301-4311 were not run, and 4320-4331 were named afresh before the rerun.
GRAY43_TUNING_SEEDS = tuple(range(4250, 4255))
GRAY43_HELD_OUT_SEEDS = tuple(range(4200, 4212))
#: 4320-4331 were run once: 4329 stopped (in its third pose the light's edge cut the
#: board's margin, the corner search found 4 x 4 corners, with the grid given too) and
#: 4331's corners came out at 3 x the others' noise. The renderer now keeps only poses
#: whose board margin is lit (``ScannerClass.lit_margin``), and 4350-4361 were named
#: before the rerun.
OTHER_FIRST_SEEDS = tuple(range(4320, 4332))
OTHER_HELD_OUT_SEEDS = tuple(range(4350, 4362))
OTHER_SMOKE_SEED = 4390


#: ``--release``: which left-out lens terms the joint fit may fit instead of stating
#: (:func:`scanqa.calibration.board_fit.calibrate_board`'s ``release``; None, the
#: default: those Eq. 6 of :mod:`scanqa.calibration.bundle` finds identified).
RELEASE = {"release": None}
#: ``--give-board``: the board's grid given (``scanqa calibrate --board``), not searched.
GIVE_BOARD = {"board": False}
#: ``--noise-px``: corner noise of camera and projector for part "sim" (None: drawn).
NOISE = {"noise_px": None}


def seed_errors(seed: int) -> dict:
    """One seed: the calibration's line-of-sight error and predicted sigma at volume
    points [mm]."""
    sim = simulate(seed, n_poses=5 if NOISE["noise_px"] else 6, noise_px=NOISE["noise_px"])
    result = calibrate_board(sim.poses, BOARD, PANEL, "k1", jackknife=False, **RELEASE)
    cal = from_opencv(result.data)
    u, v, xp, xyz = volume_points(sim.truth, sim.depth_mm)
    ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    est = cal.apply(u, v, xp, extrapolate=True).xyz
    err = np.sum((est - xyz) * ray, axis=1)
    sigma = calibration_sigma_mm(cal, result.data.covariance, u, v, xp)
    return {"seed": seed, "error": err, "sigma": sigma,
            "abs_error": np.linalg.norm(est - xyz, axis=1),
            "noise_px": result.bundle["noise_px"], "bow": sim.bow.tolist()}


def run_sim(seeds) -> dict:
    rows, z = [], []
    for seed in seeds:
        t = time.process_time()
        out = seed_errors(seed)
        ratio = out["error"] / out["sigma"]
        z.append(ratio)
        rows.append({"seed": seed, "median_abs_error_um": 1e3 * np.median(np.abs(
            out["error"])), "median_sigma_um": 1e3 * np.median(out["sigma"]),
            "rms_z": float(np.sqrt(np.mean(ratio**2))),
            "within_2sigma": float(np.mean(np.abs(ratio) <= 2)),
            "cpu_s": time.process_time() - t})
        print(json.dumps(rows[-1]), flush=True)
    z = np.concatenate(z)
    summary = {"seeds": list(seeds), "rms_z": float(np.sqrt(np.mean(z**2))),
               "within_2sigma": float(np.mean(np.abs(z) <= 2)), "points": int(z.size)}
    print(json.dumps(summary))
    return summary


def gray_seed_errors(seed: int, folder: Path, n_poses: int = 5, scanner=SCANNER,
                     board=BOARD, bits=(10, 11)) -> dict:
    """One seed rendered under Gray codes, decoded and calibrated (parts "gray", "other").

    The truth is the reference calibration: the calibration's error at the volume points
    along the line of sight and in 3-D, its predicted sigma, and the focal lengths'."""
    from scanqa.calibration.board import decode_pose
    from scanqa.simulator.boardposes import gray_descriptions, write_gray_poses

    sim = simulate(seed, n_poses=n_poses, noise_px=(0.0, 0.0), scanner=scanner, board=board)
    panel = scanner.panel
    folders = write_gray_poses(sim, board, bits, seed, folder, name=f"s{seed}_{{k}}")
    poses = [decode_pose(where, *gray_descriptions(bits, panel),
                         board if GIVE_BOARD["board"] else board.square_mm)
             for where in folders]
    result = calibrate_board(poses, board, panel, "k1", jackknife=False, **RELEASE)
    cal = from_opencv(result.data)
    u, v, xp, xyz = volume_points(sim.truth, sim.depth_mm)
    ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    diff = cal.apply(u, v, xp, extrapolate=True).xyz - xyz
    sigma = calibration_sigma_mm(cal, result.data.covariance, u, v, xp)
    focal = [result.data.Kc[0, 0] / sim.truth.Kc[0, 0] - 1,
             result.data.Kp[0, 0] / sim.truth.Kp[0, 0] - 1]
    released = [k for k, t in result.bundle["model_terms"].items() if t.get("released")]
    return {"error": np.sum(diff * ray, axis=1), "abs_error": np.linalg.norm(diff, axis=1),
            "sigma": sigma, "focal_rel": focal, "released": released,
            "noise_px": result.bundle["noise_px"]}


def run_gray(seeds, other: bool = False) -> dict:
    import tempfile

    from scanqa.simulator.boardposes import OTHER_BOARD, OTHER_SCANNER

    kind = dict(scanner=OTHER_SCANNER, board=OTHER_BOARD, bits=(10, 10)) if other else {}
    z, d3, s3, rows = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            t = time.process_time()
            out = gray_seed_errors(seed, Path(tmp), **kind)
            ratio = out["error"] / out["sigma"]
            z.append(ratio)
            d3.append(out["abs_error"])
            s3.append(out["sigma"])
            rows.append({"seed": seed, "focal_rel": out["focal_rel"],
                         "released": out["released"], "noise_px": out["noise_px"],
                         "median_abs_error_um": 1e3 * np.median(np.abs(out["error"])),
                         "median_sigma_um": 1e3 * np.median(out["sigma"]),
                         "ratio_median": float(np.median(np.abs(out["error"]))
                                               / np.median(out["sigma"])),
                         "ratio_median_3d": float(np.median(out["abs_error"])
                                                  / np.median(out["sigma"])),
                         "mean_z": float(np.mean(ratio)),
                         "rms_z": float(np.sqrt(np.mean(ratio**2))),
                         "within_2sigma": float(np.mean(np.abs(ratio) <= 2)),
                         "cpu_s": time.process_time() - t})
            print(json.dumps(rows[-1]), flush=True)
    z, d3, s3 = (np.concatenate(a) for a in (z, d3, s3))
    summary = {"seeds": list(seeds), "rms_z": float(np.sqrt(np.mean(z**2))),
               "within_2sigma": float(np.mean(np.abs(z) <= 2)), "points": int(z.size),
               "ratio_median": float(np.median(np.abs(z))),
               "ratio_median_3d": float(np.median(d3) / np.median(s3)),
               "max_abs_focal_rel": float(np.max(np.abs([r["focal_rel"] for r in rows])))}
    print(json.dumps(summary))
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("part", choices=("sim", "real", "gray", "other"))
    parser.add_argument("--tuning", action="store_true", help="the tuning seeds")
    parser.add_argument("--seeds", default=None, metavar="A,B,...",
                        help="these seeds instead (e.g. to split a long run)")
    parser.add_argument("--release", choices=("identified", "all", "none"),
                        default="identified",
                        help="which left-out lens terms the data show are fitted, not "
                             "stated: those Eq. 6 finds identified (the default), all "
                             "(session 42's --release) or none (session 42's default)")
    parser.add_argument("--give-board", action="store_true",
                        help="parts gray, other: give the board's grid to the corner "
                             "search (--board) instead of searching for it")
    parser.add_argument("--noise-px", default=None, metavar="CAMERA,PROJECTOR",
                        help="part sim: this corner noise [px] and 5 poses, e.g. 0.02,0.02 "
                             "(what rendered Gray-code poses give)")
    args = parser.parse_args(argv)
    chosen = None if args.seeds is None else tuple(int(s) for s in args.seeds.split(","))
    GIVE_BOARD["board"] = args.give_board
    RELEASE["release"] = {"identified": None, "all": True, "none": False}[args.release]
    if args.noise_px:
        NOISE["noise_px"] = tuple(float(x) for x in args.noise_px.split(","))
    if args.part == "sim":
        run_sim(chosen or (TUNING_SEEDS if args.tuning else HELD_OUT_SEEDS))
    elif args.part == "gray":
        run_gray(chosen or (GRAY43_TUNING_SEEDS if args.tuning else GRAY43_HELD_OUT_SEEDS))
    elif args.part == "other":
        run_gray(chosen or OTHER_HELD_OUT_SEEDS, other=True)
    else:
        from calibration_covariance_real import run_real

        run_real()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
