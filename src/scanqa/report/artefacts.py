"""The VDI/VDE 2634-2 acceptance report: HTML (and the same page as PDF), CSV tables and a
JSON summary.

Rendering only: every number comes from :func:`scanqa.qa.artefacts.run_artefact_qa`;
the header block from :func:`scanqa.provenance.build_header`. Sections, in order: the
verdict, the header, results (one row per quantity), form predicted vs measured,
sphere spacing over the ball-bar positions, residuals, uncertainty budget, point
selection, method, notes.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from scanqa.io.atomic import staged_dir, write_text
from scanqa.provenance import ReportHeader
from scanqa.qa.artefacts import ArtefactQAResult
from scanqa.report.html import Page
from scanqa.report.plots import new_figure
from scanqa.report.qa import csv_text

#: Columns of quantities.csv, and the report's main and folded columns.
QUANTITY_COLUMNS = ("scan", "artefact", "kind", "quantity", "name", "value_um", "U_test_um",
                    "mpe_um", "decision", "U_um", "u_points_um", "k", "predicted_um",
                    "bias_um", "length_mm", "measured_mm", "n_points", "n_dropped",
                    "noise_corr_factor", "minimum_zone_um", "decided_with", "note")
MAIN_COLUMNS = ("scan", "artefact", "quantity", "value_um", "U_test_um", "mpe_um", "decision",
                "U_um")
DETAIL_COLUMNS = ("measured_mm", "u_points_um", "predicted_um", "minimum_zone_um", "bias_um",
                  "n_points",
                  "n_dropped", "noise_corr_factor", "note")
LABELS = {"value_um": "E [um]", "U_test_um": "U test [um]", "mpe_um": "MPE [um]",
          "U_um": "U [um]", "u_points_um": "u points [um]", "predicted_um": "predicted [um]",
          "bias_um": "bias [um]", "n_points": "points", "n_dropped": "dropped",
          "noise_corr_factor": "kappa", "u_um": "u [um]",
          "minimum_zone_um": "min. zone [um]", "measured_mm": "fitted size [mm]"}
BUDGET_COLUMNS = ("scan", "artefact", "quantity", "component", "u_um", "enters")


def write_outputs(result: ArtefactQAResult, out_dir: str | os.PathLike,
                  header: ReportHeader, pdf: bool = False) -> dict:
    """Write report.html (and report.pdf), quantities.csv, budget.csv, selection.csv and
    summary.json into ``out_dir``; returns the summary. The files are published together
    or not at all (:func:`scanqa.io.atomic.staged_dir`)."""
    with staged_dir(out_dir) as out:
        info = {**result.summary(), "header": header.row()}
        write_text(out / "quantities.csv", csv_text(result.rows(), QUANTITY_COLUMNS))
        write_text(out / "budget.csv", csv_text([r for a in result.results for r in a.budget()],
                                                BUDGET_COLUMNS))
        sel = info["selections"]
        cols = tuple(dict.fromkeys(k for row in sel for k in row))
        write_text(out / "selection.csv", csv_text([{c: row.get(c, "") for c in cols}
                                                    for row in sel], cols))
        write_text(out / "summary.json", json.dumps(info, indent=1))
        page = render(result, header)
        write_text(out / "report.html", page)
        if pdf:
            from scanqa.report.pdf import write_pdf

            write_pdf(page, out / "report.pdf")
    return info


def render(result: ArtefactQAResult, header: ReportHeader) -> str:
    """The acceptance report as one self-contained HTML page."""
    page = Page("scanqa acceptance test report (VDI/VDE 2634-2)")
    page.banner(result.verdict(), "decisions (ISO 14253-1)")
    page.sigma_source(result.sigma_source)
    page.header_block(header.items())
    page.approval_block(header.operator)
    _results(page, result)
    _form(page, result)
    _spacing(page, result)
    _residuals(page, result)
    _budget(page, result)
    _selection(page, result)
    _method(page, result)
    page.heading("Notes", "notes")
    for note in result.notes or ("none",):
        page.paragraph(note, note=True)
    return page.render()


def _results(page: Page, result: ArtefactQAResult) -> None:
    page.heading("Results", "results")
    spec = result.spec
    page.paragraph("E is the test value; U test the expanded uncertainty of the test (the "
                   "artefact's certificate and form), which the decision uses; U the "
                   "expanded uncertainty of E as a measurement of the scanner's "
                   "characteristic (adds its predicted scan-to-scan spread and the fits' "
                   "bias). Decision rule ISO 14253-1: pass when |E| <= MPE - U test, fail "
                   "when |E| > MPE + U test."
                   + ("" if result.options.decide_with == "test" else
                      " This report decides with U instead of U test (--decide-with total).")
                   + (f" MPEs and certificates: {spec.name}." if spec is not None else
                      " No spec was given: nothing is decided."))
    rows = [{**r, "measured_mm": f"{r['measured_mm']:.4f}"} if math.isfinite(r["measured_mm"])
            else r for r in result.rows()]  # a diameter to 0.1 um, not 4 digits
    page.table(rows, MAIN_COLUMNS, DETAIL_COLUMNS, ("scan", "artefact", "quantity"), LABELS)


def _form(page: Page, result: ArtefactQAResult) -> None:
    rows = [r for r in result.rows() if r["quantity"] in ("PF", "F")]
    if not rows:
        return
    page.heading("Form: predicted and measured", "form")
    page.paragraph("The predicted range is the expected PF or F of noise alone from the "
                   "per-point sigmas (0.3 % rule included); the measured one adds the "
                   "artefact's form and any systematic error of the scanner.", note=True)
    fig, ax = new_figure()
    x = np.arange(len(rows))
    a = ax[0][0]
    a.bar(x - 0.2, [r["value_um"] for r in rows], 0.4, label="measured")
    a.bar(x + 0.2, [r["predicted_um"] for r in rows], 0.4, label="predicted")
    a.set_xticks(x, [f"{r['quantity']} {r['artefact']}\n{r['scan']}" for r in rows],
                 fontsize=7)
    a.set(ylabel="form (range of residuals) [um]", title="PF and F: measured vs predicted")
    a.legend()
    page.figure(fig, "measured and predicted form per scan", "form")


def _spacing(page: Page, result: ArtefactQAResult) -> None:
    sd = [(r, q) for r in result.results for q in r.quantities if q.name == "SD"
          and math.isfinite(q.value)]
    if not sd:
        return
    page.heading("Sphere spacing over the positions", "spacing")
    fig, ax = new_figure()
    a = ax[0][0]
    x = np.arange(len(sd))
    a.errorbar(x, [1e3 * q.value for _, q in sd], yerr=[1e3 * q.expanded for _, q in sd],
               fmt="o", capsize=4, label="SD with U")
    a.errorbar(x + 0.15, [1e3 * q.value for _, q in sd],
               yerr=[1e3 * q.expanded_test for _, q in sd], fmt="none", capsize=2,
               color="C2", label="U test")
    mpe = [1e3 * q.mpe for _, q in sd]
    if all(math.isfinite(m) for m in mpe):
        a.plot(x, mpe, "r--", lw=0.8, label="+- MPE")
        a.plot(x, [-m for m in mpe], "r--", lw=0.8)
    a.axhline(0, color="0.5", lw=0.8)
    a.set_xticks(x, [f"{r.spec.id}\n{r.scan}" for r, _ in sd], fontsize=7)
    a.set(xlabel="ball-bar position", ylabel="SD = measured - calibrated distance [um]",
          title="sphere-spacing error per position")
    a.legend(fontsize=8)
    page.figure(fig, "SD of each position with its U and U test, and the MPE", "spacing")


def _residuals(page: Page, result: ArtefactQAResult) -> None:
    firsts = {}
    for r in result.results:
        firsts.setdefault(r.spec.kind, r)
    if not firsts:
        return
    page.heading("Residuals", "residuals")
    for kind, r in firsts.items():
        pts, res = r.residuals()
        fig, ax = new_figure(width=6.4, height=3.8)
        a = ax[0][0]
        lim = r.residual_limit_um()
        sc = a.scatter(pts[:, 0], pts[:, 1], c=1e3 * res, s=2, cmap="RdBu_r", vmin=-lim,
                       vmax=lim)
        fig.colorbar(sc, ax=a, label="residual [um]")
        a.set(xlabel="X [mm]", ylabel="Y [mm]", aspect="equal",
              title=f"{kind.replace('_', ' ')} {r.spec.id} ({r.scan}): residuals")
        a.invert_yaxis()
        page.figure(fig, "distances of the selected points from the fitted "
                    + ("plane" if kind == "flat" else "sphere(s)") + ", seen along Z",
                    f"residuals {kind}")


def _budget(page: Page, result: ArtefactQAResult) -> None:
    page.heading("Uncertainty budget", "budget")
    page.paragraph("Standard uncertainties of each quantity by component (um); 'test' "
                   "components make U test, the decision's; the others add the scanner's "
                   "own noise for U. The fits' bias adds linearly to U.", note=True)
    rows = [r for a in result.results for r in a.budget()]
    page.table(rows, BUDGET_COLUMNS, labels=LABELS)


def _selection(page: Page, result: ArtefactQAResult) -> None:
    page.heading("Point selection", "selection")
    info = result.summary()["selections"]
    cols = list(dict.fromkeys(k for row in info for k in row))
    page.table([{c: row.get(c, "") for c in cols} for row in info], cols)
    o = result.options
    page.paragraph(
        f"Steps: search near each artefact, points on its surface (shell "
        f"{'5 % of the diameter' if o.shell_mm is None else f'{o.shell_mm:g} mm'}), points "
        f"seen at more than {o.max_incidence_deg:g} deg removed (scanqa's rule), ball-bar "
        f"mounting cones removed (+{o.mount_margin_deg:g} deg), a flat's edges removed "
        f"({o.margin_mm:g} mm), then the guideline's {100 * o.drop_fraction:g} % rule "
        f"(PF, PS, F; SD {100 * o.sd_drop_fraction:g} %).", note=True)


def _method(page: Page, result: ArtefactQAResult) -> None:
    page.heading("Method", "method")
    o = result.options
    page.paragraph(
        "PF: range of the radial distances from the least-squares sphere; PS: its "
        "diameter minus the calibrated one; SD: the distance of the least-squares centres "
        "minus the calibrated one, per position; F: range of the distances from the "
        "least-squares plane. Per-point sigmas from the optics model, scaled for oblique "
        f"views ({o.oblique}); fits' covariances scaled by the noise-correlation factor "
        f"measured over {o.tile_mm:g} mm cubes; k = {o.k:g}; cap coverage of every sphere "
        f"at least {100 * o.min_coverage:.0f} % of a hemisphere. The minimum-zone form "
        "(thinnest shell or slab holding the kept points) is shown beside PF and F.",
        note=True)
