"""Benchmark: one simulated gauge-block scan (12 patterns) at 640 x 512 and 2448 x 2048.

Each size runs in its own process so that the peak resident memory (ru_maxrss) is that
of one scan; ``cpu_seconds`` (user + system, every thread, imports included) is the
measure to compare on a loaded machine, where the wall time depends on the others. The
640 x 512 camera is the paper's sensor binned to the same field of view (pixel 30.6 um);
the 2448 x 2048 one is the paper's. Targets: under 15 s (issue 4); 60 s and 2.5 GB at
2448 x 2048 on 2 cores (issue 31).

    .venv/bin/python benchmarks/bench_simulate.py            # both sizes
    .venv/bin/python benchmarks/bench_simulate.py 640        # one size
    # side by side with an older version (its src from a git worktree), alternated; the
    # line of each pair says whether the two wrote the same images and truth:
    .venv/bin/python benchmarks/bench_simulate.py 2448 --old /tmp/old/src --pairs 1
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIZES = {"640": (640, 512), "2448": (2448, 2048)}
#: Issue 4: the small scan must be fast; issue 31: the full-size one <= 60 s, <= 2.5 GB.
TARGETS = {"640": "target < 15 s", "2448": "target <= 60 s, <= 2.5 GB"}


def _config(width: int, height: int):
    from scanqa.model.config import CameraConfig, ScannerConfig, load_config

    base = load_config(ROOT / "calib" / "paper_scanner.toml")
    scale = base.camera.width_px / width
    cam = CameraConfig(**{**asdict(base.camera), "width_px": width, "height_px": height,
                          "pixel_um": base.camera.pixel_um * scale})
    return ScannerConfig(cam, base.projector, base.fringes, base.model, base.simulator,
                         base.name, base.source, base.profile)


def run_one(key: str) -> dict:
    """Simulate and write one gauge-block scan; return time and peak memory."""
    from scanqa.simulator.experiments import run_experiment

    config = _config(*SIZES[key])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_experiment("gauge-blocks", config, tmp, repeats=1)
        seconds = time.perf_counter() - t0
        usage = resource.getrusage(resource.RUSAGE_SELF)
        digest = _digest(Path(tmp))
    return {"size": f"{config.camera.width_px} x {config.camera.height_px}",
            "pixel_um": config.camera.pixel_um, "patterns": 12,
            "seconds": round(seconds, 2), "cpu_seconds": round(usage.ru_utime
                                                               + usage.ru_stime, 1),
            "peak_rss_mb": round(usage.ru_maxrss / 1024.0, 1), "target": TARGETS[key],
            "digest": digest}


def _digest(folder: Path) -> str:
    """SHA-256 (first 16 hex digits) of the scan's PNG files and truth arrays: equal for
    two versions that render the same images and truth (the npz's zip headers carry a
    time, so its arrays are hashed, not its bytes)."""
    import numpy as np

    h = hashlib.sha256()
    for path in sorted(folder.rglob("*.png")):
        h.update(path.relative_to(folder).as_posix().encode() + path.read_bytes())
    for path in sorted(folder.rglob("*.npz")):
        with np.load(path) as arrays:
            for name in sorted(arrays.files):
                h.update(name.encode() + arrays[name].tobytes())
    return h.hexdigest()[:16]


def _child(key: str, src: str | None) -> dict:
    env = {**os.environ, "PYTHONPATH": src} if src else None
    out = subprocess.run([sys.executable, __file__, "--child", key], check=True,
                         capture_output=True, text=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "--child":
        print(json.dumps(run_one(argv[1])))
        return 0
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", help=f"of {list(SIZES)} (default: all)")
    ap.add_argument("--old", metavar="SRC", help="also time the scanqa of this source "
                    "folder (e.g. a git worktree's src), alternated with this tree's")
    ap.add_argument("--pairs", type=int, default=1, help="old/new pairs per size")
    args = ap.parse_args(argv)
    if set(args.sizes) - set(SIZES):
        ap.error(f"sizes must be among {list(SIZES)}, got {args.sizes}")
    for key in args.sizes or list(SIZES):
        if not args.old:
            print(json.dumps(_child(key, None)))
            continue
        for _ in range(args.pairs):
            old, new = _child(key, args.old), _child(key, str(ROOT / "src"))
            print(json.dumps({"tree": "old", **old}))
            print(json.dumps({"tree": "new", **new}))
            print(f"{key}: old/new CPU {old['cpu_seconds'] / new['cpu_seconds']:.2f}, "
                  f"wall {old['seconds'] / new['seconds']:.2f}, peak memory "
                  f"{old['peak_rss_mb']:.0f} -> {new['peak_rss_mb']:.0f} MB, files "
                  f"{'identical' if old['digest'] == new['digest'] else 'differ'}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
