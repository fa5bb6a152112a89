"""``scanqa demo``: the whole pipeline on the committed sample data (parsing only)."""

from __future__ import annotations

import argparse
import time

from scanqa.cli.common import emit, flags
from scanqa.model.config import load_config
from scanqa.report.characterization import characterization_lines
from scanqa.runs.demo import run_demo, summary_lines


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="characterise, calibrate, annotate and QA the sample data in one go",
        epilog="examples:\n  scanqa demo                   # sample data, ~5 s\n"
               "  scanqa demo --out /tmp/d --full   # simulate at 2448 x 2048 first "
               "(~14 min)\n\nwrites the table, the annotated PLY, the QA report and tables")
    p.add_argument("--out", default="scanqa-demo", help="output folder (default scanqa-demo)")
    p.add_argument("--data", default=None, metavar="DIR",
                   help="the data set (default: the sample data installed with scanqa)")
    p.add_argument("--full", action="store_true",
                   help="simulate the data with --full-config at its full resolution first "
                        "(chunked, bounded memory; slow)")
    p.add_argument("--full-config", default="calib/paper_scanner.toml#f11", metavar="FILE",
                   help="config of --full (default calib/paper_scanner.toml#f11, the paper's "
                        "scanner at f/11)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    full = load_config(args.full_config) if args.full else None
    with flags({"simulate them: the full demo": "simulate them with 'scanqa demo --full'"}):
        result = run_demo(args.out, data=args.data, full_config=full)
    emit("scanner characterised:")
    for line in characterization_lines(result.characterization):
        emit(f"  {line}")
    for line in summary_lines(result):
        emit(line)
    emit(f"outputs in {result.out.resolve()} (table.npz, table_report.html, gauge_cloud.ply, "
         "qa/, sphere_test/, design/, characterization/)")
    emit(f"report: {result.report.resolve()}")
    if result.artefact is not None:
        emit(f"sphere test report: {result.artefact_report.resolve()}")
    emit(f"demo finished in {time.perf_counter() - t0:.0f} s")
    return 0
