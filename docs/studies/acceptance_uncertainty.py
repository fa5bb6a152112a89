"""Acceptance of the noise model and the step uncertainty on a data set (simulated).

The model is selected on the data set's camera and projector sweeps only (``scanqa
characterize`` on both: every variant, held-out positions); then, with no further
choice, it predicts the gauge-block scans:

* per block 2-8, measured / predicted std in every scan and its mean over the scans
  (a block is "systematically off" when it is outside [0.85, 1.15] in every scan);
* the steps between evaluated blocks over all scans: the fraction with |error| <= U and
  the RMS of error / u;
* block 1 (outside the calibrated volume): its step's decision.

The same is printed for the best of the paper's readings (the one the sweeps rank first
among them) for comparison, and the characterisation of the calibration sweep alone
(a rigid scanner's only sweep) is set against the dedicated sweeps' sigma_p.

Usage::

    .venv/bin/python docs/studies/acceptance_uncertainty.py DATA [--extra-scans N]

DATA holds ``camera_sweep/``, ``projector_sweep/``, ``calibration_sweep/`` and
``gauge_blocks/`` (``sample_data/``, or the folders ``scanqa demo --full`` simulates);
``--extra-scans`` renders that many more repeats of the gauge-block scan with the
gauge folder's config and seed (new noise streams) in memory.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from scanqa.annotation.points import annotate  # noqa: E402
from scanqa.calibration.sweep import calibrate  # noqa: E402
from scanqa.characterization.noisefit import select  # noqa: E402
from scanqa.characterization.sweep import characterize_sweeps  # noqa: E402
from scanqa.decoding.decoder import decode_images, decode_pattern_dir  # noqa: E402
from scanqa.qa.blocks import run_qa  # noqa: E402
from scanqa.qa.layout import load_layout  # noqa: E402
from scanqa.runs.demo import manifest_config  # noqa: E402

OFF = (0.85, 1.15)


def gauge_scans(data: Path, extra: int, config) -> list:
    """Decoded gauge-block scans: the folder's, then ``extra`` rendered ones."""
    folders = sorted((data / "gauge_blocks").glob("p000_r*"),
                     key=lambda p: int(p.name.split("_r")[-1]))
    scans = [decode_pattern_dir(p) for p in folders]
    if extra:
        from scanqa.simulator import render
        from scanqa.simulator.experiments import (
            acquisition,
            build_positions,
            pattern_description,
        )
        desc = pattern_description(config)
        pos = build_positions("gauge-blocks", config, [0.0])[0]
        for rep in range(len(scans), len(scans) + extra):
            images = render.render_images(config, acquisition(config, pos, rep), desc)
            scans.append(decode_images(desc, images))
    return scans


def qa_over_scans(scans, table, config, layout) -> dict:
    """Per-block ratios and the evaluated steps' numbers over every scan."""
    ratios = {b: [] for b in range(2, 9)}
    z, within, evaluated, step12 = [], 0, 0, []
    for scan in scans:
        res = run_qa(annotate(scan, table, config, keep_invalid=True), layout)
        for b in res.blocks:
            if b.block_id in ratios:
                ratios[b.block_id].append(b.ratio if b.status == "ok" else math.nan)
        for s in res.steps:
            if (s.block_a, s.block_b) == (1, 2):
                step12.append(s.decision)
            if s.evaluated:
                evaluated += 1
                within += s.within_u
                z.append(s.error_um / s.u_um)
    return {"ratios": ratios, "within": within, "evaluated": evaluated,
            "rms_z": float(np.sqrt(np.mean(np.square(z)))) if z else math.nan,
            "step12": step12}


def report(name: str, out: dict) -> None:
    print(f"\n{name}: measured / predicted std per block over {len(out['step12'])} scans")
    off = []
    for bid, r in out["ratios"].items():
        r = np.array(r)
        print(f"  block {bid}: mean {np.nanmean(r):.3f}, min {np.nanmin(r):.3f}, max "
              f"{np.nanmax(r):.3f}")
        if np.all((r < OFF[0]) | (r > OFF[1])):
            off.append(bid)
    worst = max(abs(np.nanmean(r) - 1) for r in out["ratios"].values())
    print(f"  largest |mean - 1| {worst:.3f}; blocks off by > 15 % in every scan: {off or 'none'}")
    frac = out["within"] / out["evaluated"] if out["evaluated"] else math.nan
    print(f"  steps: {out['within']} of {out['evaluated']} evaluated within U "
          f"({100 * frac:.1f} %), RMS(error / u) = {out['rms_z']:.3f}; step 1-2: "
          f"{sorted(set(out['step12']))}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", type=Path)
    p.add_argument("--extra-scans", type=int, default=0)
    args = p.parse_args()
    data, t0 = args.data, time.perf_counter()
    config = manifest_config(data / "gauge_blocks")
    sweep_cfg = manifest_config(data / "camera_sweep")
    char = characterize_sweeps([data / "camera_sweep", data / "projector_sweep"], sweep_cfg)
    summary = char.summary()
    print(f"selected on the camera + projector sweeps: {char.best.label}; {summary['verdict']}")
    for f in sorted(char.fits, key=lambda f: f.cv_rms_relative):
        print(f"  {f.label:24s} held-out {100 * f.cv_rms_relative:5.2f} %  " + ", ".join(
            f"{q.name} {q.value:.4g} ({q.status})" for q in f.parameters))
    paper = select(tuple(f for f in char.fits if f.noise_reading != "two_source"))
    cal = characterize_sweeps([data / "calibration_sweep" / "sweep.toml"], config)
    same = next(f for f in cal.fits if f.label == char.best.label)
    change = 100 * (same.sigma_p_px / char.best.sigma_p_px - 1)
    print(f"\ncalibration sweep alone selects {cal.best.label}: sigma_p "
          f"{cal.best.sigma_p_px:.4g} px; the same variant as the sweeps' "
          f"{same.sigma_p_px:.4g} px vs {char.best.sigma_p_px:.4g} px ({change:+.1f} %)")
    fitted = char.apply_to(config)
    table, _ = calibrate(data / "calibration_sweep" / "sweep.toml", fitted, weights="model")
    scans = gauge_scans(data, args.extra_scans, config)
    layout = load_layout(data / "gauge_blocks" / "layout.toml")
    report(f"selected model {char.best.label}", qa_over_scans(scans, table, fitted, layout))
    report(f"best paper reading {paper.label} (same table)",
           qa_over_scans(scans, table, paper.apply_to(config), layout))
    print(f"\n(simulated data; {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
