"""The whole pipeline on the committed sample data (or freshly simulated data).

Stages: characterise the scanner from the camera sweep, build the weighted calibration
table from the plane sweep, annotate the gauge-block scan (repeats give the measured
per-point std), run the gauge-block QA, and run the design tools on the same scanner.
Everything goes into one folder; :func:`run_demo` returns what a summary needs.
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
from scanqa.calibration.build import build_table
from scanqa.calibration.sweep import iter_observations
from scanqa.calibration.table import save_table
from scanqa.characterization import (
    apply_fitted_model,
    characterize_sweeps,
    write_characterization,
)
from scanqa.config import load_config
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.errors import InputError
from scanqa.io.atomic import make_out_dir, write_text
from scanqa.io.cloud import write_cloud
from scanqa.io.sweep import load_sweep
from scanqa.qa.blocks import QAResult, load_layout, model_curve, run_qa
from scanqa.report import calibration as calibration_report
from scanqa.report import design as design_plots
from scanqa.report import qa as qa_report

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_DIR = ROOT / "sample_data"
LAYOUT = ROOT / "calib" / "gauge_blocks_paper.toml"
#: (config file, profile for full frames, profile for the camera sweep) per data set.
SAMPLE_CONFIG = (SAMPLE_DIR / "sample_scanner.toml", "sample", "sample_roi64")
FULL_CONFIG = (ROOT / "calib" / "paper_scanner.toml", "f11", "f11")
#: Simulation plan of ``--full``: (experiment, profile key, positions, repeats, folder).
#: About 40 min on 2 cores: 14 sweep positions and 3 gauge scans at 2448 x 2048 (~2 min
#: each), the camera and projector sweeps on the central 256 x 256 px.
FULL_PLAN = (("camera-sweep", 2, "-30:30:2", 1, "camera_sweep"),
             ("projector-sweep", 2, "-30:30:2", 1, "projector_sweep"),
             ("calibration-sweep", 1, "424:476:4", 1, "calibration_sweep"),
             ("gauge-blocks", 1, None, 3, "gauge_blocks"))


@dataclass
class DemoResult:
    """Paths and numbers of a demo run."""

    out: Path
    variant: dict
    qa: QAResult
    timings: dict = field(default_factory=dict)
    repeat_qa: list = field(default_factory=list)  # QAResult of every further scan

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


def _decode(path: Path):
    if not path.is_dir():
        raise InputError(f"sample scan {path} is missing: run 'sh sample_data/regenerate.sh' "
                         "or 'scanqa demo --full'")
    return decode_pattern_dir(path)


def simulate_full(data: Path, say: Callable[[str], None]) -> Path:
    """Simulate the demo's data at the paper's resolution into ``data``."""
    from scanqa.simulator.experiments import run_experiment

    cfg_path, full, roi = FULL_CONFIG
    for experiment, which, positions, repeats, folder in FULL_PLAN:
        config = load_config(cfg_path, profile=full if which == 1 else roi)
        if which == 2:  # the device sweeps need only the central part of the sensor
            config = config.replace_simulator(roi_width_px=256, roi_height_px=256)
        pos = None if positions is None else _positions(positions)
        say(f"  simulating {experiment} at {config.camera.width_px} x "
            f"{config.camera.height_px} px into {data / folder}")
        run_experiment(experiment, config, data / folder, positions=pos, repeats=repeats,
                       progress=True)
    return data


def _positions(text: str) -> list[float]:
    start, stop, step = (float(v) for v in text.split(":"))
    n = round((stop - start) / step) + 1
    return [start + i * step for i in range(n)]


def run_demo(out: str | Path, full: bool = False, say: Callable[[str], None] | None = None
             ) -> DemoResult:
    """Run every stage and write the outputs into ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (created).
    full : bool
        Simulate the data at the paper's resolution first instead of using sample_data/.
    say : callable, optional
        Receives progress lines (default: stderr).
    """
    say = say or (lambda msg: print(msg, file=sys.stderr, flush=True))
    out = make_out_dir(out)
    stage = _Stages(7 if full else 6, say)
    if full:
        stage("simulating the data at the paper's resolution (long)")
        data = simulate_full(out / "data", say)
        cfg_path, prof, prof_roi = FULL_CONFIG
    else:
        data = SAMPLE_DIR
        cfg_path, prof, prof_roi = SAMPLE_CONFIG
        if not (data / "calibration_sweep" / "sweep.toml").exists():
            raise InputError(f"sample data not found in {data}: run the demo from a clone of "
                             "the repository, or 'scanqa demo --full'")
    config = load_config(cfg_path, profile=prof)

    sweeps = [data / name for name in ("camera_sweep", "projector_sweep")
              if (data / name / "manifest.toml").exists()]
    stage(f"characterising the scanner from the {' and '.join(p.name for p in sweeps)} "
          "(Figs. 3 and 4 procedure)")
    char = characterize_sweeps(sweeps, load_config(cfg_path, profile=prof_roi))
    summary = write_characterization(char, out / "characterization",
                                     load_config(cfg_path, profile=prof_roi))
    fitted = apply_fitted_model(config, summary)
    variant = char.summary()["best_variant"]
    say(f"  supported reading: filter_floor={variant['filter_floor']}, noise_reading="
        f"{variant['noise_reading']}, sigma_p={variant['sigma_p_px']:.4g} px, gamma="
        f"{variant['gamma']:.3g} ({100 * variant['rms_relative']:.1f} % RMS)")

    stage("building the weighted calibration table")
    sweep = load_sweep(data / "calibration_sweep" / "sweep.toml")
    table, build = build_table(iter_observations(sweep), fitted, weights="model",
                               provenance=sweep.provenance(),
                               progress=_progress_line(say, "calibration"))
    save_table(out / "table.npz", table)
    write_text(out / "table_report.html", calibration_report.render(table, build))
    write_text(out / "table_report.json",
               json.dumps(calibration_report.summary(table, build), indent=1))

    stage("annotating the gauge-block scan (3 repeats)")
    scans = sorted((data / "gauge_blocks").glob("p000_r*"))
    if not scans:
        raise InputError(f"no gauge-block scans in {data / 'gauge_blocks'}")
    maps = [_decode(p) for p in scans]
    cloud = annotate(maps[0], table, fitted, maps[1:], keep_invalid=True,
                     source=str(scans[0]))
    write_cloud(out / "gauge_cloud.ply", cloud.xyz, cloud.attributes)
    say(f"  {cloud.summary()}")

    stage("gauge-block QA")
    qa = run_qa(cloud.xyz, cloud.attributes, load_layout(LAYOUT))
    qa_report.write_outputs(qa, make_out_dir(out / "qa"), cloud.xyz, model_curve(qa, fitted),
                            cloud.attributes)

    # one scan has 6 steps: pool the steps of every repeat for the coverage of U
    repeat_qa = [run_qa(c.xyz, c.attributes, load_layout(LAYOUT))
                 for c in (annotate(m, table, fitted, keep_invalid=True) for m in maps[1:])]
    write_text(out / "qa" / "steps_all_scans.csv", _steps_csv([qa, *repeat_qa], scans))

    stage("design tools on the same scanner (depth of field, W curve, volume)")
    _design(fitted, out / "design")
    stage("done")
    return DemoResult(out, variant, qa, stage.timings, repeat_qa)


def _steps_csv(results: list[QAResult], scans: list[Path]) -> str:
    """Every scan's steps in one CSV (scan folder first)."""
    rows = [{"scan": scan.name, **s.row()}
            for res, scan in zip(results, scans, strict=False) for s in res.steps]
    return qa_report.csv_text(rows, ("scan", *qa_report.STEP_COLUMNS))


def pooled_steps(result: DemoResult) -> tuple[int, int]:
    """Steps between blocks inside the calibrated volume over every scan, and how many of
    them have |error| <= U."""
    inside = within = 0
    for res in (result.qa, *result.repeat_qa):
        info = qa_report.summary(res)
        inside += info["steps_inside_volume"]
        within += info["steps_error_within_U"]
    return within, inside


def _design(config, out: Path) -> None:
    out.mkdir(exist_ok=True)
    focus = config.camera.focus_mm
    rows = design.dof_table(config)
    write_text(out / "dof.json", json.dumps([r.as_row() for r in rows], indent=1))
    design_plots.plot_dof(rows, out / "dof.png")
    design_plots.plot_curve(design.axis_curve(config, focus - 40, focus + 40, 0.25),
                            out / "curve.png", focus)
    design_plots.plot_volume(design.usable_volume(config, 0.49, step=2.0), out / "volume.png")


def summary_lines(result: DemoResult) -> list[str]:
    """The short summary printed at the end of the demo."""
    lines = ["block  measured  predicted  ratio  status"]
    for b in result.qa.blocks:
        lines.append(f"{b.block_id:5d}  {b.measured_std_um:6.1f} um  {b.predicted_std_um:6.1f} um"
                     f"  {b.ratio:5.2f}  {b.status}")
    lines.append("step   error      U (k=2)  decision")
    for s in result.qa.steps:
        lines.append(f"{s.block_a}-{s.block_b}    {s.error_um:+6.1f} um  {s.expanded_um:5.1f} um"
                     f"  {'within U' if abs(s.error_um) <= s.expanded_um else 'outside U'}, "
                     f"{s.decision}")
    info = qa_report.summary(result.qa)
    if info["fraction_within_U"] is not None:
        lines.append(f"{info['steps_error_within_U']} of {info['steps_inside_volume']} steps "
                     "between blocks inside the calibrated volume have |error| <= U")
    within, inside = pooled_steps(result)
    if inside:
        lines.append(f"over all {1 + len(result.repeat_qa)} scans: {within} of {inside} "
                     f"such steps ({100 * within / inside:.0f} %) have |error| <= U "
                     "(qa/steps_all_scans.csv)")
    return lines
