"""Profile one simulated gauge-block scan (cProfile): where the renderer's time goes.

The scan is the one of ``bench_simulate.py`` (12 patterns, the paper scanner, the
camera binned to ``--width`` x ``--height`` with the same field of view). Prints the
functions with the largest own time and the largest cumulative time; the table in
docs/benchmarks.rst ("Where the simulator's time goes") comes from it.

Run: .venv/bin/python benchmarks/profile_simulate.py [--width 640 --height 512] [--top 25]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_simulate import _config

from scanqa.simulator.experiments import run_experiment


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args()
    config = _config(args.width, args.height)
    prof = cProfile.Profile()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        prof.runcall(run_experiment, "gauge-blocks", config, tmp, repeats=1)
        seconds = time.perf_counter() - t0
    print(f"gauge-block scan {args.width} x {args.height}: {seconds:.1f} s under cProfile")
    for key in ("tottime", "cumulative"):
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats(key).print_stats(args.top)
        print(buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
