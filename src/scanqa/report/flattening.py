"""The trade-off of a flattened scan (Sect. 5.2, Fig. 7): sigma and lateral resolution
against range, as a figure and as a text table. Renders a
:class:`scanqa.annotation.flattening.FlattenCurve`; computes nothing."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scanqa.report.plots import new_figure, save_png


def tradeoff_table(curve) -> str:
    """The curve as fixed-width text: one row per range bin.

    Parameters
    ----------
    curve : FlattenCurve
        From :func:`scanqa.annotation.flattening.flatten`.

    Returns
    -------
    str
        Header, then range [mm], points, sigma before and after [um], filter diameter
        [camera px] and lateral resolution before and after [mm] per bin.
    """
    stated = "stated" if curve.target_stated else "the lowest over the scan's ranges"
    lines = [f"flatten: target sigma {curve.target_um:.3g} um ({stated}; random sigma from "
             f"{curve.source})",
             "   z_mm  points  sigma_um  flat_um  filter_px  lateral_mm (before)"]
    for row in curve.rows():
        mark = "" if row["reachable"] else "  (target not reachable)"
        lines.append(f"{row['z_mm']:7.1f} {row['n']:7d} {row['sigma_um']:9.3g} "
                     f"{row['sigma_flat_um']:8.3g} {row['filter_diameter_px']:10.2f} "
                     f"{row['lateral_resolution_mm']:8.3g} ({row['lateral_before_mm']:.3g})"
                     f"{mark}")
    return "\n".join(lines)


def plot_tradeoff(curve, path: str | os.PathLike) -> Path:
    """Write the Fig. 7 style picture: filter and optical blur diameters (left), sigma
    before/after and lateral resolution (right) against range; PNG, atomically.

    Parameters
    ----------
    curve : FlattenCurve
        From :func:`scanqa.annotation.flattening.flatten`.
    path : str or PathLike
        Output PNG.

    Returns
    -------
    Path
        ``path``.
    """
    fig, axes = new_figure(2, 1, width=5.0, height=3.6)
    left, right = axes[0]
    z = np.asarray(curve.z_mm)
    left.plot(z, curve.optical_blur_px, "o-", color="tab:orange", label="optical blur")
    left.plot(z, curve.filter_diameter_px, "s-", color="tab:blue", label="digital filter")
    left.set_xlabel("range Z [mm]")
    left.set_ylabel("diameter [camera px]")
    left.legend()
    right.plot(z, curve.sigma_um, "o-", color="tab:blue", label="sigma as scanned")
    right.plot(z, curve.sigma_flat_um, "s-", color="tab:orange", label="sigma flattened")
    right.axhline(curve.target_um, color="grey", lw=0.8, ls="--")
    right.set_xlabel("range Z [mm]")
    right.set_ylabel("sigma [um]")
    twin = right.twinx()
    twin.plot(z, 1e3 * np.asarray(curve.lateral_resolution_mm), "^:", color="tab:green",
              label="lateral resolution")
    twin.set_ylabel("lateral resolution [um]")
    right.legend(loc="upper left")
    twin.legend(loc="upper right")
    return save_png(fig, path)
