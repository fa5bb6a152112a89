"""Profile one simulated gauge-block scan (cProfile): where the renderer's time goes.

The scan is the one of ``bench_simulate.py`` (12 patterns, the paper scanner, the
camera binned to ``--width`` x ``--height`` with the same field of view), or, with
``--roi W H``, a centred window of the full 2448 x 2048 sensor (the 5 MP scan's optics
and blur sizes, in a fraction of its time: 1024 x 1024 is 1/5 of the pixels). The tiles
run one after another on one thread and the profiler counts CPU time (every row is CPU
seconds, unaffected by other jobs' load). Prints the functions with the largest own
time and the largest cumulative time, then the parts of the table in docs/benchmarks.rst
("Where the simulator's time goes").

Run: .venv/bin/python benchmarks/profile_simulate.py [--width 640 --height 512]
         [--roi 1024 1024] [--top 25]
(to profile another version: PYTHONPATH=OTHER/src .venv/bin/python benchmarks/...)
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_simulate import _config

from scanqa.model.config import ScannerConfig
from scanqa.simulator import render
from scanqa.simulator.experiments import run_experiment

#: Rows of the docs' table: label and the (file, function) whose cumulative time it sums.
PARTS = (
    ("render: everything per tile", (("render.py", "_render_tile"),)),
    ("geometry: camera and shadow rays, lighting", (("render.py", "_points"),)),
    ("- open3d's cast_rays", (("~", "cast_rays"),)),
    ("- the compiled loops (hits, projections, light)", (("raykernels.py", "light_hits"),
                                                          ("raykernels.py", "unshadowed"))),
    ("blur plan (split into items, kernels)", (("blur.py", "blur_plan"),)),
    ("blur of the frames (FFTs, crops, fold)", (("blur.py", "blur"),)),
    ("fringe terms (disc average, phasor)", (("render.py", "_fringe_terms"),)),
    ("scene noise (cells, hash, gather)", (("render.py", "of"), ("render.py", "__call__"),
                                           ("render.py", "add_to"))),
    ("sensor (Poisson, read noise, quantisation)", (("render.py", "_sensor"),)),
    ("truth (pixel centres) and its npz", (("experiments.py", "write_truth"),)),
    ("PNG frames", (("patternset.py", "write_pattern_set"),)),
    ("numba: loading (or compiling) the compiled loops", (("dispatcher.py",
                                                          "_compile_for_args"),)),
)


class _Serial:
    """A stand-in for ThreadPoolExecutor that runs the tiles in order on this thread."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def __enter__(self) -> _Serial:
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def map(self, fn, items):
        return [fn(x) for x in items]

    def submit(self, fn, *args):
        from concurrent.futures import Future

        fut = Future()
        fut.set_result(fn(*args))
        return fut

    def shutdown(self, wait: bool = True) -> None:
        pass


def _parts(stats: pstats.Stats) -> list[tuple[str, float]]:
    """Cumulative CPU time of each row of :data:`PARTS` [s]."""
    out = []
    for label, funcs in PARTS:
        total = 0.0
        for (path, _, name), (_, _, _, cumulative, _) in stats.stats.items():
            for where, func in funcs:
                builtin = where == "~" and path == "~" and func in name
                if builtin or (path.endswith(where) and name == func):
                    total += cumulative
        out.append((label, total))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--roi", type=int, nargs=2, metavar=("W", "H"),
                    help="a centred window of the 2448 x 2048 sensor instead")
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args()
    config = _config(*((2448, 2048) if args.roi else (args.width, args.height)))
    if args.roi:
        sim = replace(config.simulator, roi_width_px=args.roi[0], roi_height_px=args.roi[1])
        config = ScannerConfig(config.camera, config.projector, config.fringes,
                               config.model, sim, config.name, config.source, config.profile)
    import open3d  # noqa: F401  (its import is not the renderer's time)

    import scanqa.chunks
    import scanqa.decoding.patternset as patternset
    import scanqa.simulator.experiments as experiments

    for module in (render, scanqa.chunks, experiments, patternset):
        if hasattr(module, "ThreadPoolExecutor"):
            module.ThreadPoolExecutor = _Serial
    prof = cProfile.Profile(time.process_time)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        prof.runcall(run_experiment, "gauge-blocks", config, tmp, repeats=1)
        seconds = time.process_time() - t0
    what = f"window {args.roi[0]} x {args.roi[1]} of 2448 x 2048" if args.roi else \
        f"{args.width} x {args.height}"
    print(f"gauge-block scan, {what}: {seconds:.1f} s of CPU under cProfile, one thread")
    for key in ("tottime", "cumulative"):
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats(key).print_stats(args.top)
        print(buf.getvalue())
    stats = pstats.Stats(prof)
    for label, value in _parts(stats):
        print(f"{label:48s} {value:7.2f} s ({100 * value / seconds:4.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
