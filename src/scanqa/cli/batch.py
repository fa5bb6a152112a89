"""``scanqa batch`` and ``scanqa campaign``: many scans or simulations, serially or on Dask
distributed (parsing only; docs/cluster.rst)."""

from __future__ import annotations

import argparse

from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    calibration_term_args,
    config_from_args,
    emit,
    flags,
    number,
    warn,
)
from scanqa.errors import InputError

_FMT = argparse.RawDescriptionHelpFormatter
_BATCH_EPILOG = """examples:
  scanqa batch 'line1/*' --calibration table.npz --config scanner.toml#sample \\
      --layout gauge/layout.toml --out qa_line1
  scanqa batch scans.toml --calibration table.npz --config scanner.toml --out clouds \\
      --scheduler tcp://10.0.0.5:8786

SCANS is a scanqa-batch/1 manifest (.toml), an experiment folder with its manifest.toml,
or a glob of pattern folders and phase files (quote it). Per scan: DIR/scans/NAME/
(cloud.ply, or with --layout the QA outputs of 'scanqa qa') and done.json, its marker;
DIR/results.csv (and results.parquet with pyarrow) has one row per scan. A rerun skips
complete scans. Exit code 0 when every scan succeeded, 1 when some failed (their rows
say why), 2 on bad input."""
_CAMPAIGN_EPILOG = """examples:
  scanqa campaign study.toml --out study
  scanqa campaign study.toml --out study --workers 2

CAMPAIGN is a scanqa-campaign/1 file: a seed and [[run]] tables (name, experiment, config,
positions, repeats). Each run becomes DIR/NAME/, the folder 'scanqa simulate' writes
with the run's seed (derived from the campaign seed and the run's name); one task per
scan. DIR/results.csv lists every scan; a rerun skips finished scans."""


def _engine_arguments(p: argparse.ArgumentParser) -> None:
    group = p.add_argument_group("engine (docs/cluster.rst)")
    one = group.add_mutually_exclusive_group()
    one.add_argument("--scheduler", metavar="ADDRESS", default=None,
                     help="run on an existing Dask cluster (tcp://host:8786); workers must "
                          "see the inputs and DIR at the same paths")
    one.add_argument("--workers", type=number(int, ge=1), default=None, metavar="N",
                     help="worker processes of the local Dask cluster (default: cores)")
    one.add_argument("--serial", action="store_true",
                     help="run in this process, one scan after another (no Dask)")
    group.add_argument("--dashboard", default=":8787", metavar="ADDRESS",
                       help="local cluster's dashboard address (default :8787; :0 any "
                            "free port)")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``batch`` and ``campaign`` subcommands."""
    p = sub.add_parser("batch", formatter_class=_FMT, epilog=_BATCH_EPILOG,
                       help="decode, annotate and QA many scans (Dask distributed or serial)")
    p.add_argument("scans", metavar="SCANS", help="manifest (.toml), experiment folder or glob")
    add_calibration_argument(p)
    add_config_argument(p)
    add_model_argument(p)
    p.add_argument("--layout", default=None,
                   help="gauge-block layout TOML: QA-check every scan")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--no-report", action="store_true",
                   help="with --layout: no report.html per scan (its plots take most of "
                        "the time); the CSV and JSON outputs stay")
    p.add_argument("--keep-invalid", action="store_true",
                   help="without --layout: keep points outside the calibrated volume")
    p.add_argument("--margin", type=number(ge=0, unit="mm"), default=1.0,
                   help="edge margin of the blocks [mm] (default 1)")
    p.add_argument("--outliers", type=number(gt=0), default=None, metavar="K",
                   help="reject points beyond K robust std of the first plane fit")
    p.add_argument("--tolerance", type=number(ge=0, unit="um"), default=None,
                   help="tolerance on each height difference [um] (default 20, and the "
                        "outputs say it was the default)")
    p.add_argument("--k", type=number(gt=0), default=None,
                   help="coverage factor (default 2)")
    p.add_argument("--tile", type=number(gt=0, unit="mm"), default=2.0, metavar="MM",
                   help="tile size of the noise-correlation estimate [mm] (default 2)")
    _engine_arguments(p)
    p.set_defaults(func=run_batch)

    p = sub.add_parser("campaign", formatter_class=_FMT, epilog=_CAMPAIGN_EPILOG,
                       help="simulation campaign: many configs and positions, one task "
                            "per scan (Dask distributed or serial)")
    p.add_argument("campaign", metavar="CAMPAIGN", help="scanqa-campaign/1 file (.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--seed", type=number(int, ge=0), default=None,
                   help="override the campaign's seed")
    _engine_arguments(p)
    p.set_defaults(func=run_campaign)


def _options(args: argparse.Namespace):
    """The engine options, refused before any work when --scheduler lacks Dask."""
    from scanqa.cluster import INSTALL_HINT, EngineOptions, dask_available

    if args.scheduler and not args.serial and not dask_available():
        raise InputError(f"--scheduler needs Dask distributed ({INSTALL_HINT})")
    return EngineOptions(scheduler=args.scheduler, workers=args.workers, serial=args.serial,
                         dashboard=args.dashboard)


def _finish(result, out: str) -> int:
    for text in dict.fromkeys(r.get("sigma_warning") for r in result.rows
                              if r.get("sigma_warning")):
        warn(text)
    for row in result.failed:
        emit(f"failed: {row['scan']}: {row['error']}")
    n, failed = len(result.rows), len(result.failed)
    skipped = f" ({result.skipped} complete already)" if result.skipped else ""
    emit(f"{n} scans: {n - failed} ok{skipped}, {failed} failed; "
         f"{result.report.engine}, {result.report.seconds:.1f} s")
    emit(f"results: {', '.join(str(p) for p in result.tables)}")
    return 1 if failed else 0


def run_batch(args: argparse.Namespace) -> int:
    from scanqa.runs.batch import BatchSettings, prepare, resolve_scans
    from scanqa.runs.batch import run_batch as run

    options = _options(args)  # before any work
    if args.depth_range_mm is not None and len(args.depth_range_mm) != 2:
        raise InputError(f"--depth-range-mm takes NEAR,FAR [mm], got {args.depth_range_mm}")
    scans = resolve_scans(args.scans)
    config = config_from_args(args)
    source = args.config + (f"#{args.profile}" if args.profile else "")
    settings = BatchSettings(margin_mm=args.margin, outlier_k=args.outliers,
                             tolerance_um=args.tolerance, k=args.k, tile_mm=args.tile,
                             report=not args.no_report, keep_invalid=args.keep_invalid)
    depth = tuple(args.depth_range_mm) if args.depth_range_mm else (0.0, float("inf"))
    ctx = prepare(config, source, args.calibration, args.out, args.layout, settings, depth,
                  calibration_term_args(args))
    with flags(_SCHEDULER):
        return _finish(run(scans, ctx, options), args.out)


def run_campaign(args: argparse.Namespace) -> int:
    from scanqa.runs.campaign import load_campaign
    from scanqa.runs.campaign import run_campaign as run

    options = _options(args)  # before any work
    campaign = load_campaign(args.campaign, args.out, seed=args.seed)
    with flags(_SCHEDULER):
        return _finish(run(campaign, options), args.out)


#: The cluster's words for the scheduler address, in this command's.
_SCHEDULER = {"a scheduler address needs": "--scheduler needs",
              "give no scheduler address": "drop --scheduler"}
