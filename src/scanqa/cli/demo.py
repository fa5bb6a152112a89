"""``scanqa demo``: runs the design tools on the paper's scanner and says where the
output went (the full pipeline demo replaces this once all stages exist)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scanqa import design
from scanqa.config import load_config
from scanqa.errors import InputError
from scanqa.io.atomic import write_text
from scanqa.report import design as plots

DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "calib" / "paper_scanner.toml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="run the design tools on the paper's scanner",
                       epilog="example:\n  scanqa demo --out scanqa-demo")
    p.add_argument("--out", default="scanqa-demo", help="output folder (default scanqa-demo)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="scanner config TOML")
    p.set_defaults(func=run_demo)


def _step(msg: str) -> None:
    print(f"[demo] {msg}", file=sys.stderr, flush=True)


def run_demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output folder {out}: {err.strerror}") from None
    config = load_config(args.config)
    focus = config.camera.focus_mm
    _step("depth of field (Tables 1, 2)")
    rows = design.dof_table(config)
    write_text(out / "dof.json", json.dumps([r.as_row() for r in rows], indent=1))
    plots.plot_dof(rows, out / "dof.png")
    _step("uncertainty curve on the camera axis (Fig. 3)")
    curve = design.axis_curve(config, focus - 50, focus + 50, 0.25)
    plots.plot_curve(curve, out / "curve.png", focus)
    _step("usable volume at level 0.49 (Sect. 5.1)")
    vol = design.usable_volume(config, 0.49, step=2.0)
    plots.plot_volume(vol, out / "volume.png")
    _step("flattening filter (Sect. 5.2)")
    plots.plot_flatten(design.flatten_curve(config, focus - 30, focus + 30, 0.25),
                       out / "flatten.png")
    p5 = {r.level: r.dof_mm for r in rows if r.device == "camera" and r.period_px == 5}
    print(f"camera DOF at level 0.49, period 5: {p5[0.49]:.1f} mm (paper Table 1: 27.9 mm)")
    print(f"usable volume: {vol.usable_mm3 / 1e3:.1f} of {vol.total_mm3 / 1e3:.1f} cm^3")
    print(f"demo output: {out.resolve()} (dof.json, dof.png, curve.png, volume.png, "
          "flatten.png)")
    return 0
