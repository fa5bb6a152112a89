"""The design page in a real headless Chromium, driven by Playwright.

The page loads and shows the paper scanner's usable volume of ``scanqa design volume``; moving
a slider with the keyboard changes the drawn usable volume and the numbers, and records
its redraw time (how long a redraw takes is measured by benchmarks/bench_design_page.py,
not asserted here); the exported TOML (the page's download) loads in ``scanqa`` and
gives the numbers the page shows; loading a TOML in the page sets its inputs.

Skipped with the reason when Playwright or Chromium is missing; under
``SCANQA_REQUIRE_CLIENTS=1`` (``make test``, which installs both) that fails instead.
"""

from __future__ import annotations

import json
import os
import shutil
import threading

import pytest

from scanqa.cli import main
from scanqa.design import server

from .conftest import PAPER_CONFIG, paper_config_text

REQUIRE_CLIENTS = os.environ.get("SCANQA_REQUIRE_CLIENTS") == "1"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: Flags for a headless Chromium on a shared, GPU-less machine.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking"]


def _missing(message: str) -> None:
    if REQUIRE_CLIENTS:
        pytest.fail(message)
    pytest.skip(message)


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _missing("playwright is not installed (pip install 'scanqa[test]')")
    path = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if path is None:
        _missing("no Chromium on PATH (tried " + ", ".join(BROWSERS) + "); 'make test' "
                 "installs it (apt-get install chromium)")
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=path, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


@pytest.fixture()
def page(browser, paper_config):
    srv = server.make_server(paper_config)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    context = browser.new_context(accept_downloads=True, viewport={"width": 1400, "height": 900})
    tab = context.new_page()
    errors: list[str] = []
    tab.on("pageerror", lambda err: errors.append(str(err)))
    tab.goto(f"http://127.0.0.1:{srv.server_address[1]}/")
    settle(tab, 0)
    yield tab
    assert not errors, errors
    context.close()
    srv.shutdown()
    srv.server_close()


def settle(tab, after: int) -> None:
    """Wait until more than ``after`` redraws are done and none is pending."""
    tab.wait_for_function(
        f"Number(document.getElementById('redraw-ms').dataset.count || 0) > {after} "
        "&& !window.scanqaBusy()", timeout=120_000)


def redraws(tab) -> int:
    return int(tab.get_attribute("#redraw-ms", "data-count"))


def shown(tab, key: str) -> float:
    return float(tab.inner_text(f"#n-{key}"))


def usable_trace(tab) -> dict:
    """The drawn usable volume: its vertex count and Z range [mm]."""
    return tab.evaluate("""() => {
      const t = document.getElementById('scene').data.find(
        d => d.name.startsWith('usable volume'));
      return {n: t.x.length, zmin: Math.min(...t.z), zmax: Math.max(...t.z)}; }""")


def cli_volume(capsys, config: str, level: str = "0.49") -> dict:
    capsys.readouterr()
    assert main(["design", "volume", "--json", "--config", config, "--level", level]) == 0
    return json.loads(capsys.readouterr().out)


def test_page_loads_with_scanqa_volume_numbers(page, capsys):
    ref = cli_volume(capsys, str(PAPER_CONFIG))
    assert shown(page, "usable_cm3") == pytest.approx(ref["usable_mm3"] / 1e3, abs=5e-4)
    assert shown(page, "total_cm3") == pytest.approx(ref["total_mm3"] / 1e3, abs=5e-4)
    names = page.evaluate("() => document.getElementById('scene').data.map(d => d.name)")
    assert any(n.startswith("Cam") for n in names) and any(n.startswith("Proj") for n in names)
    assert "total volume" in names and float(page.get_attribute("#redraw-ms", "data-ms")) > 0


def test_slider_changes_the_volume_and_numbers_and_export_matches_scanqa(page, capsys,
                                                                         tmp_path):
    before, drawn = shown(page, "usable_cm3"), usable_trace(page)
    count = redraws(page)
    page.focus("#camera_f_number")
    for _ in range(30):  # f/8 -> f/11 in 0.1 steps, as a user's arrow keys would
        page.keyboard.press("ArrowRight")
    settle(page, count)
    assert page.input_value("#camera_f_number-n").startswith("11")
    after = shown(page, "usable_cm3")
    assert after > before  # a smaller aperture blurs less: a deeper usable volume
    assert usable_trace(page) != drawn
    with page.expect_download() as download:
        page.click("#export")
    path = tmp_path / "exported.toml"
    download.value.save_as(path)
    ref = cli_volume(capsys, str(path))
    assert after == pytest.approx(ref["usable_mm3"] / 1e3, abs=5e-4)


def test_loading_a_toml_sets_the_inputs(page, tmp_path):
    text = paper_config_text().replace("f_number = 8.0", "f_number = 16.0", 1)
    path = tmp_path / "f16.toml"
    path.write_text(text)
    count = redraws(page)
    page.set_input_files("#load", str(path))
    settle(page, count)
    assert page.input_value("#camera_f_number-n") == "16.0000"
    assert page.inner_text("#error") == ""


def test_a_toml_outside_the_ranges_is_refused_on_the_page(page, tmp_path):
    """The error names the setting and its range; the inputs keep the page's config."""
    text = PAPER_CONFIG.read_text().replace("f_number = 8.0", "f_number = 45.0", 1)
    path = tmp_path / "f45.toml"
    path.write_text(text)
    before = page.input_value("#camera_f_number-n")
    page.set_input_files("#load", str(path))
    page.wait_for_function("document.getElementById('error').textContent !== ''",
                           timeout=60_000)
    assert "camera_f_number must be in [1.4, 32]" in page.inner_text("#error")
    assert page.input_value("#camera_f_number-n") == before
