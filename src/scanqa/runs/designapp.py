"""The design page's local server (``scanqa design page``, Sect. 5.1 of the paper).

A small HTTP server from the standard library: ``GET /`` is the page, ``/plotly.min.js``
the Plotly bundle of the installed ``plotly`` package (no network), and three JSON
endpoints run the one Python model chain:

* ``POST /api/view`` ``{"settings": {...}, "coc_cuts_volume": bool}``: the figures, the
  grid and the numbers of :func:`scanqa.model.rig.rig_view` (``model_ms`` is its time);
* ``POST /api/export`` ``{"settings": {...}}``: the scanner config TOML every command
  reads (``--config``);
* ``POST /api/load`` (a TOML text): makes it the page's config and returns its settings.

Why not Dash, Panel or a Bokeh server: the page needs a rotatable 3D scene, which Bokeh
lacks without a compiled extension; Dash and Panel bring a web framework, a callback
layer and their own release cycles for what is one page, three requests and a model
that is already Python. plotly.js draws the scene and the curves; the standard library
serves them; the state is one config, so nothing else is needed, and the same endpoints
serve the tests, the benchmark and a future front end.
"""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from scanqa.errors import ConfigError, ScanQAError
from scanqa.io.tomlfile import dumps_toml, loads_toml
from scanqa.model import rig
from scanqa.model.config import ScannerConfig, config_from_dict
from scanqa.report import designpage

#: Largest request body the server reads [bytes].
MAX_BODY = 1_000_000


class DesignState:
    """The page's config (replaced by a load) and its thresholds; thread-safe."""

    def __init__(self, config: ScannerConfig, level: float = 0.49, coc_max_mm: float = 0.030):
        self._lock = threading.Lock()
        self.config = config
        self.settings = rig.settings_from_config(config, level, coc_max_mm)

    def view(self, body: dict) -> dict:
        """The payload of one redraw for the posted settings."""
        settings = body.get("settings", self.settings)
        with self._lock:
            config = rig.apply_settings(self.config, settings)
        values = rig.check_settings(settings)
        t0 = time.perf_counter()
        view = rig.rig_view(config, values["level"], values["coc_max_mm"],
                            bool(body.get("coc_cuts_volume", False)))
        payload = designpage.view_payload(view, values)
        payload["model_ms"] = 1e3 * (time.perf_counter() - t0)
        return payload

    def export(self, body: dict) -> str:
        """The config TOML of the posted settings."""
        with self._lock:
            config = rig.apply_settings(self.config, body.get("settings", self.settings))
        header = "# scanner config exported by scanqa design page\n"
        return header + dumps_toml(rig.config_toml_dict(config))

    def load(self, text: str) -> dict:
        """Make a config TOML the page's config; its settings (thresholds kept)."""
        data = loads_toml(text.encode("utf-8"), "the loaded scanner config", ConfigError)
        config = config_from_dict(data, source="<loaded TOML>")
        with self._lock:
            self.config = config
            self.settings = rig.settings_from_config(config, self.settings["level"],
                                                     self.settings["coc_max_mm"])
            return {"settings": self.settings}


def _handler(state: DesignState, title: str) -> type[BaseHTTPRequestHandler]:
    """A request handler class bound to one state."""

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args) -> None:  # quiet: the terminal shows the URL only
            pass

        def _send(self, code: int, body: bytes, ctype: str, cache: bool = False) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
            self.end_headers()
            try:
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the browser went away (a reload, a closed tab): nothing to answer

        def do_GET(self) -> None:
            if self.path in ("/", "/index.html"):
                page = designpage.page_html(state.settings, title)
                self._send(200, page.encode(), "text/html; charset=utf-8")
            elif self.path == "/favicon.ico":
                self._send(204, b"", "image/x-icon")
            elif self.path == "/plotly.min.js":
                self._send(200, _plotly_js(), "text/javascript", cache=True)
            else:
                self._send(404, b"not found", "text/plain")

        def do_POST(self) -> None:
            length = int(self.headers.get("Content-Length") or 0)
            if length > MAX_BODY:
                self._send(413, b'{"error": "request too large"}', "application/json")
                return
            text = self.rfile.read(length).decode("utf-8", "replace")
            try:
                if self.path == "/api/view":
                    out = designpage.dumps_payload(state.view(json.loads(text or "{}")))
                elif self.path == "/api/export":
                    self._send(200, state.export(json.loads(text or "{}")).encode(),
                               "application/toml")
                    return
                elif self.path == "/api/load":
                    out = json.dumps(state.load(text))
                else:
                    self._send(404, b'{"error": "not found"}', "application/json")
                    return
            except (ScanQAError, ValueError) as err:
                self._send(400, json.dumps({"error": str(err)}).encode(), "application/json")
                return
            self._send(200, out.encode(), "application/json")

    return Handler


_PLOTLY: list[bytes] = []


def _plotly_js() -> bytes:
    """plotly.js from the installed plotly package, read once."""
    if not _PLOTLY:
        from plotly.offline import get_plotlyjs  # the optional [design] extra
        _PLOTLY.append(get_plotlyjs().encode())
    return _PLOTLY[0]


def make_server(config: ScannerConfig, host: str = "127.0.0.1", port: int = 0,
                level: float = 0.49, coc_max_mm: float = 0.030) -> ThreadingHTTPServer:
    """A server for the design page (not started; ``port=0`` picks a free port).

    Parameters
    ----------
    config : ScannerConfig
        The scanner config the page starts from.
    host : str
        Interface to listen on; the default serves this machine only.
    port : int
        TCP port; 0 for any free one (``server.server_address[1]``).
    level : float
        Combined attenuation threshold the page starts with [-].
    coc_max_mm : float
        Camera circle-of-confusion threshold the page starts with [mm].

    Returns
    -------
    ThreadingHTTPServer
        Call ``serve_forever()``; ``server.state`` is its :class:`DesignState`.
    """
    state = DesignState(config, level, coc_max_mm)
    rig.apply_settings(config, state.settings)  # refuse a config the page cannot show
    server = ThreadingHTTPServer((host, port), _handler(state, config.name or "scanner"))
    server.daemon_threads = True
    server.state = state
    return server
