"""Acceptance of flattening on a flat swept through the volume (simulated;
docs/flattening.rst, "Measured: simulated").

The paper's f/11 scanner at full resolution (8 um pixels) with the model the simulated
sweeps select, its central ``--size`` px rendered, a flat at each of nine depths over
436-463 mm, twice with independent noise (stream ``--stream``, positions ``--first`` on).
Each scan is flattened to the volume's target (the lowest valid sigma of the model's
on-axis curve over 438-466 mm). Per depth: the std from the two scans' range difference
over sqrt 2 before and after, after / target, the predicted sigma after and the filter;
the pixels the decode masked as inconsistent (their fringe order, not their fringe); and
the 95 % sampling interval of after / target, from the effective number of independent
pixels of the range difference (:func:`scanqa.annotation.filterbank.effective_pixels`: the
filter and the camera's kernel correlate neighbours, so a 96 px flat holds only about
400 independent samples), with the verdict on the +-10 % bound: "in", "chance" (outside,
but the interval reaches inside: a single stream cannot tell the miss from sampling) or
"model" (the whole interval outside).

Usage::

    .venv/bin/python docs/studies/acceptance_flatten_sweep.py [--size 96]
        [--stream flat_heldout] [--first 50] [--depths 441 447 ...]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "benchmarks"))  # bench_flatten

#: The nine depths [mm] (docs/flattening.rst).
DEPTHS_MM = (436.0, 441.0, 445.0, 447.0, 450.0, 452.0, 455.0, 458.0, 463.0)


def main() -> None:
    from bench_flatten import rig

    from scanqa.annotation.filterbank import effective_pixels, std_interval
    from scanqa.annotation.flattening import flatten
    from scanqa.decoding.decoder import decode_images
    from scanqa.decoding.phasemap import MASK_INCONSISTENT
    from scanqa.simulator import experiments, render, scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--stream", default="flat_heldout")
    parser.add_argument("--first", type=int, default=50)
    parser.add_argument("--depths", type=float, nargs="+", default=DEPTHS_MM,
                        help="flat positions [mm]")
    args = parser.parse_args()
    cfg, cal, desc, target = rig(args.size)
    print(f"simulated, stream {args.stream!r}, positions {args.first}-"
          f"{args.first + len(args.depths) - 1}, {args.size} px; target {target:.2f} um")
    print("Z [mm]  inconsistent [%]  before [um]  filter [px]  after [um]  after/target  "
          "predicted [um]  n_eff  95 % interval  +-10 %")
    for i, z in enumerate(args.depths):
        pos = experiments.Position(args.first + i, 0.0, 0.0, 0.0, scene.plane_scene(z))
        scans = [render.render_images(cfg, experiments.acquisition(cfg, pos, rep,
                                                                   args.stream), desc)
                 for rep in (0, 1)]
        maps = [decode_images(desc, s) for s in scans]
        flats = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps,
                                                                       strict=True)]
        before = _std(cal, [m.xp for m in maps])
        after = _std(cal, [f.phase_map.xp for f in flats])
        n_eff = effective_pixels(_difference(cal, [f.phase_map.xp for f in flats]))[1]
        low, high = (v / target for v in std_interval(after, n_eff))
        masked = 100 * float(np.mean([m.mask == MASK_INCONSISTENT for m in maps]))
        print(f"{z:6.1f} {masked:17.2f} {before:12.2f} "
              f"{float(np.median(flats[0].curve.filter_diameter_px)):12.1f} {after:11.2f} "
              f"{after / target:13.3f} {float(np.median(flats[0].curve.sigma_flat_um)):15.2f}"
              f" {n_eff:6.0f}  {low:.3f}-{high:.3f}  {_verdict(after / target, low, high)}")


def _verdict(ratio: float, low: float, high: float, bound: float = 0.10) -> str:
    """"in" within the bound; else "chance" if the sampling interval reaches inside it,
    "model" if the whole interval is outside."""
    if abs(ratio - 1) <= bound:
        return "in"
    return "chance" if low <= 1 + bound and high >= 1 - bound else "model"


def _difference(cal, xps) -> np.ndarray:
    """Range difference of two scans [mm], NaN where either is missing."""
    ranges = [np.linalg.norm(cal.apply_image(xp).xyz, axis=-1) for xp in xps]
    return ranges[0] - ranges[1]


def _std(cal, xps) -> float:
    """Std of one scan's range from the difference of two [um]."""
    d = _difference(cal, xps)
    return 1e3 * float(np.nanstd(d)) / math.sqrt(2)


if __name__ == "__main__":
    main()
