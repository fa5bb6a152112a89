"""The whole pipeline on the committed sample data (or freshly simulated data).

Stages: characterise the scanner's noise from its camera and projector sweeps (or, for a
rigid scanner without them, from the calibration sweep itself), build the weighted
calibration table from the plane sweep, annotate the gauge-block scans (repeats give the
measured per-point std), run the gauge-block QA, and run the design tools on the same
scanner. Everything goes into one folder; :func:`run_demo` returns what a summary needs.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from scanqa import design
from scanqa.annotation import annotate
from scanqa.calibration.sweep import calibrate
from scanqa.characterization import characterize_sweeps
from scanqa.config import ScannerConfig, config_from_dict
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.errors import InputError
from scanqa.io.atomic import make_out_dir, write_text
from scanqa.io.manifest import read_manifest
from scanqa.qa.blocks import QAResult, run_qa
from scanqa.qa.layout import load_layout
from scanqa.report import calibration as calibration_report
from scanqa.report import design as design_plots
from scanqa.report import qa as qa_report
from scanqa.report.characterization import write_characterization

#: Simulation plan of ``--full``: (experiment, camera window, positions, repeats, folder).
#: About 40 min on 2 cores: 14 sweep positions and 3 gauge scans at 2448 x 2048 (~2 min
#: each), the camera and projector sweeps on the central 256 x 256 px.
FULL_PLAN = (("camera-sweep", 256, "-30:30:2", 1, "camera_sweep"),
             ("projector-sweep", 256, "-30:30:2", 1, "projector_sweep"),
             ("calibration-sweep", 0, "424:476:4", 1, "calibration_sweep"),
             ("gauge-blocks", 0, None, 3, "gauge_blocks"))
#: Folders a demo data set must hold (device sweeps, camera_sweep/ and projector_sweep/,
#: are optional: without them the calibration sweep is characterised).
DATA_FOLDERS = ("calibration_sweep", "gauge_blocks")


@dataclass
class DemoResult:
    """Paths and numbers of a demo run (``characterization`` is the summary.json)."""

    out: Path
    variant: dict
    qa: QAResult
    timings: dict = field(default_factory=dict)
    repeat_qa: list = field(default_factory=list)  # QAResult of every further scan
    characterization: dict = field(default_factory=dict)

    @property
    def report(self) -> Path:
        return self.out / "qa" / "report.html"


class _Stages:
    """Prints '[demo i/n] stage' lines with elapsed times."""

    def __init__(self, total: int, say: Callable[[str], None]) -> None:
        self.total, self.say, self.done = total, say, 0
        self.t0 = time.perf_counter()
        self.timings: dict = {}

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.done += 1
        self.say(f"[demo {self.done}/{self.total}] {name} (at {now - self.t0:.1f} s)")
        self.timings[name] = now


def _progress_line(say: Callable[[str], None], label: str) -> Callable[[int], None]:
    def report(done: int) -> None:
        if done % 5 == 0:
            say(f"  {label}: {done} scans")
    return report


def simulate_full(config: ScannerConfig, data: Path, say: Callable[[str], None]) -> Path:
    """Simulate the demo's data set with ``config`` (at its full resolution) into ``data``."""
    from scanqa.simulator.experiments import run_experiment

    for experiment, window, positions, repeats, folder in FULL_PLAN:
        cfg = config
        if window:  # the device sweeps need only the central part of the sensor
            cfg = config.replace_simulator(roi_width_px=window, roi_height_px=window)
        pos = None if positions is None else _positions(positions)
        say(f"  simulating {experiment} at {cfg.camera.width_px} x "
            f"{cfg.camera.height_px} px into {data / folder}")
        run_experiment(experiment, cfg, data / folder, positions=pos, repeats=repeats,
                       progress=True)
    return data


def _positions(text: str) -> list[float]:
    start, stop, step = (float(v) for v in text.split(":"))
    n = round((stop - start) / step) + 1
    return [start + i * step for i in range(n)]


def manifest_config(folder: Path) -> ScannerConfig:
    """The scanner config an experiment folder was simulated (or captured) with."""
    manifest = read_manifest(folder)
    if "config" not in manifest:
        raise InputError(f"{folder / 'manifest.toml'} records no config; the demo needs "
                         "the config its data were made with")
    return config_from_dict(manifest["config"], source=str(folder / "manifest.toml"))


def check_data(data: Path) -> list[Path]:
    """The sweeps to characterise: the device sweeps of a demo data set, or its
    calibration sweep when it has none; raises unless the required folders are there."""
    missing = [name for name in DATA_FOLDERS if not (data / name / "manifest.toml").exists()]
    if missing:
        raise InputError(f"demo data not found in {data}: missing {', '.join(missing)} (run "
                         "the demo from a clone of the repository, where sample_data/ holds "
                         "them, or simulate them with 'scanqa demo --full')")
    sweeps = [data / name for name in ("camera_sweep", "projector_sweep")
              if (data / name / "manifest.toml").exists()]
    return sweeps or [data / "calibration_sweep" / "sweep.toml"]


def run_demo(out: str | Path, data: str | Path = "sample_data",
             full_config: ScannerConfig | None = None,
             say: Callable[[str], None] | None = None) -> DemoResult:
    """Run every stage on a demo data set and write the outputs into ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (created).
    data : str or Path
        The data set: ``calibration_sweep/``, ``gauge_blocks/`` (with its
        ``layout.toml``) and a ``camera_sweep/`` and/or ``projector_sweep/``, each with
        the manifest that records its scanner config (``sample_data/`` of the
        repository is one).
    full_config : ScannerConfig, optional
        Simulate the data set with this config first (into ``out/data``; ``data`` is
        then ignored).
    say : callable, optional
        Receives progress lines (default: stderr).
    """
    say = say or (lambda msg: print(msg, file=sys.stderr, flush=True))
    out = make_out_dir(out)
    stage = _Stages(7 if full_config is not None else 6, say)
    if full_config is not None:
        stage("simulating the data at the config's full resolution (long)")
        data = simulate_full(full_config, out / "data", say)
    data = Path(data)
    sweeps = check_data(data)
    config = manifest_config(data / "gauge_blocks")

    names = [p.parent.name if p.name == "sweep.toml" else p.name for p in sweeps]
    stage(f"characterising the scanner from the {' and '.join(names)} "
          "(Figs. 3 and 4 procedure, model selected on held-out positions)")
    sweep_config = manifest_config(sweeps[0].parent if sweeps[0].name == "sweep.toml"
                                   else sweeps[0])
    char = characterize_sweeps(sweeps, sweep_config)
    write_characterization(char, out / "characterization", sweep_config)
    fitted = char.apply_to(config)
    char_summary = char.summary()
    variant = char_summary["best_variant"]
    for line in characterization_lines(char_summary):
        say(f"  {line}")

    stage("building the weighted calibration table")
    table, build = calibrate(data / "calibration_sweep" / "sweep.toml", fitted,
                             weights="model", progress=_progress_line(say, "calibration"))
    table.save(out / "table.npz")
    write_text(out / "table_report.html", calibration_report.render(table, build))
    write_text(out / "table_report.json",
               json.dumps(calibration_report.summary(table, build), indent=1))

    scans = sorted((data / "gauge_blocks").glob("p000_r*"),
                   key=lambda p: int(p.name.split("_r")[-1]))
    if not scans:
        raise InputError(f"no gauge-block scans in {data / 'gauge_blocks'}")
    stage(f"annotating the gauge-block scan ({len(scans)} repeats)")
    maps = [decode_pattern_dir(p) for p in scans]
    cloud = annotate(maps[0], table, fitted, maps[1:], keep_invalid=True,
                     source=str(scans[0]))
    cloud.write(out / "gauge_cloud.ply")
    say(f"  {cloud.summary()}")

    stage("gauge-block QA")
    layout = load_layout(data / "gauge_blocks" / "layout.toml")
    qa = run_qa(cloud, layout)
    qa_report.write_outputs(qa, make_out_dir(out / "qa"))

    # one scan has 6 steps: pool the steps of every repeat for the coverage of U
    repeat_qa = [run_qa(annotate(m, table, fitted, keep_invalid=True), layout)
                 for m in maps[1:]]
    write_text(out / "qa" / "steps_all_scans.csv", _steps_csv([qa, *repeat_qa], scans))

    stage("design tools on the same scanner (depth of field, W curve, volume)")
    _design(fitted, out / "design")
    stage("done")
    return DemoResult(out, variant, qa, stage.timings, repeat_qa, char_summary)


def _steps_csv(results: list[QAResult], scans: list[Path]) -> str:
    """Every scan's steps in one CSV (scan folder first)."""
    rows = [{"scan": scan.name, **s.row()}
            for res, scan in zip(results, scans, strict=False) for s in res.steps]
    return qa_report.csv_text(rows, ("scan", *qa_report.STEP_COLUMNS))


def pooled_steps(result: DemoResult) -> tuple[int, int]:
    """Evaluated steps (both blocks inside the calibrated volume and the model's validity)
    over every scan, and how many of them have |error| <= U."""
    evaluated = within = 0
    for res in (result.qa, *result.repeat_qa):
        info = res.summary()
        evaluated += info["steps_evaluated"]
        within += info["steps_error_within_U"]
    return within, evaluated


def _design(config, out: Path) -> None:
    out.mkdir(exist_ok=True)
    focus = config.camera.focus_mm
    rows = design.dof_table(config)
    write_text(out / "dof.json", json.dumps([r.as_row() for r in rows], indent=1))
    design_plots.plot_dof(rows, out / "dof.png")
    design_plots.plot_curve(design.axis_curve(config, focus - 40, focus + 40, 0.25),
                            out / "curve.png", focus)
    design_plots.plot_volume(design.usable_volume(config, 0.49, step=2.0), out / "volume.png")


def _interval(p: dict) -> str:
    """A parameter with what the data say about it."""
    if p["status"] == "fitted":
        return f"{p['value']:.4g} [{p['low']:.4g}, {p['high']:.4g}] (95 %)"
    if p["status"] == "bounded":
        return f"{p['value']:.4g}, only bounded: [{p['low']:.4g}, {p['high']:.4g}] (95 %)"
    return f"{p['value']:.4g}, not identifiable ({p['why']})"


def characterization_lines(summary: dict) -> list[str]:
    """What the characterisation found: the selected variant, each parameter with its
    interval or why it is not identifiable, the identifiable quantities, the baseline."""
    v = summary["best_variant"]
    lines = [f"selected model: filter_floor={v['filter_floor']}, filter_form="
             f"{v['filter_form']}, noise_reading={v['noise_reading']} (held-out RMS "
             f"{100 * v['cv_rms_relative']:.1f} %, a constant "
             f"{100 * summary['constant']['cv_rms_relative']:.1f} %)"]
    lines += [f"{p['name']} = {_interval(p)}" for p in v["parameters"]]
    lines += [f"identifiable: {c['name']} = {c['value']:.4g}"
              + (f" [{c['low']:.4g}, {c['high']:.4g}]" if "low" in c else "")
              for c in v["identifiable"]]
    if not summary["better_than_constant"]:
        lines.append(summary["verdict"])
    return lines


def summary_lines(result: DemoResult) -> list[str]:
    """The short summary printed at the end of the demo."""
    lines = ["block  measured  predicted  ratio  status"]
    for b in result.qa.blocks:
        lines.append(f"{b.block_id:5d}  {b.measured_std_um:6.1f} um  {b.predicted_std_um:6.1f} um"
                     f"  {b.ratio:5.2f}  {b.status}")
    lines.append("step   error      U        decision")
    for s in result.qa.steps:
        what = f"{s.decision} ({'within' if s.within_u else 'outside'} U)" if s.evaluated \
            else s.note
        lines.append(f"{s.block_a}-{s.block_b}    {s.error_um:+6.1f} um  {s.expanded_um:5.1f} um"
                     f"  {what}")
    info = result.qa.summary()
    if info["fraction_within_U"] is not None:
        lines.append(f"{info['steps_error_within_U']} of {info['steps_evaluated']} evaluated "
                     f"steps have |error| <= U ({info['steps_not_evaluated']} not evaluated: "
                     "a block outside the calibrated volume or the model's validity)")
    if not info["type_b_included"]:
        lines.append("U holds Type A terms only (noise, calibration table): Type B is not "
                     "included, no budget file was given")
    within, evaluated = pooled_steps(result)
    if evaluated:
        lines.append(f"over all {1 + len(result.repeat_qa)} scans: {within} of {evaluated} "
                     f"evaluated steps ({100 * within / evaluated:.0f} %) have |error| <= U "
                     "(qa/steps_all_scans.csv)")
    return lines
