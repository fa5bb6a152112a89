"""Acceptance: ``scanqa design optimise`` against a brute-force grid on three specs.

For each spec of ``benchmarks/design_specs/`` (three settings each; ``obstacle.toml``
with a fixture that the widest baselines' projector pyramid would cross) the optimiser
(coarse grid, then compass search) and a 12 x 12 x 12 grid over the same limits are run
on the paper scanner; both count their model evaluations (a usable volume at the spec's
voxel size and the feasibility checks). Targets: the optimiser's usable volume within
2 % of the grid's best (it may exceed it: it is not tied to the grid's points), with at
least 10x fewer evaluations; then the same with ``objective = "worst_sigma"`` (the
optimiser's worst sigma at most 2 % above the grid's best). For the obstacle spec the
optimum without the obstacle is printed too, to show that the obstacle binds.

Run: .venv/bin/python docs/studies/acceptance_design_optimise.py [--grid 12]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from scanqa.design import optimisation  # noqa: E402
from scanqa.model.config import load_config  # noqa: E402

SPECS = sorted((ROOT / "benchmarks" / "design_specs").glob("*.toml"))


def _fmt(values: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in values.items())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--grid", type=int, default=12, help="grid points per setting")
    args = ap.parse_args()
    config = load_config(ROOT / "calib" / "paper_scanner.toml")
    ok = True
    print("| spec | optimiser: usable cm^3, evaluations | grid: usable cm^3, evaluations "
          "| optimiser / grid | fewer evaluations |")
    for path in SPECS:
        spec = optimisation.load_spec(path)
        t0 = time.perf_counter()
        found = optimisation.optimise(config, spec)
        t1 = time.perf_counter()
        grid = optimisation.grid_search(config, spec, args.grid)
        t2 = time.perf_counter()
        ratio, fewer = found.usable_mm3 / grid.usable_mm3, grid.evaluations / found.evaluations
        ok &= ratio >= 0.98 and fewer >= 10
        print(f"| {path.stem} | {found.usable_mm3 / 1e3:.3f}, {found.evaluations} "
              f"({t1 - t0:.1f} s) | {grid.usable_mm3 / 1e3:.3f}, {grid.evaluations} "
              f"({t2 - t1:.1f} s) | {ratio:.4f} | {fewer:.1f}x |")
        print(f"|   optimiser at | {_fmt(found.values)} | grid at {_fmt(grid.values)} | | |")
        if spec.obstacles:
            free = optimisation.optimise(config, dataclasses.replace(spec, obstacles=()))
            print(f"|   without the obstacle | {free.usable_mm3 / 1e3:.3f} at "
                  f"{_fmt(free.values)} | | | |")
    print("\nobjective worst_sigma (the same specs, minimising the largest sigma in the box)")
    print("| spec | optimiser: worst sigma um, evaluations | grid: worst sigma um, "
          "evaluations | optimiser / grid | fewer evaluations |")
    for path in SPECS:
        spec = dataclasses.replace(optimisation.load_spec(path), objective="worst_sigma")
        found = optimisation.optimise(config, spec)
        grid = optimisation.grid_search(config, spec, args.grid)
        ratio = found.worst_sigma_um / grid.worst_sigma_um
        fewer = grid.evaluations / found.evaluations
        ok &= ratio <= 1.02 and fewer >= 10
        print(f"| {path.stem} | {found.worst_sigma_um:.4f}, {found.evaluations} | "
              f"{grid.worst_sigma_um:.4f}, {grid.evaluations} | {ratio:.4f} | {fewer:.1f}x |")
    print("RESULT design optimise: " + ("all specs within 2 % with >= 10x fewer evaluations"
                                        if ok else "a target was missed"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
