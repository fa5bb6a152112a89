"""Are two versions of the simulator statistically the same? The demo on scans each simulates.

For every seed, each source tree simulates the demo's three gauge-block scans (the
command of sample_data/regenerate.sh with ``--seed``) and runs its ``scanqa demo`` on
them, with the committed sweeps of sample_data/ (the same table and characterisation for
both); the demo's sphere test is simulated by the same tree with the same seed. The
script prints, per seed and tree, the measured std of every gauge block, the step errors
and the sphere test's quantities, and the new/old ratios. Use seeds that were not used
while the new version was developed.

Run: .venv/bin/python docs/studies/compare_simulator_statistics.py OLD_SRC NEW_SRC
         [--seeds 11,12] [--work /tmp/stats]
(``OLD_SRC``: e.g. the ``src`` folder of a git worktree of the old commit.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "sample_data" / "sample_scanner.toml")
#: The simulations of sample_data/regenerate.sh: experiment, profile, extra arguments.
PLAN = (("gauge-blocks", "sample", ["--repeats", "3"]),)
FOLDERS = {"gauge-blocks": "gauge_blocks"}
#: Folders of sample_data/ used as they are (linked).
KEPT = ("calibration_sweep", "camera_sweep", "projector_sweep")


def _scanqa(src: str, args: list[str]) -> None:
    env = {**os.environ, "PYTHONPATH": src}
    subprocess.run([sys.executable, "-m", "scanqa", *args], check=True, env=env,
                   stdout=subprocess.DEVNULL)


def run(src: str, seed: int, work: Path) -> dict:
    """Simulate the sample data with ``seed`` by the tree ``src``, run the demo, collect."""
    data, out = work / "data", work / "demo"
    data.mkdir(parents=True, exist_ok=True)
    for name in KEPT:
        if not (data / name).exists():
            (data / name).symlink_to(ROOT / "sample_data" / name)
    for experiment, profile, extra in PLAN:
        _scanqa(src, ["simulate", experiment, "--config", f"{CFG}#{profile}", "--seed",
                      str(seed), "--out", str(data / FOLDERS[experiment]), "--quiet", *extra])
    _scanqa(src, ["demo", "--data", str(data), "--out", str(out)])
    qa = json.loads((out / "qa" / "summary.json").read_text())
    sphere = json.loads((out / "sphere_test" / "summary.json").read_text())
    return {"blocks_std_um": {b["block_id"]: b["measured_std_um"] for b in qa["blocks"]},
            "steps_error_um": [s.get("error_um") for s in qa["steps"]],
            "sphere": sphere["quantities"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("old_src")
    ap.add_argument("new_src")
    ap.add_argument("--seeds", default="11,12")
    ap.add_argument("--work", default="/tmp/simulator_statistics")
    args = ap.parse_args()
    results = {}
    for seed in [int(s) for s in args.seeds.split(",")]:
        for name, src in (("old", args.old_src), ("new", args.new_src)):
            results[(seed, name)] = run(src, seed, Path(args.work) / f"{name}_s{seed}")
        old, new = results[(seed, "old")], results[(seed, "new")]
        print(json.dumps({"seed": seed, "old": old, "new": new}, default=str))
        for bid, s_old in old["blocks_std_um"].items():
            s_new = new["blocks_std_um"][bid]
            if s_old and s_new:
                print(f"seed {seed} block {bid}: std {s_old:.3f} -> {s_new:.3f} um "
                      f"({100 * (s_new / s_old - 1):+.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
