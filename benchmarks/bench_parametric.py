"""Benchmark: triangulating a 2448 x 2048 phase map through a parametric (OpenCV-style)
calibration with lens distortion (target <= 3 s here for the rays and the triangulation
together; annotate through it is reported beside).

The calibration is synthetic (tests/synth_parametric.py): the paper scanner's projector
and a 2448 x 2048 camera, both lenses with five-term Brown-Conrady distortion; the scene
is a plane at the standoff, projected through that calibration (not timed). Timed, each
in a fresh process state: the undistorted ray of every camera pixel (computed once per
calibration), the triangulation of every pixel (Newton iteration along each epipolar
line, slope by implicit differentiation), and annotate (both passes, the optics model
per point). CPU time is printed beside the wall time: on a machine shared with other
jobs the wall time overstates what 2 idle cores need.

Run: .venv/bin/python benchmarks/bench_parametric.py [--width 2448 --height 2048]
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

from tests.synth_parametric import phase_map, small_scanner  # noqa: E402

from scanqa.annotation.points import annotate  # noqa: E402
from scanqa.model.config import load_config  # noqa: E402


def timed(work):
    """(result, wall [s], CPU user + system [s]) of ``work()``."""
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    out = work()
    t1, r1 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    return out, t1 - t0, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--width", type=int, default=2448)
    ap.add_argument("--height", type=int, default=2048)
    args = ap.parse_args()
    config = load_config(ROOT / "calib" / "paper_scanner.toml")
    focal = 1300.0 * args.width / 400  # the test scanner's field of view, more pixels
    cal, cfg = small_scanner(config, args.width, args.height, focal_px=focal)
    rays, t_rays, c_rays = timed(lambda: cal.image_grid)
    z = 450.0  # the plane Z = 450 mm on every ray, and its projector coordinate
    points = np.stack([rays.x * z, rays.y * z, np.full(rays.x.shape, z)], -1)
    xp = cal.projector.project(points @ cal.rotation.T + cal.translation)[0]
    look, t_tri, c_tri = timed(lambda: cal.apply_image(xp))
    n = int(look.in_volume.sum())
    err = float(np.nanmax(np.abs(look.xyz[..., 2] - z)))
    mpx = xp.size / 1e6
    print(f"parametric rays: undistorting {args.width}x{args.height} px = {t_rays:.2f} s "
          f"(CPU {c_rays:.2f} s), {mpx / t_rays:.1f} Mpx/s")
    print(f"parametric triangulate: {mpx:.1f} Mpx, {n} points in volume = {t_tri:.2f} s "
          f"(CPU {c_tri:.2f} s), {mpx / t_tri:.1f} Mpx/s; max |Z - 450| {err:.1e} mm")
    print(f"parametric rays + triangulate: = {t_rays + t_tri:.2f} s (target <= 3 s), CPU "
          f"{c_rays + c_tri:.2f} s")
    scan = phase_map(xp, np.full(xp.shape, 0.02), 5.0, cal.projector.width_px)
    cloud, t_ann, c_ann = timed(lambda: annotate(scan, cal, cfg))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(f"parametric annotate: {cloud.counts['written']} points, {len(cloud.attributes)} "
          f"attributes = {t_ann:.2f} s, CPU {c_ann:.2f} s, "
          f"{cloud.counts['written'] / t_ann / 1e6:.1f} Mpt/s, peak RSS {peak:.2f} GB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
