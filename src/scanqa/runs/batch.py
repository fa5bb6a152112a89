"""Batch annotation and gauge-block QA of many scans against one calibration.

:func:`run_batch` decodes, annotates and (with a layout) QA-checks every scan of a list,
serially or on Dask distributed (:mod:`scanqa.cluster`), and writes::

    DIR/scans/NAME/cloud.ply        the annotated cloud (without a layout)
    DIR/scans/NAME/blocks.csv ...   with a layout: the QA outputs of scanqa qa
                                    (cloud_qa.ply is the cloud plus the QA fields)
    DIR/scans/NAME/done.json        the completion marker, written last (its row)
    DIR/results.csv                 one row per scan (and results.parquet with pyarrow)

A scan is *complete* when its ``done.json`` exists and records the same settings
fingerprint (config, calibration file hash, layout, QA settings, scanqa version): a
rerun skips complete scans and takes their rows from the markers, so an interrupted
batch resumes where it stopped. Each scan's outputs are published atomically, then its
marker; a scan that fails leaves no outputs and a row with its message, and the others
go on. The outputs are the same bytes whatever the engine and the number of workers:
no run time, worker or output path is written into them (a report's date is the date of
the scan's files). docs/cluster.rst describes the whole.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import glob
import io
import json
import logging
import math
import os
import shutil
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from scanqa._version import __version__
from scanqa.annotation.points import annotate
from scanqa.calibration.base import load_calibration
from scanqa.cluster import EngineOptions, EngineReport, Task, run_tasks
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError, ScanQAError
from scanqa.io.atomic import STAGE_PREFIX, make_out_dir, staged_dir, write_text
from scanqa.io.batchfiles import ScanEntry, default_name, read_batch_manifest, unique_scans
from scanqa.io.opencv import is_opencv_file
from scanqa.model.config import ScannerConfig
from scanqa.numeric import json_ready
from scanqa.provenance import ReportHeader, build_header, content_hash, file_hash
from scanqa.qa.blocks import QAResult, run_qa
from scanqa.qa.layout import Layout, load_layout
from scanqa.report import qa as qa_report

log = logging.getLogger(__name__)

#: Per-scan outputs live in DIR/SCANS_DIR/NAME.
SCANS_DIR = "scans"
#: The completion marker of a scan, written last.
MARKER = "done.json"
MARKER_FORMAT = "scanqa-batch-done/1"
#: The first columns of the results table; per-block and per-step columns follow.
BASE_COLUMNS = ("scan", "path", "status", "error", "points", "verdict", "steps_pass",
                "steps_fail", "steps_undecided", "steps_not_evaluated")


@dataclass(frozen=True)
class BatchSettings:
    """QA and output settings of a batch (those of ``scanqa qa``)."""

    margin_mm: float = 1.0
    outlier_k: float | None = None
    tolerance_um: float | None = None  # None: the QA default, said so in its outputs
    k: float | str | None = None
    tile_mm: float = 2.0
    report: bool = True          # report.html per scan (most of the time per scan)
    keep_invalid: bool = False   # without a layout: keep points outside the volume


@dataclass(frozen=True)
class BatchContext:
    """What every scan's task needs; shipped to each worker once (:mod:`scanqa.cluster`)."""

    config: ScannerConfig
    calibrations: dict           # fringe orientation -> Calibration
    layout: Layout | None
    settings: BatchSettings
    header: ReportHeader
    fingerprint: str
    out: Path                    # absolute: workers may run elsewhere


@dataclass(frozen=True)
class ScanTask:
    """One scan: output name, the path as given (written into outputs) and as opened."""

    name: str
    source: str
    path: Path


@dataclass(frozen=True)
class BatchResult:
    """Rows in scan order, how many were skipped as complete, and what ran."""

    rows: list
    skipped: int
    report: EngineReport
    tables: list                 # written results files

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r.get("status") == "failed"]


def resolve_scans(spec: str) -> list[ScanEntry]:
    """The scans named by a manifest (``.toml``), an experiment folder (with its
    manifest.toml) or a glob of pattern folders and phase files (``.npz``).

    Raises
    ------
    InputError
        When the manifest is malformed or nothing matches.
    """
    path = Path(spec)
    if path.suffix.lower() == ".toml":
        return read_batch_manifest(path)
    if path.is_dir() and (path / "manifest.toml").is_file():
        return read_batch_manifest(path / "manifest.toml")
    matches = [Path(m) for m in sorted(glob.glob(spec))]
    scans = [m for m in matches if m.is_dir() or m.suffix.lower() == ".npz"]
    if not scans:
        what = f" ({len(matches)} other files)" if matches else ""
        raise InputError(f"no scans match {spec!r}{what}: give pattern folders or phase "
                         "files (.npz), e.g. 'scans/*', or a scanqa-batch/1 manifest (.toml)")
    return unique_scans([ScanEntry(default_name(m), m) for m in scans], spec)


def prepare(config: ScannerConfig, config_source: str, calibration: str,
            out: str | os.PathLike, layout: str | None = None,
            settings: BatchSettings | None = None,
            depth_range_mm: tuple[float, float] = (0.0, math.inf),
            calibration_term: dict | None = None) -> BatchContext:
    """Load the calibration and layout once and fix the settings' fingerprint.

    Parameters
    ----------
    config : ScannerConfig
        The scanner config.
    config_source : str
        Where it came from (FILE#PROFILE), for the reports' header.
    calibration : str
        A table (.npz) or an OpenCV calibration (loaded for both fringe orientations).
    out : str or PathLike
        The batch's output folder.
    layout : str, optional
        Gauge-block layout: with it every scan is QA-checked.
    settings : BatchSettings, optional
        QA and output settings.
    depth_range_mm : (float, float)
        Z range of an OpenCV calibration's volume [mm].
    calibration_term : dict, optional
        An OpenCV calibration's term given beside it: ``covariance`` (a covariance file)
        or ``sigma_um`` (:func:`~scanqa.calibration.base.load_calibration`).
    """
    settings = settings or BatchSettings()
    term = {k: v for k, v in (calibration_term or {}).items() if v is not None}
    first = load_calibration(calibration, config, "vertical", depth_range_mm, **term)
    cals = {"vertical": first,  # a table serves both orientations: one copy is shipped
            "horizontal": load_calibration(calibration, config, "horizontal", depth_range_mm,
                                           **term)
            if is_opencv_file(calibration) else first}
    lay = load_layout(layout) if layout else None
    header = build_header(config.to_dict(), config_source, calibration)
    fingerprint = content_hash({
        "version": __version__, "config": config.to_dict(), "calibration": header.table_hash,
        "depth_range_mm": [str(v) for v in depth_range_mm],
        "calibration_term": {k: file_hash(v) if k == "covariance" else v
                             for k, v in term.items()},
        "layout": file_hash(layout) if layout else None, "settings": asdict(settings)})
    return BatchContext(config, cals, lay, settings, header, fingerprint,
                        Path(out).absolute())


def scan_date(path: Path) -> str:
    """Date of a scan's newest file (UTC): the date batch reports show."""
    files = [p for p in path.iterdir() if p.is_file()] if path.is_dir() else [path]
    stamp = max((p.stat().st_mtime for p in files), default=path.stat().st_mtime)
    when = datetime.datetime.fromtimestamp(stamp, datetime.timezone.utc)
    return when.strftime("%Y-%m-%d %H:%M UTC") + " (date of the scan's files)"


def qa_row(result: QAResult) -> dict:
    """The verdict, per-block and per-step numbers of one scan's QA."""
    v = qa_report.step_verdict(result)
    row = {"verdict": v["verdict"], "steps_pass": v["pass"], "steps_fail": v["fail"],
           "steps_undecided": v["undecided"], "steps_not_evaluated": v["not evaluated"]}
    for b in result.blocks:
        for key in ("n_points", "measured_std_um", "predicted_std_um", "status"):
            row[f"block{b.block_id}_{key}"] = getattr(b, key)
    for s in result.steps:
        name = f"step{s.block_a}_{s.block_b}"
        row |= {f"{name}_error_um": s.error_um, f"{name}_U_um": s.expanded_um,
                f"{name}_decision": s.decision}
    return {k: json_ready(v) for k, v in row.items()}


def _outputs(ctx: BatchContext, task: ScanTask, stage: Path) -> dict:
    """Decode, annotate and QA one scan into ``stage``; its row."""
    scan = decode(task.path)
    qa = ctx.layout is not None
    # without QA the cloud is written while it is computed (annotate's file mapping: one
    # copy of the cloud, not two); annotate refuses an empty cloud before writing
    cloud = annotate(scan, ctx.calibrations[scan.orientation], ctx.config,
                     keep_invalid=qa or ctx.settings.keep_invalid, source=task.source,
                     out=None if qa else stage / "cloud.ply")
    if not cloud.counts["written"]:
        raise InputError(f"{task.source}: no point lies inside the calibrated volume")
    source = cloud.metadata.get("sigma_source", {})
    row = {"scan": task.name, "path": task.source, "status": "ok", "error": "",
           "points": int(cloud.counts["written"]), "sigma_source": source.get("kind", ""),
           "sigma_warning": source.get("warning", "")}
    if not qa:
        return row
    s = ctx.settings
    result = run_qa(cloud, ctx.layout, config=ctx.config, margin_mm=s.margin_mm,
                    outlier_k=s.outlier_k, tolerance_um=s.tolerance_um, k=s.k,
                    tile_mm=s.tile_mm)
    header = replace(ctx.header, date=scan_date(task.path), data=task.source)
    qa_report.write_outputs(result, stage, header, html=s.report)
    return row | qa_row(result)


def process_scan(ctx: BatchContext, task: ScanTask) -> dict:
    """Outputs of one scan, published atomically, then its marker; returns its row (a
    failed row with the message when the scan is bad)."""
    out = ctx.out / SCANS_DIR / task.name
    try:
        if out.exists():  # incomplete or stale: start afresh, so no old file survives
            shutil.rmtree(out)
        with staged_dir(out) as stage:
            row = _outputs(ctx, task, stage)
        write_text(out / MARKER, json.dumps({"format": MARKER_FORMAT,
                                             "fingerprint": ctx.fingerprint, "row": row},
                                            indent=1) + "\n")
    except ScanQAError as err:
        return {"scan": task.name, "path": task.source, "status": "failed",
                "error": str(err)}
    return row


def read_marker(ctx: BatchContext, task: ScanTask) -> dict | None:
    """The row of a complete scan (same fingerprint and path), else None."""
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        data = json.loads((ctx.out / SCANS_DIR / task.name / MARKER).read_text("utf-8"))
        if data["format"] == MARKER_FORMAT and data["fingerprint"] == ctx.fingerprint \
                and data["row"]["path"] == task.source:
            return data["row"]
    return None


def _remove_stale_stages(folder: Path) -> None:
    """Staging folders of tasks whose worker died (no task of this batch runs now)."""
    for stage in folder.glob(STAGE_PREFIX + "*"):
        shutil.rmtree(stage, ignore_errors=True)


def run_batch(scans: list[ScanEntry], ctx: BatchContext,
              options: EngineOptions | None = None) -> BatchResult:
    """Process every scan not yet complete and write the results table.

    Parameters
    ----------
    scans : list of ScanEntry
        From :func:`resolve_scans`.
    ctx : BatchContext
        From :func:`prepare`.
    options : EngineOptions, optional
        Serial, LocalCluster (default) or an existing scheduler.

    Returns
    -------
    BatchResult
    """
    tasks = [ScanTask(s.name, str(s.path), s.path.absolute()) for s in scans]
    folder = make_out_dir(ctx.out / SCANS_DIR)
    _remove_stale_stages(folder)
    done = {t.name: row for t in tasks if (row := read_marker(ctx, t)) is not None}
    if done:
        log.info(f"batch: {len(done)} of {len(tasks)} scans complete already: skipped")
    todo = [Task(t.name, t) for t in tasks if t.name not in done]
    rows, report = run_tasks(process_scan, ctx, todo, options or EngineOptions(), "batch")
    _remove_stale_stages(folder)
    rows |= done
    ordered = [rows[t.name] for t in tasks]
    return BatchResult(ordered, len(done), report, write_results(ordered, ctx.out))


def columns(rows: list[dict], base: tuple = BASE_COLUMNS) -> list[str]:
    """The results table's columns: ``base``, then the others as first seen."""
    cols = list(base)
    for row in rows:
        cols += [k for k in row if k not in cols]
    return cols


def _cell(value: object) -> str:
    value = json_ready(value)
    if value is None:
        return ""
    return repr(value) if isinstance(value, float) else str(value)


def results_csv(rows: list[dict], base: tuple = BASE_COLUMNS) -> str:
    """The results table as CSV text (floats in full, missing values empty)."""
    cols = columns(rows, base)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(cols)
    writer.writerows([[_cell(r.get(c)) for c in cols] for r in rows])
    return buf.getvalue()


def write_results(rows: list[dict], out: Path, base: tuple = BASE_COLUMNS) -> list[Path]:
    """results.csv and, when pyarrow is installed, results.parquet (published together);
    ``base`` are the first columns."""
    try:
        import pyarrow
    except ImportError:
        pyarrow = None
    with staged_dir(out) as stage:
        write_text(stage / "results.csv", results_csv(rows, base))
        if pyarrow is not None:
            import pandas as pd

            cols = columns(rows, base)
            frame = pd.DataFrame([{c: json_ready(r.get(c)) for c in cols} for r in rows],
                                 columns=cols)
            frame.to_parquet(stage / "results.parquet", index=False)
    return [out / "results.csv"] + ([out / "results.parquet"] if pyarrow is not None else [])
