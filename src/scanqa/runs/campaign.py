"""Simulation campaigns: many scanner configs, experiments and positions, one task per scan.

A campaign file (``scanqa-campaign/1``, :mod:`scanqa.io.batchfiles`) lists runs; each run
is what one ``scanqa simulate`` call would do (an experiment, a config, positions,
repeats) and becomes the same folder, ``DIR/NAME/``. The scans of every run are
independent tasks for :mod:`scanqa.cluster` (serial, a LocalCluster or an existing
scheduler); each task renders one scan and writes its pattern folder (atomically) and,
for the first repeat of a position, that position's truth. When every scan of a run is
there, the run's own files (manifest.toml last) are written.

Determinism: a run's seed is derived from the campaign seed and the run's name only
(:func:`derive_seed`), and each scan's noise from that seed, the experiment, the
position's index and the repeat (:func:`scanqa.simulator.experiments.acquisition`). No
seed depends on the worker, the number of workers or the order in which tasks run, so a
run's folder is byte for byte what ``scanqa simulate EXPERIMENT --seed SEED`` writes.

Resuming: ``DIR/done/NAME/pNNN_rR.json`` marks a finished scan (written after its
folder, with a fingerprint of the run's plan); a rerun skips them.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from scanqa._version import __version__
from scanqa.cluster import EngineOptions, Task, run_tasks
from scanqa.decoding.coding import PatternDescription
from scanqa.errors import InputError, ScanQAError
from scanqa.io.atomic import STAGE_PREFIX, make_out_dir, staged_dir, write_text
from scanqa.io.batchfiles import CampaignRun, read_campaign
from scanqa.model.config import ScannerConfig, load_config
from scanqa.provenance import content_hash
from scanqa.runs.batch import BatchResult, write_results
from scanqa.simulator import experiments as exp

log = logging.getLogger(__name__)

#: Markers of finished scans: DIR/DONE_DIR/RUN/pNNN_rR.json.
DONE_DIR = "done"
MARKER_FORMAT = "scanqa-campaign-done/1"
#: Derived seeds lie in [0, SEED_RANGE) (the config's range of simulator.seed).
SEED_RANGE = 10**9
#: The first columns of a campaign's results table.
COLUMNS = ("scan", "run", "experiment", "position", "stage_mm", "repeat", "seed", "status",
           "error")


@dataclass(frozen=True)
class RunPlan:
    """One run, ready to render: its config carries the derived seed. The scenes are not
    part of it (Open3D's ray-casting scenes do not pickle): each process builds them
    once from the stage values (:meth:`positions`)."""

    name: str
    experiment: str
    config: ScannerConfig
    desc: PatternDescription
    stages_mm: tuple              # stage position or device offset of each position [mm]
    repeats: int
    mesh: Path | None
    fingerprint: str

    def positions(self) -> list:
        """The positions with their scenes (built once per process)."""
        if self.fingerprint not in _SCENES:
            _SCENES[self.fingerprint] = exp.build_positions(
                self.experiment, self.config, list(self.stages_mm), self.mesh)
        return _SCENES[self.fingerprint]


#: Positions with scenes per run fingerprint, in this process.
_SCENES: dict = {}


@dataclass(frozen=True)
class Campaign:
    """The runs of a campaign and its output folder; shipped to each worker once."""

    seed: int
    runs: dict                    # name -> RunPlan
    out: Path                     # absolute


@dataclass(frozen=True)
class ScanJob:
    """One scan of a campaign."""

    run: str
    index: int
    repeat: int

    @property
    def label(self) -> str:
        return f"p{self.index:03d}_r{self.repeat}"

    @property
    def key(self) -> str:
        return f"{self.run}/{self.label}"


def derive_seed(campaign_seed: int, run_name: str) -> int:
    """A run's simulator seed: the first 8 bytes of SHA-256 of "SEED/NAME" (big-endian)
    modulo 10**9 (the config's range of ``simulator.seed``).

    Parameters
    ----------
    campaign_seed : int
        The campaign's seed [-].
    run_name : str
        The run's name (its identity; the order of the runs does not matter).

    Examples
    --------
    >>> derive_seed(0, "a") == derive_seed(0, "a") != derive_seed(1, "a")
    True
    """
    digest = hashlib.sha256(f"{int(campaign_seed)}/{run_name}".encode()).digest()
    return int.from_bytes(digest[:8], "big") % SEED_RANGE


def _plan(run: CampaignRun, campaign_seed: int) -> RunPlan:
    if run.experiment not in exp.EXPERIMENTS:
        raise InputError(f"run {run.name!r}: unknown experiment {run.experiment!r} (known: "
                         f"{', '.join(exp.EXPERIMENTS)})")
    seed = derive_seed(campaign_seed, run.name)
    config = load_config(run.config).replace_simulator(seed=seed)
    positions = list(run.positions) if run.positions is not None \
        else exp.default_positions(run.experiment, config)
    repeats = run.repeats or exp.EXPERIMENTS[run.experiment]
    desc = exp.pattern_description(config, run.periods_px)
    fingerprint = content_hash({"version": __version__, "experiment": run.experiment,
                                "config": config.to_dict(), "positions": positions,
                                "repeats": repeats, "periods": run.periods_px,
                                "mesh": str(run.mesh)})
    plan = RunPlan(run.name, run.experiment, config, desc, tuple(positions), repeats, run.mesh,
                   fingerprint)
    plan.positions()  # bad positions or meshes fail here, before any task
    return plan


def load_campaign(path: str | os.PathLike, out: str | os.PathLike,
                  seed: int | None = None) -> Campaign:
    """Read a campaign file and plan its runs (configs loaded, seeds derived).

    Parameters
    ----------
    path : str or PathLike
        The ``scanqa-campaign/1`` file.
    out : str or PathLike
        The campaign's output folder.
    seed : int, optional
        Override the file's campaign seed [-].
    """
    file_seed, runs = read_campaign(path)
    seed = file_seed if seed is None else int(seed)
    return Campaign(seed, {r.name: _plan(r, seed) for r in runs}, Path(out).absolute())


def _marker(campaign: Campaign, job: ScanJob) -> Path:
    return campaign.out / DONE_DIR / job.run / f"{job.label}.json"


def _row(plan: RunPlan, job: ScanJob) -> dict:
    return {"scan": job.key, "run": plan.name, "experiment": plan.experiment,
            "position": job.index, "stage_mm": plan.stages_mm[job.index],
            "repeat": job.repeat, "seed": plan.config.simulator.seed, "status": "ok",
            "error": ""}


def simulate_scan(campaign: Campaign, job: ScanJob) -> dict:
    """Render one scan of a campaign and write its folder (and, for repeat 0, its
    position's truth), then its marker; returns its row."""
    plan = campaign.runs[job.run]
    pos, out = plan.positions()[job.index], campaign.out / plan.name
    row = _row(plan, job)
    try:
        if job.repeat == 0:
            exp.write_truth(plan.experiment, plan.config, pos, out)
        folder = out / job.label
        if folder.exists():  # an interrupted earlier run: start afresh
            shutil.rmtree(folder)
        with staged_dir(folder) as stage:
            exp.write_scan(plan.experiment, plan.config, plan.desc, pos, job.repeat, out,
                           folder=stage)
        make_out_dir(_marker(campaign, job).parent)
        write_text(_marker(campaign, job), json.dumps(
            {"format": MARKER_FORMAT, "fingerprint": plan.fingerprint, "row": row}) + "\n")
    except ScanQAError as err:
        return row | {"status": "failed", "error": str(err)}
    return row


def _done(campaign: Campaign, job: ScanJob) -> dict | None:
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        data = json.loads(_marker(campaign, job).read_text("utf-8"))
        if data["format"] == MARKER_FORMAT and \
                data["fingerprint"] == campaign.runs[job.run].fingerprint:
            return data["row"]
    return None


def _remove_stale_stages(campaign: Campaign) -> None:
    """Staging folders of tasks whose worker died (no task of this campaign runs now)."""
    for plan in campaign.runs.values():
        folder = make_out_dir(campaign.out / plan.name)
        for stage in folder.glob(STAGE_PREFIX + "*"):
            shutil.rmtree(stage, ignore_errors=True)


def jobs(campaign: Campaign) -> list[ScanJob]:
    """Every scan of the campaign, run by run, position by position."""
    return [ScanJob(p.name, i, rep) for p in campaign.runs.values()
            for i in range(len(p.stages_mm)) for rep in range(p.repeats)]


def run_campaign(campaign: Campaign, options: EngineOptions | None = None) -> BatchResult:
    """Render every scan not yet finished, finish the complete runs, write results.csv.

    Parameters
    ----------
    campaign : Campaign
        From :func:`load_campaign`.
    options : EngineOptions, optional
        Serial, LocalCluster (default) or an existing scheduler.

    Returns
    -------
    BatchResult
        One row per scan (run, position, repeat, seed, status, error).
    """
    all_jobs = jobs(campaign)
    _remove_stale_stages(campaign)
    done = {j.key: row for j in all_jobs if (row := _done(campaign, j)) is not None}
    if done:
        log.info(f"campaign: {len(done)} of {len(all_jobs)} scans finished already: skipped")
    todo = [Task(j.key, j) for j in all_jobs if j.key not in done]
    rows, report = run_tasks(simulate_scan, campaign, todo, options or EngineOptions(),
                             "campaign")
    _remove_stale_stages(campaign)
    rows |= done
    ordered = [rows[j.key] for j in all_jobs]
    for plan in campaign.runs.values():
        mine = [r for r in ordered if r.get("run") == plan.name or
                str(r["scan"]).startswith(plan.name + "/")]
        if all(r["status"] == "ok" for r in mine):
            exp.finish_experiment(plan.experiment, plan.config, plan.desc,
                                  plan.positions(), plan.repeats, campaign.out / plan.name)
        else:
            log.warning(f"campaign: run {plan.name} has failed scans: its manifest.toml is "
                        "not written (rerun to complete it)")
    tables = write_results(ordered, campaign.out, COLUMNS)
    return BatchResult(ordered, len(done), report, tables)
