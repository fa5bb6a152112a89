"""The simulated experiments of Sect. 4 and their output folders.

Each experiment is a list of acquisitions (position x repeat). Its folder holds::

    DIR/manifest.toml            experiment, seed, scanqa version, the config, positions
    DIR/layout.toml              gauge-blocks only: the artefact's layout (scanqa qa)
    DIR/p000_r0/                 images + patterns.toml of position 0, repeat 0
    DIR/truth/p000.npz           ground truth of position 0 (X, Y, Z, xp_true, ...)

docs/formats.rst, "Experiment folders", documents every key. The folder is written in a
hidden staging folder and published when complete, so an interrupted run leaves no
partial experiment.

Experiments:

* ``camera-sweep`` (Sect. 4.1): an optical flat fixed where the axes cross, facing the
  bisector of the two axes (so its fringe period seen by the camera is omega_o as in
  the model); the camera moves along its axis by ``positions`` [mm] (+ towards the flat).
* ``projector-sweep`` (Sect. 4.2): the same flat; the projector moves along its axis.
* ``calibration-sweep``: a flat perpendicular to the camera axis at world Z =
  ``positions`` [mm] (a translation stage), ``repeats`` scans per position.
* ``gauge-blocks`` (Sect. 4.3): the artefact of :func:`~scanqa.simulator.scene.paper_gauge_layout`,
  ``repeats`` scans.
* ``sphere``, ``ball-bar``, ``flat``: the VDI/VDE 2634-2 artefacts in the measuring
  volume of :func:`~scanqa.simulator.scene.measuring_volume` (docs/artefacts.rst). The
  sphere's positions are the Z of its centre on the camera axis, the ball bar's are the
  numbers 1-7 of :data:`~scanqa.simulator.scene.BALL_BAR_POSITIONS` (default all seven),
  the flat's the Z of its centre. Their folders also hold ``artefacts.toml`` (the
  layout for ``scanqa qa --layout``: approximate positions, rounded to the mm),
  ``truth.toml`` (exact centres, sizes and planes, and the meshes' departure from the
  ideal spheres) and ``spec.toml`` (the exact values as the artefacts' certificates,
  with example MPEs: not a maker's data sheet).
* ``mesh``: any STL/PLY/OBJ mesh (world frame, mm), ``repeats`` scans.
"""

from __future__ import annotations

import io
import logging
import os
import zipfile
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanqa._version import __version__
from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.patternset import write_pattern_set
from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path, make_out_dir, staged_dir, write_text
from scanqa.io.images import write_image
from scanqa.io.sweep import scanner_table, target_table
from scanqa.io.tomlfile import dumps_toml as dump_toml
from scanqa.model.config import ScannerConfig
from scanqa.numeric import inclusive_range, parse_range
from scanqa.progress import Progress
from scanqa.simulator import devices, render, scene, texture
from scanqa.simulator.render import Acquisition

#: Experiments :func:`run_experiment` knows, with their default repeats.
EXPERIMENTS = {"camera-sweep": 1, "projector-sweep": 1, "calibration-sweep": 2,
               "gauge-blocks": 3, "sphere": 1, "ball-bar": 1, "flat": 1, "mesh": 1}
#: The VDI/VDE 2634-2 artefact experiments.
ARTEFACT_EXPERIMENTS = ("sphere", "ball-bar", "flat")
#: Value of the manifest's ``format`` key.
MANIFEST_FORMAT = "scanqa-simulation/1"
#: Value of the ``format`` key of an artefact experiment's truth.toml.
ARTEFACT_TRUTH_FORMAT = "scanqa-artefact-truth/1"
#: Example MPEs of the sample scanner written into an artefact experiment's spec.toml
#: [um] (simulated values; not a maker's data sheet).
EXAMPLE_MPE_UM = {"mpe_pf_um": 60.0, "mpe_ps_um": 10.0, "mpe_sd_um": {"a": 15.0, "b": 1000.0},
                  "mpe_f_um": 60.0}

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Position:
    """One position of an experiment: stage value, device offsets and its scene."""

    index: int
    stage_mm: float
    camera_offset_mm: float
    projector_offset_mm: float
    scene: scene.Scene

    @property
    def label(self) -> str:
        """Folder label, e.g. ``p007``."""
        return f"p{self.index:03d}"


def pattern_description(config: ScannerConfig, periods: Sequence[float] | None = None
                        ) -> PatternDescription:
    """The projected sets: working period(s) plus the coarser unwrapping periods.

    Parameters
    ----------
    config : ScannerConfig
        Gives ``fringes.working_period_px``, ``simulator.unwrap_periods_px``, steps,
        the panel width and the sensor.
    periods : sequence of float, optional
        Fine periods [projector px]; default the working period.
    """
    sim = config.simulator
    fine = [config.fringes.working_period_px] if periods is None else list(periods)
    all_periods = sorted(set(map(float, [*sim.unwrap_periods_px, *fine])), reverse=True)
    sets = tuple(PhaseSet(f"p{p:g}", p, sim.steps) for p in all_periods)
    sensor = SensorModel(bit_depth=sim.bit_depth, gain_e_per_dn=sim.gain_e_per_dn,
                         read_noise_e=sim.read_noise_e,
                         saturation_dn=render.sensor_saturation_dn(config))
    return PatternDescription(config.projector.width_px, sets, sensor,
                              description="scanqa simulate")


def axes_crossing(config: ScannerConfig) -> np.ndarray:
    """Point of the camera axis closest to the projector axis (world frame) [mm]
    (:attr:`ScannerConfig.axes_crossing_mm`)."""
    return config.axes_crossing_mm


def bisector_flat(config: ScannerConfig) -> scene.Scene:
    """The optical flat of Sects. 4.1/4.2: at the axes' crossing, normal on the bisector."""
    c = axes_crossing(config)
    to_cam = -c / np.linalg.norm(c)
    to_proj = np.asarray(config.projector.position_mm) - c
    normal = to_cam + to_proj / np.linalg.norm(to_proj)
    return scene.flat_target(c, normal, (160.0, 130.0), name="optical_flat")


def default_positions(name: str, config: ScannerConfig) -> list[float]:
    """Default stage positions of an experiment [mm]."""
    focus = config.camera.focus_mm
    if name == "camera-sweep":
        return parse_range("-30:30:1")
    if name == "projector-sweep":
        return parse_range("-45:45:1.5")
    if name == "calibration-sweep":
        return [round(float(z), 9) for z in inclusive_range(focus - 30.0, focus + 30.0, 2.0)]
    if name == "ball-bar":
        return [float(i) for i in range(1, len(scene.BALL_BAR_POSITIONS) + 1)]
    if name in ("sphere", "flat"):
        return [float(focus)]
    return [0.0]


def build_positions(name: str, config: ScannerConfig, positions: Sequence[float],
                    mesh: str | os.PathLike | None = None) -> list[Position]:
    """The scenes and device offsets of each position of an experiment."""
    if name == "camera-sweep":
        flat = bisector_flat(config)
        return [Position(i, p, p, 0.0, flat) for i, p in enumerate(positions)]
    if name == "projector-sweep":
        flat = bisector_flat(config)
        return [Position(i, p, 0.0, p, flat) for i, p in enumerate(positions)]
    if name == "calibration-sweep":
        return [Position(i, p, 0.0, 0.0, texture.stage_flat(config, p))
                for i, p in enumerate(positions)]
    if name == "gauge-blocks":
        art = scene.gauge_block_artefact(scene.paper_gauge_layout(config.camera.focus_mm))
        return [Position(i, p, 0.0, 0.0, art) for i, p in enumerate(positions)]
    if name in ARTEFACT_EXPERIMENTS:
        return [Position(i, p, 0.0, 0.0, artefact_scene(name, config, p))
                for i, p in enumerate(positions)]
    if name == "mesh":
        if mesh is None:
            raise InputError("experiment 'mesh' needs a mesh file (mesh=FILE.stl)")
        obj = scene.load_mesh(mesh)
        return [Position(i, p, 0.0, 0.0, obj) for i, p in enumerate(positions)]
    raise InputError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")


def artefact_geometry(name: str, config: ScannerConfig, position: float) -> dict:
    """The exact geometry of a VDI/VDE 2634-2 artefact at one position [mm] (module notes).

    Returns a dict with ``kind`` and, for spheres and ball bars, ``diameter_mm`` and the
    centre(s); for ball bars also ``distance_mm``, ``bar_diameter_mm`` and ``label``; for
    flats ``centre_mm``, ``normal`` and ``size_mm``.
    """
    volume = scene.measuring_volume(config)
    d = scene.BALL_DIAMETER_MM
    if name == "sphere":
        return {"kind": "sphere", "diameter_mm": d, "centre_mm": [0.0, 0.0, float(position)]}
    if name == "flat":
        return {"kind": "flat", "centre_mm": [0.0, 0.0, float(position)],
                "normal": [float(v) for v in scene.tilted_normal(*scene.FLAT_TILT_DEG)],
                "size_mm": list(scene.FLAT_SIZE_MM)}
    spots = scene.ball_bar_positions(volume, scene.ball_bar_distance(volume, d))
    i = round(position)
    if not (1 <= i <= len(spots) and abs(position - i) < 1e-9):
        raise InputError(f"ball-bar positions are the numbers 1-{len(spots)} of the standard "
                         f"positions, got {position:g}")
    label, a, b = spots[i - 1]
    return {"kind": "ball_bar", "label": label, "diameter_mm": d,
            "distance_mm": float(np.linalg.norm(b - a)), "bar_diameter_mm": scene.BAR_DIAMETER_MM,
            "centre_a_mm": [float(v) for v in a], "centre_b_mm": [float(v) for v in b]}


def artefact_scene(name: str, config: ScannerConfig, position: float) -> scene.Scene:
    """The scene of a VDI/VDE 2634-2 artefact at one position (:func:`artefact_geometry`)."""
    g = artefact_geometry(name, config, position)
    if g["kind"] == "sphere":
        return scene.sphere_artefact(g["centre_mm"], g["diameter_mm"])
    if g["kind"] == "flat":
        return scene.flat_artefact(g["centre_mm"], g["normal"], tuple(g["size_mm"]))
    return scene.ball_bar_artefact(g["centre_a_mm"], g["centre_b_mm"], g["diameter_mm"],
                                   g["bar_diameter_mm"])


def acquisition(config: ScannerConfig, pos: Position, repeat: int, experiment: str = ""
                ) -> Acquisition:
    """The acquisition of one position and repeat (poses and noise stream).

    The noise stream is keyed by the experiment too, so that e.g. the first scan of a
    calibration sweep and the first gauge-block scan do not share their noise.
    """
    keys = (pos.index, repeat) if not experiment else \
        (zlib.crc32(experiment.encode()) & 0xFFFF, pos.index, repeat)
    return Acquisition(pos.scene, devices.camera_pose(pos.camera_offset_mm),
                       devices.projector_pose(config, pos.projector_offset_mm), keys)


def run_experiment(name: str, config: ScannerConfig, out_dir: str | os.PathLike,
                   positions: Sequence[float] | None = None, repeats: int | None = None,
                   periods: Sequence[float] | None = None,
                   mesh: str | os.PathLike | None = None, progress: bool = False,
                   marker_frames: int = 1) -> Path:
    """Simulate an experiment and write its folder.

    Parameters
    ----------
    name : str
        One of :data:`EXPERIMENTS`.
    config : ScannerConfig
        Scanner config (optics and ``[simulator]``).
    out_dir : str or PathLike
        Output folder (created; existing files of the same names are replaced). The
        scans are staged and published together when all are written: a failed or
        interrupted run leaves the folder as it was.
    positions : sequence of float, optional
        Stage positions or device offsets [mm]; default :func:`default_positions`.
    repeats : int, optional
        Scans per position; default per experiment (:data:`EXPERIMENTS`).
    periods : sequence of float, optional
        Fine fringe periods [projector px]; default the working period.
    mesh : path, optional
        Mesh file for the ``mesh`` experiment.
    progress : bool
        Show the progress (:mod:`scanqa.progress`: a bar on a terminal, a log line per
        scan otherwise); False shows nothing.
    marker_frames : int
        Marker frames per position of a marked target, each with its own noise (the
        sweep manifest lists them all; docs/calibration.rst, "How many marker frames").

    Returns
    -------
    Path
        The written manifest.toml.
    """
    if name not in EXPERIMENTS:
        raise InputError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")
    positions = default_positions(name, config) if positions is None else list(positions)
    repeats = EXPERIMENTS[name] if repeats is None else int(repeats)
    if not positions or repeats < 1 or marker_frames < 1:
        raise InputError("need at least one position, repeats >= 1 and marker_frames >= 1")
    desc = pattern_description(config, periods)
    pos_list = build_positions(name, config, positions, mesh)
    target = Path(out_dir)
    with staged_dir(target) as out:  # published together when every scan is written
        _simulate(name, config, out, desc, pos_list, repeats, progress, marker_frames)
    return target / "manifest.toml"


def _simulate(name: str, config: ScannerConfig, out: Path, desc: PatternDescription,
              pos_list: list[Position], repeats: int, progress: bool,
              marker_frames: int = 1) -> None:
    """Render every scan of an experiment and write its folder into ``out`` (each
    position's truth and its npz beside its tiles, on the cores the tile pool leaves idle)."""
    with Progress(f"simulate {name}", len(pos_list) * repeats, "scan", log,
                  enabled=progress) as bar, _Writer() as writer, \
            ThreadPoolExecutor(max_workers=1) as beside:
        for pos in pos_list:
            truth = beside.submit(_truth_npz, name, config, pos, out)
            for rep in range(repeats):
                try:
                    write_scan(name, config, desc, pos, rep, out,
                               lambda done, tiles: bar.update(1 / tiles), writer=writer)
                except InputError:  # the truth's message first, as when it ran first
                    truth.result()
                    raise
            truth.result()
            _write_markers(name, config, pos, out, marker_frames)
    finish_experiment(name, config, desc, pos_list, repeats, out, marker_frames)


class _Writer:
    """Writes files on one background thread while the next scan renders (the truth's
    npz and the PNG frames take ~20 s of one core at 5 MP).

    Leaving the ``with`` block waits for every write and raises the first write's error.
    """

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1)
        self._jobs: list = []

    def submit(self, fn: Callable, *args) -> None:
        """Run ``fn(*args)`` on the writer's thread."""
        self._jobs.append(self._pool.submit(fn, *args))

    def __enter__(self) -> _Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._pool.shutdown(wait=True)
        if exc_type is None:
            for job in self._jobs:
                job.result()


def write_truth(name: str, config: ScannerConfig, pos: Position, out: Path,
                writer: _Writer | None = None, marker_frames: int = 1) -> Path:
    """Render the ground truth of one position and write ``out/truth/pNNN.npz`` (and, for
    a marked target, its marker frame ``out/markers/pNNN.png``, and frames k = 1 ..
    ``marker_frames`` - 1 as ``pNNN_mK.png``, each the noise of repeat k).

    Parameters
    ----------
    name : str
        The experiment (for the message when the scene is out of view).
    config : ScannerConfig
        Scanner config.
    pos : Position
        The position.
    out : Path
        The experiment folder.
    writer : _Writer, optional
        Write the npz on this background writer (the caller waits for it).
    marker_frames : int
        Marker frames of a marked target [-].

    Raises
    ------
    InputError
        When no pixel sees the scene at this position.
    """
    path = _truth_npz(name, config, pos, out, writer)
    _write_markers(name, config, pos, out, marker_frames)
    return path


def _truth_npz(name: str, config: ScannerConfig, pos: Position, out: Path,
               writer: _Writer | None = None) -> Path:
    """Render a position's truth, check it and write its npz (see :func:`write_truth`)."""
    truth = render.truth_for(config, acquisition(config, pos, 0))
    if not truth.valid.any():
        raise InputError(f"zero valid pixels at position {pos.stage_mm:g} mm of {name}: "
                         "the scene is outside the camera or projector frustum")
    path = make_out_dir(out / "truth") / f"{pos.label}.npz"
    if writer is None:
        write_npz(path, truth.arrays())
    else:
        writer.submit(write_npz, path, truth.arrays())
    return path


def _write_markers(name: str, config: ScannerConfig, pos: Position, out: Path,
                   marker_frames: int) -> None:
    """A marked target's marker frames (see :func:`write_truth`); none for a plain one."""
    for k in range(marker_frames if pos.scene.texture is not None else 0):
        frame = render.render_marker_frame(config, acquisition(config, pos, k, name))
        write_image(make_out_dir(out / "markers") / _marker_name(pos, k), frame)


def write_scan(name: str, config: ScannerConfig, desc: PatternDescription, pos: Position,
               repeat: int, out: Path,
               on_tile: Callable[[int, int], None] | None = None,
               folder: Path | None = None, writer: _Writer | None = None) -> Path:
    """Render one scan (position ``pos``, repeat ``repeat``) and write its pattern folder
    ``out/pNNN_rR``; its noise depends only on the config's seed, the experiment, the
    position's index and the repeat (:func:`acquisition`), so scans may be rendered in
    any order and on any machine.

    Parameters
    ----------
    name : str
        The experiment.
    config : ScannerConfig
        Scanner config (its ``simulator.seed`` keys the noise).
    desc : PatternDescription
        What is projected (:func:`pattern_description`).
    pos : Position
        The position.
    repeat : int
        Repeat number [-].
    out : Path
        The experiment folder.
    on_tile : callable, optional
        ``on_tile(done, tiles)`` after every rendered tile.
    folder : Path, optional
        Write the pattern folder here instead (a staging folder that becomes
        ``out/pNNN_rR``).
    writer : _Writer, optional
        Write the images on this background writer (the caller waits for it).

    Returns
    -------
    Path
        The pattern folder.
    """
    folder = folder or out / f"{pos.label}_r{repeat}"
    images = render.render_images(config, acquisition(config, pos, repeat, name), desc,
                                  on_tile)
    if writer is None:
        write_pattern_set(folder, desc, images, "png")
    else:
        writer.submit(write_pattern_set, folder, desc, images, "png")
    return folder


def _marker_name(pos: Position, k: int) -> str:
    """File name of a position's k-th marker frame."""
    return f"{pos.label}.png" if k == 0 else f"{pos.label}_m{k}.png"


def finish_experiment(name: str, config: ScannerConfig, desc: PatternDescription,
                      pos_list: list[Position], repeats: int, out: Path,
                      marker_frames: int = 1) -> Path:
    """Write an experiment's own files once its scans are written: sweep.toml
    (calibration sweeps, listing ``marker_frames`` marker frames per position of a
    marked target, as :func:`write_truth` rendered them), layout.toml (gauge blocks),
    the artefact files and, last, manifest.toml; returns the manifest's path."""
    entries = [_entry(pos, rep, f"{pos.label}_r{rep}") for pos in pos_list
               for rep in range(repeats)]
    if name == "calibration-sweep":
        write_text(out / "sweep.toml",
                   dump_toml(_sweep(config, pos_list, entries, marker_frames)))
    if name == "gauge-blocks":  # the artefact's layout, for 'scanqa qa --layout'
        layout = scene.paper_gauge_layout(config.camera.focus_mm)
        write_text(out / "layout.toml", scene.gauge_layout_toml(layout))
    if name in ARTEFACT_EXPERIMENTS:
        _write_artefact_files(name, config, pos_list, out)
    manifest = _manifest(name, config, desc, pos_list, repeats, entries)
    return write_text(out / "manifest.toml", dump_toml(manifest))


def _write_artefact_files(name: str, config: ScannerConfig, pos_list: list[Position],
                          out: Path) -> None:
    """artefacts.toml, truth.toml and spec.toml of an artefact experiment (module notes)."""
    geoms = [(pos, artefact_geometry(name, config, pos.stage_mm)) for pos in pos_list]
    truth = []
    for pos, g in geoms:
        entry = {"scan": pos.label, **g}
        if g["kind"] != "flat":
            entry["mesh_deviation_mm"] = _mesh_deviation(pos.scene, g)
        truth.append(entry)
    write_text(out / "truth.toml", dump_toml({
        "format": ARTEFACT_TRUTH_FORMAT, "experiment": name,
        "frame": "scanner (the camera frame) [mm]", "artefact": truth}))
    write_text(out / "artefacts.toml", dump_toml(artefact_layout(name, geoms)))
    write_text(out / "spec.toml", dump_toml(example_spec(geoms[0][1])))


def _mesh_deviation(obj: scene.Scene, g: dict) -> float:
    """Largest departure of the scene's ball meshes from the ideal spheres [mm]."""
    centres = [g[k] for k in ("centre_mm", "centre_a_mm", "centre_b_mm") if k in g]
    r = g["diameter_mm"] / 2.0
    dev = 0.0
    for c in centres:
        ball = scene.sphere_mesh(c, g["diameter_mm"])
        dev = max(dev, scene.sphere_mesh_deviation(ball, c, r))
    return dev


def artefact_layout(name: str, geoms: list) -> dict:
    """The ``scanqa-artefact-layout/1`` table of an artefact experiment: one entry per
    position, approximate positions rounded to the mm."""
    def approx(v):
        return [float(round(x)) for x in v]

    kind = geoms[0][1]["kind"]
    entries = []
    for pos, g in geoms:
        e = {"id": g.get("label", f"{kind} {pos.index + 1}").replace(" ", "_"),
             "scan": pos.label}
        if kind == "sphere":
            e.update(diameter_mm=g["diameter_mm"], centre_mm=approx(g["centre_mm"]))
        elif kind == "ball_bar":
            e.update(id=f"P{pos.index + 1}", diameter_mm=g["diameter_mm"],
                     distance_mm=round(g["distance_mm"]),
                     centre_a_mm=approx(g["centre_a_mm"]), centre_b_mm=approx(g["centre_b_mm"]),
                     bar_diameter_mm=g["bar_diameter_mm"])
        else:
            e.update(centre_mm=approx(g["centre_mm"]), normal=[round(v, 2) for v in g["normal"]],
                     size_mm=g["size_mm"])
        entries.append(e)
    return {"format": "scanqa-artefact-layout/1", "name": f"simulated {name}",
            "frame": "scanner", kind: entries}


def example_spec(g: dict) -> dict:
    """A ``scanqa-spec/1`` table: the artefact's exact size as its certificate and the
    sample scanner's example MPEs (simulated; not a maker's data sheet)."""
    spec = {"format": "scanqa-spec/1",
            "name": "simulated artefacts: exact sizes as certificates, example MPEs",
            **EXAMPLE_MPE_UM}
    if g["kind"] == "sphere":
        spec["sphere"] = {"diameter_mm": g["diameter_mm"], "diameter_uncertainty_um": 0.5,
                          "k": 2.0, "form_um": 0.0}
    elif g["kind"] == "ball_bar":
        spec["ball_bar"] = {"distance_mm": round(g["distance_mm"], 6),
                            "distance_uncertainty_um": 1.0, "k": 2.0,
                            "diameter_mm": g["diameter_mm"]}
    else:
        spec["flat"] = {"flatness_um": 0.0}
    return spec


def _sweep(config: ScannerConfig, pos_list: list[Position], entries: list[dict],
           marker_frames: int = 1) -> dict:
    """The calibration's ``sweep.toml`` (scanqa.io.sweep): positions in increasing Z.

    A plain flat moving along the camera axis lists the truth's X, Y as its lateral maps;
    a printed target lists its marker frames instead, as a real sweep would; a tilted
    stage or target without print lists neither (Z of the flat is then not the reading).
    """
    sim = config.simulator
    tilted = sim.stage_tilt_deg != 0 or sim.target_tilt_deg != 0
    printed = sim.target != "none"
    rows = []
    for pos in sorted(pos_list, key=lambda p: p.stage_mm):
        row = {"z_mm": pos.stage_mm,
               "patterns": [e["folder"] for e in entries if e["index"] == pos.index]}
        if printed:
            names = [f"markers/{_marker_name(pos, k)}" for k in range(marker_frames)]
            row["markers"] = names[0] if marker_frames == 1 else names
        elif not tilted:
            row["lateral"] = f"truth/{pos.label}.npz"
        rows.append(row)
    out = {"format": "scanqa-sweep/1",
           "description": f"simulated flat target, {len(pos_list)} positions, "
                          f"{len(entries) // len(pos_list)} repeats",
           "scanner": scanner_table(config.camera, config.name)}
    if printed:
        out["target"] = target_table(sim.target_square_mm)
    out["position"] = rows
    return out


def _entry(pos: Position, rep: int, folder: str) -> dict:
    return {"index": pos.index, "repeat": rep, "stage_mm": pos.stage_mm,
            "camera_offset_mm": pos.camera_offset_mm,
            "projector_offset_mm": pos.projector_offset_mm, "folder": folder,
            "truth": f"truth/{pos.label}.npz"}


def _manifest(name: str, config: ScannerConfig, desc: PatternDescription,
              pos_list: list[Position], repeats: int, entries: list[dict]) -> dict:
    win = devices.sensor_window(config)
    meaning = {"camera-sweep": "camera offset along its axis, + towards the flat [mm]",
               "projector-sweep": "projector offset along its axis, + towards the flat [mm]",
               "calibration-sweep": "world Z of the flat target (perpendicular to the "
                                    "camera axis) [mm]",
               "gauge-blocks": "none (fixed artefact) [mm]", "mesh": "none [mm]",
               "sphere": "Z of the sphere's centre on the camera axis [mm]",
               "ball-bar": "number of the ball-bar position (1-7, truth.toml) [-]",
               "flat": "Z of the flat's centre on the camera axis [mm]"}[name]
    return {
        "format": MANIFEST_FORMAT, "experiment": name, "scanqa_version": __version__,
        "seed": config.simulator.seed, "scene": pos_list[0].scene.name,
        "stage_meaning": meaning, "repeats": repeats,
        "periods_px": [s.period_px for s in desc.phase_sets],
        "working_period_px": desc.working_period_px,
        "window": {"u0_px": win.u0, "v0_px": win.v0, "width_px": win.width,
                   "height_px": win.height},
        "truth_frame": "camera frame of each acquisition (the scanner frame when the "
                       "camera does not move) [mm]",
        "config": config.to_dict(), "acquisition": entries}


def write_npz(path: Path, arrays: dict) -> Path:
    """Write arrays as a deflated npz with fixed timestamps (reproducible); deflate
    level 1: 0.15 s of CPU per megapixel of truth against 0.4 s at level 6, for files 8 %
    larger (6.8 against 6.3 MB per megapixel)."""
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, buf.getvalue(), compresslevel=1)
    return path
