"""The ring of a segment: the master's second port, frames entering at either port, faults.

Cable redundancy (ETG.1000.4 section 5.4; the ring topology of a master
with two ports A and B): port A feeds the first slave's port 0, port B is
cabled to a free port of a slave, normally the last one. ``sim.ports``
walks a frame from either master port; :class:`RingMixin` gives
:class:`~pyethercat.sim.segment.Segment` the master-port side of that:

- :meth:`~RingMixin.close_ring` cables port B, :meth:`~RingMixin.attach_port_b`
  says whether something listens there (a master NIC: without it the ring
  cable has no link partner and the last slave closes its loop);
- :meth:`~RingMixin.process_from` takes a frame entering at A or B and says
  at which master port it leaves;
- :meth:`~RingMixin.master_port_fault` cuts the cable at port A or B, as
  ``break_link`` cuts one between two slaves;
- :meth:`~RingMixin.remove_slave` / :meth:`~RingMixin.insert_slave` unplug a
  slave and plug the same or another device into its place (hot swap);
- :func:`ring_link` gives a master both ports of the ring in this process.

The mixin also compiles what the frame path uses (SM areas, the logical
map, configured addresses, the IRQ field) on first use after a change.
Compiled state that depends on the route (configured addresses, the
logical map, the IRQ field) is kept per master port: a set flag counts an
invalidation, and a port's saved state stays good while no invalidation
happened since it was compiled, so frames alternating between A and B do
not recompile anything.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.link.redundant import RedundantLink
from pyethercat.sim.commands import Commands, station_map
from pyethercat.sim.events import irq_field
from pyethercat.sim.host import Dirty
from pyethercat.sim.ports import Ports, Route

if TYPE_CHECKING:
    from pyethercat.sim.esc import Esc
    from pyethercat.sim.fmmu import LogicalMap
    from pyethercat.sim.memory import EscMemory
    from pyethercat.sim.pdio import ProcessIo
    from pyethercat.sim.syncman import SmAreas
    from pyethercat.sim.wiring import Wiring

__all__ = ["RingMixin", "ring_link"]

#: The segment's flag of each kind of compiled state.
_DIRTY_FLAGS = ((Dirty.ADDRESSING, "addressing_dirty"), (Dirty.FMMU, "fmmu_dirty"), (Dirty.SM, "sm_dirty"),
                (Dirty.IRQ, "irq_dirty"), (Dirty.WATCHDOG, "watchdog_dirty"), (Dirty.TOPOLOGY, "topology_dirty"))


class RingMixin:
    """Master ports A and B of a segment (see the module docstring)."""

    if TYPE_CHECKING:
        ports: Ports
        commands: Commands
        topology_dirty: bool
        last_exit: int
        _entry: int
        _route: Route | None
        _routes: list[Route]
        _saved: dict[int, tuple[dict[int, list[int]], LogicalMap | None, int, list[int]]]
        _stations: dict[int, list[int]]
        _lmap: LogicalMap | None
        _irq: int
        _inval: list[int]
        _computed: list[int]
        _addressing_dirty: bool
        _fmmu_dirty: bool
        _irq_dirty: bool
        _removed: set[int]
        memory: EscMemory
        escs: list[Esc]
        sm: SmAreas
        pdio: ProcessIo
        wiring: Wiring
        sm_dirty: bool
        watchdog_dirty: bool

        @property
        def route(self) -> Route: ...
        def process(self, frame: bytes | bytearray) -> bytes | None: ...
        def power_off(self, slave: int) -> None: ...
        def power_on(self, slave: int) -> None: ...
        def replace_slave(self, index: int, spec: Any) -> None: ...

    # --- the master's port B ---------------------------------------------------------

    def close_ring(self, slave: int | None = None, port: int | None = None) -> tuple[int, int]:
        """Cable master port B to ``slave``'s ``port`` (default: the last slave's first free port)."""
        where = self.ports.set_ring(slave, port)
        self.topology_dirty = True
        return where

    @property
    def ring(self) -> tuple[int, int] | None:
        """The (slave, port) cabled to master port B, or None (no ring)."""
        return self.ports.ring

    def attach_port_b(self, attached: bool = True) -> None:
        """Whether a master NIC listens at port B (the ring cable has a link partner)."""
        if attached and self.ports.ring is None:
            raise ConfigError("the segment has no ring: close it first (ring = true)")
        self.ports.master_b = attached
        self.topology_dirty = True

    def master_port_fault(self, port: int, broken: bool = True) -> None:
        """Cut (or reconnect) the cable at master port A (0) or B (1)."""
        slave, p = self.ports.master_port_key(port)
        if broken:
            self.ports.break_link(slave, p)
        else:
            self.ports.restore_link(slave, p)
        self.topology_dirty = True

    def route_from(self, port: int) -> Route:
        """The walk of frames entering at master port ``port`` (A = 0, B = 1)."""
        self.route  # noqa: B018  (brings the routes up to date)
        if port >= len(self._routes):
            raise ConfigError("the segment has no ring: the master has no port B")
        return self._routes[port]

    def process_from(self, frame: bytes | bytearray, port: int) -> tuple[int, bytes] | None:
        """A frame entering at master port ``port``: (the port it leaves by, the frame), or None if lost."""
        if port != self._entry:
            self._use_entry(port)
        out = self.process(frame)
        return None if out is None else (self.last_exit, out)

    # --- hot swap -----------------------------------------------------------------------

    def remove_slave(self, index: int) -> None:
        """Unplug slave ``index``: its neighbours lose their links, as at a power-off."""
        self.power_off(index)
        self._removed.add(index)

    def insert_slave(self, index: int, spec: Any = None) -> None:
        """Plug a device into the place of slave ``index``: the same one (``spec`` None) or another.

        The device starts as after power-on: INIT, station address 0, its
        EEPROM's alias."""
        if spec is not None:
            self.replace_slave(index, spec)
        self._removed.discard(index)
        self.power_on(index)

    def removed(self, index: int) -> bool:
        """Whether slave ``index`` is unplugged."""
        return index in self._removed

    # --- compiled state ---------------------------------------------------------------------

    def sm_span(self) -> tuple[int, int]:
        """[lo, hi) covered by any enabled SM of any slave (compiled on demand)."""
        if self.sm_dirty:
            self._refresh_sm_state()
        return self.sm.span

    def _refresh_sm_state(self) -> None:
        self.sm.compile(self.escs)
        self.pdio.invalidate()
        self.commands.invalidate(sm_changed=True)
        self.wiring.invalidate()
        self.sm_dirty = False
        self.fmmu_dirty = True
        self.watchdog_dirty = True

    def _refresh_fmmus(self) -> None:
        route = self.route
        if self.sm_dirty:
            self._refresh_sm_state()
        self._lmap = self.sm.logical_map(route, self.escs)
        self._computed[1] = self._inval[1]
        self.fmmu_dirty = False

    def _refresh_addressing(self) -> None:
        self._stations = station_map(self.memory, self.route.passes)
        self._computed[0] = self._inval[0]
        self.addressing_dirty = False

    def _refresh_irq(self) -> None:
        self._irq = irq_field(self.memory, self.route.passes)
        self._computed[2] = self._inval[2]
        self.irq_dirty = False

    def _invalidate_all(self) -> None:
        """Everything compiled must be rebuilt (slaves added, replaced, powered)."""
        self.topology_dirty = self.addressing_dirty = self.fmmu_dirty = True
        self.sm_dirty = self.irq_dirty = self.watchdog_dirty = True
        self.commands.invalidate()

    def invalidate(self, what: Dirty) -> None:
        """Compiled state ``what`` must be rebuilt before its next use."""
        for bit, flag in _DIRTY_FLAGS:
            if what & bit:
                setattr(self, flag, True)


    @property
    def unsettled(self) -> bool:
        """Whether the walk, SM areas, addresses or logical map must be compiled again."""
        return (self.topology_dirty or self.sm_dirty or self._addressing_dirty
                or self._fmmu_dirty or self._lmap is None)

    def settle(self) -> None:
        """Compile now what the next frames would compile after a change of the segment.

        A pulled cable, a port fault or a slave switched off changes the walk of
        every frame, and with it the addresses, the logical map and the IRQ
        field the frame path uses. Compiled lazily, that work falls on the first
        frames after the change (more than a millisecond for a few slaves, in
        Python): a 1 kHz master then sees a frame come back late although a real
        cable change costs the ESCs nothing. The control channel calls this
        between frames, so the next frame finds everything ready, including the
        logical plans of the datagrams each master port carried before.
        """
        # A datagram seen at either port: after a cable change each port's copy passes
        # slaves it did not pass before, so every port plans every shape.
        seen: dict[tuple[int, int, bool, bool], None] = {}
        for saved in self._saved.values():
            if saved[1] is not None:
                seen.update(dict.fromkeys(saved[1].plan_keys()))
        if self._lmap is not None:
            seen.update(dict.fromkeys(self._lmap.plan_keys()))
        keys = list(seen)
        entry = self._entry
        self.route  # noqa: B018  (the new walks)
        if self.sm_dirty:
            self._refresh_sm_state()
        for port in range(len(self._routes)):
            if port != self._entry:
                self._use_entry(port)
            if self._addressing_dirty:
                self._refresh_addressing()
            if self._fmmu_dirty or self._lmap is None:
                self._refresh_fmmus()
                lmap = self._lmap
                assert lmap is not None
                span = lmap.span_key()
                # Before any process data, the likely first datagram: one LRW over the map.
                for slaves in lmap.prepare(keys or ([span] if span is not None else [])):
                    self.sm.prepare_publish(slaves)
            if self._irq_dirty:
                self._refresh_irq()
        if self._entry != entry:
            self._use_entry(entry)

    # --- route-dependent compiled state per master port --------------------------------

    @property
    def addressing_dirty(self) -> bool:
        return self._addressing_dirty

    @addressing_dirty.setter
    def addressing_dirty(self, value: bool) -> None:
        if value:
            self._inval[0] += 1
        self._addressing_dirty = value

    @property
    def fmmu_dirty(self) -> bool:
        return self._fmmu_dirty

    @fmmu_dirty.setter
    def fmmu_dirty(self, value: bool) -> None:
        if value:
            self._inval[1] += 1
        self._fmmu_dirty = value

    @property
    def irq_dirty(self) -> bool:
        return self._irq_dirty

    @irq_dirty.setter
    def irq_dirty(self, value: bool) -> None:
        if value:
            self._inval[2] += 1
        self._irq_dirty = value

    def _use_entry(self, port: int) -> None:
        """Frames now enter at master port ``port``: switch the route and its compiled state."""
        self.route  # noqa: B018  (brings the routes up to date)
        if port >= len(self._routes):
            raise ConfigError("the segment has no ring: the master has no port B")
        self._saved[self._entry] = (self._stations, self._lmap, self._irq, list(self._computed))
        self._entry = port
        self._route = self._routes[port]
        saved = self._saved.get(port)
        if saved is None:
            self._computed = [-1, -1, -1]
            self._addressing_dirty = self._fmmu_dirty = self._irq_dirty = True
        else:
            self._stations, self._lmap, self._irq, self._computed = saved
            done, inval = self._computed, self._inval
            self._addressing_dirty = done[0] != inval[0]
            self._fmmu_dirty = done[1] != inval[1]
            self._irq_dirty = done[2] != inval[2]
        self.commands.route_tag = port



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
