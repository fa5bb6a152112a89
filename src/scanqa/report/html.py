"""A tiny self-contained HTML writer: a verdict banner, a header block, sections,
tables (with their secondary columns folded) and embedded SVG figures.

Rendering only; every number shown is computed elsewhere. The same page is the PDF
(:mod:`scanqa.report.pdf` prints it with WeasyPrint): the print rules in the style
sheet set the paper size, keep figures and table rows whole, and open the folded
columns, so that screen and paper show the same content.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Sequence

_STYLE = """
body{font-family:system-ui,'DejaVu Sans',sans-serif;margin:1.2em auto;max-width:1180px;
color:#222;padding:0 1em}
h1{font-size:1.45em;margin:0.2em 0 0.4em}h2{font-size:1.15em;border-bottom:1px solid #ccc;
margin-top:1.6em}
table{border-collapse:collapse;margin:0.5em 0;font-size:0.9em}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#f3f3f3}
td.l,th.l{text-align:left}img{max-width:100%}figure{margin:0.6em 0}
.note{color:#555;font-size:0.9em}.fail{color:#b00;font-weight:bold}.pass{color:#070}
.verdict{display:flex;align-items:center;gap:1.2em;border-radius:6px;padding:0.6em 1em;
margin:0.4em 0 0.8em;border:2px solid}
.verdict .word{font-size:2.1em;font-weight:bold;letter-spacing:0.04em}
.verdict .counts{font-size:1.05em}
.sigma-source{margin:0.5em 0;padding:0.4em 0.8em;border-left:4px solid #4a7}
.sigma-warning{border-left-color:#c60;background:#fff4e0}
.v-pass{background:#e7f6e7;border-color:#2a7a2a;color:#145214}
.v-fail{background:#fbe5e5;border-color:#b00;color:#8a0000}
.v-undecided,.v-incomplete{background:#fff4d6;border-color:#b07a00;color:#6b4a00}
.v-not-evaluated{background:#eef0f3;border-color:#777;color:#333}
table.header{font-size:0.88em;margin:0.2em 0 0.6em}table.header th{text-align:left;
width:11em}table.header td{text-align:left}
.scroll{overflow-x:auto;max-width:100%}
details.more{margin:0.2em 0 0.8em}details.more summary{cursor:pointer;color:#335;
font-size:0.9em}
@page{size:A4;margin:14mm 12mm 16mm;@bottom-right{content:"page " counter(page) " of "
counter(pages);font-size:8pt;color:#555}}
@media print{body{max-width:none;margin:0;padding:0;font-size:9pt}
h2,h2+p{break-after:avoid}figure,tr,.verdict,table.header{break-inside:avoid}
img{max-height:120mm}details.more summary{display:none}
table{font-size:8pt}td,th{padding:1px 4px}}
"""


#: Collections with more marks than this are drawn as an embedded raster inside the SVG
#: (axes, text and lines stay vector; a scatter of 10^5 points would make the page huge).
#: Each vector mark is one ``<use>`` that matplotlib writes and WeasyPrint then parses and
#: paints one by one (about 1.7 ms each): the demo's sphere map of ~2000 marks cost 3.3 s
#: of the PDF and 0.15 s of the SVG; as a raster 0.05 s. Only scatters of points reach
#: this (bars are patches, error bars a few segments).
MAX_VECTOR_MARKS = 200


def figure_data_uri(fig, dpi: int = 100) -> str:
    """SVG of a matplotlib figure as a data: URI (and close the figure): vector axes,
    text and curves, dense scatters and images rasterised at ``dpi`` inside it."""
    import matplotlib.pyplot as plt

    for ax in fig.axes:
        for coll in ax.collections:
            if len(coll.get_offsets()) > MAX_VECTOR_MARKS:
                coll.set_rasterized(True)
    buf = io.BytesIO()
    fig.tight_layout()
    # tight_layout leaves a placeholder layout engine, and savefig draws the whole figure
    # once more (rasterised scatters too) before printing when there is one: the layout
    # is done, so drop it - the same bytes from one draw instead of two
    fig.set_layout_engine(None)
    # a fixed salt for the SVG's element ids: the same figure gives the same bytes
    with plt.rc_context({"svg.hashsalt": "scanqa"}):
        fig.savefig(buf, format="svg", dpi=dpi, metadata={"Date": None})
    plt.close(fig)
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _cell(value: object) -> str:
    if isinstance(value, float):
        return "&ndash;" if not math.isfinite(value) else f"{value:.4g}"
    if value is None:
        return "&ndash;"
    return html.escape(str(value))


def _left(value: object) -> str:
    return ' class="l"' if isinstance(value, str) else ""


class Page:
    """An HTML page built section by section."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.parts: list[str] = [f"<h1>{html.escape(title)}</h1>"]
        self.headings: list[str] = []

    def banner(self, verdict: dict, what: str = "decisions") -> None:
        """The verdict first: PASS / FAIL / UNDECIDED / INCOMPLETE / NOT EVALUATED and
        the count of each decision (:func:`scanqa.qa.verdict.verdict`)."""
        word = verdict["verdict"]
        counts = ", ".join(f"{verdict[k]} {k}" for k in ("pass", "fail", "undecided",
                                                          "not evaluated"))
        cls = "v-" + word.lower().replace(" ", "-")
        self.parts.append(f'<div class="verdict {cls}" id="verdict"><span class="word">'
                          f'{html.escape(word)}</span> <span class="counts">'
                          f'{html.escape(what)}: {html.escape(counts)}</span></div>')

    def sigma_source(self, source: dict | None) -> None:
        """Where the per-point sigmas come from, on the first screen; an assumed sigma
        as a warning (:func:`scanqa.annotation.points.sigma_source`)."""
        source = source or {"kind": "unknown", "detail": "the cloud does not say (a cloud "
                            "from elsewhere or an older scanqa)", "warning": ""}
        warning = source.get("warning", "")
        cls = "sigma-source sigma-warning" if warning or source.get("kind") != \
            "characterised" else "sigma-source"
        text = f"Per-point sigma: {source.get('kind', 'unknown')} ({source.get('detail', '')})"
        if warning:
            text += f". WARNING: {warning}"
        if source.get("calibration"):
            text += f". Calibration term: {source['calibration']} "
            text += f"({source.get('calibration_detail', '')})"
        if source.get("calibration_warning"):
            cls = "sigma-source sigma-warning"
        self.parts.append(f'<div class="{cls}" id="sigma-source">{html.escape(text)}</div>')

    def header_block(self, items: Sequence[tuple[str, str]]) -> None:
        """The report's provenance as a two-column table (:mod:`scanqa.provenance`)."""
        rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                       for k, v in items)
        self.parts.append(f'<table class="header" id="header">{rows}</table>')

    def approval_block(self, prepared_by: str = "") -> None:
        """Prepared / reviewed / approved, each with name, date and signature to fill in
        (the preparer's name when the command line gave it)."""
        rows = "".join(
            f"<tr><th>{role}</th><td>{html.escape(name)}</td><td></td><td></td></tr>"
            for role, name in (("Prepared", prepared_by), ("Reviewed", ""),
                               ("Approved", "")))
        self.parts.append('<table class="header approval" id="approval"><tr><th></th>'
                          "<th>Name</th><th>Date</th><th>Signature</th></tr>"
                          f"{rows}</table>")

    def heading(self, text: str, anchor: str = "") -> None:
        ident = f' id="{html.escape(anchor)}"' if anchor else ""
        self.headings.append(text)
        self.parts.append(f"<h2{ident}>{html.escape(text)}</h2>")

    def paragraph(self, text: str, note: bool = False) -> None:
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")

    def table(self, rows: Sequence[dict], columns: Sequence[str] | None = None,
              details: Sequence[str] = (), key: Sequence[str] = (),
              labels: dict | None = None) -> None:
        """A table of ``columns``; ``details`` columns go into a second table (with the
        ``key`` columns that identify a row), folded on screen and printed below."""
        if not rows:
            self.paragraph("(no rows)", note=True)
            return
        self.parts.append(_table(rows, list(columns or rows[0]), labels or {}))
        if details:
            inner = _table(rows, [*key, *details], labels or {})
            self.parts.append(f'<details class="more"><summary>more columns: '
                              f'{html.escape(", ".join(details))}</summary>{inner}</details>')

    def figure(self, fig, caption: str = "", alt: str = "figure") -> None:
        uri = figure_data_uri(fig)
        cap = f"<figcaption class='note'>{html.escape(caption)}</figcaption>" if caption else ""
        self.parts.append(f"<figure><img alt='{html.escape(alt)}' src='{uri}'>{cap}</figure>")

    def render(self) -> str:
        return ("<!DOCTYPE html><html><head><meta charset='utf-8'>"
                "<meta name='viewport' content='width=device-width'>"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                f"<body>{''.join(self.parts)}</body></html>")


def _table(rows: Sequence[dict], cols: list[str], labels: dict) -> str:
    head = "".join(f"<th{_left(rows[0].get(c))}>{html.escape(labels.get(c, c))}</th>"
                   for c in cols)
    body = "".join("<tr>" + "".join(f"<td{_left(r.get(c))}>{_cell(r.get(c))}</td>"
                                    for c in cols) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><tr>{head}</tr>{body}</table></div>'
