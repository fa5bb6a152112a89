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
frames), its CPU seconds, and per second of the run how many of the process's threads
were busy (over half of that second on a core, from /proc): the parallel efficiency
of the run, and where it runs on one core. Meaningful on idle cores only: under other
jobs' load a runnable thread waits for a core and does not count as busy.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
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


class _Timeline:
    """Phases of one run (wall start, end, CPU of the process during it) and a sampler of
    the process's and its threads' CPU seconds (/proc/self/task, every 0.25 s)."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.phases: list[tuple[str, float, float, float]] = []
        self.samples: list[tuple[float, float, dict]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def now(self) -> float:
        return time.perf_counter() - self.t0

    def _sample(self) -> None:
        tick = os.sysconf("SC_CLK_TCK")
        while not self._stop.wait(0.25):
            tasks = {}
            for tid in os.listdir("/proc/self/task"):
                try:
                    with open(f"/proc/self/task/{tid}/stat") as f:
                        fields = f.read().rsplit(")", 1)[1].split()
                except OSError:
                    continue
                tasks[tid] = (int(fields[11]) + int(fields[12])) / tick
            self.samples.append((self.now(), time.process_time(), tasks))

    def wrap(self, module, name: str, label: str) -> None:
        """Record every call of ``module.name`` as a phase ``label``."""
        fn = getattr(module, name)

        def timed(*args, **kwargs):
            start, cpu = self.now(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.phases.append((label, start, self.now(), time.process_time() - cpu))

        setattr(module, name, timed)

    def report(self) -> None:
        self._stop.set()
        self._thread.join()
        for label in dict.fromkeys(p[0] for p in self.phases):
            runs = [p for p in self.phases if p[0] == label]
            start, end = min(p[1] for p in runs), max(p[2] for p in runs)
            cpu = sum(p[3] for p in runs) if label == "tile" else runs[0][3]
            what = f"{len(runs)} calls, CPU of the calls" if label == "tile" else \
                "CPU of the process meanwhile"
            print(f"{label:6s} {start:6.1f} -> {end:6.1f} s  wall {end - start:5.1f} s  "
                  f"{what} {cpu:5.1f} s")
        busy = []
        for (t0, _, a), (t1, _, b) in zip(self.samples[:-4:4], self.samples[4::4], strict=True):
            busy.append(sum((b[k] - a.get(k, 0.0)) / (t1 - t0) > 0.5 for k in b))
        print("threads busy, per second:", "".join(str(min(n, 9)) for n in busy))
        print("seconds with 0 / 1 / 2+ busy threads:",
              " / ".join(str(n) for n in (busy.count(0), busy.count(1),
                                           sum(n >= 2 for n in busy))))


def timeline(config: ScannerConfig) -> None:
    """Run one scan on the real pools and print its phases and busy threads."""
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
