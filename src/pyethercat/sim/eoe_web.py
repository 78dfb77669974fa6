"""The diagnostic web page a simulated EoE device serves (through EtherCAT, on port 80).

A small HTTP server (standard library, one thread per connection) with:

- ``/``: the page a person reads: identity, EtherCAT state, temperatures,
  errors and a live value, one self-contained HTML document (inline style,
  no scripts, no external assets) that reloads itself every few seconds;
- ``/status.json``: the same facts for programs;
- ``/blob?size=N``: N bytes (default 1 MiB, at most 64 MiB) of a fixed
  pseudo-random sequence, ``random.Random(N).randbytes(N)``, for transfer
  tests and benchmarks (the receiver can make the same bytes and compare).

The content comes from the device's ``status()`` callable: a dict with
``name``, ``kind``, ``identity`` (label/value pairs), ``state``, ``state_ok``,
``temperatures`` (label/degrees pairs), ``errors`` (texts), ``live`` (label/
value pairs, the first one being the live value: a value of the device model
that moves while the device works, such as a drive's position actual value,
shown large with ids ``live-label`` and ``live-value``) and ``network``
(label/value pairs).
"""

from __future__ import annotations

import html
import json
import random
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlparse

__all__ = ["render_page", "start_web_server", "blob", "MAX_BLOB"]

#: Largest ``/blob`` served.
MAX_BLOB = 64 << 20
_DEFAULT_BLOB = 1 << 20
_REFRESH_S = 3

_STYLE = """
body{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;margin:0;background:#eef1f4;color:#1c2733}
header{background:#1f4e79;color:#fff;padding:18px 28px}
header h1{margin:0;font-size:24px}header p{margin:4px 0 0;opacity:.85;font-size:14px}
main{display:flex;flex-wrap:wrap;gap:18px;padding:22px 28px}
section{background:#fff;border-radius:8px;box-shadow:0 1px 3px rgba(0,0,0,.15);padding:14px 18px;
min-width:300px;flex:1}
h2{font-size:16px;margin:0 0 10px;color:#1f4e79;text-transform:uppercase;letter-spacing:.05em}
table{border-collapse:collapse;width:100%}td{padding:5px 4px;border-bottom:1px solid #e3e7eb;
font-size:15px}td.k{color:#5a6673;width:45%}td.v{font-family:"DejaVu Sans Mono",monospace}
.state{display:inline-block;padding:6px 16px;border-radius:16px;font-weight:bold;font-size:20px}
.ok{background:#d8f0dc;color:#1d6b2c}.bad{background:#f8d7da;color:#8a1c24}
.live{font-size:34px;font-weight:bold;font-family:"DejaVu Sans Mono",monospace;color:#1f4e79}
.bar{height:10px;background:#e3e7eb;border-radius:5px;overflow:hidden}
.bar span{display:block;height:10px;background:#e08a1e}
ul{margin:0;padding-left:20px}li{margin:4px 0}.none{color:#1d6b2c}
footer{padding:0 28px 18px;color:#5a6673;font-size:12px}
"""


def _rows(pairs: list[tuple[str, Any]]) -> str:
    return "".join(f"<tr><td class='k'>{html.escape(str(k))}</td>"
                   f"<td class='v'>{html.escape(str(v))}</td></tr>" for k, v in pairs)


def render_page(status: dict[str, Any]) -> str:
    """The diagnostic page as one HTML document."""
    name = html.escape(str(status.get("name", "EtherCAT device")))
    kind = html.escape(str(status.get("kind", "")))
    state = html.escape(str(status.get("state", "?")))
    state_cls = "ok" if status.get("state_ok") else "bad"
    live: list[tuple[str, Any]] = list(status.get("live", []))
    first = live[0] if live else ("Live value", "-")
    temps = ""
    for label, deg in status.get("temperatures", []):
        width = max(0, min(100, int(deg)))
        temps += (f"<tr><td class='k'>{html.escape(str(label))}</td><td class='v'>{deg:.1f} °C"
                  f"<div class='bar'><span style='width:{width}%'></span></div></td></tr>")
    errors = status.get("errors", [])
    err_html = ("<ul>" + "".join(f"<li>{html.escape(str(e))}</li>" for e in errors) + "</ul>"
                if errors else "<p class='none'>No errors</p>")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="refresh" content="{_REFRESH_S}">
<title>{name} - diagnostics</title><style>{_STYLE}</style></head>
<body><header><h1>{name}</h1><p>{kind} &middot; diagnostic page served through
Ethernet over EtherCAT</p></header>
<main>
<section><h2>EtherCAT state</h2><p><span class="state {state_cls}" id="state">{state}</span></p>
<table>{_rows(list(status.get("network", [])))}</table></section>
<section><h2 id="live-label">{html.escape(str(first[0]))}</h2>
<p class="live" id="live-value">{html.escape(str(first[1]))}</p>
<table>{_rows(live[1:])}</table></section>
<section><h2>Identity</h2><table id="identity">{_rows(list(status.get("identity", [])))}</table>
</section>
<section><h2>Temperatures</h2><table id="temperatures">{temps}</table></section>
<section><h2>Errors</h2><div id="errors">{err_html}</div></section>
</main><footer>pyethercat simulated device &middot; refreshes every {_REFRESH_S} s &middot;
<a href="/status.json">status.json</a></footer></body></html>
"""


def blob(size: int) -> bytes:
    """The bytes ``/blob?size=N`` serves."""
    return random.Random(size).randbytes(size)


def start_web_server(status: Callable[[], dict[str, Any]], port: int = 80,
                     host: str = "0.0.0.0") -> ThreadingHTTPServer:
    """Listen on ``host:port`` (in the caller's network namespace) and serve in a thread.

    ``shutdown()`` and ``server_close()`` on the returned server stop it.
    """

    class Handler(BaseHTTPRequestHandler):
        server_version = "pyethercat-eoe/1"
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
            return  # no access log on the simulator's stderr

        def do_GET(self) -> None:  # noqa: N802 - http.server's naming
            try:
                self._get()
            except Exception as exc:  # noqa: BLE001 - a broken page must still answer
                self._reply(500, "text/plain", f"error: {exc}\n".encode())

        def _get(self) -> None:
            url = urlparse(self.path)
            if url.path in ("/", "/index.html"):
                self._reply(200, "text/html; charset=utf-8", render_page(status()).encode())
            elif url.path == "/status.json":
                self._reply(200, "application/json", json.dumps(status()).encode())
            elif url.path == "/blob":
                try:
                    size = int(parse_qs(url.query).get("size", [str(_DEFAULT_BLOB)])[0])
                except ValueError:
                    size = -1
                if not 0 <= size <= MAX_BLOB:
                    self._reply(400, "text/plain", b"size must be 0..67108864\n")
                    return
                self._reply(200, "application/octet-stream", blob(size))
            else:
                self._reply(404, "text/plain", b"not found\n")

        def _reply(self, code: int, ctype: str, body: bytes) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

    server = ThreadingHTTPServer((host, port), Handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name=f"eoe-web-{port}", daemon=True).start()
    return server
