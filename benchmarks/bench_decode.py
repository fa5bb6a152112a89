"""Benchmark: decode 3 periods x 4 steps of a 2448 x 2048 camera, scanqa vs fringes.

scanqa runs twice: with the camera's noise given (gain 4 e-/DN, read noise 8 e-, as
every scanqa version could) and with the noise estimated from the images (the default
when patterns.toml has no [sensor] gain and read noise), which adds a fixed-size
estimate of about 60k sampled pixels.

Each decoder runs in its own subprocess so that its peak memory (``ru_maxrss``) is its
own (VmHWM); the images are written once to a temporary ``.npy`` stack (uint16, 12-bit values
with Gaussian noise) and loaded by both. Reported per decoder: the best wall time of
``--repeat`` runs, the process peak RSS, and the peak above the loaded inputs. For
scanqa the numpy peak from tracemalloc is reported too. Both are JIT-warmed on a small
image first, so that no compile time (or numba's import) is counted: fringes (PyPI,
numba) runs its numba kernel on all cores; scanqa runs numpy and, with numba installed
(the ``fast`` extra), its compiled demodulation, on a thread per core.

Usage::

    .venv/bin/python benchmarks/bench_decode.py [--rows 2048 --cols 2448 --repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PERIODS = (1280.0, 80.0, 16.0)
WIDTH = 1280


def _description(noise_from_data: bool = False):
    from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel

    sets = tuple(PhaseSet(f"p{p:g}", p, 4) for p in PERIODS)
    sensor = SensorModel(bit_depth=12) if noise_from_data else \
        SensorModel(bit_depth=12, gain_e_per_dn=4.0, read_noise_e=8.0)
    return PatternDescription(WIDTH, sets, sensor=sensor)


def make_images(rows: int, cols: int, seed: int = 0) -> np.ndarray:
    """(12, rows, cols) uint16 fringe images of a tilted plane, with noise [DN]."""
    from scanqa.decoding.patternset import synthesize_images

    rng = np.random.default_rng(seed)
    xp = np.linspace(0.0, WIDTH - 1.0, cols)[None, :] + np.linspace(0, 5, rows)[:, None]
    out = np.empty((4 * len(PERIODS), rows, cols), np.uint16)
    for i, stack in enumerate(synthesize_images(_description(), xp, 1500.0, 1000.0)):
        for k, frame in enumerate(stack):
            noisy = frame + rng.normal(0.0, 3.0, frame.shape)
            out[4 * i + k] = np.clip(np.rint(noisy), 0, 4095)
    return out


def _rss_mb() -> float:
    """Current resident set size [MB] (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _maxrss_mb() -> float:
    """Peak resident set size of this process [MB].

    VmHWM from /proc, because ``ru_maxrss`` survives fork + exec and would report the
    parent's peak (the image synthesis) instead of the decoder's.
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1e3  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3  # Linux: kB


def _cpu_s() -> float:
    """CPU seconds of this process, every thread (user + system): on a machine others
    load, a fairer reading than the wall time."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _run_scanqa(images: np.ndarray, repeat: int, noise_from_data: bool = False) -> dict:
    import tracemalloc

    from scanqa.decoding.decoder import decode_images

    desc = _description(noise_from_data)
    stacks = [images[4 * i:4 * i + 4] for i in range(len(PERIODS))]
    decode_images(desc, [s[:, :16, :64] for s in stacks])  # JIT warm-up, as for fringes
    base = _rss_mb()
    times, cpu, pm = [], [], None
    for _ in range(repeat):
        pm = None  # free the previous result: the peak is that of one decode
        t0, c0 = time.perf_counter(), _cpu_s()
        pm = decode_images(desc, stacks)
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu_s() - c0)
    valid = int(pm.valid.sum())
    pm = None
    tracemalloc.start()
    decode_images(desc, stacks)
    traced = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return {"times": times, "cpu": cpu, "base_mb": base, "maxrss_mb": _maxrss_mb(),
            "tracemalloc_peak_mb": traced, "valid": valid}


def _run_fringes(images: np.ndarray, repeat: int) -> dict:
    import logging

    from fringes import Fringes

    logging.getLogger("fringes").setLevel(logging.ERROR)
    f = Fringes(X=WIDTH, Y=16, K=len(PERIODS), N=4, v=tuple(WIDTH / p for p in PERIODS),
                axes=(1,), reverse=True, p0=0.0, dtype="uint16")
    f.decode(images[:, :16, :64])  # JIT warm-up (compile or load from numba's cache)
    base = _rss_mb()
    times, cpu, dec = [], [], None
    for _ in range(repeat):
        dec = None  # free the previous result: the peak is that of one decode
        t0, c0 = time.perf_counter(), _cpu_s()
        dec = f.decode(images)
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu_s() - c0)
    valid = int(np.isfinite(dec.x).sum())
    return {"times": times, "cpu": cpu, "base_mb": base, "maxrss_mb": _maxrss_mb(),
            "valid": valid}


def _child(which: str, stack_path: str, repeat: int) -> None:
    images = np.load(stack_path)
    if which == "fringes":
        print(json.dumps(_run_fringes(images, repeat)))
    else:
        print(json.dumps(_run_scanqa(images, repeat, noise_from_data=which == "scanqa-data")))


def _spawn(which: str, stack_path: Path, repeat: int) -> dict | None:
    cmd = [sys.executable, __file__, "--child", which, "--stack", str(stack_path),
           "--repeat", str(repeat)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        print(f"{which} failed:\n{proc.stderr.strip()[-2000:]}", file=sys.stderr)
        return None
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _report(name: str, res: dict | None) -> str:
    if res is None:
        return f"{name:12s} not available"
    extra = res["maxrss_mb"] - res["base_mb"]
    line = (f"{name:12s} best {min(res['times']):6.3f} s (runs: "
            f"{', '.join(f'{t:.3f}' for t in res['times'])}), peak RSS "
            f"{res['maxrss_mb']:.0f} MB = inputs {res['base_mb']:.0f} MB + {extra:.0f} MB, "
            f"valid px {res['valid']}")
    if res.get("cpu"):
        line += f", CPU best {min(res['cpu']):.3f} s"
    if "tracemalloc_peak_mb" in res:
        line += f", numpy peak (tracemalloc) {res['tracemalloc_peak_mb']:.0f} MB"
    return line


def main(argv: list[str] | None = None) -> int:
    """Run both decoders on the same images and print one result line."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=2048)
    ap.add_argument("--cols", type=int, default=2448)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child", choices=("scanqa", "scanqa-data", "fringes"),
                    help=argparse.SUPPRESS)
    ap.add_argument("--stack", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(args.child, args.stack, args.repeat)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        stack = Path(tmp) / "images.npy"
        np.save(stack, make_images(args.rows, args.cols))
        results = {w: _spawn(w, stack, args.repeat)
                   for w in ("scanqa", "scanqa-data", "fringes")}
    print(f"decode {len(PERIODS)} periods x 4 steps, {args.cols} x {args.rows} px, uint16:")
    for name, res in results.items():
        print("  " + _report(name, res))
    sq, sd, fr = results["scanqa"], results["scanqa-data"], results["fringes"]
    t_sq = f"{min(sq['times']):.3f} s" if sq else "n/a"
    t_sd = f"{min(sd['times']):.3f} s" if sd else "n/a"
    t_fr = f"{min(fr['times']):.3f} s" if fr else "n/a"
    ratio = f", scanqa/fringes time {min(sq['times']) / min(fr['times']):.2f}" \
        f" (CPU {min(sq['cpu']) / min(fr['cpu']):.2f})" if sq and fr else ""
    print(f"RESULT bench_decode: scanqa {t_sq} (noise from the images {t_sd}), fringes "
          f"{t_fr}{ratio} (target < 3 s and faster than fringes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
