"""Acceptance of the VDI/VDE 2634-2 tests against simulator truth (simulated throughout).

The sample scanner (the paper's optics at f/11, its sensor binned 8 x 8: 306 x 256 px of
64 um, profile ``sample`` of sample_data/sample_scanner.toml) scans, with fresh noise
each time:

* the 12 mm test sphere at the centre of the measuring volume, ``--single-scans`` times;
* the ball bar (12 mm balls, 40 mm apart) in each of its 7 positions, ``--scans`` times;
* the 50 x 40 mm flat (tilted 10 deg about X, 15 deg about Y), ``--single-scans`` times;

each decoded, turned into points by the table built from the committed calibration
sweep, and evaluated by :func:`scanqa.qa.artefacts.run_artefact_qa` with the simulator's
exact sizes as certificates (U_cert 0.5 um for the sphere, 1 um for the bar).

Truth. PS and SD have two: the artefact's (the true diameter and distance: the test
value's truth for an error-free scanner, E = 0) and the scanner's (its systematic test
value, what the test measures: the same artefact rendered without any noise - no scene
noise, no read noise, shot noise made negligible by a 2.5e8 e- signal on 16 bits - and
evaluated the same way). PF and F are ranges of noisy residuals: the scanner's value is
their expectation over scans, estimated for each scan by the mean of the other scans.
Each scan's test value is checked against the truth within its own U (k = 2); the
predicted form (PF, F) is compared with the measured one per scan. A 95 % U misses one
value in twenty: with 5 scans, 5 of 5 within U happens in only 77 % of runs of an honest
U, so the single artefacts get 20 scans (>= 18 within U: 92 % of runs) and the ball bar
35 (5 per position, >= 32 within U: 94 %).

Usage::

    .venv/bin/python docs/studies/acceptance_artefacts.py [--scans 5] [--single-scans 20]
        [--json out.json]

About 13 min on 2 cores with the defaults (rendering: ~5 s a sphere, ~9 s a ball-bar
position, ~14 s the flat).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

from scanqa.annotation.points import annotate  # noqa: E402
from scanqa.calibration.sweep import calibrate  # noqa: E402
from scanqa.characterization.sweep import characterize_sweeps  # noqa: E402
from scanqa.decoding.decoder import decode_images  # noqa: E402
from scanqa.io.atomic import write_text  # noqa: E402
from scanqa.io.spec import read_spec  # noqa: E402
from scanqa.io.tomlfile import dumps_toml  # noqa: E402
from scanqa.model.config import load_config  # noqa: E402
from scanqa.qa.artefacts import load_artefact_layout, run_artefact_qa  # noqa: E402
from scanqa.runs.demo import manifest_config  # noqa: E402
from scanqa.simulator import render  # noqa: E402
from scanqa.simulator.experiments import (  # noqa: E402
    acquisition,
    artefact_geometry,
    artefact_layout,
    build_positions,
    example_spec,
    pattern_description,
)

CONFIG = ROOT / "sample_data" / "sample_scanner.toml"
SWEEP = ROOT / "sample_data" / "calibration_sweep" / "sweep.toml"


def noise_free(config):
    """The same scanner with every noise source off or negligible (the truth renders):
    2.5e8 e- of signal make the shot noise 6e-5 of it, 16 bits the quantisation 1.5e-5."""
    return config.replace_simulator(scene_noise_rel=0.0, read_noise_e=0.0, bit_depth=16,
                                    mean_signal_e=2.5e8, full_well_e=1e9,
                                    gain_e_per_dn=1e9 / 65535)


def scans_of(name: str, config, positions, repeats: int, table, model_config, folder: Path
             ) -> list:
    """The QA results of every position x repeat, each scan rendered in memory and
    evaluated at once (a full-resolution cloud is ~0.3 GB: they are not kept)."""
    desc = pattern_description(config)
    pos = build_positions(name, config, positions)
    geoms = [(p, artefact_geometry(name, config, p.stage_mm)) for p in pos]
    write_text(folder / f"{name}.toml", dumps_toml(artefact_layout(name, geoms)))
    write_text(folder / f"{name}_spec.toml", dumps_toml(example_spec(geoms[0][1])))
    layout = load_artefact_layout(folder / f"{name}.toml")
    spec = read_spec(folder / f"{name}_spec.toml")
    results = []
    for p in pos:
        for rep in range(repeats):
            images = render.render_images(config, acquisition(config, p, rep, name), desc)
            cloud = annotate(decode_images(desc, images), table, model_config,
                             keep_invalid=True)
            results.extend(run_artefact_qa([(f"{p.label}_r{rep}", cloud)], layout,
                                           spec).results)
            del images, cloud
    return results


def by_quantity(results) -> dict:
    """{(quantity, position label): [(scan, Quantity)]}."""
    out: dict = {}
    for r in results:
        for q in r.quantities:
            out.setdefault((q.name, r.scan.split("_")[0]), []).append((r.scan, q))
    return out


def check_against(values, truth_fn) -> list[dict]:
    """Per scan: value, truth, error, U, within."""
    rows = []
    for i, (scan, q) in enumerate(values):
        t = truth_fn(i)
        rows.append({"scan": scan, "value_um": 1e3 * q.value, "truth_um": 1e3 * t,
                     "error_um": 1e3 * (q.value - t), "U_um": 1e3 * q.expanded,
                     "within": bool(abs(q.value - t) <= q.expanded),
                     "predicted_um": 1e3 * q.predicted})
    return rows


def leave_one_out(values) -> callable:
    v = np.array([q.value for _, q in values])
    return lambda i: float(np.delete(v, i).mean())


def summarise(label: str, rows: list[dict]) -> dict:
    n, k = len(rows), sum(r["within"] for r in rows)
    z = [r["error_um"] / (r["U_um"] / 2) for r in rows]
    print(f"{label}: {k} of {n} within U ({100 * k / n:.0f} %), RMS error/u "
          f"{math.sqrt(np.mean(np.square(z))):.2f}, errors {min(r['error_um'] for r in rows):+.2f}"
          f" .. {max(r['error_um'] for r in rows):+.2f} um, U "
          f"{min(r['U_um'] for r in rows):.2f} .. {max(r['U_um'] for r in rows):.2f} um")
    return {"within": k, "n": n, "rows": rows}


def form_ratio(label: str, rows: list[dict]) -> dict:
    ratio = [r["predicted_um"] / r["value_um"] for r in rows]
    ok = sum(abs(x - 1) <= 0.2 for x in ratio)
    print(f"{label} predicted / measured: {min(ratio):.3f} .. {max(ratio):.3f} (mean "
          f"{np.mean(ratio):.3f}); {ok} of {len(ratio)} within 20 %")
    return {"ratios": ratio, "within_20": ok, "n": len(ratio)}


def scanner(data: Path | None):
    """(scanner config, model config, table): the sample scanner's, or those of a data
    folder simulated by ``scanqa demo --full`` (its gauge scans' config; the model the
    folder's camera + projector sweeps select; the table of its calibration sweep)."""
    t0 = time.perf_counter()
    if data is None:
        config = load_config(CONFIG, profile="sample")
        table, _ = calibrate(SWEEP, config, weights="model")
        model_config = config
    else:
        config = manifest_config(data / "gauge_blocks")
        char = characterize_sweeps([data / "camera_sweep", data / "projector_sweep"],
                                   manifest_config(data / "camera_sweep"))
        print(f"model selected on {data}'s camera + projector sweeps: {char.best.label}")
        model_config = char.apply_to(config)
        table, _ = calibrate(data / "calibration_sweep" / "sweep.toml", model_config,
                             weights="model")
    print(f"scanner {config.name}: {config.camera.width_px} x {config.camera.height_px} px "
          f"of {config.camera.pixel_um:g} um, f/{config.camera.f_number:g}; table built in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    return config, model_config, table


def run(scans: int, single_scans: int, data: Path | None = None) -> dict:
    config, model_config, table = scanner(data)
    report: dict = {"scans": scans, "single_scans": single_scans,
                    "scanner": f"{config.camera.width_px} x {config.camera.height_px} px",
                    "data": str(data) if data else "sample_data"}
    plan = (("sphere", [450.0], single_scans), ("ball-bar", [float(i) for i in range(1, 8)],
                                                 scans), ("flat", [450.0], single_scans))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, positions, repeats in plan:
            t = time.perf_counter()
            clean = scans_of(name, noise_free(config), positions, 1, table, model_config,
                             folder)
            noisy = scans_of(name, config, positions, repeats, table, model_config, folder)
            print(f"{name}: {len(noisy)} scans + {len(clean)} noise-free rendered and "
                  f"evaluated in {time.perf_counter() - t:.0f} s", flush=True)
            report[name] = compare(by_quantity(noisy), by_quantity(clean))
    return report


def compare(noisy: dict, clean: dict) -> dict:
    out = {}
    for (qname, pos) in sorted(noisy):
        values = noisy[(qname, pos)]
        key = f"{qname} {pos}"
        if qname in ("PS", "SD"):
            nf = clean[(qname, pos)][0][1].value
            out[key] = {
                "noise_free_um": 1e3 * nf,
                "vs_scanner": summarise(f"{key} vs the scanner's (noise-free) value "
                                        f"{1e3 * nf:+.2f} um", check_against(values, lambda i,
                                                                              v=nf: v)),
                "vs_artefact": summarise(f"{key} vs the artefact (E = 0)",
                                         check_against(values, lambda i: 0.0))}
        else:
            rows = check_against(values, leave_one_out(values))
            out[key] = {"vs_scanner": summarise(f"{key} vs the mean of the other scans", rows),
                        "form": form_ratio(key, rows)}
    return out


def pooled(report: dict) -> None:
    """The acceptance lines: every quantity's scans pooled."""
    for qname in ("PS", "PF", "SD", "F"):
        for truth in ("vs_scanner", "vs_artefact"):
            parts = [v[truth] for name in ("sphere", "ball-bar", "flat")
                     for k, v in report[name].items() if k.startswith(qname + " ") and truth in v]
            if parts:
                k, n = sum(p["within"] for p in parts), sum(p["n"] for p in parts)
                print(f"ACCEPT {qname} {truth}: {k} of {n} within U ({100 * k / n:.0f} %)")
    forms = [v["form"] for name in ("sphere", "flat") for v in report[name].values() if "form" in v]
    k, n = sum(f["within_20"] for f in forms), sum(f["n"] for f in forms)
    print(f"ACCEPT predicted form within 20 %: {k} of {n}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=5, help="scans per ball-bar position")
    ap.add_argument("--single-scans", type=int, default=20,
                    help="scans of the sphere and of the flat")
    ap.add_argument("--json", default=None, help="write the numbers to this file")
    ap.add_argument("--data", type=Path, default=None,
                    help="a folder simulated by 'scanqa demo --full' (camera_sweep/, "
                         "projector_sweep/, calibration_sweep/, gauge_blocks/): its scanner "
                         "(the paper's, full resolution), model and table instead of the "
                         "sample scanner's")
    args = ap.parse_args()
    t0 = time.perf_counter()
    report = run(args.scans, args.single_scans, args.data)
    pooled(report)
    print(f"acceptance run = {time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
