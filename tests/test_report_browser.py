"""The gauge-block QA report opens in headless Chromium with every plot shown.

The report is made by ``scanqa qa`` (with ``--config``, so it has the model's W curve)
from a synthetic cloud of the paper's artefact in which block 1 lies outside the
calibrated volume (no prediction: NaN bars). A small script injected before ``</body>``
lists every ``<img>`` after the load event (complete, naturalWidth, naturalHeight) in a
``<pre>`` that ``chromium --dump-dom`` prints. Under ``SCANQA_REQUIRE_CLIENTS=1`` (set by
``make test``, which installs chromium) a missing browser fails the test instead of
skipping it.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.io.cloud import write_cloud

from .conftest import PAPER_CONFIG
from .test_gauge import LAYOUT, synthetic_cloud

REQUIRE_CLIENTS = os.environ.get("SCANQA_REQUIRE_CLIENTS") == "1"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
PROBE_ID = "scanqa-probe"
PROBE = f"""<script>
window.addEventListener('load', function () {{
  var imgs = Array.prototype.slice.call(document.images).map(function (im) {{
    return {{alt: im.alt, complete: im.complete, width: im.naturalWidth,
            height: im.naturalHeight}};
  }});
  var pre = document.createElement('pre');
  pre.id = '{PROBE_ID}';
  pre.textContent = JSON.stringify(imgs);
  document.body.appendChild(pre);
}});
</script>"""
#: A 1 x 1 PNG, and bytes that are no image at all.
GOOD_PNG = ("data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42"
            "mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg==")
BROKEN_PNG = "data:image/png;base64,AAAA"


@pytest.fixture(scope="module")
def chromium() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    message = ("no Chromium on PATH (tried " + ", ".join(BROWSERS) + "); 'make test' "
               "installs it (apt-get install chromium)")
    if REQUIRE_CLIENTS:
        pytest.fail(message)
    pytest.skip(message)


def loaded_images(browser: str, page: Path, workdir: Path) -> list[dict]:
    """Open ``page`` headless with the probe injected; the <img> states after load."""
    probe = workdir / f"{page.stem}_probe.html"
    text = page.read_text(encoding="utf-8")
    assert "</body>" in text
    probe.write_text(text.replace("</body>", PROBE + "</body>"), encoding="utf-8")
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={workdir / 'profile'}",
           "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180, check=False)
    found = re.search(rf'<pre id="{PROBE_ID}">(.*?)</pre>', proc.stdout, re.S)
    assert found, (f"chromium printed no probe result (exit {proc.returncode}):\n"
                   f"{proc.stderr[-2000:]}")
    return json.loads(html.unescape(found.group(1)))


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    xyz, attrs, layout = synthetic_cloud()
    block1 = layout.blocks[0]
    x0, x1, y0, y1 = block1.region_mm
    on1 = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    attrs["in_volume"][on1] = 0.0
    attrs["model_valid"][on1] = 0.0
    attrs["sigma_model_um"][on1] = np.nan
    out = tmp_path_factory.mktemp("report")
    write_cloud(out / "cloud.ply", xyz, attrs)
    assert main(["qa", str(out / "cloud.ply"), "--layout", str(LAYOUT), "--config",
                 str(PAPER_CONFIG), "--out", str(out / "qa")]) == 0
    summary = json.loads((out / "qa" / "summary.json").read_text())
    assert summary["blocks"][0]["status"] == "outside_volume"
    return out / "qa" / "report.html"


def test_every_plot_of_the_qa_report_is_shown(chromium, report, tmp_path):
    expected = len(re.findall(r"<img\b", report.read_text(encoding="utf-8")))
    images = loaded_images(chromium, report, tmp_path)
    # the per-block bars, the W curve, the residual map and the step errors
    assert expected >= 4
    assert len(images) == expected
    for im in images:
        assert im["complete"] and im["width"] > 0 and im["height"] > 0, im


SCREEN = f"""<script>
window.addEventListener('load', function () {{
  var v = document.getElementById('verdict'), h = document.getElementById('header');
  var r = v ? v.getBoundingClientRect() : null, hr = h ? h.getBoundingClientRect() : null;
  var tables = Array.prototype.slice.call(document.querySelectorAll('table'));
  var pre = document.createElement('pre');
  pre.id = '{PROBE_ID}';
  pre.textContent = JSON.stringify({{
    width: window.innerWidth, height: window.innerHeight,
    verdict: r ? {{top: r.top, bottom: r.bottom, text: v.textContent}} : null,
    header: hr ? {{top: hr.top, bottom: hr.bottom}} : null,
    scroll_width: document.documentElement.scrollWidth,
    widest_table: Math.max.apply(null, tables.map(function (t) {{
      return t.getBoundingClientRect().right; }}))}});
  document.body.appendChild(pre);
}});
</script>"""


def first_screen(browser: str, page: Path, workdir: Path) -> dict:
    """Layout of ``page`` in a 1400 x 900 window: where the verdict and the header block
    are, and how wide the page and its widest table are."""
    probe = workdir / f"{page.stem}_screen.html"
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", SCREEN + "</body>"),
                     encoding="utf-8")
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
           "--hide-scrollbars", "--window-size=1400,900", "--disable-background-networking",
           f"--user-data-dir={workdir / 'profile'}", "--virtual-time-budget=10000",
           "--dump-dom", probe.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180, check=False)
    found = re.search(rf'<pre id="{PROBE_ID}">(.*?)</pre>', proc.stdout, re.S)
    assert found, f"no probe result (exit {proc.returncode}):\n{proc.stderr[-2000:]}"
    return json.loads(html.unescape(found.group(1)))


@pytest.fixture(scope="module")
def artefact_report(tmp_path_factory) -> Path:
    from .test_qa_artefacts import CENTRE, ball, cloud_of

    out = tmp_path_factory.mktemp("artefact_report")
    c = cloud_of([ball(np.random.default_rng(3), CENTRE)[:2]])
    write_cloud(out / "sphere.ply", c.xyz, c.attributes)
    (out / "layout.toml").write_text(
        'format = "scanqa-artefact-layout/1"\n[[sphere]]\nid = "S1"\ndiameter_mm = 12.0\n'
        f"centre_mm = [{CENTRE[0]}, {CENTRE[1]}, {CENTRE[2]}]\n")
    (out / "spec.toml").write_text(
        'format = "scanqa-spec/1"\nmpe_pf_um = 60.0\nmpe_ps_um = 10.0\n'
        "[sphere]\ndiameter_mm = 12.0\ndiameter_uncertainty_um = 0.5\n")
    assert main(["qa", str(out / "sphere.ply"), "--layout", str(out / "layout.toml"), "--spec",
                 str(out / "spec.toml"), "--operator", "A. Tester", "--out",
                 str(out / "qa")]) == 0
    return out / "qa" / "report.html"


@pytest.mark.parametrize("which", ["gauge", "artefact"])
def test_the_first_screen_shows_the_verdict(chromium, report, artefact_report, tmp_path,
                                            which):
    """A 1400 x 900 px window: the verdict banner lies wholly on the first screen (the
    viewport under the browser's bar), the header block
    starts on it, and no table runs past the window's right edge (the gauge-block table
    had 13 columns and hid its status column at this width)."""
    page = report if which == "gauge" else artefact_report
    screen = first_screen(chromium, page, tmp_path)
    # the window is 1400 x 900; its viewport is what is left under the browser's bar
    assert screen["width"] == 1400 and 700 <= screen["height"] <= 900, screen
    v = screen["verdict"]
    assert v is not None and 0 <= v["top"] < v["bottom"] <= screen["height"], v
    assert re.match(r"(PASS|FAIL|UNDECIDED|INCOMPLETE|NOT EVALUATED) ", v["text"]), v
    assert screen["header"] is not None and screen["header"]["top"] < screen["height"]
    assert screen["scroll_width"] <= 1400 and screen["widest_table"] <= 1400, screen


def test_the_probe_sees_a_verdict_below_the_fold(chromium, tmp_path):
    """The check can fail: a verdict after 1200 px of text is reported below 900 px."""
    page = tmp_path / "late.html"
    page.write_text("<!DOCTYPE html><html><body><div style='height:1200px'></div>"
                    "<div id='verdict'>PASS</div><table style='width:2000px'><tr><td>x</td>"
                    "</tr></table></body></html>", encoding="utf-8")
    screen = first_screen(chromium, page, tmp_path)
    assert screen["verdict"]["top"] > screen["height"] and screen["widest_table"] > 1400


def test_probe_sees_a_broken_image(chromium, tmp_path):
    """The check can fail: an image that does not decode has naturalWidth 0."""
    page = tmp_path / "page.html"
    page.write_text(f"<!DOCTYPE html><html><body><img alt='good' src='{GOOD_PNG}'>"
                    f"<img alt='broken' src='{BROKEN_PNG}'></body></html>", encoding="utf-8")
    images = {im["alt"]: im for im in loaded_images(chromium, page, tmp_path)}
    assert images["good"]["width"] == 1
    assert images["broken"]["width"] == 0
