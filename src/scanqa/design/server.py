"""The design page's local server (``scanqa design page``, Sect. 5.1 of the paper).

A small HTTP server from the standard library: ``GET /`` is the page, ``/plotly.min.js``
the Plotly bundle of the installed ``plotly`` package (no network), and three JSON
endpoints run the one Python model chain:

* ``POST /api/view`` ``{"settings": {...}, "coc_cuts_volume": bool}``: the figures, the
  grid and the numbers of :func:`scanqa.design.rig.rig_view` (``model_ms`` is its time);
* ``POST /api/export`` ``{"settings": {...}}``: the scanner config TOML every command
  reads (``--config``);
* ``POST /api/load`` ``{"toml": TEXT}``: makes that scanner config TOML the page's config
  and returns its settings (refused, with the setting and its range, when the page cannot
  show it).

Every POST is JSON (``Content-Type: application/json``) from the page's own origin, for
this page's host name (:func:`make_server`, Notes); a bad request gets one JSON line
``{"error": ...}`` naming the field or header and its fix, never a traceback. Silent
connections are dropped after :data:`TIMEOUT_S`, a request still arriving after
:data:`REQUEST_S` (a client that trickles it byte by byte) too, and at most
:data:`MAX_CONNECTIONS` are served at once.

Why not Dash, Panel or a Bokeh server: the page needs a rotatable 3D scene, which Bokeh
lacks without a compiled extension; Dash and Panel bring a web framework, a callback
layer and their own release cycles for what is one page, three requests and a model
that is already Python. plotly.js draws the scene and the curves; the standard library
serves them; the state is one config, so nothing else is needed, and the same endpoints
serve the tests, the benchmark and a future front end.
"""

from __future__ import annotations

import contextlib
import io
import ipaddress
import json
import logging
import math
import select
import socket
import sys
import threading
import time
import traceback
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import urlsplit

from scanqa.design import page as designpage
from scanqa.design import rig
from scanqa.errors import ConfigError, InputError, ScanQAError
from scanqa.io.tomlfile import dumps_toml, loads_toml
from scanqa.model.config import ScannerConfig, config_from_dict

log = logging.getLogger(__name__)

#: Largest request body the server reads [bytes].
MAX_BODY = 1_000_000
#: Seconds a connection may stay silent (while its request line, headers or body are
#: read) before the server drops it [s].
TIMEOUT_S = 10.0
#: Seconds one request (its line, headers and body) may take to arrive in all [s].
REQUEST_S = 30.0
#: Connections served at once; one more is answered 503 and closed at once, so slow
#: clients cannot hold an unbounded number of threads.
MAX_CONNECTIONS = 16
#: Host names the page answers to besides IP literals and the ``--host`` given: a
#: request for any other name is a DNS-rebinding attempt (another site's name resolved
#: to this machine) and is refused.
LOCAL_NAMES = ("localhost", "localhost.localdomain")
#: The fields each endpoint reads from its JSON object.
FIELDS = {"/api/view": ("settings", "coc_cuts_volume"), "/api/export": ("settings",),
          "/api/load": ("toml",)}


class RequestError(ScanQAError):
    """A request the server refuses: its HTTP status and one line naming the fix."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


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
        """Make a config TOML the page's config; its settings (thresholds kept).

        Raises
        ------
        ConfigError
            Not a valid scanner config.
        InputError
            A valid config the page cannot show: one of its settings lies outside the
            page's range (:data:`scanqa.design.rig.SETTINGS`); the page's config is kept.
        """
        data = loads_toml(text.encode("utf-8"), "the loaded scanner config", ConfigError)
        config = config_from_dict(data, source="<loaded TOML>")
        settings = rig.settings_from_config(config, self.settings["level"],
                                            self.settings["coc_max_mm"])
        try:
            rig.apply_settings(config, settings)
        except ScanQAError as err:
            raise InputError(f"the loaded scanner config is outside the design page's "
                             f"ranges: {err}; edit that value in the file (the other "
                             "scanqa commands take any valid config)") from None
        with self._lock:
            self.config = config
            self.settings = settings
            return {"settings": self.settings}


def check_host(host: str) -> str:
    """A warning for a host that serves other machines ("" when it is this one).

    Raises
    ------
    InputError
        For an empty host, which would listen on every interface without saying so.
    """
    if not host.strip():
        raise InputError("host '' would serve the design page on every network interface: "
                         "give host 127.0.0.1 (this machine, the default), or 0.0.0.0 if "
                         "other machines must reach it")
    try:
        local = ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        local = host.lower() in LOCAL_NAMES
    if local:
        return ""
    return (f"host {host} serves the design page beyond this machine, with no "
            "authentication: anyone who reaches this port can load and export scanner "
            "configs; use host 127.0.0.1 unless that is intended")


def _host_name(value: str) -> str:
    """The name of a Host or Origin netloc, without port and brackets, lower case."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1:value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def _allowed_host(name: str, bound: str) -> bool:
    """Whether a request for host ``name`` may be served by a server bound to ``bound``."""
    if name in LOCAL_NAMES or name.endswith(".localhost") or name == bound.lower():
        return True
    try:
        ipaddress.ip_address(name)  # an address typed by the user, not a rebound name
    except ValueError:
        return False
    return True


def _number(key: str, value: object) -> float:
    """A setting's value as a float; raises :class:`RequestError` naming the key."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RequestError(400, f"settings.{key} must be a number, got {value!r:.60}")
    try:
        out = float(value)
    except OverflowError:
        out = math.inf
    if not math.isfinite(out):
        raise RequestError(400, f"settings.{key} must be a finite number, got "
                                f"{str(value)[:40]}")
    return out


def parse_body(path: str, text: str) -> dict:
    """The JSON object of a POST to ``path``, its fields type-checked.

    Raises
    ------
    RequestError
        400 naming the field: not JSON, nested too deep, not an object, an unknown
        field, ``settings`` not an object of numbers, ``coc_cuts_volume`` not a
        boolean, ``toml`` not a string.
    """
    try:
        body = json.loads(text) if text.strip() else {}
    except RecursionError:
        raise RequestError(400, f"POST {path}: the JSON body is nested too deeply") from None
    except ValueError as err:
        raise RequestError(400, f"POST {path}: the body is not valid JSON ({err})") from None
    fields = FIELDS[path]
    if not isinstance(body, dict):
        raise RequestError(400, f"POST {path}: the body must be a JSON object with "
                                f"{' and '.join(map(repr, fields))}, got a JSON "
                                f"{type(body).__name__}")
    unknown = sorted(set(body) - set(fields))
    if unknown:
        raise RequestError(400, f"POST {path}: unknown field {unknown[0][:60]!r} (known: "
                                f"{', '.join(fields)})")
    if "settings" in body:
        settings = body["settings"]
        if not isinstance(settings, dict):
            raise RequestError(400, f"POST {path}: settings must be an object of named "
                                    f"numbers, got {type(settings).__name__}")
        body["settings"] = {k: _number(k, v) if k in rig.SETTINGS else v
                            for k, v in settings.items()}
    if not isinstance(body.get("coc_cuts_volume", False), bool):
        raise RequestError(400, f"POST {path}: coc_cuts_volume must be true or false")
    if path == "/api/load" and not isinstance(body.get("toml"), str):
        raise RequestError(400, "POST /api/load: the body must be {\"toml\": TEXT} with the "
                                "scanner config TOML as a string")
    return body


class _DeadlineReader(io.RawIOBase):
    """A socket's reads that fail with :class:`TimeoutError` once ``deadline`` has passed
    (each read also waits at most ``timeout`` seconds)."""

    def __init__(self, sock: socket.socket, deadline: float, timeout: float):
        super().__init__()
        self._sock, self._deadline, self._timeout = sock, deadline, timeout

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        left = self._deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("the request took too long to arrive")
        self._sock.settimeout(min(self._timeout, left))
        return self._sock.recv_into(buffer)


def _handler(state: DesignState, title: str, bound: str, timeout_s: float,
             request_s: float) -> type[BaseHTTPRequestHandler]:
    """A request handler class bound to one state."""

    class Handler(BaseHTTPRequestHandler):
        timeout = timeout_s  # a silent client is dropped (StreamRequestHandler.setup)

        def setup(self) -> None:
            super().setup()  # a trickling client is dropped after request_s in all
            self.rfile = io.BufferedReader(_DeadlineReader(
                self.connection, time.monotonic() + request_s, timeout_s))

        def log_message(self, *args) -> None:  # quiet: the terminal shows the URL only
            pass

        def _send(self, code: int, body: bytes, ctype: str, cache: bool = False) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            try:
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError, TimeoutError):
                pass  # the browser went away (a reload, a closed tab): nothing to answer

        def _error(self, code: int, message: str) -> None:
            self._send(code, json.dumps({"error": message}).encode(), "application/json")

        def _check_origin(self) -> None:
            """Refuse requests for another host name (DNS rebinding) and, for POST,
            from another origin (a cross-site form or fetch)."""
            host = self.headers.get("Host")
            if not host or not _allowed_host(_host_name(host), bound):
                raise RequestError(403, f"{self.command} {self.path[:80]}: Host "
                                        f"{(host or '')[:80]!r} is not this page's: open the "
                                        "page as http://127.0.0.1:PORT/ or "
                                        "http://localhost:PORT/")
            if self.command != "POST":
                return
            origin = self.headers.get("Origin")
            site = self.headers.get("Sec-Fetch-Site", "same-origin")
            if site not in ("same-origin", "none"):
                raise RequestError(403, f"POST {self.path[:80]}: a {site} request is refused: "
                                        "the design page accepts requests from its own page")
            if origin is not None:
                parts = urlsplit(origin)
                if parts.scheme != "http" or parts.netloc.lower() != host.strip().lower():
                    raise RequestError(403, f"POST {self.path[:80]}: Origin {origin[:80]!r} is "
                                            "not this page's: the design page accepts requests "
                                            "from its own page only")

        def _body(self) -> str:
            """The request body, after the checks of its headers."""
            ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
            if ctype != "application/json":
                raise RequestError(415, f"POST {self.path[:80]}: Content-Type must be "
                                        f"application/json, got {ctype[:60]!r}")
            if self.headers.get("Transfer-Encoding"):
                raise RequestError(411, f"POST {self.path[:80]}: send the body with a "
                                        "Content-Length, not Transfer-Encoding")
            raw = self.headers.get("Content-Length")
            if raw is None:
                raise RequestError(411, f"POST {self.path[:80]}: a Content-Length is required")
            if not raw.strip().isdigit():
                raise RequestError(400, f"POST {self.path[:80]}: Content-Length must be a "
                                        f"whole number of bytes >= 0, got {raw[:40]!r}")
            length = int(raw) if len(raw.strip()) <= 15 else MAX_BODY + 1
            if length > MAX_BODY:
                raise RequestError(413, f"POST {self.path[:80]}: the body of {length} bytes is "
                                        f"over the limit of {MAX_BODY}")
            self.unread = False
            data = self.rfile.read(length)
            if len(data) < length:
                raise RequestError(400, f"POST {self.path[:80]}: the body ended after "
                                        f"{len(data)} of {length} bytes")
            try:
                return data.decode("utf-8")
            except UnicodeDecodeError:
                raise RequestError(400, f"POST {self.path[:80]}: the body is not UTF-8") from None

        unread = True  # the body is still in the socket

        def _drain(self) -> None:
            """Read what a refused POST has sent of its body: closing a socket with
            unread data resets it, and the client would lose the answer."""
            if self.command != "POST" or not self.unread:
                return
            total, end = 0, time.monotonic() + 2.0
            with contextlib.suppress(OSError, ValueError):
                while total < 4 * MAX_BODY and time.monotonic() < end:
                    if not select.select([self.connection], [], [], 0.05)[0]:
                        break
                    chunk = self.connection.recv(65536)
                    if not chunk:
                        break
                    total += len(chunk)

        def _guard(self, serve) -> None:
            """Serve; a refused request is answered with its status and one line; an
            unexpected error with 500 (and recorded: the server's ``errors``)."""
            try:
                self._check_origin()
                serve()
            except RequestError as err:
                self.close_connection = True
                self._error(err.status, str(err))
                self._drain()
            except ScanQAError as err:
                self._error(400, str(err))
            except (TimeoutError, ConnectionError):
                self.close_connection = True  # the client stalled or went away
            except Exception as err:  # one reply per request, never none
                self.server.errors.append(traceback.format_exc())
                log.error("design page: internal error on %s %s: %s: %s", self.command,
                          self.path[:80], type(err).__name__, err)
                self._error(500, f"internal error: {type(err).__name__}: {err}")

        def do_GET(self) -> None:
            self._guard(self._get)

        def do_POST(self) -> None:
            self._guard(self._post)

        def _get(self) -> None:
            if self.path in ("/", "/index.html"):
                page = designpage.page_html(state.settings, title)
                self._send(200, page.encode(), "text/html; charset=utf-8")
            elif self.path == "/favicon.ico":
                self._send(204, b"", "image/x-icon")
            elif self.path == "/plotly.min.js":
                self._send(200, _plotly_js(), "text/javascript", cache=True)
            else:
                self._send(404, b"not found", "text/plain")

        def _post(self) -> None:
            if self.path not in FIELDS:
                raise RequestError(404, f"POST {self.path[:80]}: not found (the endpoints: "
                                        f"{', '.join(FIELDS)})")
            body = parse_body(self.path, self._body())
            if self.path == "/api/view":
                out = designpage.dumps_payload(state.view(body))
            elif self.path == "/api/export":
                self._send(200, state.export(body).encode(), "application/toml")
                return
            else:
                out = json.dumps(state.load(body["toml"]))
            self._send(200, out.encode(), "application/json")

    return Handler


class DesignServer(ThreadingHTTPServer):
    """A threading HTTP server that serves at most ``max_connections`` at once.

    One more connection is answered ``503`` and closed before a thread is started;
    ``errors`` collects the tracebacks of requests that ended in a 500 (none expected).
    """

    daemon_threads = True

    def __init__(self, address, handler, max_connections: int = MAX_CONNECTIONS):
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        super().__init__(address, handler)
        self._slots = threading.BoundedSemaphore(max_connections)
        self.errors: list[str] = []

    def process_request(self, request, client_address) -> None:
        if not self._slots.acquire(blocking=False):
            try:
                request.sendall(b"HTTP/1.0 503 Service Unavailable\r\nContent-Type: "
                                b"application/json\r\nContent-Length: 48\r\n\r\n"
                                b'{"error": "too many connections: retry shortly"}')
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except Exception:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request, client_address) -> None:
        """An exception that escaped a handler: recorded, one line on stderr."""
        self.errors.append(traceback.format_exc())
        log.error("design page: error serving %s: %r", client_address, sys.exc_info()[1])


_PLOTLY: list[bytes] = []


def _plotly_js() -> bytes:
    """plotly.js from the installed plotly package, read once."""
    if not _PLOTLY:
        from plotly.offline import get_plotlyjs  # the optional [design] extra
        _PLOTLY.append(get_plotlyjs().encode())
    return _PLOTLY[0]


def make_server(config: ScannerConfig, host: str = "127.0.0.1", port: int = 0,
                level: float = 0.49, coc_max_mm: float = 0.030, timeout_s: float = TIMEOUT_S,
                max_connections: int = MAX_CONNECTIONS,
                request_s: float = REQUEST_S) -> DesignServer:
    """A server for the design page (not started; ``port=0`` picks a free port).

    Parameters
    ----------
    config : ScannerConfig
        The scanner config the page starts from.
    host : str
        Interface to listen on; the default serves this machine only (an empty host is
        refused: :func:`check_host`).
    port : int
        TCP port; 0 for any free one (``server.server_address[1]``).
    level : float
        Combined attenuation threshold the page starts with [-].
    coc_max_mm : float
        Camera circle-of-confusion threshold the page starts with [mm].
    timeout_s : float
        A connection silent this long is dropped [s].
    max_connections : int
        Connections served at once; more are answered 503.
    request_s : float
        A request still arriving after this long is dropped [s].

    Returns
    -------
    DesignServer
        Call ``serve_forever()``; ``server.state`` is its :class:`DesignState`.

    Notes
    -----
    Every request must name this page's host (``Host``: localhost, an IP address or
    ``host``), which defeats DNS rebinding; a POST must come from the page's own origin
    (``Origin``, ``Sec-Fetch-Site`` when a browser sends them) with ``Content-Type:
    application/json``, which a cross-site form cannot send without a preflight the server
    does not grant. The port is not compared: a tunnel (``ssh -L``) may change it.
    """
    check_host(host)
    state = DesignState(config, level, coc_max_mm)
    rig.apply_settings(config, state.settings)  # refuse a config the page cannot show
    server = DesignServer((host, port), _handler(state, config.name or "scanner", host,
                                                 timeout_s, request_s), max_connections)
    server.state = state
    return server
