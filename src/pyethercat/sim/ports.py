"""Ports, links and loop control of a segment, and the walk of a frame through it.

Every slave has ports 0-3 (as many as its ESC implements); port 0 faces the
master. A frame entering a slave at a port goes to the processing unit if
that port is 0, then leaves by the next port in the order 0 -> 3 -> 1 -> 2
-> 0 (ESC datasheet section I, "Frame processing"; KickCAT
``EmulatedNetwork.cc`` ``walkFrame``; IgH ``master/slave.c``). A closed port (no link, or closed by loop
control 0x0101) sends the frame on to the next port at once, so a broken
link closes the loop at the port before it and the frame still comes back.

:meth:`Ports.walk` computes, once per topology change, the :class:`Route`:
the processing-unit passes in order, the arrival time at every port (DC
receive times), the total forwarding delay and whether the frame returns.
:meth:`Ports.update` also brings DL status 0x0110 (link, loop, communication
per port) and the lost-link counters up to date.

A ring (cable redundancy): the master has a second port B cabled to a free
port of a slave, normally the last one (``Ports.ring``). A frame can then
enter at either master port and leave at either: :meth:`Ports.update`
computes one route per entry. A frame entering at B travels the ring
backwards without passing any processing unit (a port other than 0 forwards
without processing) until it finds a closed port 0 (a broken ring): that
slave loops it into its processing unit, and every slave after it processes
the frame on its way back to B. In an intact ring the copy sent on A is
processed by every slave and leaves at B, the copy sent on B comes back at A
untouched (ETG.1000.4 section 5.4; ET1100 datasheet section I, "Frame
processing order").

Auto-close (loop control value 1): a port whose link went down stays closed
when the link comes back, until the master writes 1 again after link up, or
a valid frame arrives at it (ESC datasheet section II, DL control 0x0101;
gatorcat ``esc.zig`` ``LoopControlSettings``, IEC 61158-4-12 6.1.3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError
from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.wire import registers as R

__all__ = ["MASTER", "NEXT_PORT", "PORT_A", "PORT_B", "Ports", "Route"]

I64 = npt.NDArray[np.int64]

#: Next port in the forwarding order 0 -> 3 -> 1 -> 2 -> 0.
NEXT_PORT = (3, 2, 0, 1)
MASTER = -1
#: The master's ports: A feeds the first slave's port 0, B closes the ring.
PORT_A = 0
PORT_B = 1
_AUTO_CLOSE = int(R.LoopControl.AUTO_CLOSE)


@dataclass
class Route:
    """The walk of a frame from the master through the segment (computed per topology)."""

    passes: I64                # slave index of each processing-unit pass, in order
    port0_closed: list[bool]   # per pass: the slave's port 0 is closed (circulating rule)
    #: (slave, port, ns after entry, processing-unit passes before it) of every port arrival
    arrivals: list[tuple[int, int, int, int]]
    arrive_ns: I64             # (slaves x 4) first arrival time per port, -1 = not visited
    epu_ns: I64                # per slave: time of its (first) processing-unit pass, -1 = none
    returned: bool             # the frame comes back to the master (at either port)
    delay_ns: int              # forwarding + cable delays of the whole walk
    contiguous: bool           # passes == arange(len(passes)) (fast slicing)
    #: (slave, port, arrival index) of arrivals at an auto-close port held closed
    #: after its link came back: a valid frame there re-opens it.
    reopen: list[tuple[int, int, int]]
    #: The master port the frame entered at and the one it leaves by (-1: lost).
    entry: int = PORT_A
    exit: int = PORT_A
    #: Pass indices where the slave's port 0 is closed (derived, for the frame path).
    closed_idx: list[int] = field(init=False)
    #: len(passes), and whether the frame is processed at all (derived).
    count: int = field(init=False)
    live: bool = field(init=False)
    #: ``epu_ns`` with 0 for slaves the frame does not pass (derived: DC pass times).
    epu_at_ns: I64 = field(init=False)

    def __post_init__(self) -> None:
        self.epu_at_ns = np.maximum(self.epu_ns, 0)
        self.closed_idx = [i for i, c in enumerate(self.port0_closed) if c]
        self.count = len(self.passes)
        self.live = bool(self.count or self.returned)

    def passes_done(self, any_circulating: bool) -> int:
        """Passes made before the circulating-frame rule destroys the frame (all if it does not).

        A frame already marked circulating is destroyed at the first closed
        port 0, an unmarked one at the second (KickCAT issue #35 / PR #34, which
        cites the ESC datasheet section I ch. 3.5)."""
        closed = self.closed_idx
        if closed and (any_circulating or len(closed) > 1):
            return closed[0] if any_circulating else closed[1]
        return self.count


class Ports:
    """Cables between slave ports, cut cables, loop states and the walk (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc]) -> None:
        self.memory = memory
        self.escs = escs
        self.links: list[list[tuple[int, int] | None]] = []
        self.cable: dict[tuple[int, int], int] = {}
        self.fwd_delay: list[int] = []
        self.broken: set[tuple[int, int]] = set()
        self.autoclose_latched: set[tuple[int, int]] = set()
        self._had_link: dict[tuple[int, int], bool] = {}
        #: The slave port cabled to the master's port B (a ring), or None.
        self.ring: tuple[int, int] | None = None
        #: Whether something listens at the master's port B (a second master
        #: NIC); without it the ring cable has no link partner.
        self.master_b = False

    # --- building --------------------------------------------------------------------

    def add(self, index: int, name: str, delay_ns: int, parent: int | None, port: int | None,
            cable_delay_ns: int) -> None:
        """Connect slave ``index`` (see ``Segment.add_slave`` for parent/port); nothing changes on an error."""
        if index == 0:
            if parent is not None:
                raise ConfigError("the first slave is connected to the master; it has no parent")
        else:
            if parent is None:
                parent = index - 1
                port = self.free_port(parent)
            if not 0 <= parent < index:
                raise ConfigError(f"slave {name!r}: parent {parent} does not exist yet")
            if port is None:
                port = self.free_port(parent)
            pname = self.escs[parent].name
            if port not in self.escs[parent].profile.implemented_ports or port == 0:
                raise ConfigError(f"slave {name!r}: parent {pname!r} has no usable port {port}")
            if self.links[parent][port] is not None:
                raise ConfigError(f"slave {name!r}: port {port} of {pname!r} is already connected")
        self.links.append([None, None, None, None])
        self.fwd_delay.append(int(delay_ns))
        if parent is not None and port is not None:
            self.links[parent][port] = (index, 0)
            self.links[index][0] = (parent, port)
            self.cable[(parent, port)] = cable_delay_ns
            self.cable[(index, 0)] = cable_delay_ns

    def free_port(self, slave: int) -> int:
        prof = self.escs[slave].profile
        for p in (1, 2, 3):
            if p in prof.implemented_ports and self.links[slave][p] is None and (slave, p) != self.ring:
                return p
        raise ConfigError(f"slave {self.escs[slave].name!r} has no free port for the next slave")

    def set_ring(self, slave: int | None = None, port: int | None = None) -> tuple[int, int]:
        """Cable the master's port B to ``slave``'s ``port``.

        Default: the free port of the last slave in bus order (the last one a
        frame from port A passes; in a tree that is not the last one added)."""
        n = len(self.escs)
        if n == 0:
            raise ConfigError("a ring needs at least one slave")
        if slave is None:
            # The walk with every cable up and every port on auto (as cabled).
            up = [[self._port_exists(i, p) and (self.links[i][p] is not None or (i, p) == (0, 0))
                   for p in range(4)] for i in range(n)]
            closed = [[not x for x in row] for row in up]
            passes = self.walk(up, closed).passes
            slave = int(passes[-1]) if len(passes) else n - 1
        s = slave
        if not 0 <= s < n:
            raise ConfigError(f"ring: no slave {s} (the segment has {n})")
        p = self.free_port(s) if port is None else port
        name = self.escs[s].name
        if p == 0 or p not in self.escs[s].profile.implemented_ports:
            raise ConfigError(f"ring: slave {name!r} has no usable port {p}")
        if self.links[s][p] is not None:
            raise ConfigError(f"ring: port {p} of slave {name!r} is already connected")
        self.ring = (s, p)
        return s, p

    # --- links -----------------------------------------------------------------------

    def _port_exists(self, s: int, p: int) -> bool:
        return p in self.escs[s].profile.implemented_ports

    def link_up(self, s: int, p: int) -> bool:
        if not self.escs[s].powered or not self._port_exists(s, p):
            return False
        if s == 0 and p == 0:
            return (0, 0) not in self.broken
        if (s, p) == self.ring:
            return self.master_b and (s, p) not in self.broken
        peer = self.links[s][p]
        if peer is None or (s, p) in self.broken or peer in self.broken:
            return False
        return self.escs[peer[0]].powered

    def _loop_closed(self, s: int, p: int, link: bool) -> bool:
        if not self._port_exists(s, p):
            return True
        lc = (int(self.memory.mem[s, R.DL_CONTROL_LOOP]) >> (2 * p)) & 3
        if lc == R.LoopControl.OPEN:
            return False
        if lc == R.LoopControl.CLOSED:
            return True
        if lc == _AUTO_CLOSE:
            return not link or (s, p) in self.autoclose_latched
        return not link

    def peer_key(self, slave: int, port: int) -> tuple[int, int] | None:
        """The far end of the cable at ``slave``'s ``port`` (None: the master's cable).

        A fault on a port the chip does not have, or on one without a cable,
        would do nothing at all; it is refused instead (ConfigError naming the
        slave and the port)."""
        n = len(self.escs)
        if not 0 <= slave < n:
            raise ConfigError(f"no slave {slave} (the segment has {n})")
        name = f"slave {self.escs[slave].name!r} (index {slave})"
        ports = self.escs[slave].profile.implemented_ports
        if port not in ports:
            raise ConfigError(f"{name} has no port {port} (ports {', '.join(map(str, ports))})")
        peer = self.links[slave][port]
        if peer is None and not (slave == 0 and port == 0) and (slave, port) != self.ring:
            raise ConfigError(f"{name}: port {port} has no cable")
        return peer

    def master_port_key(self, port: int) -> tuple[int, int]:
        """The slave port cabled to master port A (0) or B (1)."""
        if port == PORT_A:
            return 0, 0
        if port == PORT_B and self.ring is not None:
            return self.ring
        raise ConfigError(f"the master has no port {'AB'[port] if port in (0, 1) else port} "
                          f"in this segment" + (" (no ring)" if port == PORT_B else ""))

    def break_link(self, slave: int, port: int) -> None:
        self.peer_key(slave, port)
        self.broken.add((slave, port))

    def restore_link(self, slave: int, port: int) -> None:
        peer = self.peer_key(slave, port)
        self.broken.discard((slave, port))
        if peer is not None:
            self.broken.discard(peer)

    def slave_reset(self, slave: int) -> None:
        """A slave powered up again: no latched ports, no link seen yet."""
        for p in range(4):
            self.autoclose_latched.discard((slave, p))
            self._had_link[(slave, p)] = False

    def loop_control_written(self, index: int, new: int) -> None:
        """Auto-close (1) written after the link came back re-opens a latched port.

        Written while the link is still down it re-opens nothing: only a write
        of 1 after link up does."""
        for p in range(4):
            if (new >> (2 * p)) & 3 == _AUTO_CLOSE and self.link_up(index, p):
                self.autoclose_latched.discard((index, p))

    def reopen(self, route: Route, any_circulating: bool, crc_at: int) -> bool:
        """A valid frame arrived at latched auto-close ports: they open; True if any did.

        Valid: it arrived before the frame got a CRC error (arrival index below
        ``crc_at``) and before the circulating-frame rule destroyed it. The
        frame itself was handled with the port closed; the next walk has it
        open."""
        passes_done = route.passes_done(any_circulating)
        opened = False
        for s, p, i in route.reopen:
            if i < crc_at and route.arrivals[i][3] <= passes_done:
                self.autoclose_latched.discard((s, p))
                opened = True
        return opened

    # --- the walk --------------------------------------------------------------------

    def update(self) -> list[Route]:
        """DL status of every slave (raising its DL-status event on a change) and the new walks.

        One route per master port: [A] or, with a ring, [A, B]."""
        n = len(self.escs)
        links = [[self.link_up(s, p) for p in range(4)] for s in range(n)]
        closed = [[self._loop_closed(s, p, links[s][p]) for p in range(4)] for s in range(n)]
        mem = self.memory.mem
        for s in range(n):
            esc = self.escs[s]
            if not esc.powered:
                continue
            dl = esc.u16(R.DL_STATUS) & 0x000F
            for p in range(4):
                key = (s, p)
                had = self._had_link.get(key, False)
                if had and not links[s][p]:
                    c = int(mem[s, R.LOST_LINK_COUNTER + p])
                    mem[s, R.LOST_LINK_COUNTER + p] = min(255, c + 1)
                    lc = (int(mem[s, R.DL_CONTROL_LOOP]) >> (2 * p)) & 3
                    if lc == _AUTO_CLOSE:
                        self.autoclose_latched.add(key)
                self._had_link[key] = links[s][p]
                if links[s][p]:
                    dl |= R.dl_status_link(p) | R.dl_status_com(p)
                if closed[s][p]:
                    dl |= R.dl_status_loop(p)
            if dl != esc.u16(R.DL_STATUS):
                esc.set_u16(R.DL_STATUS, dl)
                esc.set_ecat_event(int(R.EcatEvent.DL_STATUS))
        routes = [self.walk(links, closed, PORT_A)]
        if self.ring is not None:
            routes.append(self.walk(links, closed, PORT_B))
        return routes

    def walk(self, links: list[list[bool]], closed: list[list[bool]], entry: int = PORT_A) -> Route:
        """The route of a frame entering at master port ``entry`` (A: slave 0 port 0, B: the ring port)."""
        n = len(self.escs)
        passes: list[int] = []
        port0_closed: list[bool] = []
        arrivals: list[tuple[int, int, int, int]] = []
        arrive = np.full((n, 4), -1, np.int64)
        epu = np.full(n, -1, np.int64)
        exit_port = -1
        t = 0
        start = (0, 0) if entry == PORT_A else self.ring
        if n == 0 or start is None or not links[start[0]][start[1]]:
            return Route(np.zeros(0, np.int64), [], [], arrive, epu, False, 0, True, [],
                         entry, -1)
        s, p = start
        via_link = True
        ring = self.ring
        limit = 16 * n + 16
        steps = 0
        reopen: list[tuple[int, int, int]] = []
        latched = self.autoclose_latched
        while steps < limit:
            steps += 1
            if via_link:
                if (s, p) in latched and closed[s][p]:
                    reopen.append((s, p, len(arrivals)))
                arrivals.append((s, p, t, len(passes)))
                if arrive[s, p] < 0:
                    arrive[s, p] = t
            if p == 0:
                passes.append(s)
                port0_closed.append(closed[s][0])
                if epu[s] < 0:
                    # The processing unit sits in the middle of the chip's
                    # pipeline: half the forwarding delay after the port.
                    epu[s] = t + self.fwd_delay[s] // 2
                if sum(port0_closed) >= 2:
                    break  # circulating: destroyed on the second closed-port-0 pass
            q = NEXT_PORT[p]
            if closed[s][q]:
                s, p, via_link = s, q, False
                continue
            if not links[s][q]:
                break  # open port without link: the frame is lost
            t += self.fwd_delay[s]
            if s == 0 and q == 0:
                exit_port = PORT_A
                break
            if (s, q) == ring:
                exit_port = PORT_B
                break
            peer = self.links[s][q]
            assert peer is not None
            t += self.cable.get((s, q), 0)
            s, p, via_link = peer[0], peer[1], True
        arr = np.array(passes, dtype=np.int64)
        contiguous = bool(len(arr) == 0 or np.array_equal(arr, np.arange(len(arr))))
        return Route(arr, port0_closed, arrivals, arrive, epu, exit_port >= 0, t, contiguous,
                     reopen, entry, exit_port)
