"""Serving the dashboard with uvicorn, on a socket bound before the first request.

:func:`serve` binds the address itself (so port 0 works and the address is
known before a request comes), announces the address with the token, and
runs uvicorn until SIGINT or SIGTERM.
"""

from __future__ import annotations

import socket
from collections.abc import Callable

from pyethercat.errors import ConfigError
from pyethercat.web.hub import Hub
from pyethercat.web.security import Access
from pyethercat.web.source import MasterConnection

__all__ = ["serve", "bind_socket", "dashboard_url"]


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (one-line errors)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        what = "needs root for a port below 1024" if exc.errno == 13 else (exc.strerror or exc)
        raise ConfigError(f"dashboard: cannot listen on {host}:{port}: {what}") from None
    sock.listen(64)
    return sock


def dashboard_url(host: str, port: int, token: str | None) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/" + (f"?token={token}" if token else "")


def serve(conn: MasterConnection, access: Access, *, rate: float = 10.0,
          announce: Callable[[str], None] | None = None) -> None:
    """Serve the dashboard of ``conn``'s master until interrupted."""
    import uvicorn

    from pyethercat.web.app import create_app

    sock = bind_socket(access.host, access.port)
    access.port = sock.getsockname()[1]
    hub = Hub(conn, rate=rate, writable=access.writable)
    app = create_app(hub, access)
    if announce is not None:
        announce(dashboard_url(access.host, access.port, access.token))
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on",
                            ws="websockets-sansio", ws_ping_interval=20.0)
    server = uvicorn.Server(config)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
