"""Opening a master from the command line's global options.

``--iface IF`` and ``--udp HOST:PORT`` open a real link (``--iface`` also takes
any link name with a scheme, ``--iface unix:/run/seg.sock``), with
``--redundant-iface``/``--redundant-udp`` the second port of a ring; ``--sim
TOPOLOGY.toml`` builds the simulated segment and joins it to the master: in
this process through the in-process pair link (the segment answers each
frame synchronously, so nothing waits on timers; a topology with
``ring`` in its ``[segment]`` gets both ports), or with ``child=True`` in a
child process over a Unix socketpair. The master package never imports the
simulator; this module is where the two meet.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from pyethercat.errors import ConfigError
from pyethercat.master.master import Master

__all__ = ["CHILD_SIM_TIMEOUT", "Connection", "connect"]

#: Frame timeout (seconds) of a master whose simulator runs in a child process.
CHILD_SIM_TIMEOUT = 1.0


@dataclass
class Connection:
    """An open master and, for ``--sim``, the simulated segment or its child process."""

    master: Master
    #: The in-process ``Segment`` (``--sim`` without ``child``), else None.
    segment: Any = None
    #: The ``SimProcess`` handle (``--sim`` with ``child``), else None.
    process: Any = None


@contextlib.contextmanager
def connect(obj: dict[str, Any] | None, *, child: bool = False, pcap: str | None = None,
            **options: Any) -> Iterator[Connection]:
    """Open the master the global options ask for; close everything afterwards.

    ``options`` go to :class:`~pyethercat.master.master.Master` (with the
    frame timeout and retries of the global options). ``pcap``
    records every frame the master sends and receives.
    """
    obj = obj or {}
    iface, udp, sim = obj.get("iface"), obj.get("udp"), obj.get("sim")
    if sum(x is not None for x in (iface, udp, sim)) != 1:
        raise ConfigError("say where the segment is: give one of --iface IF, --udp HOST:PORT "
                          "or --sim TOPOLOGY.toml (before the command)")
    second_iface, second_udp = obj.get("redundant_iface"), obj.get("redundant_udp")
    if (second_iface or second_udp) and sim is not None:
        raise ConfigError("--sim makes its ring from the topology ([segment] ring = true): "
                          "no --redundant-iface/--redundant-udp with it")
    # --frame-timeout/--retries (or their environment variables); a command's own wins.
    for option, key in (("timeout", "frame_timeout"), ("retries", "retries")):
        if obj.get(key) is not None:
            options.setdefault(option, obj[key])
    conn: Connection
    if sim is not None and not child:
        from pyethercat.clock import VirtualClock
        from pyethercat.link.pair import PairLink
        from pyethercat.sim.topology import load_topology

        segment = load_topology(sim).build()
        link: Any
        if segment.ring is not None:
            from pyethercat.sim.ring import ring_link

            link = ring_link(segment, name=f"sim:{sim}")
        else:
            link = PairLink.responder_link(segment.process, name=f"sim:{sim}")
        link = _capture(link, pcap)
        options.setdefault("clock", VirtualClock())
        conn = Connection(Master(link, **options), segment=segment)
    elif sim is not None:
        from pyethercat.sim.server import start_sim_process
        from pyethercat.sim.topology import load_topology

        process = start_sim_process(sim, link="unix", ring=bool(load_topology(sim).ring))
        # A socketpair loses no frame: a late reply is the child kept off the CPU
        # (a busy machine), and a dead child closes the link. The 4 x 50 ms a real
        # segment is given would turn a busy moment into a failed command.
        options.setdefault("timeout", CHILD_SIM_TIMEOUT)
        try:
            assert process.link is not None
            # The handle closes its link itself when it stops.
            conn = Connection(Master(_capture(process.link, pcap), owns_link=pcap is not None,
                                     **options), process=process)
            # The simulator answering is a process on our own CPUs: polling for its
            # replies takes CPU time from it (demo RTT p50 +10-130 us with polling).
            conn.master.scheduler.reply_spin = 0.0
        except BaseException:
            process.stop()
            raise
    else:
        from pyethercat.link.registry import iface_link, open_link

        link = open_link(iface_link(iface) if iface is not None else f"udp:{udp}")
        if second_iface or second_udp:
            from pyethercat.link.redundant import RedundantLink

            try:
                link = RedundantLink(link, open_link(
                    iface_link(second_iface) if second_iface else f"udp:{second_udp}"))
            except BaseException:
                link.close()
                raise
        conn = Connection(Master(_capture(link, pcap), **options))
    try:
        yield conn
    finally:
        conn.master.close()
        if conn.process is not None:
            conn.process.stop()


def _capture(link: Any, pcap: str | None) -> Any:
    if pcap is None:
        return link
    from pyethercat.link.capture import CaptureLink
    from pyethercat.link.redundant import RedundantLink

    if isinstance(link, RedundantLink):
        # One capture per port: FILE for A, FILE-b for B (pcapng keeps the order per file).
        from pathlib import Path

        p = Path(pcap)
        second = str(p.with_name(f"{p.stem}-b{p.suffix}"))
        try:
            return RedundantLink(CaptureLink(link.primary, pcap), CaptureLink(link.secondary, second),
                                 name=link.name)
        except OSError as exc:
            link.close()
            raise ConfigError(f"cannot write the capture {pcap}: {exc.strerror or exc}") from None

    try:
        return CaptureLink(link, pcap)
    except OSError as exc:
        link.close()
        raise ConfigError(f"cannot write the capture {pcap}: {exc.strerror or exc}") from None
