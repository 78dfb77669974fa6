"""``pyethercat gateway``: serve the ETG.8200 mailbox gateway while the master runs.

::

    pyethercat --iface eth1 gateway [--bind 127.0.0.1:34980] [--state PREOP] [--seconds S]

The master scans the segment, brings the slaves to ``--state`` (PRE-OP: the
mailbox works from there) and forwards gateway requests until Ctrl-C (or
``--seconds``); meanwhile other ``pyethercat`` commands on the same link
reach it through its control socket. It listens on loopback unless ``--bind`` says otherwise,
IgH's ``ethercat_mbg`` and TwinCAT's gateway use the same port, 34980. On exit
it prints what it served.
"""

from __future__ import annotations

import time
from typing import Any

import click

from pyethercat.cli._session import own_master, serving
from pyethercat.master.gateway import MailboxGateway, parse_bind
from pyethercat.wire.al import AlState

__all__ = ["register"]


def register(cli: click.Group) -> None:
    """Add ``gateway``."""

    @cli.command("gateway")
    @click.option("--bind", default="127.0.0.1:34980", show_default=True, metavar="HOST:PORT",
                  help="Where to listen (UDP).")
    @click.option("--state", default="PREOP", show_default=True,
                  help="State to bring the slaves to first (PREOP, SAFEOP, BOOT ...).")
    @click.option("--seconds", type=float, default=None,
                  help="Stop after this long (default: until Ctrl-C).")
    @click.pass_obj
    def gateway_cmd(obj: dict[str, Any], bind: str, state: str, seconds: float | None) -> None:
        """Forward ETG.8200 mailbox requests (UDP) to the slaves."""
        address = parse_bind(bind)
        with own_master(obj) as conn, serving(obj, conn.master):
            # other commands reach this master through its control socket meanwhile
            m = conn.master
            m.scan()
            m.set_state(AlState.parse(state))
            gw = MailboxGateway(m, bind=address)
            host, port = gw.address
            click.echo(f"mailbox gateway on udp {host}:{port}: address 0 = master, "
                       f"station address or 1000 + position = slave; {len(m.slaves)} slaves")
            limit = None if seconds is None else time.monotonic() + seconds
            with gw:
                try:
                    while limit is None or time.monotonic() < limit:
                        time.sleep(0.1 if limit is None else min(0.1, max(0.0,
                                   limit - time.monotonic())))
                except KeyboardInterrupt:
                    pass
            st = gw.stats
            dropped = ", ".join(f"{k} {v}" for k, v in sorted(st.dropped.items())) or "none"
            click.echo(f"served {st.answered} of {st.received} requests ({st.to_master} to the "
                       f"master, {st.forwarded} forwarded, {st.failed} failed); dropped: "
                       f"{dropped}")
