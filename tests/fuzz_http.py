"""Seeded requests against the design page's server (``scanqa design page``).

Each case sends one request over a raw socket - a method, a path, the headers (Host,
Origin, Sec-Fetch-Site, Content-Type, Content-Length) and a body, each possibly mutated:
settings off by orders of magnitude, of other types, missing or unknown; bodies that are
not JSON objects, nested 10 to 200 000 deep, truncated, not UTF-8; scanner config TOMLs
with values outside the page's ranges or of other types; lengths negative, non-numeric,
missing or over the limit; requests cut short or garbage on the wire; another site's
Origin or a rebound Host name. Every few cases a burst of idle connections fills the
server's slots.

The promise checked: every request gets an HTTP answer (or, for a request cut short,
the server closes the connection after its timeout) - never a 500, never a traceback on
the server (``server.errors``), never more than :data:`SLOW_S` seconds; a request the
server must refuse (a rebound Host, another origin, a text/plain POST, a bad length, a
body of the wrong shape, a config outside the page's ranges) is refused with the status
the module notes of :mod:`scanqa.design.server` give - one accepted is *silent* - and
after every case the page still exports a config that loads.

``python -m tests.fuzz_http CASES SEED`` (``make fuzz`` runs 1000); test_fuzz_http.py runs
a small slice.
"""

from __future__ import annotations

import json
import random
import socket
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from scanqa.design import rig
from scanqa.design import server as designapp
from scanqa.io.tomlfile import loads_toml
from scanqa.model.config import config_from_dict, load_config

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "calib" / "paper_scanner.toml"
#: A request not answered within this long is a hang [s].
SLOW_S = 30.0
#: The fuzzed server's socket timeout and connection cap (small, so that cut-short
#: requests and bursts are cheap).
TIMEOUT_S = 1.0
MAX_CONNECTIONS = 6
PATHS = ("/", "/index.html", "/favicon.ico", "/api/view", "/api/export", "/api/load",
         "/api/../api/view", "/api/view?x=1", "//api/load", "/%00", "/" + "a" * 3000, "*",
         "/api/VIEW", "/api/load/")
OTHER_METHODS = ("HEAD", "PUT", "DELETE", "OPTIONS", "PATCH", "FOO", "post", "CONNECT")
ENDPOINTS = ("/api/view", "/api/export", "/api/load")
#: Statuses a well-formed request may get (a valid config may still be refused: 400).
ANY_OK = frozenset({200, 400})


@dataclass
class Case:
    """One request and the statuses it may get (None: any answer below 500)."""

    raw: bytes
    expect: frozenset | None
    why: str
    partial: bool = False  # cut short: the server closes it after its timeout


@dataclass
class Result:
    """What a run found."""

    cases: int = 0
    statuses: Counter = field(default_factory=Counter)
    failures: list = field(default_factory=list)  # (case, kind, detail)
    silent: list = field(default_factory=list)

    @property
    def tracebacks(self) -> int:
        return sum(1 for f in self.failures if f[1] in ("500", "traceback", "no answer"))

    @property
    def hangs(self) -> int:
        return sum(1 for f in self.failures if f[1] == "hang")


def _request(method: str, path: str, headers: list[tuple[str, str]], body: bytes) -> bytes:
    head = f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers)
    return head.encode("latin-1", "replace") + b"\r\n" + body


def _scaled(rng: random.Random, value: float) -> object:
    """A setting's value mutated: off by orders of magnitude, of another type, or odd."""
    choice = rng.randrange(9)
    if choice == 0:
        return value * 10.0 ** rng.choice([-9, -3, -1, 1, 3, 9, 300])
    if choice == 1:
        return -value
    if choice == 2:
        return rng.choice(["8", None, [value], {"v": value}, True, "", "NaN"])
    if choice == 3:
        return float("nan") if rng.random() < 0.5 else float("inf")
    if choice == 4:
        return int("9" * rng.choice([20, 400]))
    if choice == 5:
        return 0
    return value * rng.uniform(0.9, 1.1)  # a nearby, probably valid value


def _settings_body(rng: random.Random, base: dict, path: str) -> tuple[bytes, bool]:
    """A JSON body for view/export; True when it is invalid for certain."""
    settings = dict(base)
    invalid = False
    for _ in range(rng.randrange(4)):
        key = rng.choice(list(settings))
        new = _scaled(rng, base[key])
        settings[key] = new
    for key, new in settings.items():
        spec = rig.SETTINGS[key]
        invalid |= not (isinstance(new, (int, float)) and not isinstance(new, bool)
                        and spec.check.test(new))
    body: dict = {"settings": settings}
    roll = rng.random()
    if roll < 0.08:
        del settings[rng.choice(list(settings))]
        invalid = True
    elif roll < 0.14:
        settings["bogus_" + str(rng.randrange(99))] = 1.0
        invalid = True
    elif roll < 0.2:
        body = {"setings": settings}
        invalid = True
    elif roll < 0.24:
        body, invalid = {}, False  # the page's own settings
    if path == "/api/view" and rng.random() < 0.3:
        cut = rng.choice([True, False, "yes", 1, None])
        body["coc_cuts_volume"] = cut
        invalid |= not isinstance(cut, bool)
    text = json.dumps(body, allow_nan=True)
    return text.encode(), invalid


def _odd_body(rng: random.Random) -> tuple[bytes, bool]:
    """A body of the wrong shape: not JSON, not an object, too deep, not UTF-8."""
    depth = rng.choice([10, 999, 5000, 200_000])
    options = [
        (b"[1]", True), (b"null", True), (b'{"settings": 5}', True), (b'"x"', True),
        (b"{", True), (b"\xff\xfe{}", True), (b"[" * depth + b"]" * depth, True),
        (b'{"settings":' * depth + b"{}" + b"}" * depth, True),
        (json.dumps({"settings": {"a": [[[]]]}}).encode(), True),
        (bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))), True),
        (b"", False),  # an empty body is {}: the page's own settings
        (b"{}", False),
    ]
    return rng.choice(options)


def _toml_body(rng: random.Random, text: str) -> tuple[bytes, bool]:
    """A body for /api/load; True when it is invalid for certain."""
    roll = rng.random()
    if roll < 0.15:
        return json.dumps({"toml": rng.choice([5, None, [text], {"a": 1}])}).encode(), True
    if roll < 0.25:
        return json.dumps({"config": text}).encode(), True
    if roll < 0.5:  # a value out of the page's range, by an order of magnitude
        key, value = rng.choice([("f_number = 8.0", "f_number = 80.0"),
                                 ("focal_mm = 100.0", "focal_mm = 1000.0"),
                                 ("focus_mm = 450.0", "focus_mm = 4500.0")])
        if key in text:
            return json.dumps({"toml": text.replace(key, value, 1)}).encode(), True
    if roll < 0.7:  # bytes of the TOML cut or damaged: may still be valid
        cut = rng.randrange(len(text))
        mutated = text[:cut] + rng.choice(["", "= [", "\x00", "]]", "x = 1\n"]) + text[cut:]
        return json.dumps({"toml": mutated}).encode(), False
    if roll < 0.8:
        return json.dumps({"toml": text.replace("f_number = 8.0", "f_number = 'eight'", 1)
                           }).encode(), True
    return json.dumps({"toml": text}).encode(), False


def make_case(rng: random.Random, port: int, base: dict, toml: str) -> Case:
    """One seeded request and the statuses it may get."""
    host = f"127.0.0.1:{port}"
    roll = rng.random()
    if roll < 0.04:  # garbage on the wire
        raw = rng.choice([b"\r\n\r\n", b"GET\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n",
                          b"\x00\x01\x02 / HTTP/1.1\r\n\r\n", b"GET / HTTP/1.1\r\n" +
                          b"X: " + b"a" * 70_000 + b"\r\n\r\n",
                          b"GET / HTTP/1.1\r\n" + b"X: y\r\n" * 150 + b"\r\n",
                          bytes(rng.randrange(256) for _ in range(64)) + b"\r\n\r\n"])
        return Case(raw, None, "garbage")
    if roll < 0.07:  # cut short
        raw = rng.choice([b"GET / HTTP/1.1\r\n", b"POST /api/view HTTP/1.1\r\nHost: " +
                          host.encode() + b"\r\nContent-Type: application/json\r\n"
                          b"Content-Length: 100\r\n\r\n{\"settings\"", b"G"])
        return Case(raw, None, "cut short", partial=True)
    if roll < 0.1:
        method = rng.choice(OTHER_METHODS)
        return Case(_request(method, rng.choice(PATHS), [("Host", host)], b""),
                    frozenset({501}), f"method {method}")
    method = "POST" if rng.random() < 0.8 else "GET"
    path = rng.choice(ENDPOINTS) if rng.random() < 0.85 else rng.choice(PATHS)
    served = "/" + path.lstrip("/")  # http.server folds a leading '//' (open redirects)
    headers = [("Host", host)]
    expect: frozenset | None = None
    why = f"{method} {path[:40]}"
    # the checks in the server's order: Host, Origin, then (POST) type, length, body
    mutation = rng.random()
    if mutation < 0.06:
        name = rng.choice(["attacker.example", "evil.localhost.example", "", "127.0.0.1.nip.io"])
        headers = [("Host", f"{name}:{port}")] if name else []
        expect, why = frozenset({403}), why + f", Host {name!r}"
    elif mutation < 0.1:
        headers.append(("Host", f"localhost:{port}"))  # a second Host header
        expect = None
    if method == "GET":
        if expect is None and served in ("/", "/index.html"):
            expect = frozenset({200})
        return Case(_request(method, path, headers, b""), expect, why)
    if expect is None:
        origin = rng.random()
        if origin < 0.06:
            headers.append(("Origin", rng.choice(["http://evil.example", "null",
                                                  f"https://127.0.0.1:{port}"])))
            expect, why = frozenset({403}), why + ", foreign Origin"
        elif origin < 0.1:
            headers.append(("Sec-Fetch-Site", rng.choice(["cross-site", "same-site"])))
            expect, why = frozenset({403}), why + ", cross-site"
        elif origin < 0.2:
            headers.append(("Origin", f"http://{host}"))
            headers.append(("Sec-Fetch-Site", "same-origin"))
    if expect is None and served not in ENDPOINTS:
        expect = frozenset({404})  # the path is looked up before type, length and body
    if served == "/api/load":
        body, invalid = _toml_body(rng, toml)
    elif rng.random() < 0.25:
        body, invalid = _odd_body(rng)
    else:
        body, invalid = _settings_body(rng, base, path)
    ctype = "application/json"
    if rng.random() < 0.08:
        ctype = rng.choice(["text/plain", "application/x-www-form-urlencoded", "",
                            "multipart/form-data", "application/jsonx"])
        if expect is None:
            expect, why = frozenset({415}), why + f", Content-Type {ctype!r}"
    if ctype:
        headers.append(("Content-Type", ctype))
    length = str(len(body))
    if rng.random() < 0.1:
        length = rng.choice(["-1", "abc", "", None, "99999999999", "1e3", "0x10",
                             "9" * 5000, str(len(body) + 10 ** 6)])
        bad = {"-1": 400, "abc": 400, "": 400, None: 411, "1e3": 400, "0x10": 400}
        if expect is None:
            code = bad.get(length, 413)
            expect, why = frozenset({code}), why + f", Content-Length {str(length)[:20]!r}"
    if length is not None:
        headers.append(("Content-Length", length))
    if expect is None:
        if len(body) > designapp.MAX_BODY:
            expect, why = frozenset({413}), why + f", a body of {len(body)} bytes"
        elif invalid:
            expect, why = frozenset({400}), why + ", invalid body"
        else:
            expect = ANY_OK
    return Case(_request(method, path, headers, body), expect, why)


def send(port: int, case: Case) -> tuple[int | None, bytes, float]:
    """Send one case; (status or None when the server closed without one, answer, s)."""
    t0 = time.monotonic()
    data = b""
    with socket.create_connection(("127.0.0.1", port), timeout=SLOW_S) as sock:
        try:
            sock.sendall(case.raw)
            while True:
                chunk = sock.recv(1 << 16)
                if not chunk:
                    break
                data += chunk
        except (ConnectionResetError, BrokenPipeError):
            pass
    status = None
    if data.startswith(b"HTTP/"):
        try:
            status = int(data.split(b" ", 2)[1])
        except (IndexError, ValueError):
            status = None
    return status, data, time.monotonic() - t0


def burst(port: int) -> int | None:
    """Fill the server's slots with idle clients; the status of one more request (the
    server's timeout must outlast the burst)."""
    idle = []
    for _ in range(MAX_CONNECTIONS):
        sock = socket.create_connection(("127.0.0.1", port), timeout=SLOW_S)
        sock.sendall(b"GET / HTTP/1.1\r\n")
        idle.append(sock)
    status = send(port, Case(_request("GET", "/favicon.ico",
                                      [("Host", f"127.0.0.1:{port}")], b""), None, ""))[0]
    for sock in idle:
        sock.close()
    return status


def exports_a_config(port: int) -> bool:
    """Whether the page's state still exports a config TOML that loads."""
    case = Case(_request("POST", "/api/export", [("Host", f"127.0.0.1:{port}"),
                                                 ("Content-Type", "application/json"),
                                                 ("Content-Length", "2")], b"{}"), None, "")
    status, data, _ = send(port, case)
    if status != 200:
        return False
    text = data.split(b"\r\n\r\n", 1)[1]
    config_from_dict(loads_toml(text, "the exported config"), source="<export>")
    return True


def fuzz_http(cases: int, seed: int) -> Result:
    """Run ``cases`` seeded requests against a fresh server; what they found."""
    rng = random.Random(seed)
    config = load_config(CONFIG)
    srv = designapp.make_server(config, timeout_s=TIMEOUT_S, max_connections=MAX_CONNECTIONS)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    port = srv.server_address[1]
    base, toml = dict(srv.state.settings), CONFIG.read_text()
    crowded = designapp.make_server(config, timeout_s=SLOW_S, max_connections=MAX_CONNECTIONS)
    threading.Thread(target=crowded.serve_forever, daemon=True).start()
    res = Result()
    try:
        for i in range(cases):
            if i % 100 == 99:  # every 100 cases: a burst of idle clients
                status = burst(crowded.server_address[1])
                res.cases += 1
                res.statuses[status] += 1
                if status != 503:
                    res.failures.append((i, "burst", f"status {status}, expected 503"))
                continue
            case = make_case(rng, port, base, toml)
            errors = len(srv.errors)
            try:
                status, data, took = send(port, case)
            except TimeoutError:
                status, data, took = None, b"", SLOW_S
            res.cases += 1
            res.statuses[status] += 1
            if took >= SLOW_S:
                res.failures.append((i, "hang", case.why))
            elif len(srv.errors) > errors:
                res.failures.append((i, "traceback", srv.errors[-1].strip().splitlines()[-1]))
            elif status is not None and status >= 500 and status not in (501, 503):
                res.failures.append((i, "500", f"{case.why}: {data[-200:]!r}"))
            elif status is None and not case.partial and case.why != "garbage":
                res.failures.append((i, "no answer", case.why))
            elif case.expect is not None and status not in case.expect:
                if status == 200:
                    res.silent.append((i, case.why))
                elif status != 503:
                    res.failures.append((i, "wrong status", f"{case.why}: {status}, expected "
                                                            f"{sorted(case.expect)}"))
            if i % 25 == 24 and not exports_a_config(port):
                res.failures.append((i, "state", "the page no longer exports a config"))
    finally:
        for server in (srv, crowded):
            server.shutdown()
            server.server_close()
    if crowded.errors:
        res.failures.append((cases, "traceback", crowded.errors[-1].strip().splitlines()[-1]))
    return res


def main(argv: list[str] | None = None) -> int:
    """``python -m tests.fuzz_http [CASES [SEED]]``; exit 1 on any failure."""
    args = argv if argv is not None else sys.argv[1:]
    cases = int(args[0]) if args else 1000
    seed = int(args[1]) if len(args) > 1 else 0
    res = fuzz_http(cases, seed)
    print(f"design page HTTP: {res.cases} requests, statuses {dict(res.statuses)}, "
          f"{res.tracebacks} tracebacks, {res.hangs} hangs, {len(res.silent)} silent, "
          f"{len(res.failures)} failures")
    for case, kind, detail in res.failures[:20]:
        print(f"    case {case}: {kind}: {detail}")
    for case, why in res.silent[:20]:
        print(f"    case {case}: silent: {why}")
    return 1 if res.failures or res.silent else 0


if __name__ == "__main__":
    sys.exit(main())
