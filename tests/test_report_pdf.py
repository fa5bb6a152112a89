"""The reports as PDF: rendered page by page with poppler's ``pdftoppm``, and read back
with ``pdftotext``: every section of the HTML, the verdict on the first page and the
header block are in it. Under ``SCANQA_REQUIRE_CLIENTS=1`` (``make test``, which
installs poppler-utils) a missing poppler fails the test instead of skipping it."""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from scanqa.cli import main
from scanqa.io.cloud import write_cloud

from .conftest import PAPER_CONFIG
from .test_gauge import LAYOUT, synthetic_cloud
from .test_qa_artefacts import BAR_A, BAR_B, CENTRE, ball, bar_cloud, cloud_of

REQUIRE_CLIENTS = os.environ.get("SCANQA_REQUIRE_CLIENTS") == "1"
HEADER_LABELS = ("Report id", "Date", "scanqa version", "Scanner config", "Calibration",
                 "Artefact certificate", "Data", "Operator", "Notes")


@pytest.fixture(scope="module")
def poppler() -> None:
    missing = [t for t in ("pdftoppm", "pdftotext", "pdfinfo") if not shutil.which(t)]
    if missing:
        message = (f"poppler-utils missing ({', '.join(missing)}); 'make test' installs it "
                   "(apt-get install poppler-utils)")
        if REQUIRE_CLIENTS:
            pytest.fail(message)
        pytest.skip(message)


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict:
    """An artefact report (a sphere and a ball bar in two scans) and a gauge-block
    report, both with --pdf, --operator and --notes."""
    d = tmp_path_factory.mktemp("pdf")
    rng = np.random.default_rng(11)
    sphere = cloud_of([ball(rng, CENTRE)[:2]])
    write_cloud(d / "p000_r0.ply", sphere.xyz, sphere.attributes)
    bar, _, _ = bar_cloud(rng)
    write_cloud(d / "p001_r0.ply", bar.xyz, bar.attributes)
    (d / "layout.toml").write_text(
        'format = "scanqa-artefact-layout/1"\n'
        '[[sphere]]\nid = "S1"\ndiameter_mm = 12.0\nscan = "p000"\n'
        f"centre_mm = [{CENTRE[0]}, {CENTRE[1]}, {CENTRE[2]}]\n"
        '[[ball_bar]]\nid = "P1"\ndiameter_mm = 12.0\nscan = "p001"\n'
        f"distance_mm = {np.linalg.norm(BAR_B - BAR_A):.6f}\n"
        "centre_a_mm = [-14.0, -12.0, 442.0]\ncentre_b_mm = [14.0, 12.0, 458.0]\n")
    (d / "spec.toml").write_text(
        'format = "scanqa-spec/1"\nname = "lab spec 7"\nmpe_pf_um = 60.0\nmpe_ps_um = 10.0\n'
        "mpe_sd_um = { a = 15.0, b = 1000.0 }\n"
        "[sphere]\ndiameter_mm = 12.0\ndiameter_uncertainty_um = 0.5\n"
        f"[ball_bar]\ndistance_mm = {np.linalg.norm(BAR_B - BAR_A):.6f}\n"
        "distance_uncertainty_um = 1.0\n")
    common = ["--operator", "Ada Tester", "--notes", "bench 3, 20.1 C", "--pdf"]
    assert main(["qa", str(d / "p000_r0.ply"), str(d / "p001_r0.ply"), "--layout",
                 str(d / "layout.toml"), "--spec", str(d / "spec.toml"), *common,
                 "--out", str(d / "artefact")]) == 0
    xyz, attrs, _ = synthetic_cloud()
    write_cloud(d / "gauge.ply", xyz, attrs)
    assert main(["qa", str(d / "gauge.ply"), "--layout", str(LAYOUT), "--config",
                 str(PAPER_CONFIG), *common, "--out", str(d / "gauge")]) == 0
    return {"artefact": d / "artefact", "gauge": d / "gauge"}


def pdf_text(pdf: Path, *pages: str) -> str:
    out = subprocess.run(["pdftotext", "-layout", *pages, str(pdf), "-"], capture_output=True,
                         text=True, check=True).stdout
    return re.sub(r"\s+", " ", out)


def headings(page_html: str) -> list[str]:
    return [html.unescape(h) for h in re.findall(r"<h2[^>]*>(.*?)</h2>", page_html)]


@pytest.mark.parametrize("which", ["artefact", "gauge"])
def test_pdf_renders_and_holds_every_section(poppler, reports, which, tmp_path):
    folder = reports[which]
    pdf = folder / "report.pdf"
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True,
                          check=True).stdout
    pages = int(re.search(r"Pages:\s+(\d+)", info).group(1))
    subprocess.run(["pdftoppm", "-r", "30", "-png", str(pdf), str(tmp_path / "page")],
                   check=True)
    images = sorted(tmp_path.glob("page*.png"))
    assert len(images) == pages >= 2
    for im in images:  # every page drawn: some dark ink on it
        assert imread(im)[..., :3].min() < 0.5, im
    text = pdf_text(pdf)
    sections = headings((folder / "report.html").read_text(encoding="utf-8"))
    assert len(sections) >= (8 if which == "artefact" else 5)
    for title in sections:
        assert re.sub(r"\s+", " ", title) in text, title
    for label in HEADER_LABELS:
        assert label in text, label
    assert "Ada Tester" in text and "bench 3, 20.1 C" in text
    first = pdf_text(pdf, "-f", "1", "-l", "1")
    assert re.search(r"\b(PASS|FAIL|UNDECIDED|INCOMPLETE|NOT EVALUATED) ", first)
    assert "Operator" in first
    # a lab signs it: the report id and the approval block on page 1
    report_id = re.search(r"SQA-[0-9a-f]{12}", (folder / "report.html").read_text()).group()
    assert report_id in first
    assert re.search(r"Prepared Ada Tester.*Reviewed.*Approved", first)
    # the plots are vector (SVG; dense scatters rasterised inside them)
    page_html = (folder / "report.html").read_text(encoding="utf-8")
    assert "data:image/svg+xml;base64," in page_html and "data:image/png" not in page_html


def test_the_artefact_pdf_names_the_certificate_and_the_calibration(poppler, reports):
    text = pdf_text(reports["artefact"] / "report.pdf")
    assert "lab spec 7: sphere D = 12.0000 mm, U = 0.5 um (k = 2)" in text
    assert "ball bar L =" in text and "sha256" in text
    gauge = pdf_text(reports["gauge"] / "report.pdf")
    assert "paper_scanner" in gauge  # the config given with --config, named and hashed
