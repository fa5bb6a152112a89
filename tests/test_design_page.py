"""The design page's server (``scanqa design page``) through its HTTP endpoints.

The numbers the page shows must be ``scanqa design volume``'s for the same thresholds (Fig. 6:
A_c A_p >= 0.49, c_c < 0.030 mm), and the TOML it exports must load in ``scanqa`` and
give the same numbers. The browser side is tests/test_design_browser.py.
"""

from __future__ import annotations

import http.client
import json
import socket
import threading
import urllib.error
import urllib.request

import pytest

from scanqa.cli import main
from scanqa.design import rig
from scanqa.design import server as designapp
from scanqa.errors import InputError

from .conftest import PAPER_CONFIG


@pytest.fixture(scope="module")
def served(paper_config):
    srv = designapp.make_server(paper_config)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield srv
    srv.shutdown()
    srv.server_close()
    assert srv.errors == []  # no request ended in a traceback


@pytest.fixture(scope="module")
def server(served):
    return f"http://127.0.0.1:{served.server_address[1]}"


def post(url: str, body: str) -> bytes:
    req = urllib.request.Request(url, data=body.encode(), method="POST",
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=120) as resp:
        return resp.read()


def cli_volume(capsys, *argv) -> dict:
    capsys.readouterr()
    assert main(["design", "volume", "--json", *argv]) == 0
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
    loaded = json.loads(post(server + "/api/load",
                             json.dumps({"toml": path.read_text()})))["settings"]
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
        post(server + "/api/load", json.dumps({"toml": "[camera\nfocal_mm = "}))
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


# ------------------------------------------------ requests the server refuses (issue 45)


def raw(srv, method: str, path: str, body: bytes = b"", headers: dict | None = None,
        host: str | None = None) -> tuple[int, dict]:
    """One request with exactly these headers; (status, the JSON or text answer)."""
    conn = http.client.HTTPConnection("127.0.0.1", srv.server_address[1], timeout=60)
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    conn.putheader("Host", host or f"127.0.0.1:{srv.server_address[1]}")
    for key, value in (headers or {}).items():
        conn.putheader(key, value)
    conn.endheaders(body)
    resp = conn.getresponse()
    data = resp.read()
    conn.close()
    try:
        return resp.status, json.loads(data)
    except ValueError:
        return resp.status, {"text": data.decode("utf-8", "replace")}


JSON = {"Content-Type": "application/json"}


def test_a_cross_site_text_plain_post_is_refused_and_the_config_kept(served):
    before = dict(served.state.settings)
    toml = PAPER_CONFIG.read_text().replace("f_number = 8.0", "f_number = 16.0", 1)
    body = json.dumps({"toml": toml}).encode()
    # what a form or a no-cors fetch of another site can send: text/plain, no preflight
    code, answer = raw(served, "POST", "/api/load", body,
                       {"Content-Type": "text/plain", "Content-Length": str(len(body))})
    assert code == 415 and "Content-Type must be application/json" in answer["error"]
    for extra in ({"Origin": "http://evil.example"}, {"Origin": "null"},
                  {"Sec-Fetch-Site": "cross-site"}):
        code, answer = raw(served, "POST", "/api/load", body,
                           {**JSON, "Content-Length": str(len(body)), **extra})
        assert code == 403 and "own page" in answer["error"], extra
    assert served.state.settings == before


@pytest.mark.parametrize(("method", "path"), [("GET", "/"), ("POST", "/api/export")])
def test_a_rebound_host_name_is_refused(served, method, path):
    port = served.server_address[1]
    body = b"{}" if method == "POST" else b""
    code, answer = raw(served, method, path, body, {**JSON, "Content-Length": str(len(body))},
                       host=f"attacker.example:{port}")
    assert code == 403 and "Host 'attacker.example:" in answer["error"]
    code, _ = raw(served, method, path, body, {**JSON, "Content-Length": str(len(body))},
                  host=f"localhost:{port}")  # the page's own names are served
    assert code == 200
    origin = {"Origin": f"http://localhost:{port}", "Sec-Fetch-Site": "same-origin"}
    code, _ = raw(served, method, path, body,  # what the browser sends from the page
                  {**JSON, "Content-Length": str(len(body)), **origin}, host=f"localhost:{port}")
    assert code == 200


@pytest.mark.parametrize(("length", "code", "message"), [
    ("-1", 400, "Content-Length must be a whole number"),
    ("abc", 400, "Content-Length must be a whole number"),
    (None, 411, "Content-Length is required"),
    ("99999999999", 413, "over the limit"),
])
def test_a_bad_content_length_is_refused(served, length, code, message):
    headers = dict(JSON) if length is None else {**JSON, "Content-Length": length}
    got, answer = raw(served, "POST", "/api/view", b"{}", headers)
    assert got == code and message in answer["error"]


@pytest.mark.parametrize(("body", "message"), [
    ("[1]", "must be a JSON object with 'settings' and 'coc_cuts_volume', got a JSON list"),
    ("null", "must be a JSON object"),
    ('{"settings": 5}', "settings must be an object of named numbers, got int"),
    ('{"settings": {"camera_f_number": "8"}}', "settings.camera_f_number must be a number"),
    ('{"settings": {"camera_f_number": 1e999}}', "settings.camera_f_number must be a finite"),
    ('{"settings": {"camera_f_number": ' + "9" * 400 + "}}", "must be a finite number"),
    ('{"coc_cuts_volume": "yes"}', "coc_cuts_volume must be true or false"),
    ('{"setings": {}}', "unknown field 'setings'"),
    ("[" * 200_000 + "]" * 200_000, "nested too deeply"),
    ("{", "not valid JSON"),
])
def test_a_malformed_body_is_a_400_naming_the_field(served, body, message):
    data = body.encode()
    code, answer = raw(served, "POST", "/api/view", data,
                       {**JSON, "Content-Length": str(len(data))})
    assert code == 400 and message in answer["error"]


def test_a_load_outside_the_page_ranges_is_refused_and_export_stays_a_config(served,
                                                                              tmp_path):
    toml = PAPER_CONFIG.read_text().replace("f_number = 8.0", "f_number = 45.0", 1)
    data = json.dumps({"toml": toml}).encode()
    code, answer = raw(served, "POST", "/api/load", data,
                       {**JSON, "Content-Length": str(len(data))})
    assert code == 400
    assert "outside the design page's ranges: camera_f_number must be in [1.4, 32]" \
        in answer["error"]
    code, answer = raw(served, "POST", "/api/load", b'{"toml": 5}',
                       {**JSON, "Content-Length": "11"})
    assert code == 400 and '{"toml": TEXT}' in answer["error"]
    before = served.state.config.camera.f_number
    # the page kept its config: an export is still a scanner config TOML
    code, answer = raw(served, "POST", "/api/export", b"{}", {**JSON, "Content-Length": "2"})
    path = tmp_path / "scanner.toml"
    path.write_text(answer["text"])
    assert code == 200 and "error" not in answer["text"]
    from scanqa.model.config import load_config
    assert load_config(path).camera.f_number == before != 45.0


def test_the_exported_page_never_saves_an_error_as_the_toml():
    from scanqa.design import page as designpage
    script = designpage.page_html({k: 1.0 for k in rig.SETTINGS}, "t")
    export = script[script.index("getElementById('export')"):script.index("getElementById('load')")]
    assert "if (!r.ok)" in export and export.index("r.ok") < export.index("a.download")
    assert script.count("headers: JSON_TYPE") == 3  # every POST is application/json


def serve(srv):
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


def test_a_silent_client_is_dropped(paper_config):
    srv = serve(designapp.make_server(paper_config, timeout_s=0.5))
    try:
        slow = socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=60)
        slow.sendall(b"GET / HTTP/1.1\r\n")  # and then nothing
        assert slow.recv(100) == b""  # closed by the server, not held for ever
        slow.close()
    finally:
        srv.shutdown()
        srv.server_close()
    assert srv.errors == []


def test_connections_over_the_cap_get_a_503_and_no_thread(paper_config):
    srv = serve(designapp.make_server(paper_config, max_connections=3))
    try:
        idle = []
        for _ in range(3):  # slow clients holding every slot
            sock = socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=60)
            sock.sendall(b"GET / HTTP/1.1\r\n")
            idle.append(sock)
        code, answer = raw(srv, "GET", "/")
        assert code == 503 and "too many connections" in answer["error"]
        threads = threading.active_count()
        assert all(raw(srv, "GET", "/favicon.ico")[0] == 503 for _ in range(20))
        assert threading.active_count() == threads  # a refused client costs no thread
        for sock in idle:
            sock.close()
        for _ in range(600):  # the slots come free as their threads see the close
            if raw(srv, "GET", "/favicon.ico")[0] == 204:
                break
        else:
            pytest.fail("the server did not serve again after the idle clients left")
    finally:
        srv.shutdown()
        srv.server_close()
    assert srv.errors == []


def test_cli_refuses_an_empty_host_and_warns_of_a_public_one(capsys, monkeypatch):
    assert main(["design", "page", "--config", str(PAPER_CONFIG), "--port", "0",
                 "--no-browser", "--host", ""]) == 2
    err = capsys.readouterr().err
    assert "--host '' would serve the design page on every network interface" in err
    assert "Traceback" not in err
    monkeypatch.setattr(designapp.ThreadingHTTPServer, "serve_forever",
                        lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["design", "page", "--config", str(PAPER_CONFIG), "--port", "0",
                 "--no-browser", "--host", "0.0.0.0"]) == 0
    assert "warning: --host 0.0.0.0 serves the design page beyond this machine" \
        in capsys.readouterr().err


def test_a_trickling_client_is_dropped(paper_config):
    """A header line every 0.2 s never lets the socket time out; the request's own
    deadline drops it."""
    import select

    srv = serve(designapp.make_server(paper_config, timeout_s=5.0, request_s=1.0))
    try:
        sock = socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=60)
        sock.sendall(b"GET / HTTP/1.1\r\n")
        closed = False
        for i in range(300):  # up to a minute of trickling
            if select.select([sock], [], [], 0.2)[0]:
                closed = sock.recv(100) == b""
                break
            try:
                sock.sendall(f"X-{i}: y\r\n".encode())
            except OSError:  # closed (reset) between the check and the send
                closed = True
                break
        sock.close()
        assert closed
    finally:
        srv.shutdown()
        srv.server_close()
    assert srv.errors == []


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
