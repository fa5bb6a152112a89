"""The gauge-block QA report: HTML with embedded plots, CSV tables and a JSON summary.

Rendering only: every number comes from :func:`scanqa.qa.blocks.run_qa`, the paper's
Table 3 beside it from :mod:`scanqa.qa.paper`.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from scanqa.io.atomic import staged_dir, write_text
from scanqa.provenance import ReportHeader
from scanqa.qa.blocks import QAResult
from scanqa.qa.paper import TABLE3_COLUMNS, paper_series, table3_rows
from scanqa.qa.verdict import verdict
from scanqa.report.html import Page
from scanqa.report.plots import cell_map, new_figure

BLOCK_COLUMNS = ("block_id", "nominal_height_mm", "n_points", "measured_std_um",
                 "measured_std_u_um", "predicted_std_um", "ratio", "flatness_um",
                 "mean_attenuation", "in_volume_fraction", "model_valid_fraction", "status")
STEP_COLUMNS = ("block_a", "block_b", "nominal_diff_mm", "measured_diff_mm", "error_um",
                "u_um", "nu_eff", "U_um", "k", "tolerance_um", "decision", "within_U")
BUDGET_COLUMNS = ("component", "type", "source", "u", "unit", "c_um_per_unit",
                  "contribution_um", "dof")
#: The block table of the report: main columns (fit a 1400 px screen and the page) and
#: the folded details.
BLOCK_MAIN = ("block_id", "nominal_height_mm", "n_points", "measured_std_um",
              "predicted_std_um", "ratio", "status")
BLOCK_DETAILS = ("flatness_um", "mean_attenuation", "in_volume_fraction", "noise_corr_factor")
#: Short column headers with units (the CSV keeps the field names).
LABELS = {"block_id": "block", "nominal_height_mm": "height [mm]", "n_points": "points",
          "measured_std_um": "measured std [um]", "predicted_std_um": "predicted std [um]",
          "paper_predicted_um": "paper pred. [um]", "paper_measured_um": "paper meas. [um]",
          "paper_ratio": "paper ratio",
          "flatness_um": "flatness [um]", "mean_attenuation": "attenuation",
          "in_volume_fraction": "in volume", "noise_corr_factor": "kappa",
          "block_a": "a", "block_b": "b", "nominal_diff_mm": "nominal [mm]",
          "measured_diff_mm": "measured [mm]", "error_um": "error [um]", "u_um": "u [um]",
          "U_um": "U [um]", "tolerance_um": "T [um]", "decision": "decision",
          "within_U": "|error| <= U"}


def csv_text(rows: list[dict], columns: tuple) -> str:
    """Rows as CSV text with the given columns (NaN as an empty cell), written by the
    ``csv`` module: a cell holding a comma, a quote or a line break is quoted, so every
    row has one cell per column for any CSV reader."""
    import csv
    import io

    def cell(v):
        if isinstance(v, float):
            return "" if not math.isfinite(v) else f"{v:.6g}"
        return str(v)

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([cell(r[c]) for c in columns] for r in rows)
    return buf.getvalue()


def write_outputs(result: QAResult, out_dir: str | os.PathLike,
                  header: ReportHeader | None = None, pdf: bool = False,
                  html: bool = True) -> dict:
    """Write report.html (and with ``pdf`` report.pdf), blocks.csv, steps.csv, budget.csv,
    summary.json and, when the result holds its cloud, cloud_qa.ply (the cloud plus the
    per-point QA fields) into ``out_dir``; returns the summary. ``html=False`` leaves
    out the reports (their plots take most of the time; ``scanqa batch --no-report``).
    The folder is created when missing; the files are published together or not at all
    (:func:`scanqa.io.atomic.staged_dir`)."""
    info = result.summary()
    with staged_dir(out_dir) as out:
        write_text(out / "blocks.csv", csv_text([b.row() for b in result.blocks],
                                                BLOCK_COLUMNS))
        write_text(out / "steps.csv", csv_text([s.row() for s in result.steps], STEP_COLUMNS))
        write_text(out / "budget.csv", csv_text(
            [{"block_a": s.block_a, "block_b": s.block_b, **c.row()}
             for s in result.steps if s.budget is not None for c in s.budget.components],
            ("block_a", "block_b", *BUDGET_COLUMNS)))
        write_text(out / "summary.json", json.dumps(info, indent=1))
        if html:
            page = render(result, header)
            write_text(out / "report.html", page)
        if html and pdf:
            from scanqa.report.pdf import write_pdf

            write_pdf(page, out / "report.pdf")
        cloud = result.annotated_cloud()
        if cloud is not None:
            cloud.write(out / "cloud_qa.ply")
    return info


def step_verdict(result: QAResult) -> dict:
    """The report's verdict: the decisions of the evaluated steps (a step with a flagged
    block is "not evaluated" and decides nothing)."""
    return verdict([s.decision for s in result.steps])


def render(result: QAResult, header: ReportHeader | None = None) -> str:
    """The QA report as one self-contained HTML page: the verdict first, then the header
    block (when given) and the sections."""
    page = Page("scanqa gauge-block QA report")
    page.banner(step_verdict(result), "height differences (ISO 14253-1)")
    page.sigma_source(result.summary()["sigma_source"])
    if header is not None:
        page.header_block(header.items())
        page.approval_block(header.operator)
    info = result.summary()
    _summary_section(page, result, info)
    _table3_section(page, result)
    _range_section(page, result, result.curve)
    if result.cloud is not None:
        _residual_section(page, result, result.cloud.xyz)
    _steps_section(page, result)
    _budget_section(page, result, info)
    if result.notes:
        page.heading("Notes", "notes")
        for note in result.notes:
            page.paragraph(note, note=True)
    return page.render()


def _k_text(k) -> str:
    return "k from each step's effective degrees of freedom (Welch-Satterthwaite, 95 %)" \
        if isinstance(k, str) else f"k = {k:g} (stated)"


def _summary_section(page: Page, result: QAResult, info: dict) -> None:
    page.heading("Summary", "summary")
    frac = info["fraction_within_U"]
    flagged = [f"{b.block_id} ({b.status})" for b in result.blocks if b.status != "ok"]
    dec = info["decisions"]
    page.paragraph(
        f"{len(result.blocks)} blocks: {info['blocks_ok']} inside the calibrated volume and "
        f"the model's validity, {info['blocks_flagged']} flagged"
        + (f" ({', '.join(flagged)})" if flagged else "") + f". {len(result.steps)} height "
        f"differences: {info['steps_evaluated']} evaluated, {info['steps_not_evaluated']} not "
        f"evaluated (a flagged block); {info['steps_error_within_U']} of the "
        f"{info['steps_evaluated']} evaluated have |error| <= U"
        + (f" ({100 * frac:.0f} %)" if frac is not None else "")
        + f". Decisions: {dec['pass']} pass, {dec['fail']} fail, {dec['undecided']} "
        f"undecided, {dec['not evaluated']} not evaluated.")
    default = " (the default; give --tolerance)" if result.settings.get(
        "tolerance_source") == "default" else ""
    page.paragraph(f"Edge margin {result.settings['margin_mm']:g} mm; tolerance T "
                   f"{result.settings['tolerance_um']:g} um{default}; "
                   f"{_k_text(result.settings['k'])}; "
                   "decision rule ISO 14253-1 (pass when |error| <= T - U, fail when "
                   "|error| > T + U); a block is flagged when more than "
                   f"{100 * result.settings['max_flagged_fraction']:g} % of its points lie "
                   "outside the calibrated volume or the model's validity.", note=True)
    if not info["type_b_included"]:
        page.paragraph("Type B is not included: no budget file was given, so U holds the "
                       "noise and calibration-table terms only (no gauge-block certificate, "
                       "temperature, stage scale or flatness of the calibration flat).")


def _table3_section(page: Page, result: QAResult) -> None:
    paper = bool(result.settings.get("paper_comparison"))
    page.heading("Per block: measured vs predicted std"
                 + (" (paper Table 3)" if paper else ""), "blocks")
    rows = table3_rows(result.blocks, paper)
    extra = TABLE3_COLUMNS if paper else ()
    page.table(rows, [*BLOCK_MAIN, *extra], BLOCK_DETAILS, ("block_id",), LABELS)
    tile = result.settings.get("tile_mm", 2.0)
    page.paragraph("noise_corr_factor: how many points share one noise draw, measured on the "
                   f"block over tiles of {tile:g} mm; the plane's uncertainty (and so each "
                   "step's u) is scaled by it.", note=True)
    fig, ax = new_figure()
    ids = [b.block_id for b in result.blocks]
    x = np.arange(len(ids))
    ax[0][0].bar(x - 0.2, [b.measured_std_um for b in result.blocks], 0.4, label="measured")
    ax[0][0].bar(x + 0.2, [b.predicted_std_um for b in result.blocks], 0.4, label="predicted")
    if paper:
        paper_p, paper_m = paper_series(ids)
        ax[0][0].plot(x, paper_p, "k^", label="paper predicted")
        ax[0][0].plot(x, paper_m, "kv", label="paper measured")
    ax[0][0].set_xticks(x, [str(i) for i in ids])
    ax[0][0].set(xlabel="block", ylabel="std of plane residuals [um]",
                 title="measured vs predicted std per block")
    ax[0][0].legend()
    page.figure(fig, "scanqa's measured and predicted std per block"
                + (", with the paper's Table 3" if paper else ""), "table3")


def _range_section(page: Page, result: QAResult, curve: dict | None) -> None:
    page.heading("Uncertainty over range with the blocks marked", "range")
    fig, ax = new_figure()
    a = ax[0][0]
    if curve is not None:
        ok = curve["model_valid"]
        a.plot(curve["z_mm"], np.where(ok, curve["sigma_um"], np.nan), color="0.5",
               label="model on the camera axis")
    for b in result.blocks:
        if math.isfinite(b.mean_z_mm):
            a.plot(b.mean_z_mm, b.measured_std_um, "o", color="C0")
            a.plot(b.mean_z_mm, b.predicted_std_um, "s", color="C1")
            a.annotate(str(b.block_id), (b.mean_z_mm, b.measured_std_um),
                       textcoords="offset points", xytext=(3, 3))
    a.plot([], [], "o", color="C0", label="measured")
    a.plot([], [], "s", color="C1", label="predicted")
    a.set(xlabel="Z [mm]", ylabel="std [um]", title="std over range (blocks numbered)")
    a.legend()
    page.figure(fig, "the W curve of the model and each block's measured/predicted std",
                "range")


def _residual_section(page: Page, result: QAResult, xyz: np.ndarray) -> None:
    page.heading("Residual maps", "residuals")
    fig, ax = new_figure(width=7.0, height=5.0)
    sel = (result.block_id >= 0) & np.isfinite(result.residual_um) \
        & np.isfinite(xyz[:, :2]).all(axis=1)
    cell = math.nan
    if sel.any():
        lim = result.residual_limit_um()
        x, y = xyz[sel, 0], xyz[sel, 1]
        cell = result.residual_map_cell_mm()
        im = cell_map(ax[0][0], x, y, result.residual_um[sel], cell, cmap="RdBu_r",
                      vmin=-lim, vmax=lim)
        fig.colorbar(im, ax=ax[0][0], label="residual to the block's plane [um]")
    ax[0][0].set(xlabel="X [mm]", ylabel="Y [mm]", aspect="equal",
                 title="plane residuals per block")
    ax[0][0].invert_yaxis()
    page.figure(fig, "residuals of every block's orthogonal plane fit"
                + (f", on cells of {cell:.3g} mm (1.5 times the points' spacing): each "
                   "shows the residual of its last point" if math.isfinite(cell) else ""),
                "residuals")


def _budget_section(page: Page, result: QAResult, info: dict) -> None:
    page.heading("Uncertainty budget per step (GUM)", "budget")
    page.paragraph("Each contribution is |c| u: the input's standard uncertainty u (in its "
                   "unit) times its sensitivity coefficient c (um per unit). Type A terms are "
                   "evaluated from the data with their degrees of freedom; Type B terms come "
                   "from the budget file (infinite degrees of freedom).", note=True)
    if not info["type_b_included"]:
        page.paragraph("Type B is not included (no budget file).", note=True)
    geometry = result.settings.get("calibration_geometry")
    page.paragraph(f"Calibration geometry: the covariance of the {geometry}, carried to "
                   "each step." if geometry else "Calibration geometry: not included (no "
                   "calibration covariance was given).", note=True)
    for s in result.steps:
        if s.budget is None:
            continue
        b = s.budget.summary()
        nu = b["nu_eff"]
        page.paragraph(f"Step {s.block_a}-{s.block_b}: u = {b['u_um']:.3g} um, nu_eff = "
                       + (f"{nu:.3g}" if nu is not None else "inf")
                       + f", k = {b['k']:.3g} ({b['k_rule']}), U = {b['U_um']:.3g} um"
                       + (f", reference corrected by {b['reference_correction_um']:+.3g} um"
                          if b["reference_correction_um"] else "")
                       + ("" if s.evaluated else f" - {s.note}") + ".")
        page.table(b["components"], list(BUDGET_COLUMNS))


def _steps_section(page: Page, result: QAResult) -> None:
    paper = bool(result.settings.get("paper_comparison"))
    page.heading("Height differences between successive blocks"
                 + (" (paper Table 4)" if paper else ""), "steps")
    page.table([s.row() for s in result.steps], list(STEP_COLUMNS), labels=LABELS)
    if paper:
        page.paragraph("The paper's Table 4 values are not legible in its text; it reports "
                       "that the biases stay below the single-point standard deviation.",
                       note=True)
    fig, ax = new_figure()
    labels = [f"{s.block_a}-{s.block_b}" for s in result.steps]
    x = np.arange(len(labels))
    for evaluated, style, label in ((True, "o", "error with U"),
                                    (False, "x", "not evaluated (flagged block)")):
        idx = [i for i, s in enumerate(result.steps) if s.evaluated == evaluated]
        if idx:
            ax[0][0].errorbar(x[idx], [result.steps[i].error_um for i in idx],
                              yerr=[result.steps[i].expanded_um for i in idx], fmt=style,
                              capsize=4, color="C0" if evaluated else "0.6", label=label)
    ax[0][0].axhline(0, color="0.5", lw=0.8)
    if result.steps:
        t = result.steps[0].tolerance_um
        ax[0][0].axhline(t, color="C3", ls="--", lw=0.8, label="tolerance")
        ax[0][0].axhline(-t, color="C3", ls="--", lw=0.8)
    ax[0][0].set_xticks(x, labels)
    ax[0][0].set(xlabel="blocks", ylabel="measured - nominal [um]",
                 title="step errors with expanded uncertainty")
    ax[0][0].legend()
    page.figure(fig, "height-difference errors with U bars", "steps")
