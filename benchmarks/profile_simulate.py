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

``--timeline`` instead runs the scan as ``bench_simulate`` does (the real thread pools,
no profiler) and prints when each phase ran (truth, tiles, the truth's npz, the PNG
frames) with its CPU seconds (of the process, for a phase beside the tiles their CPU
too), each tile thread's busy time, and how often a tile's thread was asleep inside a
tile (state S or D in /proc every 20 ms: waiting for the GIL that the other thread holds,
or for a page; a thread that waits for a core is runnable, state R). Under other jobs'
load the wall times stretch and that share shrinks somewhat (the threads also wait for
a core), so compare two versions in neighbouring runs.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import subprocess
import sys
import tempfile
import threading
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
    ("- the box cast (boxcast, without the GIL)", (("boxcast.py", "first_triangles"),)),
    ("- the compiled loops (hits, projections, light)", (("raykernels.py", "light_hits"),
                                                          ("raykernels.py", "unshadowed"))),
    ("blur plan (split into items, kernels)", (("blur.py", "blur_plan"),)),
    ("blur of the frames (FFTs, crops, fold)", (("blur.py", "blur"),)),
    ("fringe terms (disc average, phasor)", (("render.py", "_fringe_terms"),)),
    ("scene noise (cells, hash, gather)", (("render.py", "of"), ("render.py", "__call__"),
                                           ("render.py", "add_to"))),
    ("sensor (Poisson, read noise, quantisation)", (("render.py", "_sensor"),)),
    ("truth (pixel centres) and its npz", (("experiments.py", "_truth_npz"),)),
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


#: The sampler process: every 20 ms, the state of each thread of process argv[1]
#: (R running or runnable, S sleeping, D in I/O) on one line of argv[2].
_SAMPLER = """
import os, sys, time
pid, out = sys.argv[1], open(sys.argv[2], "w")
while os.path.exists(f"/proc/{pid}"):
    states = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as f:
                states.append(tid + ":" + f.read().rsplit(")", 1)[1].split()[0])
        except OSError:
            pass
    out.write(f"{time.perf_counter()} {' '.join(states)}\\n")
    out.flush()
    time.sleep(0.02)
"""


class _Timeline:
    """Phases of one run (wall start and end, CPU seconds) and a sampler of the state of
    every thread of the process (/proc/self/task, every 20 ms)."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.phases: list[tuple[str, float, float, float, int]] = []
        self._log = tempfile.NamedTemporaryFile("w+", suffix=".states")
        # another process: a thread of this one would need the GIL to sample, and so
        # would miss the very moments when a tile's thread holds it
        self._sampler = subprocess.Popen([sys.executable, "-c", _SAMPLER, str(os.getpid()),
                                          self._log.name])

    def now(self) -> float:
        return time.perf_counter() - self.t0

    def samples(self) -> list[tuple[float, dict]]:
        """(time since the start [s], {thread id: state}) of every sample."""
        out = []
        for line in open(self._log.name):
            t, *pairs = line.split()
            out.append((float(t) - self.t0, dict((int(a), b) for a, b in
                                                 (x.split(":") for x in pairs))))
        return out

    def wrap(self, module, name: str, label: str) -> None:
        """Record every call of ``module.name`` as a phase ``label`` (CPU: of the
        calling thread for the tiles, which run two at once; else of the process)."""
        fn = getattr(module, name)
        clock = time.thread_time if label == "tile" else time.process_time

        def timed(*args, **kwargs):
            start, cpu = self.now(), clock()
            try:
                return fn(*args, **kwargs)
            finally:
                self.phases.append((label, start, self.now(), clock() - cpu,
                                    threading.get_native_id()))

        setattr(module, name, timed)

    def report(self) -> None:
        """Print the phases and how often a tile's thread slept inside its tile."""
        self._sampler.terminate()
        self._sampler.wait()
        samples = self.samples()
        for label in dict.fromkeys(p[0] for p in self.phases):
            runs = [p for p in self.phases if p[0] == label]
            start, end = min(p[1] for p in runs), max(p[2] for p in runs)
            cpu = sum(p[3] for p in runs) if label == "tile" else runs[0][3]
            print(f"{label:6s} {start:6.1f} -> {end:6.1f} s  wall {end - start:5.1f} s  "
                  f"CPU {cpu:5.1f} s ({len(runs)} calls)")
        tiles = [p for p in self.phases if p[0] == "tile"]
        for tid in dict.fromkeys(p[4] for p in tiles):  # each tile thread's busy time
            mine = [p for p in tiles if p[4] == tid]
            print(f"  tile thread {tid}: {len(mine)} tiles, {sum(p[2] - p[1] for p in mine):5.1f}"
                  f" s inside them, CPU {sum(p[3] for p in mine):5.1f} s, its last tile "
                  f"ended at {max(p[2] for p in mine):6.1f} s")
        inside = [states[p[4]] for t, states in samples for p in tiles
                  if p[1] <= t <= p[2] and p[4] in states]
        asleep = sum(state in "SD" for state in inside)
        print(f"tile threads inside a tile: {len(inside)} samples, asleep (waiting for the "
              f"GIL or a page) in {asleep} = {100 * asleep / max(len(inside), 1):.1f} %; "
              "the rest running or waiting for a core")


def timeline(config: ScannerConfig) -> None:
    """Run one scan on the real pools; print its phases and the tile threads' sleep."""
    import scanqa.simulator.experiments as experiments

    tl = _Timeline()
    for module, name, label in ((render, "truth_for", "truth"), (render, "_render_tile", "tile"),
                                (experiments, "write_npz", "npz"),
                                (experiments, "write_pattern_set", "png")):
        tl.wrap(module, name, label)
    cpu = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        start = tl.now()
        run_experiment("gauge-blocks", config, tmp, repeats=1)
        end = tl.now()
    print(f"run_experiment {start:.1f} -> {end:.1f} s: wall {end - start:.1f} s, "
          f"CPU {time.process_time() - cpu:.1f} s")
    tl.report()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--roi", type=int, nargs=2, metavar=("W", "H"),
                    help="a centred window of the 2448 x 2048 sensor instead")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--timeline", action="store_true",
                    help="phases and busy threads of a run on the real pools instead")
    args = ap.parse_args()
    config = _config(*((2448, 2048) if args.roi else (args.width, args.height)))
    if args.roi:
        sim = replace(config.simulator, roi_width_px=args.roi[0], roi_height_px=args.roi[1])
        config = ScannerConfig(config.camera, config.projector, config.fringes,
                               config.model, sim, config.name, config.source, config.profile)
    if args.timeline:
        timeline(config)
        return 0
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
