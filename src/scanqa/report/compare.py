"""The comparison report: the statistics, a colour map of the deviations and of their
significance, and a histogram (rendering only; :mod:`scanqa.qa.compare` computes)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from scanqa.io.atomic import staged_dir, write_text
from scanqa.qa.compare import Comparison
from scanqa.qa.results import map_cell_mm
from scanqa.report.html import Page
from scanqa.report.plots import cell_map, new_figure


def render(result: Comparison) -> str:
    """The report as one self-contained HTML page."""
    info = result.summary()
    page = Page("scanqa comparison with a reference")
    if "verdict" in info:
        word = info["verdict"]
        page.banner({"verdict": word.upper(), "pass": int(word == "pass"),
                     "fail": int(word == "fail"), "undecided": int(word == "undecided"),
                     "not evaluated": int(word == "not evaluated")},
                    f"tolerance {info['tolerance_um']:g} um (ISO 14253-1, worst point)")
    page.sigma_source(info["sigma_source"])
    page.heading("Summary", "summary")
    rows = [{"quantity": k, "value": v} for k, v in info.items()
            if k not in ("format", "sigma_source", "notes", "alignment", "median_U_by_term_um",
                         "smallest_significant_deviation_um", "dominant_U_term")]
    page.table(rows, ["quantity", "value"])
    if "alignment" in info:
        _alignment(page, info["alignment"])
    if info.get("median_U_by_term_um"):
        _power(page, info)
    page.paragraph(f"Deviation along the reference surface's normal; u combines the scan's "
                   f"sigma_total (projected on the normal) with the reference's; a point is "
                   f"significant when |deviation| > U = {result.k:g} u.", note=True)
    a = result.cloud.attributes
    xyz = np.asarray(result.cloud.xyz)
    dev = np.asarray(a["deviation_um"], float)
    ok = np.isfinite(dev)
    if ok.any():
        page.heading("Maps", "maps")
        fig, cell = _maps(xyz[ok], dev[ok], np.asarray(a["significance"], float)[ok],
                          result.deviation_limit_um())
        page.figure(fig, "deviation [um] and significance |deviation| / U over the scan (X, Y "
                    f"in mm), on cells of {cell:.3g} mm (1.5 times the points' spacing): "
                    "each shows its last point", alt="deviation map")
    for note in result.notes:
        page.paragraph(note, note=True)
    return page.render()


def _alignment(page: Page, fit: dict) -> None:
    """The best fit's transform and its standard uncertainties (scanqa.qa.align)."""
    page.heading("Alignment", "alignment")
    axes = "xyz"
    rows = [{"motion": f"shift {a} of the centre", "value": f"{t:+.4f} mm",
             "u": f"{u:.3g} um"} for a, t, u in zip(axes, fit["centre_shift_mm"],
                                                    fit["u_translation_um"], strict=True)]
    rows += [{"motion": f"rotation {a}", "value": f"{r:+.5f} deg", "u": f"{u:.3g} mdeg"}
             for a, r, u in zip(axes, fit["rotation_vector_deg"], fit["u_rotation_mdeg"],
                                strict=True)]
    page.table(rows, ["motion", "value", "u"])
    page.paragraph(f"The reference was moved onto the scan by {fit['method']} "
                   f"({fit['region']}, {fit['points']} points, RMS {fit['rms_um']:.2f} um). "
                   "The shift is that of the reference point that lands on the fit points' "
                   f"centroid {tuple(round(c, 2) for c in fit['centre_mm'])} mm, the "
                   "rotations (a rotation vector) turn about it; summary.json has the 4 x 4 "
                   "matrix and the covariance. "
                   "Each point's u includes the deviation's uncertainty from the fit."
                   + (f" Barely fixed by the surface: {', '.join(fit['free_motions'])}."
                      if fit["free_motions"] else ""), note=True)


def _power(page: Page, info: dict) -> None:
    """What U is made of, and the smallest deviation the comparison can call significant."""
    page.heading("What U is made of", "u-by-term")
    terms = info["median_U_by_term_um"]
    page.table([{"term": name, "median U [um]": "not in the cloud" if v is None
                 else f"{v:.4g}"} for name, v in terms.items()], ["term", "median U [um]"])
    small = info["smallest_significant_deviation_um"]
    page.paragraph(f"U is dominated by the {info['dominant_U_term']} term. The smallest "
                   f"deviation this comparison can call significant: {small['median_point']:.4g}"
                   f" um at the median point, {small['best_5_percent']:.4g} um at the best 5 % "
                   "of points; smaller deviations are within the uncertainty whatever their "
                   "size.", note=info["dominant_U_term"] != "random")


def _maps(xyz: np.ndarray, dev: np.ndarray, significance: np.ndarray, lim: float):
    # every point enters the maps, as images of cells (a scatter of a real scan's 3.4e5
    # points took 20 s of CPU; a stride sample of 4e4 of them still 1 s per map)
    fig, ax = new_figure(3, 1, width=4.6, height=4.0)
    x, y = xyz[:, 0], xyz[:, 1]
    cell = map_cell_mm(x, y)
    m = cell_map(ax[0, 0], x, y, dev, cell, cmap="coolwarm", vmin=-lim, vmax=lim)
    fig.colorbar(m, ax=ax[0, 0], label="deviation [um]")
    m = cell_map(ax[0, 1], x, y, significance, cell, cmap="viridis", vmin=0, vmax=2)
    fig.colorbar(m, ax=ax[0, 1], label="|deviation| / U")
    for axis in ax[0, :2]:
        axis.set_aspect("equal")
        axis.invert_yaxis()
        axis.set_xlabel("X [mm]")
        axis.set_ylabel("Y [mm]")
    ax[0, 2].hist(dev, bins=80, color="#4a7")
    ax[0, 2].set_xlabel("deviation [um]")
    ax[0, 2].set_ylabel("points")
    return fig, cell


def write_outputs(result: Comparison, out_dir: str | os.PathLike) -> dict:
    """report.html, summary.json and cloud_compare.ply, published together."""
    info = result.summary()
    with staged_dir(out_dir) as out:
        write_text(Path(out) / "summary.json", json.dumps(info, indent=1))
        write_text(Path(out) / "report.html", render(result))
        result.cloud.write(Path(out) / "cloud_compare.ply")
    return info
