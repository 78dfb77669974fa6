"""``pyethercat diag``: where is the fault? (ring ports, the side each slave is reached from, located faults)."""

from __future__ import annotations

import json
from typing import Any

import click

from pyethercat.cli._session import open_session
from pyethercat.master.control import ring_ops

__all__ = ["register"]


@click.command("diag")
@click.option("--events", type=click.IntRange(0, 500), default=0, metavar="N",
              help="Also print the last N fault events of a running master.")
@click.option("--json", "as_json", is_flag=True, help="Print the faults as JSON.")
@click.pass_obj
def diag_command(obj: dict[str, Any], events: int, as_json: bool) -> None:
    """Locate faults: a broken cable, a failed node, a dead master port, a cable with CRC errors.

    Reads DL status and the error counters of every slave once (on both
    ports of a ring). A fault reads "link: between slave 4 port 1 and slave 5
    port 0". See docs/redundancy.md for how to read the report.
    """
    with open_session(obj) as session:
        reply = session.call(ring_ops.Diagnose(events=events))
    if as_json:
        click.echo(json.dumps({"state": reply.state,
                               "faults": [{"kind": f.kind, "where": f.where, "detail": f.detail}
                                          for f in reply.faults],
                               "events": reply.events}))
        return
    for line in reply.lines:
        click.echo(line)
    if reply.events:
        click.echo("events:")
        for text in reply.events:
            click.echo(f"  {text}")


def register(cli: click.Group) -> None:
    """Add ``diag`` to the ``pyethercat`` group."""
    cli.add_command(diag_command)
