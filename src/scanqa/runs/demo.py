"""The whole pipeline on the committed sample data (or freshly simulated data).

Stages: characterise the scanner's noise from its camera and projector sweeps (or, for a
rigid scanner without them, from the calibration sweep itself), build the weighted
calibration table from the plane sweep, annotate the gauge-block scans (repeats give the
measured per-point std), run the gauge-block QA, run a VDI/VDE 2634-2 sphere test (PF,
PS) on a sphere simulated on the fly with the same scanner (about 5 s), and run the
design tools on the same scanner. Everything goes into one folder; :func:`run_demo`
returns what a summary needs.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from scanqa.annotation.points import annotate
from scanqa.calibration.sweep import calibrate
from scanqa.characterization.sweep import characterize_sweeps, sweep_folder
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.design import tools
from scanqa.errors import InputError
from scanqa.io.atomic import make_out_dir, staged_dir, write_text
from scanqa.io.manifest import read_manifest
from scanqa.io.spec import read_spec
from scanqa.model.config import ScannerConfig, config_from_dict
from scanqa.numeric import parse_range
from scanqa.progress import Progress
from scanqa.provenance import build_header, certificate_text
from scanqa.qa.artefacts import ArtefactQAResult, load_artefact_layout, run_artefact_qa
from scanqa.qa.blocks import QAResult, run_qa
from scanqa.qa.layout import load_layout
from scanqa.report import artefacts as artefact_report
from scanqa.report import calibration as calibration_report
from scanqa.report import design as design_plots
from scanqa.report import qa as qa_report
from scanqa.report.characterization import characterization_lines, write_characterization

#: Simulation plan of ``--full``: (experiment, camera window, positions, repeats, folder).
#: About 14 min on 2 idle cores (docs/benchmarks.rst): 14 sweep positions and 3 gauge
#: scans at 2448 x 2048 (~1 min each), the camera and projector sweeps on the central
#: 256 x 256 px.
FULL_PLAN = (("camera-sweep", 256, "-30:30:2", 1, "camera_sweep"),
             ("projector-sweep", 256, "-30:30:2", 1, "projector_sweep"),
             ("calibration-sweep", 0, "424:476:4", 1, "calibration_sweep"),
             ("gauge-blocks", 0, None, 3, "gauge_blocks"))
#: Folders a demo data set must hold (device sweeps, camera_sweep/ and projector_sweep/,
#: are optional: without them the calibration sweep is characterised).
DATA_FOLDERS = ("calibration_sweep", "gauge_blocks")

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoResult:
    """Paths and numbers of a demo run (``characterization`` is the summary.json)."""

    out: Path
    variant: dict
    qa: QAResult
    timings: dict = field(default_factory=dict)
    repeat_qa: list = field(default_factory=list)  # QAResult of every further scan
    artefact: ArtefactQAResult | None = None  # the sphere test
    characterization: dict = field(default_factory=dict)

    @property
    def artefact_report(self) -> Path:
        return self.out / "sphere_test" / "report.html"

    @property
    def report(self) -> Path:
        return self.out / "qa" / "report.html"


class _Stages:
    """The demo's stages as one progress display (:mod:`scanqa.progress`): a bar on a
    terminal, a line 'demo: stage i/n (name)' per stage in logs; with their times."""

    def __init__(self, total: int) -> None:
        self.bar = Progress("demo", total, "stage", log)
        self.t0 = time.perf_counter()
        self.timings: dict = {}

    def __call__(self, name: str) -> None:
        self.bar.update(1, note=name)
        self.timings[name] = time.perf_counter()


def simulate_full(config: ScannerConfig, data: Path) -> Path:
    """Simulate the demo's data set with ``config`` (at its full resolution) into ``data``."""
    from scanqa.simulator.experiments import run_experiment

    for experiment, window, positions, repeats, folder in FULL_PLAN:
        cfg = config
        if window:  # the device sweeps need only the central part of the sensor
            cfg = config.replace_simulator(roi_width_px=window, roi_height_px=window)
        pos = None if positions is None else parse_range(positions)
        log.info(f"simulating {experiment} at {cfg.camera.width_px} x "
                 f"{cfg.camera.height_px} px into {folder}")
        run_experiment(experiment, cfg, data / folder, positions=pos, repeats=repeats,
                       progress=True)
    return data


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
        raise InputError(f"demo data not found in {data}: missing {', '.join(missing)} (give "
                         "the sample data, scanqa.sample_data_path(), or simulate them: the "
                         "full demo)")
    sweeps = [data / name for name in ("camera_sweep", "projector_sweep")
              if (data / name / "manifest.toml").exists()]
    return sweeps or [data / "calibration_sweep" / "sweep.toml"]


def sample_data_path() -> Path:
    """The sample data set: the simulated sweeps, gauge-block scans and their scanner
    config (``sample_scanner.toml``) that the demo and the README's examples use.

    The copy inside an installed wheel (``scanqa/sample_data``), else ``sample_data/``
    of the repository that holds this source (a clone, an editable install).

    Returns
    -------
    Path
        The folder (``calibration_sweep/``, ``gauge_blocks/`` with ``layout.toml``,
        ``camera_sweep/``, ``projector_sweep/``, ``sample_scanner.toml``).
    """
    package = Path(__file__).resolve().parents[1]
    for folder in (package / "sample_data", package.parents[1] / "sample_data"):
        if (folder / "sample_scanner.toml").is_file():
            return folder
    raise InputError(f"the sample data are not installed with scanqa ({package}): "
                     "reinstall it from a wheel or a clone of the repository")


def run_demo(out: str | Path, data: str | Path | None = None,
             full_config: ScannerConfig | None = None) -> DemoResult:
    """Run every stage on a demo data set and write the outputs into ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (created). The outputs are staged and published together at the
        end: a failed run leaves them as they were.
    data : str or Path, optional
        The data set: ``calibration_sweep/``, ``gauge_blocks/`` (with its
        ``layout.toml``) and a ``camera_sweep/`` and/or ``projector_sweep/``, each with
        the manifest that records its scanner config; default :func:`sample_data_path`.
    full_config : ScannerConfig, optional
        Simulate the data set with this config first (into ``out/data``; ``data`` is
        then ignored). Each simulated experiment is published as soon as it is complete
        (it is the demo's input: an hour of simulation is kept if a later stage fails).

    Notes
    -----
    Progress goes to the ``scanqa`` logger (:mod:`scanqa.progress`).
    """
    target = Path(out)
    stage = _Stages(8 if full_config is not None else 7)
    with stage.bar:
        if full_config is not None:
            stage("simulating the data at the config's full resolution (long)")
            data = simulate_full(full_config, target / "data")
        data = sample_data_path() if data is None else data
        with staged_dir(target) as staged:
            result = _run_stages(stage, staged, Path(data), target)
    return replace(result, out=target)


def _run_stages(stage: _Stages, out: Path, data: Path, final: Path) -> DemoResult:
    """The demo's stages after the data exist, writing into ``out`` (a staging folder
    published as ``final``: the reports name the final paths)."""
    sweeps = check_data(data)
    config = manifest_config(data / "gauge_blocks")

    names = [sweep_folder(p).name for p in sweeps]
    stage(f"characterising the scanner from the {' and '.join(names)} "
          "(Figs. 3 and 4 procedure, model selected on held-out positions)")
    sweep_config = manifest_config(sweep_folder(sweeps[0]))
    char = characterize_sweeps(sweeps, sweep_config)
    write_characterization(char, out / "characterization", sweep_config)
    fitted = char.apply_to(config)
    char_summary = char.summary()
    variant = char_summary["best_variant"]
    for line in characterization_lines(char_summary):
        log.info(f"  {line}")

    stage("building the weighted calibration table")
    table, build = calibrate(data / "calibration_sweep" / "sweep.toml", fitted,
                             weights="model")
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
    log.info(cloud.summary())

    stage("gauge-block QA")
    layout = load_layout(data / "gauge_blocks" / "layout.toml")
    qa = run_qa(cloud, layout)
    header = build_header(fitted.to_dict(), f"{data / 'gauge_blocks'} manifest, model "
                          "characterised by the demo", str(out / "table.npz"),
                          data=str(scans[0]), operator="scanqa demo",
                          notes="simulated data (the sample scanner)")
    header = replace(header, table=str(final / "table.npz"))  # hashed staged, shown final
    qa_report.write_outputs(qa, out / "qa", header)

    # one scan has 6 steps: pool the steps of every repeat for the coverage of U
    repeat_qa = [run_qa(annotate(m, table, fitted, keep_invalid=True), layout)
                 for m in maps[1:]]
    write_text(out / "qa" / "steps_all_scans.csv", _steps_csv([qa, *repeat_qa], scans))

    stage("VDI/VDE 2634-2 sphere test on a sphere simulated now (PF, PS)")
    artefact = sphere_test(config, fitted, table, out, header, final)

    stage("design tools on the same scanner (depth of field, W curve, volume)")
    _design(fitted, out / "design")
    stage("done")
    return DemoResult(out, variant, qa, stage.timings, repeat_qa, artefact, char_summary)


def sphere_test(config: ScannerConfig, fitted: ScannerConfig, table, out: Path, header,
                final: Path | None = None) -> ArtefactQAResult:
    """Simulate the test sphere with the demo's scanner, annotate it with the demo's table
    and run PF and PS against the simulated spec; report into ``out/sphere_test``."""
    from scanqa.simulator.experiments import run_experiment

    folder = out / "data" / "sphere"
    run_experiment("sphere", config, folder, repeats=1)
    scans = sorted(folder.glob("p000_r*"))
    clouds = [(p.name, annotate(decode_pattern_dir(p), table, fitted, keep_invalid=True,
                                source=str(p))) for p in scans]
    spec = read_spec(folder / "spec.toml")
    result = run_artefact_qa(clouds, load_artefact_layout(folder / "artefacts.toml"), spec)
    shown = (final or out) / "data" / "sphere" / scans[0].name
    header = replace(header, certificate=certificate_text(spec), data=str(shown))
    artefact_report.write_outputs(result, out / "sphere_test", header)
    return result


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
    make_out_dir(out)
    focus = config.camera.focus_mm
    rows = tools.dof_table(config)
    write_text(out / "dof.json", json.dumps([r.as_row() for r in rows], indent=1))
    design_plots.plot_dof(rows, out / "dof.png")
    design_plots.plot_curve(tools.axis_curve(config, focus - 40, focus + 40, 0.25),
                            out / "curve.png", focus)
    design_plots.plot_volume(tools.usable_volume(config, 0.49, step=2.0), out / "volume.png")


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
    if result.artefact is not None:
        lines.append("sphere test (VDI/VDE 2634-2, simulated sphere of 12 mm):")
        for row in result.artefact.rows():
            pred = f", predicted {row['predicted_um']:.1f} um" \
                if row["predicted_um"] == row["predicted_um"] else ""
            lines.append(f"  {row['quantity']} = {row['value_um']:+.1f} um (U "
                         f"{row['U_um']:.1f} um{pred}), MPE {row['mpe_um']:.0f} um: "
                         f"{row['decision']}")
    return lines
