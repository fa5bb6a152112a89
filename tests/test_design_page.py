"""The design page's server (``scanqa design page``) through its HTTP endpoints.

The numbers the page shows must be ``scanqa volume``'s for the same thresholds (Fig. 6:
A_c A_p >= 0.49, c_c < 0.030 mm), and the TOML it exports must load in ``scanqa`` and
give the same numbers. The browser side is tests/test_design_browser.py.
"""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request

import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.model import rig
from scanqa.runs import designapp

from .conftest import PAPER_CONFIG


@pytest.fixture(scope="module")
def server(paper_config):
    srv = designapp.make_server(paper_config)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}"
    srv.shutdown()
    srv.server_close()


def post(url: str, body: str) -> bytes:
    req = urllib.request.Request(url, data=body.encode(), method="POST")
    with urllib.request.urlopen(req, timeout=120) as resp:
        return resp.read()


def cli_volume(capsys, *argv) -> dict:
    capsys.readouterr()
    assert main(["volume", "--json", *argv]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("cut", [False, True])
def test_page_numbers_are_scanqa_volume(server, capsys, cut):
    payload = json.loads(post(server + "/api/view", json.dumps({"coc_cuts_volume": cut})))
    extra = ["--coc-max", "0.030"] if cut else []
    ref = cli_volume(capsys, "--config", str(PAPER_CONFIG), "--level", "0.49", *extra)
    assert payload["numbers"]["usable_mm3"] == ref["usable_mm3"]
    assert payload["numbers"]["total_mm3"] == ref["total_mm3"]
    if not cut:  # the paper scanner's Fig. 6 volume (tests/test_design_volume.py)
        assert ref["usable_mm3"] == 92242.0


def test_exported_toml_loads_in_scanqa_with_the_same_numbers(server, capsys, tmp_path,
                                                            paper_config):
    settings = rig.settings_from_config(paper_config)
    settings.update(camera_f_number=11.0, angle_deg=15.0, baseline_mm=120.0, level=0.36)
    body = json.dumps({"settings": settings})
    page = json.loads(post(server + "/api/view", body))["numbers"]
    path = tmp_path / "exported.toml"
    path.write_bytes(post(server + "/api/export", body))
    ref = cli_volume(capsys, "--config", str(path), "--level", "0.36")
    assert (page["usable_mm3"], page["total_mm3"]) == (ref["usable_mm3"], ref["total_mm3"])
    # a different scanner than the paper's: the change reached the model
    assert ref["usable_mm3"] != 92242.0
    loaded = json.loads(post(server + "/api/load", path.read_text()))["settings"]
    for key in ("camera_f_number", "angle_deg", "baseline_mm"):
        assert loaded[key] == pytest.approx(settings[key], rel=1e-12)  # round trip


def test_page_serves_html_and_plotly(server):
    with urllib.request.urlopen(server + "/", timeout=60) as resp:
        text = resp.read().decode()
    assert 'id="camera_f_number"' in text and "/plotly.min.js" in text
    with urllib.request.urlopen(server + "/plotly.min.js", timeout=60) as resp:
        assert b"plotly" in resp.read(200).lower()


@pytest.mark.parametrize(("body", "message"), [
    ({"settings": {"camera_f_number": 8.0}}, "missing setting"),
    ({"settings": {"bogus": 1.0}}, "unknown setting 'bogus'"),
])
def test_bad_settings_are_a_400_with_the_key(server, body, message):
    with pytest.raises(urllib.error.HTTPError) as err:
        post(server + "/api/view", json.dumps(body))
    assert err.value.code == 400
    assert message in json.loads(err.value.read())["error"]


def test_bad_toml_load_is_a_400(server):
    with pytest.raises(urllib.error.HTTPError) as err:
        post(server + "/api/load", "[camera\nfocal_mm = ")
    assert "not valid TOML" in json.loads(err.value.read())["error"]


def test_settings_round_trip_through_a_config(paper_config):
    settings = rig.settings_from_config(paper_config)
    again = rig.settings_from_config(rig.apply_settings(paper_config, settings))
    assert again == pytest.approx(settings, rel=1e-12)


def test_out_of_range_setting_names_key_and_range(paper_config):
    settings = rig.settings_from_config(paper_config)
    settings["camera_f_number"] = 99.0
    with pytest.raises(InputError, match=r"camera_f_number must be in \[1.4, 32\]"):
        rig.check_settings(settings)


def test_rig_view_draws_the_scanner(paper_config):
    view = rig.rig_view(paper_config)
    verts, tris = view.total_mesh
    assert len(tris) >= 4 and verts[:, 2].min() >= view.volume.z_min_mm - 1e-6
    uverts, _ = view.usable_mesh
    n = view.numbers
    # the usable picture lies within the usable depth's range, to a coarse voxel
    assert n["usable_near_mm"] < paper_config.camera.focus_mm < n["usable_far_mm"]
    assert view.camera_pyramid.shape == view.projector_pyramid.shape == (5, 3)
    assert uverts.size and n["coc_near_mm"] < 450.0 < n["coc_far_mm"]


def test_cli_serves_the_page_until_interrupted(capsys, monkeypatch):
    served = []

    def interrupted(server, *args, **kwargs):
        served.append(server.state.settings)
        raise KeyboardInterrupt

    monkeypatch.setattr(designapp.ThreadingHTTPServer, "serve_forever", interrupted)
    assert main(["design", "page", "--config", str(PAPER_CONFIG), "--port", "0",
                 "--no-browser", "--level", "0.36"]) == 0
    assert "scanqa design page: http://127.0.0.1:" in capsys.readouterr().out
    assert served[0]["level"] == 0.36 and served[0]["coc_max_mm"] == 0.030


def test_cli_refuses_a_level_outside_the_page_range(capsys):
    assert main(["design", "page", "--config", str(PAPER_CONFIG), "--port", "0",
                 "--no-browser", "--level", "1.5"]) == 2
    assert "level must be in [0.05, 0.95]" in capsys.readouterr().err


def test_page_opens_on_a_dlp_scanner_with_long_fringes(capsys, monkeypatch):
    """calib/slstudio_example.toml: 114 px fringes on a 5.4 um DLP (the period range once
    stopped at 64 px); the page's settings pass their own check."""
    config = PAPER_CONFIG.parent / "slstudio_example.toml"
    served = []

    def interrupted(server, *args, **kwargs):
        served.append(server.state.settings)
        raise KeyboardInterrupt

    monkeypatch.setattr(designapp.ThreadingHTTPServer, "serve_forever", interrupted)
    assert main(["design", "page", "--config", str(config), "--port", "0",
                 "--no-browser"]) == 0
    assert served[0]["period_px"] == 114.0
    assert rig.check_settings(served[0])["period_px"] == 114.0
