"""``pyethercat web``: the diagnostics dashboard of a running master, in the browser.

``web [--bind 127.0.0.1:8080] [--token T|generate] [--allow-writes]`` finds
the master running on the link (``run``, ``demo``, a program serving its
master) through its control socket, as every other verb does, and serves
the dashboard; with no master running it opens the segment itself (states,
ports, counters and mailbox, no cyclic exchange). ``run --web`` starts this
command as a child process beside the cyclic loop (:func:`start_child`), so
the dashboard's work never holds the master process's interpreter.

The dashboard needs the optional ``web`` dependencies (Starlette, uvicorn,
websockets): ``pip install 'pyethercat[web]'``.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import subprocess
import sys
import time
from typing import Any

import click

from pyethercat.errors import ConfigError

__all__ = ["register", "start_child", "web_options", "WebChild", "TOKEN_ENV"]

#: The token of a dashboard started by ``run --web`` travels in the environment, not argv.
TOKEN_ENV = "PYETHERCAT_WEB_TOKEN"
_ANNOUNCE = "dashboard: "


def _need_web_extra() -> None:
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
        import websockets  # noqa: F401
    except ImportError as exc:
        raise ConfigError(f"the dashboard needs the 'web' extra ({exc.name} is missing): "
                          "pip install 'pyethercat[web]'") from None


def resolve_access(bind: str, token: str | None, allow_writes: bool) -> Any:
    """The :class:`~pyethercat.web.security.Access` of the options (refusals are one line)."""
    from pyethercat.web.security import Access, check_bind, new_token, parse_bind

    host, port = parse_bind(bind)
    if token == "generate":
        token = new_token()
    token = check_bind(host, token)
    if allow_writes and not token:
        token = new_token()  # writes always need one: made here, printed with the address
    return Access(host, port, token, allow_writes)


def _serve(obj: dict[str, Any], access: Any, rate: float, quiet: bool) -> None:
    from pyethercat.cli._connect import connect
    from pyethercat.cli._session import spec_of
    from pyethercat.master.control.client import find_master
    from pyethercat.master.control.endpoint import endpoint_path
    from pyethercat.master.control.handlers import MasterContext
    from pyethercat.web.server import serve
    from pyethercat.web.source import DirectConnection, RemoteConnection

    def announce(url: str) -> None:
        click.echo(f"{_ANNOUNCE}{url}")
        sys.stdout.flush()

    spec = spec_of(obj)
    client = None if obj.get("direct") else find_master(spec)
    if client is not None:
        client.close()
        conn = RemoteConnection(endpoint_path(spec), spec)
        try:
            serve(conn, access, rate=rate, announce=announce)
        finally:
            conn.close()
        return
    if not quiet:
        click.echo(f"pyethercat: no master runs on {spec}: the dashboard opens the segment "
                   "itself (no cyclic exchange)", err=True)
    with connect(obj) as c:
        serve(DirectConnection(MasterContext(c.master, spec, direct=True)), access, rate=rate,
              announce=announce)


def web_options(f: Any) -> Any:
    """``--bind``, ``--token``, ``--allow-writes`` (shared by ``web``)."""
    f = click.option("--allow-writes", is_flag=True,
                     help="Let the token's holder write outputs and SDOs (read-only otherwise).")(f)
    f = click.option("--token", default=None, metavar="TOKEN",
                     help="Needed on every request; 'generate' makes one. Required for a "
                          "non-loopback --bind.")(f)
    f = click.option("--bind", default="127.0.0.1:8080", show_default=True, metavar="HOST:PORT",
                     help="Address to listen on (port 0: any free port).")(f)
    return f


class WebChild:
    """A ``pyethercat web`` process serving the dashboard of this process's master."""

    def __init__(self, proc: subprocess.Popen[bytes], url: str) -> None:
        self.proc = proc
        self.url = url

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _child_setup() -> None:
    # PR_SET_PDEATHSIG: the dashboard ends when the master's process does, however it ends.
    with __import__("contextlib").suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)
    # A master started under SCHED_FIFO (chrt) would hand its priority down: the dashboard
    # is no real-time job and must not compete with the cyclic loop (sched(7)).
    with __import__("contextlib").suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def start_child(obj: dict[str, Any], access: Any, *, rate: float = 10.0,
                timeout: float = 120.0) -> WebChild:
    """Start ``pyethercat web`` for the master this process serves; returns once it listens."""
    _need_web_extra()
    args = [sys.executable, "-m", "pyethercat"]
    for key, opt in (("iface", "--iface"), ("udp", "--udp"), ("sim", "--sim")):
        if obj.get(key) is not None:
            args += [opt, str(obj[key])]
    host = f"[{access.host}]" if ":" in access.host else access.host
    args += ["web", "--bind", f"{host}:{access.port}", "--rate", str(rate), "--quiet"]
    if access.writable:
        args.append("--allow-writes")
    env = dict(os.environ)
    if access.token:
        env[TOKEN_ENV] = access.token
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, env=env, preexec_fn=_child_setup)
    assert proc.stdout is not None
    limit = time.monotonic() + timeout
    line = b""
    while time.monotonic() < limit and proc.poll() is None:
        ready, _, _ = select.select([proc.stdout], [], [], 0.2)
        if ready:
            line = proc.stdout.readline()
            if line.startswith(_ANNOUNCE.encode()) or not line:
                break
    text = line.decode(errors="replace").strip()
    if not text.startswith(_ANNOUNCE):
        WebChild(proc, "").close()
        raise ConfigError("the dashboard did not start (see the messages above)")
    return WebChild(proc, text[len(_ANNOUNCE):])


def register(cli: click.Group) -> None:
    """Add ``web`` to the command line."""

    @cli.command("web")
    @web_options
    @click.option("--rate", default=10.0, show_default=True, type=float, metavar="HZ",
                  help="Snapshots of the master per second (at most 20).")
    @click.option("--quiet", is_flag=True, hidden=True)
    @click.pass_obj
    def web_cmd(obj: dict[str, Any], bind: str, token: str | None, allow_writes: bool,
                rate: float, quiet: bool) -> None:
        """Serve the diagnostics dashboard of the master running on the link."""
        _need_web_extra()
        if rate <= 0:
            raise ConfigError(f"web: --rate must be positive, got {rate:g}")
        token = token or os.environ.get(TOKEN_ENV) or None
        access = resolve_access(bind, token, allow_writes)
        _serve(obj or {}, access, rate, quiet)
