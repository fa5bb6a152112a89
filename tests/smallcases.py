"""Small valid inputs of every file format scanqa reads, and the commands that read them.

For the failure-path tests (test_failures.py) and the fuzz test (test_fuzz.py): a
gauge-block cloud (PLY) with its layout, a small scanner config with a calibration table
and a phase map that match it, and a decodable pattern folder. Everything is built from
independent geometry (synth_sweep) or copied from the committed sample data, in a
fraction of a second.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from scanqa.calibration.build import build_table
from scanqa.calibration.table import save_table
from scanqa.decoding.phasemap import PhaseMap, save_phase_map
from scanqa.io.cloud import write_cloud
from scanqa.io.images import read_image
from scanqa.io.ply import write_ply
from scanqa.io.tomlfile import dumps_toml, tomllib
from scanqa.model.config import ScannerConfig, load_config

from .synth_sweep import plane_truth, small_camera, sweep

ROOT = Path(__file__).resolve().parents[1]
PATTERN_SOURCE = ROOT / "sample_data" / "camera_sweep" / "p015_r0"
#: Blocks of the small artefact: id, nominal height [mm], region [mm].
BLOCKS = ((1, 20.0, (-16.0, -6.0, -5.0, 5.0)), (2, 10.0, (-5.0, 5.0, -5.0, 5.0)),
          (3, 5.0, (6.0, 16.0, -5.0, 5.0)))
BASE_Z_MM = 470.0

LAYOUT_TOML = 'format = "scanqa-gauge-layout/1"\nname = "small"\n' + "".join(
    f"\n[[block]]\nid = {bid}\nnominal_height_mm = {h}\ntop_z_mm = {BASE_Z_MM - h}\n"
    f"region_mm = [{r[0]}, {r[1]}, {r[2]}, {r[3]}]\n" for bid, h, r in BLOCKS)


def gauge_cloud(spacing_mm: float = 0.5, noise_mm: float = 0.004, seed: int = 0
                ) -> tuple[np.ndarray, dict]:
    """Points on the tops of :data:`BLOCKS` with per-point sigmas: (xyz [mm], attributes)."""
    rng = np.random.default_rng(seed)
    parts = []
    for _, h, (x0, x1, y0, y1) in BLOCKS:
        x, y = np.meshgrid(np.arange(x0, x1, spacing_mm), np.arange(y0, y1, spacing_mm))
        z = np.full_like(x, BASE_Z_MM - h) + rng.normal(0.0, noise_mm, x.shape)
        parts.append(np.stack([x.ravel(), y.ravel(), z.ravel()], -1))
    xyz = np.concatenate(parts)
    n = len(xyz)
    attrs = {"sigma_model_um": np.full(n, 4.0, np.float32),
             "sigma_calibration_um": np.full(n, 0.5, np.float32),
             "table_corr_mm": np.full(n, 0.5, np.float32),
             "in_volume": np.ones(n, np.float32), "model_valid": np.ones(n, np.float32),
             "att_camera": np.full(n, 0.8, np.float32),
             "att_projector": np.full(n, 0.8, np.float32)}
    return xyz, attrs


def small_config() -> ScannerConfig:
    """The paper's scanner with a 40 x 32 px sensor (same optics)."""
    return small_camera(load_config(ROOT / "calib" / "paper_scanner.toml"), 40, 32)


def phase_map(config: ScannerConfig, z_mm: float = 450.0) -> PhaseMap:
    """The noiseless phase map of the plane Z = z_mm seen by ``config``'s camera."""
    xp, _ = plane_truth(config, z_mm)
    shape = xp.shape
    return PhaseMap(xp, np.full(shape, 100.0), np.full(shape, 120.0),
                    np.zeros(shape, np.uint8), np.full(shape, 0.01),
                    config.fringes.working_period_px, "vertical",
                    config.projector.width_px, {"software": "tests"})


def write_inputs(folder: Path) -> dict[str, Path]:
    """Write one valid input of each format into ``folder``; returns their paths:
    ``ply``, ``layout``, ``config``, ``table``, ``phase``, ``patterns`` (a folder)."""
    folder.mkdir(parents=True, exist_ok=True)
    xyz, attrs = gauge_cloud()
    paths = {"ply": write_ply(folder / "cloud.ply", xyz, attrs, {"source": "tests"}),
             "layout": folder / "layout.toml", "config": folder / "config.toml",
             "table": folder / "table.npz", "phase": folder / "phase.npz",
             "patterns": folder / "patterns"}
    paths["layout"].write_text(LAYOUT_TOML)
    config = small_config()
    paths["config"].write_text(dumps_toml(config.to_dict()))
    table, _ = build_table(sweep(config, np.arange(430.0, 470.1, 4.0), seed=1), config,
                           cell_px=8)
    save_table(paths["table"], table)
    save_phase_map(paths["phase"], phase_map(config))
    shutil.copytree(PATTERN_SOURCE, paths["patterns"])
    paths["stack"] = _stack_patterns(paths["patterns"], folder / "stack")
    paths["csv"] = write_cloud(folder / "cloud.csv", xyz, attrs, {"source": "tests"})
    return paths


def _stack_patterns(patterns: Path, folder: Path) -> Path:
    """The pattern folder with its 80 px set as one (4, H, W) .npz stack (``p80.npz``)."""
    shutil.copytree(patterns, folder)
    text = (folder / "patterns.toml").read_text()
    data = tomllib.loads(text)
    for item in data["set"]:
        if item.get("name") == "p80":
            frames = [read_image(folder / f) for f in item.pop("files")]
            np.savez(folder / "p80.npz", p80=np.stack(frames))
            item["stack"] = "p80.npz"
            for f in folder.glob("p80_*.png"):
                f.unlink()
    (folder / "patterns.toml").write_text(dumps_toml(data))
    return folder


def command(kind: str, paths: dict[str, Path], out: Path) -> list[str]:
    """The command line that reads the input of ``kind`` (writing into ``out``)."""
    p = {k: str(v) for k, v in paths.items()}
    return {
        "ply": ["qa", p["ply"], "--layout", p["layout"], "--out", str(out)],
        "layout": ["qa", p["ply"], "--layout", p["layout"], "--out", str(out)],
        "config": ["annotate", p["phase"], "--table", p["table"], "--config", p["config"],
                   "--out", str(out / "cloud.ply")],
        "table": ["annotate", p["phase"], "--table", p["table"], "--config", p["config"],
                  "--out", str(out / "cloud.ply")],
        "phase": ["annotate", p["phase"], "--table", p["table"], "--config", p["config"],
                  "--out", str(out / "cloud.ply")],
        "patterns": ["decode", p["patterns"], "--out", str(out / "phase.npz")],
        "image": ["decode", p["patterns"], "--out", str(out / "phase.npz")],
        "stack": ["decode", p["stack"], "--out", str(out / "phase.npz")],
        "csv": ["qa", p["csv"], "--layout", p["layout"], "--out", str(out)],
    }[kind]
