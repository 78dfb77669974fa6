"""``pyethercat gateway``: serve the ETG.8200 mailbox gateway while the master runs.

::

    pyethercat --iface eth1 gateway [--bind 127.0.0.1:34980] [--state PREOP] [--cycle US]
                                    [--seconds S]

When a master already runs on the link (``pyethercat run``, the web
dashboard's, a program's), the gateway attaches to it: requests travel
through its control socket and its own mailboxes serve them, the cycle and
the slaves' states undisturbed. Otherwise the gateway opens its own master,
scans, brings the slaves to ``--state`` (PRE-OP by default: the mailbox works
from there; SAFE-OP and OP run the cyclic exchange, every ``--cycle``
microseconds, as ``run`` does) and serves the control socket meanwhile, so
other ``pyethercat`` commands reach it. It listens on loopback unless
``--bind`` says otherwise; IgH's ``ethercat_mbg`` and TwinCAT's gateway use
the same port, 34980. Ctrl-C (or ``--seconds``) ends it; on exit it prints
what it served.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

import click

from pyethercat.cli._lifecycle import StopSignals
from pyethercat.cli._session import own_master, serving, spec_of
from pyethercat.errors import ConfigError
from pyethercat.master.control import messages as msg
from pyethercat.master.control.client import find_master
from pyethercat.master.control.gateway_ops import RemoteForward
from pyethercat.master.control.protocol import ProtocolError
from pyethercat.master.control.snapshot import rebuild
from pyethercat.master.gateway import MailboxGateway, parse_bind
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState

__all__ = ["register"]

#: States whose slaves need the cyclic exchange (SM watchdog, process data).
_CYCLIC = (AlState.SAFEOP, AlState.OP)


class _Attached:
    """What the gateway needs of a master running in another process: its scan."""

    def __init__(self, slaves: list[Slave]) -> None:
        self.slaves = slaves


def register(cli: click.Group) -> None:
    """Add ``gateway``."""

    @cli.command("gateway")
    @click.option("--bind", default="127.0.0.1:34980", show_default=True, metavar="HOST:PORT",
                  help="Where to listen (UDP).")
    @click.option("--state", default=None,
                  help="With its own master: the state to bring the slaves to first (PREOP, "
                       "the default; SAFEOP and OP cycle; BOOT). Attached to a running "
                       "master, its states stay as they are.")
    @click.option("--cycle", "cycle_us", type=click.IntRange(min=50), default=1000,
                  show_default=True, metavar="US",
                  help="With its own master in SAFEOP or OP: the cycle time.")
    @click.option("--seconds", type=float, default=None,
                  help="Stop after this long (default: until Ctrl-C).")
    @click.pass_obj
    def gateway_cmd(obj: dict[str, Any], bind: str, state: str | None, cycle_us: int,
                    seconds: float | None) -> None:
        """Forward ETG.8200 mailbox requests (UDP) to the slaves."""
        address = parse_bind(bind)
        target = AlState.parse(state) if state is not None else None
        spec = spec_of(obj)
        client = None
        if not obj.get("direct"):
            try:
                client = find_master(spec)
            except ProtocolError as exc:
                raise ConfigError(f"{exc}; --direct opens the segment without it") from None
        if client is not None:
            with client:
                assert client.hello is not None
                if target is not None:
                    raise ConfigError(
                        f"a master runs on {client.hello.link} (pid {client.hello.pid}): the "
                        "gateway attaches to it and leaves its slaves' states alone; --state "
                        "is for a gateway with a master of its own (change states with "
                        "'pyethercat states')")
                reply: msg.SlaveList = client.call(msg.ListSlaves())
                slaves, _consistent = rebuild(reply.slaves)
                forward = RemoteForward(client.path)
                try:
                    gw = MailboxGateway(_Attached(slaves), bind=address, forward=forward)
                    _serve(gw, len(slaves), seconds,
                           f"through the master running on {client.hello.link} (pid "
                           f"{client.hello.pid})")
                finally:
                    forward.close()
            return
        with own_master(obj) as conn, serving(obj, conn.master):
            # other commands reach this master through its control socket meanwhile
            m = conn.master
            m.scan()
            with _in_state(m, target or AlState.PREOP, cycle_us):
                gw = MailboxGateway(m, bind=address)
                _serve(gw, len(m.slaves), seconds, None)


@contextlib.contextmanager
def _in_state(m: Any, state: AlState, cycle_us: int) -> Iterator[None]:
    """The slaves in ``state``: SAFE-OP and OP with the cyclic exchange running meanwhile."""
    if state not in _CYCLIC:
        m.set_state(state)
        yield
        return
    runner = m.start(cycle_us / 1e6, target=state)
    try:
        yield
    finally:
        runner.stop()


def _serve(gw: MailboxGateway, count: int, seconds: float | None, via: str | None) -> None:
    host, port = gw.address
    limit = None if seconds is None else time.monotonic() + seconds
    # SIGINT and SIGTERM end the serving in order (the statistics below), also when
    # the gateway was started with SIGINT ignored (a background job of a script); the
    # handlers are in place before the line that says the gateway is ready.
    with gw, StopSignals():
        try:
            click.echo(f"mailbox gateway on udp {host}:{port}: address 0 = master, station "
                       f"address or 1000 + position = slave; {count} slaves"
                       + (f"; {via}" if via is not None else ""))
            while limit is None or time.monotonic() < limit:
                time.sleep(0.1 if limit is None else min(0.1, max(0.0,
                           limit - time.monotonic())))
        except KeyboardInterrupt:
            pass
    st = gw.stats
    dropped = ", ".join(f"{k} {v}" for k, v in sorted(st.dropped.items())) or "none"
    click.echo(f"served {st.answered} of {st.received} requests ({st.to_master} to the "
               f"master, {st.forwarded} forwarded, {st.failed} failed); dropped: {dropped}")
