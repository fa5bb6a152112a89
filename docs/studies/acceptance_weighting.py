"""Calibration weighting compared over several noise seeds (simulated; docs/calibration.rst).

A sweep of the sample camera's central 96 x 96 px reaching far past the depth of field
(414 ... 490 mm every 2 mm, camera attenuation ~0.05 at its ends) is simulated once per
seed; from each, four tables are built:

* ``model``: weights 1 / sigma^2 from the optics model with the parameters the sample
  camera and projector sweeps select (``scanqa characterize`` on them);
* ``modulation``: weights from the decoder's per-pixel sigma_xp (no optics model);
* ``none``: equal weights over every plane;
* ``none, in DOF``: equal weights over the planes inside the depth of field only (camera
  attenuation >= 0.49 on the axis) - the strongest fair unweighted baseline.

Each table is applied to the true phase of hold-out planes midway between the calibrated
ones; the score is the RMS error against truth over the hold-out planes inside the depth
of field (where scans are measured). Prints one line per seed and the mean and spread.

Usage::

    .venv/bin/python docs/studies/acceptance_weighting.py [--seeds 12] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from scanqa.calibration.build import PlaneObservation, build_table  # noqa: E402
from scanqa.characterization.sweep import characterize_sweeps  # noqa: E402
from scanqa.decoding.decoder import decode_images  # noqa: E402
from scanqa.model import optics  # noqa: E402
from scanqa.model.config import ScannerConfig, load_config  # noqa: E402
from scanqa.simulator import render  # noqa: E402
from scanqa.simulator.experiments import (  # noqa: E402
    acquisition,
    build_positions,
    pattern_description,
)

SWEEP_Z = tuple(float(z) for z in np.arange(414.0, 491.0, 2.0))
WINDOW_PX = 96
LEVEL = 0.49
SCHEMES = ("model", "modulation", "none", "none, in DOF")


def small_camera(config: ScannerConfig, size: int) -> ScannerConfig:
    """The config with a size x size sensor (same optics, centred window)."""
    cam = replace(config.camera, width_px=size, height_px=size)
    return ScannerConfig(cam, config.projector, config.fringes, config.model,
                         config.simulator, config.name, config.source)


def simulate(config: ScannerConfig) -> list[PlaneObservation]:
    desc = pattern_description(config)
    out = []
    for pos in build_positions("calibration-sweep", config, SWEEP_Z):
        pm = decode_images(desc, render.render_images(config, acquisition(config, pos, 0), desc))
        out.append(PlaneObservation(pos.stage_mm, pm.xp, pm.mask, pm.modulation, pm.sigma_xp,
                                    source=f"z={pos.stage_mm}"))
    return out


def holdout_rms(config: ScannerConfig, table, zs: np.ndarray) -> float:
    """RMS error [mm] of the table on the true phase of planes at ``zs``."""
    sq, n = 0.0, 0
    for z in zs:
        pos = build_positions("calibration-sweep", config, [float(z)])[0]
        truth = render.truth_for(config, acquisition(config, pos, 0))
        v, u = np.nonzero(truth.valid)
        xyz = np.stack([truth.x, truth.y, truth.z], axis=-1)[truth.valid]
        err = table.apply(u, v, truth.xp[truth.valid]).xyz - xyz
        if not np.isfinite(err).all():
            raise RuntimeError(f"plane {z} mm lies outside a table's range")
        sq += float(np.sum(err**2))
        n += len(err)
    return float(np.sqrt(sq / n))


def camera_attenuation(config: ScannerConfig, zs) -> np.ndarray:
    z = np.asarray(zs, dtype=float)
    return optics.predict(np.stack([0 * z, 0 * z, z], -1), config).attenuation_camera


def run_seed(config: ScannerConfig, fitted: ScannerConfig, seed: int) -> dict:
    cfg = config.replace_simulator(seed=seed)
    obs = simulate(cfg)
    zs = np.arange(SWEEP_Z[0] + 1.0, SWEEP_Z[-1], 2.0)
    keep = camera_attenuation(cfg, [o.z_mm for o in obs]) >= LEVEL
    kept = [o.z_mm for o, k in zip(obs, keep, strict=True) if k]
    # every table is scored on the same planes: inside the DOF and inside the range of
    # the table from the DOF's planes alone
    inside = zs[(camera_attenuation(cfg, zs) >= LEVEL) & (zs > min(kept)) & (zs < max(kept))]
    tables = {"model": build_table(obs, replace(cfg, model=fitted.model), weights="model"),
              "modulation": build_table(obs, cfg, weights="modulation"),
              "none": build_table(obs, cfg, weights="none"),
              "none, in DOF": build_table([o for o, k in zip(obs, keep, strict=True) if k],
                                          cfg, weights="none")}
    return {name: 1e3 * holdout_rms(cfg, t[0], inside) for name, t in tables.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=12)
    p.add_argument("--json", default=None, help="write the per-seed numbers here")
    args = p.parse_args()
    sample = ROOT / "sample_data"
    base = load_config(sample / "sample_scanner.toml", profile="sample")
    char = characterize_sweeps([sample / "camera_sweep", sample / "projector_sweep"],
                               load_config(sample / "sample_scanner.toml",
                                           profile="sample_roi64"))
    fitted = char.apply_to(base)
    config = small_camera(base, WINDOW_PX)
    rows = []
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        row = run_seed(config, fitted, seed)
        rows.append(row)
        print(f"seed {seed}: " + ", ".join(f"{k} {v:.3f} um" for k, v in row.items())
              + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    table = {k: np.array([r[k] for r in rows]) for k in SCHEMES}
    print(f"simulated, {args.seeds} seeds, hold-out RMS inside the DOF [um]: mean (std, min-max)")
    for k, v in table.items():
        print(f"  {k:14s} {v.mean():.3f} ({v.std(ddof=1) if v.size > 1 else 0:.3f}, "
              f"{v.min():.3f}-{v.max():.3f})")
    wins = np.mean(table["model"] < table["none, in DOF"])
    print(f"  model better than 'none, in DOF' in {100 * wins:.0f} % of seeds; model / "
          f"modulation mean ratio {np.mean(table['model'] / table['modulation']):.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"seeds": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
