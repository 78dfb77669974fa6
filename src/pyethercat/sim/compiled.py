"""What a segment's frame path compiles from the registers and the walk of frames.

The frame path (``sim.segment``) uses compiled state instead of reading
registers per frame: the walk (:class:`~pyethercat.sim.ports.Route`), the
SM areas, the configured-address map, the logical map (``sim.fmmu``) and
the IRQ field. :class:`CompiledState` holds it, knows what is stale (the
``Dirty`` bits an ESC or a cable change raises, ``sim.host``) and compiles
it on first use after a change.

State that depends on the route (configured addresses, the logical map, the
IRQ field) is kept per master port: frames of a ring enter at port A or B
(``sim.ring``) and walk the slaves in opposite orders. Each invalidation is
counted, and a port's saved state stays good while no invalidation happened
since it was compiled, so frames alternating between A and B do not
recompile anything.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pyethercat.errors import ConfigError
from pyethercat.sim.commands import station_map
from pyethercat.sim.events import irq_field
from pyethercat.sim.host import Dirty
from pyethercat.sim.ports import PORT_A

if TYPE_CHECKING:
    from pyethercat.sim.commands import Commands
    from pyethercat.sim.esc import Esc
    from pyethercat.sim.fmmu import LogicalMap
    from pyethercat.sim.memory import EscMemory
    from pyethercat.sim.pdio import ProcessIo
    from pyethercat.sim.ports import Ports, Route
    from pyethercat.sim.syncman import SmAreas
    from pyethercat.sim.watchdog import Watchdogs
    from pyethercat.sim.wiring import Wiring

__all__ = ["CompiledState"]

_ADDRESSING, _FMMU, _IRQ = 0, 1, 2
_Saved = tuple[dict[int, list[int]], "LogicalMap | None", int, list[int]]


class CompiledState:
    """The compiled state of one segment and its staleness (see the module docstring).

    The frame path reads the public attributes directly: ``route`` (the walk
    of frames entering at master port ``entry``), ``stations``, ``lmap`` and
    ``irq``, each valid while its ``*_stale`` flag (or ``topology_dirty``,
    ``sm_dirty``) is clear.
    """

    def __init__(self, ports: Ports, memory: EscMemory, escs: list[Esc], sm: SmAreas,
                 commands: Commands, pdio: ProcessIo, wiring: Wiring, watchdogs: Watchdogs) -> None:
        self._ports = ports
        self._memory = memory
        self._escs = escs
        self._sm = sm
        self._commands = commands
        self._pdio = pdio
        self._wiring = wiring
        self._watchdogs = watchdogs
        #: Segment-wide: the walk, the SM areas, the watchdog limits.
        self.topology_dirty = True
        self.sm_dirty = True
        self.watchdog_dirty = True
        #: Route-dependent: stale flags, and per kind the invalidations counted
        #: and the count when last compiled.
        self.addressing_stale = self.fmmu_stale = self.irq_stale = True
        self._inval = [0, 0, 0]
        self._computed = [-1, -1, -1]
        self.route: Route | None = None
        #: One route per master port (see sim.ports); ``route`` is the entry's.
        self.routes: list[Route] = []
        #: The master port frames enter at, and per port the state saved when
        #: frames last entered there (a ring alternates A and B).
        self.entry = PORT_A
        self._saved: dict[int, _Saved] = {}
        self.stations: dict[int, list[int]] = {}
        self.lmap: LogicalMap | None = None
        self.irq = 0

    # --- staleness ----------------------------------------------------------------------

    def invalidate(self, what: Dirty) -> None:
        """Compiled state ``what`` must be rebuilt before its next use."""
        if what & Dirty.TOPOLOGY:
            self.topology_dirty = True
        if what & Dirty.SM:
            self.sm_dirty = True
        if what & Dirty.WATCHDOG:
            self.watchdog_dirty = True
        if what & Dirty.ADDRESSING:
            self._inval[_ADDRESSING] += 1
            self.addressing_stale = True
        if what & Dirty.FMMU:
            self._inval[_FMMU] += 1
            self.fmmu_stale = True
        if what & Dirty.IRQ:
            self.irq_changed()

    def irq_changed(self) -> None:
        """ECAT event requests or masks changed (the frame path's cheap form of invalidate)."""
        self._inval[_IRQ] += 1
        self.irq_stale = True

    def invalidate_all(self) -> None:
        """Everything compiled must be rebuilt (slaves added, replaced, powered)."""
        self.invalidate(Dirty.TOPOLOGY | Dirty.ADDRESSING | Dirty.FMMU | Dirty.SM | Dirty.IRQ
                        | Dirty.WATCHDOG)
        self._commands.invalidate()

    @property
    def unsettled(self) -> bool:
        """Whether the walk, SM areas, addresses or logical map must be compiled again."""
        return (self.topology_dirty or self.sm_dirty or self.addressing_stale
                or self.fmmu_stale or self.lmap is None)

    # --- compiling ------------------------------------------------------------------------

    def walk(self) -> Route:
        """The walk of frames entering at the current master port (recomputed after topology changes)."""
        if self.topology_dirty or self.route is None:
            self.routes = self._ports.update()
            if self.entry >= len(self.routes):
                self.entry = PORT_A
            self.route = self.routes[self.entry]
            self.topology_dirty = False
            self.invalidate(Dirty.ADDRESSING | Dirty.FMMU | Dirty.IRQ)
            self._commands.brd_plans.clear()
            self._commands.fprd_plans.clear()
        return self.route

    def route_from(self, port: int) -> Route:
        """The walk of frames entering at master port ``port`` (A = 0, B = 1)."""
        self.walk()
        if port >= len(self.routes):
            raise ConfigError("the segment has no ring: the master has no port B")
        return self.routes[port]

    def sm_span(self) -> tuple[int, int]:
        """[lo, hi) covered by any enabled SM of any slave."""
        if self.sm_dirty:
            self.compile_sm()
        return self._sm.span

    def compile_sm(self) -> None:
        self._sm.compile(self._escs)
        self._pdio.invalidate()
        self._commands.invalidate(sm_changed=True)
        self._wiring.invalidate()
        self.sm_dirty = False
        self.invalidate(Dirty.FMMU | Dirty.WATCHDOG)

    def compile_watchdogs(self) -> None:
        if self.sm_dirty:
            self.compile_sm()
        self._watchdogs.refresh(len(self._escs))
        self.watchdog_dirty = False

    def compile_fmmus(self) -> None:
        route = self.walk()
        if self.sm_dirty:
            self.compile_sm()
        self.lmap = self._sm.logical_map(route, self._escs)
        self._computed[_FMMU] = self._inval[_FMMU]
        self.fmmu_stale = False

    def compile_addressing(self) -> None:
        self.stations = station_map(self._memory, self.walk().passes)
        self._commands.fprd_plans.clear()
        self._computed[_ADDRESSING] = self._inval[_ADDRESSING]
        self.addressing_stale = False

    def compile_irq(self) -> None:
        self.irq = irq_field(self._memory, self.walk().passes)
        self._computed[_IRQ] = self._inval[_IRQ]
        self.irq_stale = False

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
        if self.lmap is not None:
            seen.update(dict.fromkeys(self.lmap.plan_keys()))
        keys = list(seen)
        entry = self.entry
        self.walk()
        if self.sm_dirty:
            self.compile_sm()
        for port in range(len(self.routes)):
            if port != self.entry:
                self.use_entry(port)
            if self.addressing_stale:
                self.compile_addressing()
            if self.fmmu_stale or self.lmap is None:
                self.compile_fmmus()
                lmap = self.lmap
                assert lmap is not None
                span = lmap.span_key()
                # Before any process data, the likely first datagram: one LRW over the map
                # (its plan holds the publish of the buffers it completes: sim.fused).
                lmap.prepare(keys or ([span] if span is not None else []))
            if self.irq_stale:
                self.compile_irq()
        if self.entry != entry:
            self.use_entry(entry)

    def use_entry(self, port: int) -> None:
        """Frames now enter at master port ``port``: switch the route and its compiled state."""
        self.walk()
        if port >= len(self.routes):
            raise ConfigError("the segment has no ring: the master has no port B")
        self._saved[self.entry] = (self.stations, self.lmap, self.irq, list(self._computed))
        self.entry = port
        self.route = self.routes[port]
        saved = self._saved.get(port)
        if saved is None:
            self._computed = [-1, -1, -1]
            self.addressing_stale = self.fmmu_stale = self.irq_stale = True
        else:
            self.stations, self.lmap, self.irq, self._computed = saved
            done, inval = self._computed, self._inval
            self.addressing_stale = done[_ADDRESSING] != inval[_ADDRESSING]
            self.fmmu_stale = done[_FMMU] != inval[_FMMU]
            self.irq_stale = done[_IRQ] != inval[_IRQ]
        self._commands.route_tag = port
