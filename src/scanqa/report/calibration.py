"""Calibration report: residual per position, coverage, rejections, table uncertainty."""

from __future__ import annotations

import numpy as np

from scanqa.calibration.build import BuildReport
from scanqa.calibration.table import CalibrationTable
from scanqa.report.html import Page
from scanqa.report.plots import new_figure


def summary(table: CalibrationTable, report: BuildReport) -> dict:
    """JSON-ready summary of a build."""
    centre = np.argmin(np.abs(table.s_nodes))
    sig = table.sigma_node[..., centre] * 1e3
    cover = np.isfinite(table.s_lo)
    return {
        "format": "scanqa-calibration-report/1",
        "weights": table.weights,
        "camera_px": [table.width_px, table.height_px],
        "cell_px": table.cell_px,
        "nodes": [int(table.node_v.size), int(table.node_u.size), int(table.s_nodes.size)],
        "covered_node_fraction": float(cover.mean()),
        "z_range_mm": list(table.z_range_mm),
        "table_sigma_um_median": float(np.nanmedian(sig)) if np.isfinite(sig).any() else None,
        "table_sigma_um_p95": float(np.nanpercentile(sig, 95)) if np.isfinite(sig).any()
        else None,
        **report.as_dict(),
    }


def render(table: CalibrationTable, report: BuildReport) -> str:
    """The calibration report as one self-contained HTML page."""
    info = summary(table, report)
    page = Page("scanqa calibration report")
    page.paragraph(f"weights: {table.weights}; camera {table.width_px} x {table.height_px} px; "
                   f"nodes every {table.cell_px:g} px; stage range "
                   f"{info['z_range_mm'][0]:g} to {info['z_range_mm'][1]:g} mm; "
                   f"{100 * info['covered_node_fraction']:.1f} % of nodes covered.")
    page.heading("Residual per position", "residuals")
    rows = report.positions
    fig, ax = new_figure()
    z = [r["z_mm"] for r in rows]
    ax[0][0].plot(z, [r["rms_residual_um"] or np.nan for r in rows], "o")
    ax[0][0].set(xlabel="stage Z [mm]", ylabel="RMS fit residual [um]",
                 title="node residuals of the per-ray fit")
    page.figure(fig, "RMS over nodes of the stage-2 fit residual at each position", "residuals")
    page.table(rows)
    page.heading("Rejected samples", "rejected")
    page.table([{"reason": k, "samples": v} for k, v in report.rejected.items()]
               + [{"reason": "used", "samples": report.used_samples}])
    page.heading("Coverage and table uncertainty", "maps")
    fig, ax = new_figure(ncols=2, width=5.5)
    span = np.where(np.isfinite(table.s_lo), table.s_hi - table.s_lo, np.nan)
    im = ax[0][0].imshow(span, cmap="viridis")
    fig.colorbar(im, ax=ax[0][0], label="calibrated phase span [projector px]")
    ax[0][0].set(title="coverage", xlabel="node u", ylabel="node v")
    centre = int(np.argmin(np.abs(table.s_nodes)))
    im = ax[0][1].imshow(table.sigma_node[..., centre] * 1e3, cmap="magma")
    fig.colorbar(im, ax=ax[0][1], label="table sigma [um]")
    ax[0][1].set(title="table uncertainty at the reference phase", xlabel="node u")
    page.figure(fig, "left: calibrated phase span per node; right: the table's own std",
                "maps")
    return page.render()
