"""Plots of the design tools (depth of field, W curve, usable volume, flattening)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scanqa.design.tools import DepthOfField, UsableVolume
from scanqa.report.plots import new_figure, save_png


def plot_dof(rows: Sequence[DepthOfField], path: str | os.PathLike) -> Path:
    """Depth of field vs attenuation level, one line per device and period."""
    fig, axes = new_figure(ncols=2)
    for ax, device in zip(axes[0], ("camera", "projector"), strict=True):
        for period in sorted({r.period_px for r in rows}):
            sel = [r for r in rows if r.device == device and r.period_px == period]
            ax.plot([r.level for r in sel], [r.dof_mm for r in sel], "o-",
                    label=f"period {period:g} px")
        ax.axvline(0.49, color="0.6", lw=0.8, ls="--")
        ax.set(title=f"{device} depth of field", xlabel="attenuation level [-]",
               ylabel="depth of field [mm]")
        ax.legend()
    return save_png(fig, path)


def plot_curve(curve: dict, path: str | os.PathLike, focus_mm: float) -> Path:
    """Attenuations and sigma over range on the camera axis (the W curve, Fig. 3/4)."""
    fig, axes = new_figure(ncols=2)
    z, ok = curve["z_mm"], curve["model_valid"]
    ax = axes[0][0]
    ax.plot(z, curve["attenuation_camera"], label="camera A_c")
    ax.plot(z, curve["attenuation_projector"], label="projector A_p")
    ax.set(xlabel="Z [mm]", ylabel="attenuation [-]", title="attenuation")
    ax.legend()
    ax = axes[0][1]
    ax.plot(z, np.where(ok, curve["sigma_um"], np.nan), label="sigma (model valid)")
    ax.plot(z, np.where(ok, np.nan, curve["sigma_um"]), color="0.7",
            label="sigma (r > 1/2: outside validity)")
    ax.axvline(focus_mm, color="0.6", lw=0.8, ls="--")
    valid = curve["sigma_um"][ok]
    if valid.size:
        ax.set_ylim(0, 1.5 * np.nanmax(valid))
    ax.set(xlabel="Z [mm]", ylabel="sigma along line of sight [um]", title="uncertainty")
    ax.legend()
    return save_png(fig, path)


def plot_volume(vol: UsableVolume, path: str | os.PathLike) -> Path:
    """XZ slice (Y = 0) of the total and usable reconstruction volumes (Fig. 6)."""
    fig, axes = new_figure(width=5.0, height=6.0)
    ax = axes[0][0]
    img = vol.slice_inside.astype(float) + vol.slice_usable.astype(float)
    ext = (vol.slice_x_mm[0], vol.slice_x_mm[-1], vol.slice_z_mm[-1], vol.slice_z_mm[0])
    ax.imshow(img, extent=ext, cmap="YlOrBr", vmin=0, vmax=2, aspect="auto")
    ax.set(xlabel="X [mm]", ylabel="Z [mm]",
           title=f"inside both frusta (orange), usable (A_c A_p >= {vol.level:g}, brown)\n"
                 f"usable {vol.usable_mm3 / 1e3:.1f} of {vol.total_mm3 / 1e3:.1f} cm^3 "
                 f"({100 * vol.fraction:.1f} %)")
    return save_png(fig, path)


def plot_flatten(res: dict, path: str | os.PathLike) -> Path:
    """Optical blur and digital filter diameters, and the flattened curve (Fig. 7)."""
    fig, axes = new_figure(ncols=2)
    z = res["z_mm"]
    ax = axes[0][0]
    ax.plot(z, res["optical_blur_diameter_px"], label="optical blur")
    ax.plot(z, res["filter_diameter_px"], label="digital filter")
    ax.set(xlabel="Z [mm]", ylabel="diameter [camera px]", title="filter diameters")
    ax.legend()
    ax = axes[0][1]
    ax.plot(z, np.where(res["model_valid"], res["sigma_um"], np.nan), label="actual")
    ax.plot(z, res["sigma_flat_um"], label="after filtering")
    ax.set(xlabel="Z [mm]", ylabel="sigma [um]", title="uncertainty")
    ax.legend()
    return save_png(fig, path)
