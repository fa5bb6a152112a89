"""Rendering of a characterisation: its summary.json and plots of the noise and the
attenuation over the sweep with every fitted reading (Figs. 3 and 4 of the paper).

Rendering only: every number comes from :mod:`scanqa.characterization.sweep`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from scanqa.characterization.noisefit import select
from scanqa.characterization.sweep import Characterization, JointCharacterization, VariantFit
from scanqa.io.atomic import staged_dir, write_text
from scanqa.model.config import ScannerConfig
from scanqa.numeric import json_ready
from scanqa.report.plots import new_figure, save_png


def write_characterization(result: Characterization | JointCharacterization,
                           out_dir: str | os.PathLike,
                           config: ScannerConfig | None = None) -> Path:
    """Write ``summary.json`` and ``std.png``/``attenuation.png`` into ``out_dir`` (for a
    joint fit, one pair per sweep: ``std_camera-sweep.png``, ...)."""
    summary = json.dumps(json_ready(result.summary()), indent=1)
    with staged_dir(out_dir) as out:  # the summary and its plots together, or none
        write_text(out / "summary.json", summary + "\n")
        if config is not None:
            if isinstance(result, JointCharacterization):
                for c in result.sweeps:
                    _plot(c, config, out, result.fits, f"_{c.experiment}")
            else:
                _plot(result, config, out)
    return Path(out_dir) / "summary.json"


def _plot(result: Characterization, config: ScannerConfig, out: Path,
          fits: tuple[VariantFit, ...] | None = None, suffix: str = "") -> None:
    cam = result.experiment == "camera-sweep"
    z = np.array([p.z_c_mm if cam else p.z_p_mm for p in result.positions])
    std = np.array([p.residual_std_px for p in result.positions])
    fig, axes = new_figure(width=6.0, height=4.0)
    ax = axes[0][0]
    ax.plot(z, std, "o", ms=3, label="sweep (surface-fit residual)")
    fits = result.fits if fits is None else fits
    best = select(fits)
    for fit in fits:
        style = "-" if fit is best else ":"
        ax.plot(z, result.model_std(fit, config), style, label=(
            f"{fit.label}: sigma_p={fit.sigma_p_px:.4f}, gamma={fit.gamma:.2f}, "
            f"held-out rms={100 * fit.cv_rms_relative:.1f}%"))
    ax.set_xlabel("Z_c [mm]" if cam else "Z_p [mm]")
    ax.set_ylabel("std of x_p [projector px]")
    ax.set_ylim(0, np.nanmax(std) * 1.3)
    ax.legend(fontsize=6)
    save_png(fig, out / f"std{suffix}.png")
    fig, axes = new_figure(width=6.0, height=4.0)
    ax = axes[0][0]
    ax.plot(z, [p.attenuation for p in result.positions], "o", ms=3, label="sweep")
    ax.plot(z, [p.attenuation_model for p in result.positions], "-", label="A(C/omega_o)")
    ax.set_xlabel("Z_c [mm]" if cam else "Z_p [mm]")
    ax.set_ylabel("attenuation [-]")
    ax.legend()
    save_png(fig, out / f"attenuation{suffix}.png")


def _interval(p: dict) -> str:
    """A parameter with what the data say about it."""
    if p["status"] == "fitted":
        return f"{p['value']:.4g} [{p['low']:.4g}, {p['high']:.4g}] (95 %)"
    if p["status"] == "bounded":
        return f"{p['value']:.4g}, only bounded: [{p['low']:.4g}, {p['high']:.4g}] (95 %)"
    return f"{p['value']:.4g}, not identifiable ({p['why']})"


def characterization_lines(summary: dict) -> list[str]:
    """What the characterisation found: the selected variant, each parameter with its
    interval or why it is not identifiable, the identifiable quantities, the baseline."""
    v = summary["best_variant"]
    lines = [f"selected model: filter_floor={v['filter_floor']}, filter_form="
             f"{v['filter_form']}, noise_reading={v['noise_reading']} (held-out RMS "
             f"{100 * v['cv_rms_relative']:.1f} %, a constant "
             f"{100 * summary['constant']['cv_rms_relative']:.1f} %)"]
    lines += [f"{p['name']} = {_interval(p)}" for p in v["parameters"]]
    lines += [f"identifiable: {c['name']} = {c['value']:.4g}"
              + (f" [{c['low']:.4g}, {c['high']:.4g}]" if "low" in c else "")
              for c in v["identifiable"]]
    if not summary["better_than_constant"]:
        lines.append(summary["verdict"])
    return lines
