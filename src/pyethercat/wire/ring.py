"""The order in which a frame visits ESC ports, and the tree that order gives a segment.

A frame enters an ESC, passes the processing unit behind port 0 and leaves
through the next open port in the cycle 0 -> 3 -> 1 -> 2 -> 0 (ET1100
datasheet section I, "Frame processing"); what comes back on a port goes on
to the next open port. Auto-increment positions number the slaves in the
order the frame meets them, so a depth-first walk of every slave's open
ports, in that order, finds where each slave hangs (SOEM ``ecx_config_init``,
IgH ``ec_master_calc_topology``). The master's scan and the DC set-up both
stand on :func:`walk_ring`.
"""

from __future__ import annotations

from collections.abc import Sequence, Set

__all__ = ["PORT_CYCLE", "next_port", "port_sequence", "prev_port", "walk_ring"]

#: Port visiting order inside an ESC (the processing unit sits behind port 0).
PORT_CYCLE = (0, 3, 1, 2)
_NEXT = {0: 3, 3: 1, 1: 2, 2: 0}
_PREV = {3: 0, 1: 3, 2: 1, 0: 2}


def next_port(port: int, active: Set[int]) -> int:
    """The next active port after ``port`` in the order 0-3-1-2 (``port`` itself if none)."""
    p = port
    for _ in range(4):
        p = _NEXT[p]
        if p in active:
            return p
    return port


def prev_port(port: int, active: Set[int]) -> int:
    """The previous active port before ``port`` in the order 0-3-1-2 (``port`` itself if none).

    For an entry port this is the last port the frame leaves through before
    it goes back out of the entry port: its latch closes the slave's own
    round trip (SOEM ``ecx_prevport``; IgH ``ec_slave_get_previous_port``).
    """
    p = port
    for _ in range(4):
        p = _PREV[p]
        if p in active:
            return p
    return port


def port_sequence(entry: int, active: Set[int]) -> list[int]:
    """The active ports after ``entry`` in visiting order: where the children hang."""
    out: list[int] = []
    p = entry
    for _ in range(3):
        p = _NEXT[p]
        if p in active:
            out.append(p)
    return out


def walk_ring(entries: Sequence[int], active: Sequence[Set[int]]
              ) -> tuple[list[tuple[int, int] | None], int]:
    """Where each slave hangs: ``(parent position, parent port)``, and how many the walk explains.

    ``entries[i]`` is the port the frame enters slave ``i`` by (0 unless it is
    fed backwards), ``active[i]`` its open ports with communication. The
    first slave hangs on the master (``None``). Slaves the open ports do not
    reach (the count says more slaves than the ports explain) keep ``None``;
    an open port with nothing left to reach (a ring back to a second master
    port) is passed over.
    """
    parents: list[tuple[int, int] | None] = [None] * len(entries)
    if not entries:
        return parents, 0
    nxt = 1
    stack = [(0, port_sequence(entries[0], active[0]))]
    while stack:
        pos, ports = stack[-1]
        if not ports:
            stack.pop()
            continue
        port = ports.pop(0)
        if nxt >= len(entries):
            continue
        parents[nxt] = (pos, port)
        stack.append((nxt, port_sequence(entries[nxt], active[nxt])))
        nxt += 1
    return parents, nxt
