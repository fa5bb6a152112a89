"""Benchmark: building a calibration table from 41 positions at 2448 x 2048 and applying it.

Targets (issue 5): apply to a 2448 x 2048 phase map in <= 1 s; build from 41 positions in
<= 60 s with peak memory <= 4 GB. The sweep is synthesised plane by plane from the paper
scanner's pinhole geometry (generation time is not counted in the build time, but its
memory is part of the peak, which is the process's max RSS).

Run: .venv/bin/python benchmarks/bench_calibration.py [--positions 41] [--width 2448 --height 2048]
     [--repeat 3]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.synth_sweep import plane_truth, small_camera, sweep  # noqa: E402

from scanqa.calibration.build import build_table  # noqa: E402
from scanqa.model.config import load_config  # noqa: E402


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--positions", type=int, default=41)
    ap.add_argument("--width", type=int, default=2448)
    ap.add_argument("--height", type=int, default=2048)
    ap.add_argument("--repeat", type=int, default=3, help="timed applications (best reported)")
    args = ap.parse_args()
    cfg = small_camera(load_config(ROOT / "calib" / "paper_scanner.toml"), args.width,
                       args.height)
    zs = np.linspace(430.0, 470.0, args.positions)
    gen_time = [0.0]

    def observations():
        for z in zs:
            t0 = time.perf_counter()
            obs = sweep(cfg, [z], seed=int(z * 10))[0]
            gen_time[0] += time.perf_counter() - t0
            yield obs

    t0 = time.perf_counter()
    table, _report = build_table(observations(), cfg)
    build = time.perf_counter() - t0 - gen_time[0]
    build_peak = peak_rss_gb()
    xp, q = plane_truth(cfg, 451.3)
    table.apply_image(xp)  # warm-up (packs the table once)
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        look = table.apply_image(xp)
        times.append(time.perf_counter() - t0)
    err = 1e3 * np.sqrt(np.nanmean((look.xyz[..., 2] - q[..., 2]) ** 2))
    npx = args.width * args.height
    best = min(times)
    print(f"calibration build: {args.positions} positions at {args.width}x{args.height}: "
          f"{build:.1f} s (target <= 60 s), {args.positions * npx / build / 1e6:.1f} Mpx/s, "
          f"peak RSS {build_peak:.2f} GB (target <= 4 GB)")
    print(f"calibration apply: best {best:.3f} s of {len(times)} (spread {best:.3f}-"
          f"{max(times):.3f} s) for {npx / 1e6:.1f} Mpx ({npx / best / 1e6:.1f} Mpx/s, "
          f"target <= 1 s); RMS Z error vs truth {err:.3f} um; peak RSS {peak_rss_gb():.2f} GB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
