"""The ring of a segment: the master's second port, frames entering at either port, faults.

Cable redundancy (ETG.1000.4 section 5.4; the ring topology of a master
with two ports A and B): port A feeds the first slave's port 0, port B is
cabled to a free port of a slave, normally the last one. ``sim.ports``
walks a frame from either master port; :class:`MasterPorts` is the master's
side of that, owned by :class:`~pyethercat.sim.segment.Segment`:

- :meth:`~MasterPorts.close_ring` cables port B, :meth:`~MasterPorts.attach_port_b`
  says whether something listens there (a master NIC: without it the ring
  cable has no link partner and the last slave closes its loop);
- :meth:`~MasterPorts.master_port_fault` cuts the cable at port A or B, as
  ``Segment.break_link`` cuts one between two slaves;
- :meth:`~MasterPorts.enter_at` makes the next frames enter at A or B: the
  segment's compiled state (``sim.compiled``) switches to that port's walk
  (``Segment.process_from`` takes a frame entering at either port and says
  at which master port it leaves);
- :func:`ring_link` gives a master both ports of the ring in this process.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.link.redundant import RedundantLink

if TYPE_CHECKING:
    from pyethercat.sim.compiled import CompiledState
    from pyethercat.sim.ports import Ports

__all__ = ["MasterPorts", "ring_link"]


class MasterPorts:
    """Master ports A and B of a segment (see the module docstring): the cabling in
    ``ports``, the walk of each port in ``state``."""

    def __init__(self, ports: Ports, state: CompiledState) -> None:
        self._ports = ports
        self._state = state

    def close_ring(self, slave: int | None = None, port: int | None = None) -> tuple[int, int]:
        """Cable master port B to ``slave``'s ``port`` (default: the last slave's first free port)."""
        where = self._ports.set_ring(slave, port)
        self._state.topology_dirty = True
        return where

    @property
    def ring(self) -> tuple[int, int] | None:
        """The (slave, port) cabled to master port B, or None (no ring)."""
        return self._ports.ring

    def attach_port_b(self, attached: bool = True) -> None:
        """Whether a master NIC listens at port B (the ring cable has a link partner)."""
        if attached and self._ports.ring is None:
            raise ConfigError("the segment has no ring: close it first (ring = true)")
        self._ports.master_b = attached
        self._state.topology_dirty = True

    def master_port_fault(self, port: int, broken: bool = True) -> None:
        """Cut (or reconnect) the cable at master port A (0) or B (1)."""
        slave, p = self._ports.master_port_key(port)
        if broken:
            self._ports.break_link(slave, p)
        else:
            self._ports.restore_link(slave, p)
        self._state.topology_dirty = True

    def enter_at(self, port: int) -> None:
        """The next frames enter at master port ``port`` (A = 0, B = 1)."""
        if port != self._state.entry:
            self._state.use_entry(port)


class _SimPort(PairLink):
    """The master's end of an in-process pair that knows its cable's state (a NIC's carrier)."""

    carrier_fn: Callable[[], bool] | None = None

    def carrier(self) -> bool | None:
        fn = self.carrier_fn
        return None if fn is None else fn()


def ring_link(segment: Any, name: str = "sim",
              before: Callable[[int], None] | None = None) -> RedundantLink:
    """The master's ports A and B of an in-process ring served by ``segment``.

    Two in-process pairs: a frame sent on either is answered inside ``send``
    (as :meth:`PairLink.responder_link` does for one port) and comes back on
    the port where it leaves the ring. Each port reports the state of its
    cable as its carrier. The segment's ring is closed at the last slave when
    the topology did not place it. ``before(port)`` runs just before each
    frame enters the ring at ``port`` (a fault injected there hits a frame
    whose other copy is already through).
    """
    if segment.ring is None:
        segment.close_ring()
    segment.attach_port_b()
    master_a, sim_a = _SimPort.pair(f"{name}:A", f"{name}:A-sim")
    master_b, sim_b = _SimPort.pair(f"{name}:B", f"{name}:B-sim")
    sims = (sim_a, sim_b)

    def answer(port: int) -> Callable[[bytes], bytes | None]:
        def respond(frame: bytes) -> bytes | None:
            if before is not None:
                before(port)
            got = segment.process_from(frame, port)
            if got is None:
                return None
            exit_port, out = got
            if exit_port == port:
                return bytes(out)
            sims[exit_port].send(out)  # queued at the master's end of the other port
            return None
        return respond

    def cable(port: int) -> Callable[[], bool]:
        def up() -> bool:
            s, p = segment.ports.master_port_key(port)
            return bool(segment.ports.link_up(s, p))
        return up

    sim_a.set_responder(answer(0))
    sim_b.set_responder(answer(1))
    master_a.carrier_fn = cable(0)
    master_b.carrier_fn = cable(1)
    return RedundantLink(master_a, master_b, name)
