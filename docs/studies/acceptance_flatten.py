"""Acceptance of flattening on the gauge-block artefact (simulated; docs/flattening.rst).

The paper's f/11 scanner at full resolution (8 um pixels) with the model the simulated
sweeps select, its central 1024 x 1024 px rendered (blocks 2, 3, 6 and 7 and the base
plate, 443.7-469.1 mm), twice with independent noise. The scan is flattened to the
volume's target (the lowest valid sigma of the model's on-axis curve over 438-466 mm);
per block top and on the base, away from the edges (by the true Z, eroded 16 px): the
std from the two scans' range difference over sqrt 2, before and after, and the
predicted sigma after. Nothing here was tuned: the noise streams are this script's own.

Usage::

    .venv/bin/python docs/studies/acceptance_flatten.py [--size 1024]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "benchmarks"))  # bench_flatten


def main() -> None:
    from bench_flatten import rig

    from scanqa.annotation.flattening import flatten
    from scanqa.decoding.decoder import decode_images
    from scanqa.simulator import experiments, render, scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1024)
    args = parser.parse_args()
    cfg, cal, desc, target = rig(args.size)
    layout = scene.paper_gauge_layout()
    artefact = scene.gauge_block_artefact(layout)
    t0 = time.perf_counter()
    scans, truth = [], None
    for rep in (0, 1):
        pos = experiments.Position(0, 0.0, 0.0, 0.0, artefact)
        acq = experiments.acquisition(cfg, pos, rep, "flatten_gauge")
        scans.append(render.render_images(cfg, acq, desc))
        truth = render.truth_for(cfg, acq)
    print(f"rendered 2 scans of {args.size} x {args.size} px in {time.perf_counter() - t0:.0f} s")
    maps = [decode_images(desc, s) for s in scans]
    flats = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps, strict=True)]
    tops = {f"block {b.block_id}": layout.base_z_mm - b.height_mm for b in layout.blocks}
    tops["base"] = layout.base_z_mm
    print(f"target {target:.2f} um")
    print("surface   Z [mm]  pixels  before [um]  after [um]  after/target  predicted [um]")
    for name, z in tops.items():
        on = ndimage.binary_erosion(np.abs(truth.z - z) < 0.05, iterations=16)
        if on.sum() < 500:
            continue
        std = [_std(cal, [m.xp for m in maps], on),
               _std(cal, [f.phase_map.xp for f in flats], on)]
        pred = float(np.nanmedian(flats[0].sigma_flat_mm[on])) * 1e3
        print(f"{name:8s} {z:7.2f} {int(on.sum()):7d} {std[0]:12.2f} {std[1]:11.2f} "
              f"{std[1] / target:13.3f} {pred:15.2f}")


def _std(cal, xps, on) -> float:
    ranges = [np.linalg.norm(cal.apply_image(np.where(on, xp, np.nan)).xyz, axis=-1)
              for xp in xps]
    d = ranges[0] - ranges[1]
    return 1e3 * float(np.nanstd(d)) / math.sqrt(2)


if __name__ == "__main__":
    main()
