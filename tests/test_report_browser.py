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


def test_probe_sees_a_broken_image(chromium, tmp_path):
    """The check can fail: an image that does not decode has naturalWidth 0."""
    page = tmp_path / "page.html"
    page.write_text(f"<!DOCTYPE html><html><body><img alt='good' src='{GOOD_PNG}'>"
                    f"<img alt='broken' src='{BROKEN_PNG}'></body></html>", encoding="utf-8")
    images = {im["alt"]: im for im in loaded_images(chromium, page, tmp_path)}
    assert images["good"]["width"] == 1
    assert images["broken"]["width"] == 0
