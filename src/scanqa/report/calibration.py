"""Calibration report: residual per position, coverage, rejections, table uncertainty."""

from __future__ import annotations

import numpy as np

from scanqa.calibration.build import BuildReport
from scanqa.calibration.table import CalibrationTable
from scanqa.report.html import Page
from scanqa.report.plots import new_figure


def summary(table: CalibrationTable, report: BuildReport) -> dict:
    """JSON-ready summary of a build."""
    nodes = table.node_summary()
    return {
        "format": "scanqa-calibration-report/1",
        "weights": table.weights,
        "camera_px": [table.width_px, table.height_px],
        "cell_px": table.cell_px,
        "nodes": [int(table.node_v.size), int(table.node_u.size), int(table.s_nodes.size)],
        "covered_node_fraction": nodes["covered_node_fraction"],
        "z_range_mm": list(table.z_range_mm),
        "table_sigma_um_median": nodes["table_sigma_um_median"],
        "table_sigma_um_p95": nodes["table_sigma_um_p95"],
        **report.as_dict(),
        **({"target_geometry": table.provenance["target_geometry"]}
           if "target_geometry" in table.provenance else {}),
    }


def render(table: CalibrationTable, report: BuildReport) -> str:
    """The calibration report as one self-contained HTML page."""
    info = summary(table, report)
    page = Page("scanqa calibration report")
    page.paragraph(f"weights: {table.weights}; camera {table.width_px} x {table.height_px} px; "
                   f"nodes every {table.cell_px:g} px; stage range "
                   f"{info['z_range_mm'][0]:g} to {info['z_range_mm'][1]:g} mm; "
                   f"{100 * info['covered_node_fraction']:.1f} % of nodes covered.")
    if "target_geometry" in info:
        _geometry_section(page, info["target_geometry"])
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
    im = ax[0][1].imshow(table.sigma_node[..., table.reference_node] * 1e3, cmap="magma")
    fig.colorbar(im, ax=ax[0][1], label="table sigma [um]")
    ax[0][1].set(title="table uncertainty at the reference phase", xlabel="node u")
    page.figure(fig, "left: calibrated phase span per node; right: the table's own std",
                "maps")
    return page.render()


def _marker_error(page: Page, err: dict) -> None:
    """The error the marker fit's uncertainty implies, and a warning past the bound."""
    q = round(100 * err["quantile"])
    sx, sy = err["rotation_std_deg"]
    rot = (f"the target's rotation known to {sx:.4f} / {sy:.4f} deg toward x / y (1 std) "
           if sx is not None else "the target's rotation ")
    page.paragraph(
        f"From {err['marker_frames']} marker frame(s) per position: {rot}alone implies "
        f"{err['rotation_error_um']:.2f} um RMS of registered table error "
        f"({err['rotation_error_quantile_um']:.2f} um in {q} % of sweeps); the whole "
        f"marker fit, whose errors partly cancel, {err['fit_error_um']:.2f} um "
        f"({err['fit_error_quantile_um']:.2f} um in {q} %), against a bound of "
        f"{err['bound_um']:.2f} um (0.1 of the model's single-point sigma at focus).")
    if err["exceeds_bound"]:
        needed = err["frames_needed"]
        page.paragraph(
            f"Warning: the marker fit's implied error ({err['fit_error_quantile_um']:.2f} "
            f"um in {q} % of sweeps) exceeds the bound ({err['bound_um']:.2f} um): capture "
            + (f"{needed} marker frames per position" if needed else
               "more marker frames per position or a finer target")
            + " (docs/calibration.rst, 'How many marker frames').", note=True)


def _geometry_section(page: Page, geo: dict) -> None:
    """The camera and stage fitted to the marked target, and what the sweep pinned."""
    page.heading("Camera and stage from the marked target", "geometry")
    held = [name for name, key in (("the principal point (held at the sensor centre)",
                                    "principal_point_fitted"),
                                   ("the tangential distortion p1, p2 (held at 0)",
                                    "decentring_fitted")) if not geo.get(key, True)]
    std = geo.get("std", {})
    known = (f" (its normal known to {std['target_normal_x_deg']:.4f} / "
             f"{std['target_normal_y_deg']:.4f} deg toward x / y, 1 std)"
             if "target_normal_x_deg" in std else "")
    lean = (f" toward azimuth {geo['target_tilt_azimuth_deg']:.2f} deg"
            if "target_tilt_azimuth_deg" in geo else "")
    page.paragraph(f"stage tilt {geo['stage_tilt_deg']:.4f} deg, target tilt "
                   f"{geo['target_tilt_deg']:.4f} deg{lean}{known}, focal length "
                   f"{geo['focal_px']:.2f} px, corner RMS {geo['rms_px']:.3f} px. Not fitted: "
                   + ("; ".join(held) if held else "nothing") + ".")
    if "marker_error" in geo:
        _marker_error(page, geo["marker_error"])
    if not geo.get("principal_point_fitted", True) and geo.get("decentring_fitted", False):
        page.paragraph("The sweep did not separate the principal point from the stage axis "
                       "(a lens that needs p1, p2): the table's volume may be sheared by a "
                       "few um over its depth (docs/calibration.rst, 'The marked target').",
                       note=True)
    page.table([{"parameter": k, "value": v, "std": std.get(k, "")}
                for k, v in (("focal_px", geo["focal_px"]),
                             ("cx_px", geo["principal_point_px"][0]),
                             ("cy_px", geo["principal_point_px"][1]),
                             *zip(("k1", "k2", "p1", "p2"), geo["distortion_k1_k2_p1_p2"],
                                  strict=True))])
