"""Why the flattened flat misses its target where it does, and how much of a single
stream's scatter is chance (simulated; docs/flattening.rst, "Bias and chance").

Derivation streams only (``--stream``, default "derive39b"; never the check streams of
``docs/studies/acceptance_flatten_sweep.py``). At each depth the flat is rendered
``--repeats`` times (independent noise, two scans each; positions from ``--first`` on),
every pair flattened to the volume's target as the acceptance does. Per depth and over
the repeats:

* after / target, its mean and its std over the repeats (the scatter one stream shows);
* the sampling error a single pair predicts for it, 1 / sqrt(2 n_eff), n_eff the
  effective independent pixels of the range difference after filtering
  (:func:`scanqa.annotation.filterbank.effective_pixels`): the std over the repeats checks it;
* the two factors the flattened std is the product of: the model's sigma before against
  the measured one (model / measured; above 1 the filter comes out too large and the flat
  ends below the target) and the filter's measured gain (after / before, both measured)
  against the predicted one (sigma_flat / sigma of the plan's bin); and the unfiltered
  measured std against the target (below 1: the target needs no filter there).

Usage::

    .venv/bin/python docs/studies/diagnose_flatten_bias.py [--stream derive39b] [--size 96]
        [--repeats 8] [--first 600] [--depths 445 450 463]
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

#: The acceptance's nine depths [mm].
DEPTHS_MM = (436.0, 441.0, 445.0, 447.0, 450.0, 452.0, 455.0, 458.0, 463.0)


def _pair(cfg, cal, desc, target: float, z: float, index: int, stream: str) -> dict:
    from acceptance_flatten_sweep import _std

    from scanqa.annotation.filterbank import effective_pixels
    from scanqa.annotation.flattening import flatten
    from scanqa.decoding.decoder import decode_images
    from scanqa.simulator import experiments, render, scene

    pos = experiments.Position(index, 0.0, 0.0, 0.0, scene.plane_scene(z))
    scans = [render.render_images(cfg, experiments.acquisition(cfg, pos, rep, stream), desc)
             for rep in (0, 1)]
    maps = [decode_images(desc, s) for s in scans]
    flats = [flatten(desc, s, m, cal, cfg, target) for s, m in zip(scans, maps, strict=True)]
    ranges = [np.linalg.norm(cal.apply_image(f.phase_map.xp).xyz, axis=-1) for f in flats]
    _, n_eff = effective_pixels(ranges[0] - ranges[1])
    curve = flats[0].curve
    return {"before": _std(cal, [m.xp for m in maps]),
            "after": _std(cal, [f.phase_map.xp for f in flats]), "n_eff": n_eff,
            "model": float(np.median(curve.sigma_um)),
            "model_after": float(np.median(curve.sigma_flat_um)),
            "filter": float(np.median(curve.filter_diameter_px))}


def main() -> None:
    from bench_flatten import rig

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stream", default="derive39b")
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--first", type=int, default=600)
    parser.add_argument("--depths", type=float, nargs="+", default=DEPTHS_MM)
    args = parser.parse_args()
    cfg, cal, desc, target = rig(args.size)
    print(f"simulated, stream {args.stream!r}, {args.size} px, {args.repeats} pairs per "
          f"depth from position {args.first}; target {target:.2f} um")
    print("Z [mm] filter [px]  after/target mean  std over pairs  predicted 1/sqrt(2 n_eff)"
          "  n_eff  model/measured before  gain measured/predicted  before/target")
    for i, z in enumerate(args.depths):
        rows = [_pair(cfg, cal, desc, target, z, args.first + r * len(args.depths) + i,
                      args.stream) for r in range(args.repeats)]
        after = np.array([r["after"] for r in rows]) / target
        n_eff = np.array([r["n_eff"] for r in rows])
        model = np.array([r["model"] / r["before"] for r in rows])
        gain = np.array([(r["after"] / r["before"]) / (r["model_after"] / r["model"])
                         for r in rows])
        before = np.array([r["before"] for r in rows]) / target
        se = np.std(after, ddof=1) / math.sqrt(len(rows))
        print(f"{z:6.1f} {np.median([r['filter'] for r in rows]):11.1f} "
              f"{after.mean():12.3f} +- {se:.3f} {np.std(after, ddof=1):14.3f} "
              f"{np.mean(1 / np.sqrt(2 * n_eff)):25.3f} {np.mean(n_eff):6.0f} "
              f"{model.mean():21.3f} {gain.mean():24.3f} {before.mean():14.3f}")


if __name__ == "__main__":
    main()
