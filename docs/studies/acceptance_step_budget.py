"""Gauge-block steps on the realistic simulated scanner, with and without the
calibration-geometry term of the step budget (simulated throughout).

The scanner of ``docs/studies/acceptance_calibration.py`` (the sample camera with 5 px of
distortion at the sensor corners and a principal point 5.8 px off centre, projector
distortion, the stage axis tilted 1 deg, the target tilted 2 deg, a printed chessboard of
``--square-mm`` squares) per seed N: a sweep of 27 positions x ``--sweep-repeats``
(noise seed = the sample's + 10 N, as ``acceptance_calibration.py --seed N``), the marker
table built from it (``scanqa calibrate``), and ``--scans`` gauge-block scans (noise seed
902 + 10 N). Every scan is annotated with the table and evaluated by ``scanqa qa``'s
:func:`~scanqa.qa.blocks.run_qa` twice: without the calibration-geometry term, and with
it (the marker fit's covariance, :func:`scanqa.calibration.uncertainty.marker_covariance`).
The simulator's blocks have exactly their nominal heights, so each step's error is its
measured minus its nominal height difference.

Printed per seed and pooled: evaluated steps within U, RMS(error / u), and the
geometry term's size; and the first scan of each seed again with the simulator's true
phase in place of the decoded one, whose step errors are the calibration's alone (set
against the table and geometry lines). Seeds are reported in the order given; say which
were held out. ``--compare-fits`` sets the marker fits of the first two seeds against
each other instead (chi-square of their difference; the steps moved from one fit's
geometry to the other's).

Usage::

    python docs/studies/acceptance_step_budget.py --seeds 0 1 2 3 4 [--out DIR]
        [--scans 2] [--sweep-repeats 1] [--square-mm 2] [--json out.json]

About 7 min a seed on 2 quiet cores (27 sweep positions with their marker frames, 2 gauge
scans); the simulations are cached in DIR (default ``acceptance_step_data``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "docs" / "studies"))

from acceptance_calibration import SWEEP_Z, scanner  # noqa: E402

from scanqa.annotation.points import annotate  # noqa: E402
from scanqa.calibration.sweep import calibrate, geometry_covariance  # noqa: E402
from scanqa.calibration.sweep_fit import geometry_from_summary  # noqa: E402
from scanqa.decoding.decoder import decode_pattern_dir  # noqa: E402
from scanqa.qa.blocks import run_qa  # noqa: E402
from scanqa.qa.layout import load_layout  # noqa: E402
from scanqa.simulator.experiments import run_experiment  # noqa: E402


def simulate(out: Path, cfg, seed: int, scans: int, sweep_repeats: int) -> dict[str, Path]:
    """Simulate (or reuse) a seed's sweep and gauge scans."""
    runs = {"sweep": ("calibration-sweep", cfg.replace_simulator(
                seed=cfg.simulator.seed + 10 * seed), SWEEP_Z, sweep_repeats),
            "gauge": ("gauge-blocks", cfg.replace_simulator(seed=902 + 10 * seed), None, scans)}
    folders = {}
    for key, (name, config, positions, repeats) in runs.items():
        folder = out / f"seed{seed}" / key
        if not (folder / "manifest.toml").is_file():
            t0 = time.time()
            run_experiment(name, config, folder, positions=positions, repeats=repeats)
            print(f"seed {seed}: simulated {key} in {time.time() - t0:.0f} s", flush=True)
        folders[key] = folder
    return folders


def steps_of(result) -> list[dict]:
    """The evaluated steps: error, u, U, the geometry line (0 when absent) [um]."""
    rows = []
    for s in result.steps:
        if not s.evaluated:
            continue
        geom = [c for c in s.budget.components if c.name == "calibration geometry"]
        rows.append({"step": f"{s.block_a}-{s.block_b}", "error_um": s.error_um,
                     "u_um": s.u_um, "U_um": s.expanded_um, "within": bool(s.within_u),
                     "geometry_um": geom[0].contribution_um if geom else 0.0})
    return rows


def calibration_only(scan, truth: Path, table, cfg, layout, term) -> list[dict]:
    """The steps of ``scan`` with its phase replaced by the simulator's true phase (same
    pixels): their errors are the calibration's alone (table and geometry), set against
    the budget's two calibration lines."""
    with np.load(truth) as t:
        xp = np.where(t["valid"] & np.isfinite(scan.xp), t["xp_true"], np.nan)
    mask = np.where(np.isfinite(xp), scan.mask, np.maximum(scan.mask, 1)).astype(scan.mask.dtype)
    cloud = annotate(dataclasses.replace(scan, xp=xp, mask=mask), table, cfg,
                     keep_invalid=True)
    rows = []
    for s in run_qa(cloud, layout, calibration=term).steps:
        if s.evaluated:
            part = {c.name: c.contribution_um for c in s.budget.components}
            rows.append({"step": f"{s.block_a}-{s.block_b}", "error_um": s.error_um,
                         "table_um": part["calibration table"],
                         "geometry_um": part["calibration geometry"]})
    return rows


def summary(rows: list[dict]) -> dict:
    z = np.array([r["error_um"] / r["u_um"] for r in rows])
    return {"within": int(sum(r["within"] for r in rows)), "n": len(rows),
            "rms_z": float(np.sqrt(np.mean(z**2))) if len(z) else math.nan,
            "geometry_um_median": float(np.median([r["geometry_um"] for r in rows]))
            if rows else math.nan}


def run_seed(out: Path, cfg, seed: int, scans: int, sweep_repeats: int) -> dict:
    folders = simulate(out, cfg, seed, scans, sweep_repeats)
    table, _ = calibrate(folders["sweep"], cfg)
    geometry = geometry_from_summary(table.provenance["target_geometry"])
    term = geometry_covariance(table)
    geo = geometry.summary()
    print(f"seed {seed}: marker fit f {geo['focal_px']:.2f} +- {geo['std']['focal_px']:.2f} px,"
          f" stage tilt {geo['stage_tilt_deg']:.4f} deg (true 1), target tilt "
          f"{geo['target_tilt_deg']:.4f} deg (true 2), principal point fitted: "
          f"{geo['principal_point_fitted']}", flush=True)
    layout = load_layout(folders["gauge"] / "layout.toml")
    without, with_term = [], []
    for folder in sorted(folders["gauge"].glob("p000_r*")):
        scan = decode_pattern_dir(folder)
        cloud = annotate(scan, table, cfg, keep_invalid=True)
        without += steps_of(run_qa(cloud, layout))
        with_term += steps_of(run_qa(cloud, layout, calibration=term))
    cal = calibration_only(scan, folders["gauge"] / "truth" / "p000.npz", table, cfg, layout,
                           term)
    return {"seed": seed, "without": without, "with": with_term, "calibration_only": cal,
            "geometry_std": geometry.summary()["std"]}


def compare_fits(out: Path, cfg, seeds: list[int]) -> dict:
    """Two independent marker fits of the same scanner: their parameter difference
    against the sum of their covariances (chi-square over the free parameters), and the
    change of the first seed's gauge steps when its points are moved to the second fit's
    geometry against sqrt(u_1^2 + u_2^2) of the geometry term."""
    from scanqa.calibration.sweep import marker_geometry
    from scanqa.calibration.uncertainty import marker_covariance, step_sigma_mm
    from scanqa.io.sweep import load_sweep
    from scanqa.qa.planes import fit_plane

    geos = [marker_geometry(load_sweep(out / f"seed{s}" / "sweep"), cfg) for s in seeds]
    diff = geos[1].parameters - geos[0].parameters
    cov = geos[0].covariance + geos[1].covariance
    free = np.diag(cov) > 0
    chi2 = float(diff[free] @ np.linalg.solve(cov[np.ix_(free, free)], diff[free]))
    print(f"fits of seeds {seeds}: chi-square {chi2:.2f} over {int(free.sum())} free "
          "parameters", flush=True)
    table, _ = calibrate(out / f"seed{seeds[0]}" / "sweep", cfg)
    gauge = out / f"seed{seeds[0]}" / "gauge"
    cloud = annotate(decode_pattern_dir(gauge / "p000_r0"), table, cfg, keep_invalid=True)
    result = run_qa(cloud, load_layout(gauge / "layout.toml"))
    xyz, blocks = np.asarray(cloud.xyz, float), {b.block_id: b for b in result.blocks}
    terms = [marker_covariance(g) for g in geos]
    rows = []
    for s in (s for s in result.steps if s.evaluated):
        a, b = xyz[blocks[s.block_a].index], xyz[blocks[s.block_b].index]
        moved = [terms[0].move(p, geos[1].parameters) for p in (a, b)]
        fit = fit_plane(moved[0])
        change = fit.normal @ (fit.centroid - moved[1].mean(0)) - s.measured_diff_mm
        u = math.hypot(*(step_sigma_mm(t, a, b) for t in terms))
        rows.append({"step": f"{s.block_a}-{s.block_b}", "change_um": 1e3 * change,
                     "u_um": 1e3 * u})
        print(f"  step {rows[-1]['step']}: moved by {1e3 * change:+.4f} um, "
              f"sqrt(u_1^2 + u_2^2) {1e3 * u:.4f} um", flush=True)
    return {"chi2": chi2, "free": int(free.sum()), "steps": rows}


def show(label: str, part: dict) -> None:
    print(f"{label}: {part['within']} of {part['n']} within U, RMS(error/u) "
          f"{part['rms_z']:.3f}; geometry term median {part['geometry_um_median']:.3f} um",
          flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", required=True)
    p.add_argument("--out", type=Path, default=Path("acceptance_step_data"))
    p.add_argument("--scans", type=int, default=2, help="gauge-block scans per seed")
    p.add_argument("--sweep-repeats", type=int, default=1)
    p.add_argument("--square-mm", type=float, default=2.0)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--compare-fits", action="store_true",
                   help="instead: the first two seeds' marker fits against each other")
    args = p.parse_args(argv)
    cfg = scanner(square_mm=args.square_mm)
    if args.compare_fits:
        compare_fits(args.out, cfg, args.seeds[:2])
        return 0
    pooled: dict = {"without": [], "with": []}
    pooled_cal: list = []
    report = {"simulated": True, "seeds": {}}
    for seed in args.seeds:
        res = run_seed(args.out, cfg, seed, args.scans, args.sweep_repeats)
        report["seeds"][seed] = res
        for key in pooled:
            pooled[key] += res[key]
            show(f"seed {seed} {key} the geometry term", summary(res[key]))
        for a, b in zip(res["without"], res["with"], strict=True):
            print(f"  step {a['step']}: error {a['error_um']:+.3f} um, u {a['u_um']:.3f} -> "
                  f"{b['u_um']:.3f} um (geometry {b['geometry_um']:.3f} um)")
        for c in res["calibration_only"]:
            print(f"  true phase, step {c['step']}: error {c['error_um']:+.3f} um; table "
                  f"{c['table_um']:.3f} um, geometry {c['geometry_um']:.3f} um")
        pooled_cal += res["calibration_only"]
    for key, rows in pooled.items():
        report[key] = summary(rows)
        show(f"POOLED seeds {args.seeds} {key} the geometry term", report[key])
    z = [c["error_um"] / math.hypot(c["table_um"], c["geometry_um"]) for c in pooled_cal]
    report["calibration_only_rms_z"] = float(np.sqrt(np.mean(np.square(z))))
    print(f"POOLED true phase: RMS(error / u_calibration) {report['calibration_only_rms_z']:.3f}"
          f" over {len(z)} steps (u_calibration = table and geometry lines in quadrature)")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
