"""One command line invocation's way to the segment: a running master, or its own.

:func:`open_session` first looks for a master that already runs on the
link named by ``--iface``/``--udp``/``--sim`` (its control socket, see
:mod:`pyethercat.master.control`) and sends the command's requests there:
one master per wire, the cycle undisturbed. When none runs (or with
``--direct``) it opens a master itself for the one command, and serves the
same requests in process with the same handlers, so the output is the same
either way. ``--direct`` beside a running master warns: two masters then
share the wire.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from typing import Any

import click

from pyethercat.cli._connect import connect
from pyethercat.cli._select import select, single
from pyethercat.errors import ConfigError
from pyethercat.master.control import messages as msg
from pyethercat.master.control.client import find_master, probe
from pyethercat.master.control.endpoint import endpoint_path, link_spec
from pyethercat.master.control.handlers import MasterContext, dispatch
from pyethercat.master.control.protocol import ControlRequest, ProtocolError, from_json, to_json
from pyethercat.master.control.server import serve
from pyethercat.master.control.snapshot import rebuild
from pyethercat.master.master import Master
from pyethercat.master.scan import Progress
from pyethercat.master.slave import Slave

__all__ = ["Session", "open_session", "own_master", "serving", "spec_of", "scan_progress"]


def spec_of(obj: dict[str, Any] | None) -> str:
    """The link the global options name (``raw:IF``, ``udp:H:P``, ``sim:PATH``)."""
    obj = obj or {}
    given = {k: obj.get(k) for k in ("iface", "udp", "sim") if obj.get(k) is not None}
    if len(given) != 1:
        raise ConfigError("say where the segment is: give one of --iface IF, --udp HOST:PORT "
                          "or --sim TOPOLOGY.toml")
    return link_spec(**given)


@contextlib.contextmanager
def scan_progress() -> Iterator[Progress | None]:
    """A progress callback drawing a bar on a terminal's stderr (nothing otherwise)."""
    if not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                  console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("scanning", total=None)

        def update(stage: str, done: int, total: int) -> None:
            what = "reading SII" if stage == "sii" else stage
            bar.update(task, description=what, completed=done, total=total or None)

        yield update


class _Context(MasterContext):
    """A direct master whose first scan draws the progress bar."""

    def __init__(self, master: Any, link: str,
                 progress: Callable[[], AbstractContextManager[Progress | None]]) -> None:
        super().__init__(master, link, direct=True)
        self._bar = progress

    def slaves(self) -> list[Slave]:
        if self.scanned:
            return super().slaves()
        with self._bar() as cb:
            self.progress = cb
            return super().slaves()


class Session:
    """Requests to the segment's master; ``remote`` tells whether it is a running one."""

    def __init__(self, spec: str, call: Callable[[ControlRequest], Any], remote: bool,
                 pid: int | None = None, context: MasterContext | None = None) -> None:
        self.spec = spec
        self.remote = remote
        self.pid = pid
        #: The in-process master's context (direct sessions only): a command may hand
        #: it callbacks such as ``transfer_progress``.
        self.context = context
        self._call = call
        self._aliases: list[int] | None = None
        self._slaves: list[Slave] | None = None
        self.consistent = True

    def call(self, req: ControlRequest) -> Any:
        """Send ``req``; returns its typed reply."""
        return self._call(req)

    # -- slaves -----------------------------------------------------------------------------

    def aliases(self) -> list[int]:
        """The alias of every slave by position (cheap: no SII read)."""
        if self._aliases is None:
            if self._slaves is not None:
                self._aliases = [s.alias for s in self._slaves]
            else:
                self._aliases = list(self.call(msg.Roster()).aliases)
        return self._aliases

    def slaves(self) -> list[Slave]:
        """The slaves with their SII, ports and topology (rebuilt from the master's scan)."""
        if self._slaves is None:
            reply: msg.SlaveList = self.call(msg.ListSlaves())
            self._slaves, consistent = rebuild(reply.slaves)
            self.consistent = reply.consistent and consistent
        return self._slaves

    def select(self, position: str | None, alias: str | None) -> list[int]:
        """Positions chosen by IgH's ``-p``/``-a`` (every slave when neither is given)."""
        if alias is None and position is not None and "," not in position \
                and "-" not in position:
            # A single absolute position needs no roster: the master checks it.
            from pyethercat.cli._select import parse_list

            return parse_list(position, 0)
        return select(self.aliases(), position, alias)

    def single(self, position: str | None, alias: str | None, verb: str) -> int:
        """The one position ``-p``/``-a`` select (:class:`ConfigError` otherwise)."""
        if alias is None and position is not None and "," not in position \
                and "-" not in position:
            return self.select(position, None)[0]
        return single(self.aliases(), position, alias, verb)


def _round_trip(req: ControlRequest, reply: Any) -> Any:
    # The in-process path goes through the same encoding as the socket, so a direct
    # command and a command to a running master see identical replies.
    return from_json(req.reply, to_json(reply))


@contextlib.contextmanager
def open_session(obj: dict[str, Any] | None, *, direct_only: bool = False) -> Iterator[Session]:
    """The session for one command (see the module text).

    ``direct_only``: always open an own master (a command that cannot be
    served by a running one).
    """
    spec = spec_of(obj)
    direct = bool((obj or {}).get("direct")) or direct_only
    if not direct:
        try:
            client = find_master(spec)
        except ProtocolError as exc:
            raise ConfigError(f"{exc}; --direct opens the segment without it") from None
        if client is not None:
            with client:
                assert client.hello is not None
                yield Session(spec, client.call, True, client.hello.pid)
            return
    else:
        _check_alone(obj, spec)
    with connect(obj) as conn:
        ctx = _Context(conn.master, spec, scan_progress)

        def call(req: ControlRequest) -> Any:
            return _round_trip(req, dispatch(ctx, req))

        yield Session(spec, call, False, context=ctx)


def _check_alone(obj: dict[str, Any] | None, spec: str) -> None:
    """Refuse (or with ``--direct`` warn) when a master already runs on the link."""
    running = probe(endpoint_path(spec))
    if running is None:
        return
    if (obj or {}).get("direct"):
        click.echo(f"pyethercat: warning: a master runs on {running.link} (pid "
                   f"{running.pid}); --direct opens a second master on the same wire",
                   err=True)
        return
    raise ConfigError(f"a master runs on {running.link} (pid {running.pid}): one master per "
                      "wire; this command needs the segment to itself (stop that master, or "
                      "give --direct to share the wire anyway)")


@contextlib.contextmanager
def own_master(obj: dict[str, Any] | None, **options: Any) -> Iterator[Any]:
    """``connect(obj, **options)`` for a command that needs its own master (``eni``, ``xml``).

    Refused while another master runs on the link, unless ``--direct``.
    """
    _check_alone(obj, spec_of(obj))
    with connect(obj, **options) as conn:
        yield conn


@contextlib.contextmanager
def serving(obj: dict[str, Any], master: Master) -> Iterator[None]:
    """Serve ``master`` on its link's control socket while it runs (one master per wire).

    A master already running on the link makes this refuse, unless
    ``--direct`` was given (then this one runs without a socket, with a warning).
    """
    spec = spec_of(obj)
    if obj.get("direct"):
        running = probe(endpoint_path(spec))
        if running is not None:
            click.echo(f"pyethercat: warning: a master runs on {running.link} (pid "
                       f"{running.pid}); --direct runs a second master on the same wire",
                       err=True)
            yield
            return
    server = serve(master, spec)
    try:
        yield
    finally:
        server.close()
