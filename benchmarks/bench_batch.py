"""Benchmark: scanqa batch on 40 scans of the sample gauge set-up, serial vs a LocalCluster
of 2 workers, and a simulation campaign of 8 scans, serial vs 2 workers.

The batch decodes, annotates and QA-checks (with report.html) each scan against the table
built from the sample calibration sweep (built first, not timed). The 40 scans are the 3
committed gauge-block scans listed repeatedly under distinct names (a manifest; nothing
is copied). The campaign renders 8 gauge-block scans of the sample scanner (2 runs of 4
repeats). The cluster times include starting the cluster and the workers' imports (what
a user waits for); the peak memory is per worker process (``ru_maxrss``), and for the
serial run that of this process. No target: the ratio depends on the machine's cores.

Run: .venv/bin/python benchmarks/bench_batch.py [--scans 40] [--campaign-scans 8]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data"
CONFIG = f"{SAMPLE / 'sample_scanner.toml'}#sample"

from scanqa.calibration.sweep import calibrate  # noqa: E402
from scanqa.cluster import EngineOptions  # noqa: E402
from scanqa.model.config import load_config  # noqa: E402
from scanqa.runs.batch import prepare, resolve_scans, run_batch  # noqa: E402
from scanqa.runs.campaign import load_campaign, run_campaign  # noqa: E402


def _line(what: str, n: int, result, serial_s: float | None = None) -> str:
    peaks = result.report.worker_peak_mb
    s = result.report.seconds
    ratio = f", speed-up {serial_s / s:.2f}x over serial" if serial_s else ""
    failed = len(result.failed)
    load = os.getloadavg()[0]  # other jobs on the machine slow both runs
    return (f"{what}: {n} scans, {s:.1f} s, {n / s:.3f} scans/s{ratio}, "
            f"peak RSS {max(peaks.values()):.0f} MB per worker (each: "
            f"{', '.join(f'{v:.0f}' for v in peaks.values())} MB), {failed} failed, "
            f"load average {load:.1f} on {os.cpu_count()} cores")


def bench_batch(tmp: Path, n: int) -> None:
    config = load_config(CONFIG)
    table, _ = calibrate(SAMPLE / "calibration_sweep" / "sweep.toml", config)
    table.save(tmp / "table.npz")
    lines = ['format = "scanqa-batch/1"']
    for i in range(n):
        lines += ["[[scan]]", f'name = "s{i:02d}"',
                  f'path = "{SAMPLE / "gauge_blocks" / f"p000_r{i % 3}"}"']
    (tmp / "scans.toml").write_text("\n".join(lines) + "\n")
    scans = resolve_scans(str(tmp / "scans.toml"))
    layout = str(SAMPLE / "gauge_blocks" / "layout.toml")
    serial = run_batch(scans, prepare(config, CONFIG, str(tmp / "table.npz"), tmp / "serial",
                                      layout), EngineOptions(serial=True))
    print(_line("batch serial", n, serial), flush=True)
    dask = run_batch(scans, prepare(config, CONFIG, str(tmp / "table.npz"), tmp / "dask",
                                    layout), EngineOptions(workers=2, dashboard=":0"))
    print(_line("batch 2 workers", n, dask, serial.report.seconds), flush=True)


def bench_campaign(tmp: Path, n: int) -> None:
    text = 'format = "scanqa-campaign/1"\nseed = 1\n'
    for name in ("a", "b"):
        text += (f'\n[[run]]\nname = "{name}"\nexperiment = "gauge-blocks"\n'
                 f'config = "{CONFIG}"\nrepeats = {n // 2}\n')
    (tmp / "campaign.toml").write_text(text)
    serial = run_campaign(load_campaign(tmp / "campaign.toml", tmp / "c_serial"),
                          EngineOptions(serial=True))
    print(_line("campaign serial (simulated gauge scans)", n, serial), flush=True)
    dask = run_campaign(load_campaign(tmp / "campaign.toml", tmp / "c_dask"),
                        EngineOptions(workers=2, dashboard=":0"))
    print(_line("campaign 2 workers (simulated gauge scans)", n, dask,
                serial.report.seconds), flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=40, help="batch size; 0 skips the batch")
    ap.add_argument("--campaign-scans", type=int, default=8,
                    help="campaign size (even); 0 skips the campaign")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if args.scans > 0:
            bench_batch(Path(tmp), args.scans)
        if args.campaign_scans > 0:
            bench_campaign(Path(tmp), args.campaign_scans)
    print(f"bench_batch: whole script {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # the LocalCluster's worker processes import this file again
    sys.exit(main())
