"""A simulated EtherCAT segment: slaves joined port to port.

:meth:`Segment.process` takes one Ethernet frame from the master (it enters
the first slave's port 0) and returns the frame as it comes back, or None if
it is lost (open port without link, CRC error, drop, circulating frame).

This module is the segment's frame path and the place its parts meet:

- ``sim.ports``: ports, links, loop control and the walk of a frame
  (:class:`~pyethercat.sim.ports.Route`, computed once per topology change);
- ``sim.commands``: the rules of node-addressed and broadcast commands;
- ``sim.syncman`` and ``sim.fmmu``: the SM areas and the FMMU plans of
  logical addressing, compiled into index arrays;
- ``sim.dc``: local clocks, receive-time latches, system time, the time-control loop;
  ``sim.dc_sync``: SYNC pulses and latch inputs (``dc.sync``);
- ``sim.faults``, ``sim.watchdog``, ``sim.wiring``;
- ``sim.compiled``: what the frame path compiles (walk, SM areas, station
  map, logical map, IRQ field) and what of it is stale, per master port;
- ``sim.ring``: the master's ports A and B (a ring);
- ``sim.esc``: one ESC per slave, which reaches the segment only through
  the host protocol ``sim.host.EscHost`` (:class:`SegmentHost`, below).

Datagrams are processed one after the other, each for all slaves on the
route ("datagram-major"). This is equivalent to the wire order because
slaves share nothing but the frame: the only cross-slave effect inside one
frame is the logical image, which ``sim.fmmu`` keeps in route order.
Logical commands and broadcasts are array operations over the memory array;
configured/positional commands address one slave through its ESC.

Time: :meth:`tick` runs the time-driven parts (process-data watchdogs,
SYNC0/SYNC1 events to device applications); :meth:`process` calls it first.
With a virtual clock (the default) each processed frame advances the clock
by its modelled wire time (frame bytes x ``mac_wire_ns`` plus the forwarding
and cable delays), so DC times move as on a real segment; set
``advance_clock = False`` to drive time only from outside.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from pyethercat.clock import TimeSource, VirtualClock
from pyethercat.errors import ConfigError
from pyethercat.sim.after_frame import AfterFrame
from pyethercat.sim.apps import DeviceApps
from pyethercat.sim.arrival import OutputArrival
from pyethercat.sim.commands import Commands
from pyethercat.sim.compiled import CompiledState
from pyethercat.sim.datagrams import MALFORMED, Head, scan_frame
from pyethercat.sim.dc import DcClocks
from pyethercat.sim.esc import Esc
from pyethercat.sim.faults import NEVER, Faults
from pyethercat.sim.fmmu import DatagramPlan
from pyethercat.sim.fused import FusedLogical
from pyethercat.sim.host import Dirty
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.pdio import ProcessIo
from pyethercat.sim.ports import MASTER, NEXT_PORT, Ports, Route
from pyethercat.sim.ring import MasterPorts
from pyethercat.sim.slave import SimSlave, SimSlaveSpec
from pyethercat.sim.syncman import SmAreas
from pyethercat.sim.watchdog import Watchdogs
from pyethercat.sim.wiring import Wiring
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import (
    CIRCULATING_BIT,
    HEADER_SIZE,
    HEADER_TAIL,
    WKC,
    Command,
)
from pyethercat.wire.frame import (
    ECAT_HEADER_SIZE,
    ETH_HEADER_SIZE,
    LOCALLY_ADMINISTERED_BIT,
    WIRE_NS_PER_BYTE,
    ecat_offset,
)

__all__ = [
    "FCS_SIZE",
    "MASTER",
    "NEXT_PORT",
    "Route",
    "Segment",
    "SegmentHost",
    "SimSlave",
    "SimSlaveSpec",
]

I64 = npt.NDArray[np.int64]

#: Ethernet FCS bytes (on the wire, not in the frames we exchange).
FCS_SIZE = 4
_BRD = int(Command.BRD)
_FPRD = int(Command.FPRD)
_LWR = int(Command.LWR)
_LRD = int(Command.LRD)
#: Addressing class of each command code (IntEnum compares cost ~0.1 us each on the
#: frame path): 1 logical, 2 broadcast, 3 auto-increment, 4 configured; NOP and
#: unknown codes are absent (they pass untouched).
_CLASS: dict[int, int] = {
    int(Command.LRD): 1, int(Command.LWR): 1, int(Command.LRW): 1,
    int(Command.BRD): 2, int(Command.BWR): 2, int(Command.BRW): 2,
    int(Command.APRD): 3, int(Command.APWR): 3, int(Command.APRW): 3, int(Command.ARMW): 3,
    int(Command.FPRD): 4, int(Command.FPWR): 4, int(Command.FPRW): 4, int(Command.FRMW): 4,
}
_MIN_FRAME = ETH_HEADER_SIZE + ECAT_HEADER_SIZE
_OR_REDUCE = np.bitwise_or.reduce
_EMPTY = np.zeros(0, np.int64)
#: Processing time of one frame past which watchdogs are paused by it (see process()).
_SLOW_FRAME_NS = 1_000_000


class Segment:
    """A segment of simulated slaves; :meth:`process` answers one frame.

    With a ring (``sim.ring``) frames enter at master port A or B
    (:meth:`process_from`)."""

    def __init__(self, clock: TimeSource | None = None, mac_wire_ns: int = WIRE_NS_PER_BYTE) -> None:
        self.clock = clock if clock is not None else VirtualClock()
        self._host = SegmentHost(self)
        self.mac_wire_ns = mac_wire_ns
        #: Whether each processed frame advances a virtual clock by its wire time.
        self.advance_clock = True
        self.slaves: list[SimSlave] = []
        self.escs: list[Esc] = []
        self.memory = EscMemory()
        #: Duration for which SII commands keep the busy bit (0: the profiles' timing).
        self.sii_busy_ns = 0
        self.ports = Ports(self.memory, self.escs)
        self.faults = Faults(self.memory)
        self.dc = DcClocks(self.memory, self.escs, lambda: self.route)
        self.watchdogs = Watchdogs(self.memory)
        #: The firmware's work a frame sets in motion, run once it has passed (``sim.after_frame``).
        self.after_frame = AfterFrame(self._wall_ns, self._charge)
        self.wiring = Wiring(self.memory, self.escs)
        self.sm = SmAreas(self.memory)
        self.commands = Commands(self)
        self.apps = DeviceApps()
        self.arrival = OutputArrival(self.escs, self.sm, self.watchdogs, self.apps, self.wiring, self.now_ns,
                                     self.after_frame.add)
        self.pdio = ProcessIo(self.memory, self.escs, self.now_ns, self._host.has_outputs)
        self.dc.sync.sync0_sink = self.apps.sync0
        self.dc.sync.sync0_models = self.apps.sync0_models
        #: Compiled state and its staleness (see sim.compiled), the master's ports.
        self.state = CompiledState(self.ports, self.memory, self.escs, self.sm, self.commands,
                                   self.pdio, self.wiring, self.watchdogs)
        self.master_ports = MasterPorts(self.ports, self.state)
        #: The master port the last processed frame left by (-1: lost).
        self.last_exit = -1
        #: Slaves unplugged by remove_slave (hot swap).
        self._removed: set[int] = set()
        #: ECAT event bits that may be set in some slave (cleared by vectorised reads).
        self.event_bits = 0xFFFF
        #: Parses of single-datagram frames by bytes 12..25: (end, headers, circulating).
        self._parsed: dict[bytes, tuple[int, list[Head], bool]] = {}
        # Shared with the parts (never rebound there): the frame path reads them directly.
        self._bplan = self.commands.brd_plans
        self._fplan = self.commands.fprd_plans
        self._corrupt = self.faults.corrupt
        self._rates = self.faults.rates
        self._sync = self.dc.sync.sync_next
        self._cur_passes: I64 = _EMPTY
        self.frames = 0
        self.frames_lost = 0

    @property
    def clock(self) -> TimeSource:
        """The segment's time source (virtual by default)."""
        return self._clock

    @clock.setter
    def clock(self, clock: TimeSource) -> None:
        self._clock = clock
        # A virtual clock moves by each frame's wire time (see the module docstring);
        # the frame path uses its public ``ns``.
        self._vclock = clock if isinstance(clock, VirtualClock) else None

    def now_ns(self) -> int:
        """Current segment time."""
        return self._clock.now_ns()

    # --- building --------------------------------------------------------------------

    def add_slave(self, spec: SimSlaveSpec, parent: int | None = None, port: int | None = None,
                  cable_delay_ns: int = 5) -> int:
        """Add a slave; return its index.

        Without ``parent`` the slave continues the line: it joins the first
        free port (order 3, 1, 2... as the walk goes: 1 first, then 2, then
        3) of the previous slave on its port 0. With ``parent``/``port`` it
        hangs on that port of that slave (a tree branch).
        """
        index = len(self.slaves)
        esc = spec.make_esc(self._host, self.memory, index)
        self.escs.append(esc)  # (Ports.add looks the new slave's profile up)
        try:
            self.ports.add(index, spec.name, spec.delay_ns, parent, port, cable_delay_ns)
        except ConfigError:
            self.escs.pop()
            raise
        self.memory.add()
        self.slaves.append(SimSlave(spec.name, spec, index, esc))
        self.commands.add_slave(esc)
        self.watchdogs.add_slave()
        self.arrival.add_slave()
        self.apps.add(None, None, -1)
        esc.power_on()
        self._install(index, spec, esc)
        self.apps.power_on(index)
        self.state.invalidate_all()
        return index

    def replace_slave(self, index: int, spec: SimSlaveSpec) -> None:
        """Another device (``spec``) in the place of slave ``index``, switched off.

        Its cables stay where they were (ports the new chip lacks have no
        link); :meth:`insert_slave` switches it on."""
        self.power_off(index)
        esc = spec.make_esc(self._host, self.memory, index)
        self.escs[index] = esc
        self.slaves[index] = SimSlave(spec.name, spec, index, esc)
        self.ports.fwd_delay[index] = spec.delay_ns
        self.commands.replace_slave(index, esc)
        self._install(index, spec, esc)
        self.state.invalidate_all()

    def _install(self, index: int, spec: SimSlaveSpec, esc: Esc) -> None:
        """The slave's clock, model instance and application (new slave or hot swap)."""
        self.dc.add_slave(index, self.clock.now_ns(), spec.drift_ppm)
        model, instance = spec.model, spec.instance
        if model is not None:
            if instance < 0:
                instance = model.new_instance()
            model.placed(instance, index, self.pdio)
        self.apps.replace(index, spec.app, model, instance)
        if model is not None and model.sync_events:
            self.dc.sync.listen(index)
        if spec.app is not None:
            spec.app.attach(esc.pdi)

    def slave(self, key: int | str) -> SimSlave:
        """A slave by index or name."""
        found = self.slaves[key] if isinstance(key, int) else next(
            (s for s in self.slaves if s.name == key), None)
        if found is None:
            raise ConfigError(f"no slave named {key!r}")
        return found

    @property
    def route(self) -> Route:
        """The walk of frames entering at the current master port (recomputed after topology changes)."""
        state = self.state
        route = state.route
        return route if route is not None and not state.topology_dirty else state.walk()

    def invalidate(self, what: Dirty) -> None:
        """Compiled state ``what`` must be rebuilt before its next use."""
        self.state.invalidate(what)

    def sm_span(self) -> tuple[int, int]:
        """[lo, hi) covered by any enabled SM of any slave (compiled on demand)."""
        return self.state.sm_span()

    @property
    def unsettled(self) -> bool:
        """Whether the next frame would compile state again (``CompiledState.unsettled``)."""
        return self.state.unsettled

    def settle(self) -> None:
        """Compile between frames what a change made stale (``CompiledState.settle``)."""
        self.state.settle()

    # --- the master's ports (sim.ring) ----------------------------------------------------

    def close_ring(self, slave: int | None = None, port: int | None = None) -> tuple[int, int]:
        """Cable master port B to ``slave``'s ``port`` (``MasterPorts.close_ring``)."""
        return self.master_ports.close_ring(slave, port)

    @property
    def ring(self) -> tuple[int, int] | None:
        """The (slave, port) cabled to master port B, or None (no ring)."""
        return self.ports.ring

    def attach_port_b(self, attached: bool = True) -> None:
        """Whether a master NIC listens at port B (``MasterPorts.attach_port_b``)."""
        self.master_ports.attach_port_b(attached)

    def master_port_fault(self, port: int, broken: bool = True) -> None:
        """Cut (or reconnect) the cable at master port A (0) or B (1)."""
        self.master_ports.master_port_fault(port, broken)

    def process_from(self, frame: bytes | bytearray, port: int) -> tuple[int, bytes] | None:
        """A frame entering at master port ``port``: (the port it leaves by, the frame), or None if lost."""
        self.master_ports.enter_at(port)
        out = self.process(frame)
        return None if out is None else (self.last_exit, out)

    # --- faults ------------------------------------------------------------------------

    def break_link(self, slave: int, port: int) -> None:
        """Cut the cable at ``slave``'s ``port`` (both ends lose the link)."""
        self.ports.break_link(slave, port)
        self.state.topology_dirty = True

    def restore_link(self, slave: int, port: int) -> None:
        """Reconnect a cable cut with :meth:`break_link`."""
        self.ports.restore_link(slave, port)
        self.state.topology_dirty = True

    def power_off(self, slave: int) -> None:
        """Switch a slave off: it disappears, its neighbours lose their links."""
        self.escs[slave].powered = False
        self.memory.clear(slave)
        self.arrival.stop(slave)
        self.dc.sync.sync_drop(slave)
        self.state.invalidate_all()

    def power_on(self, slave: int) -> None:
        """Switch a slave on: INIT, station address 0, alias from the SII."""
        self.reset_slave(slave)

    def remove_slave(self, index: int) -> None:
        """Unplug slave ``index`` (hot swap): its neighbours lose their links, as at a power-off."""
        self.power_off(index)
        self._removed.add(index)

    def insert_slave(self, index: int, spec: SimSlaveSpec | None = None) -> None:
        """Plug a device into the place of slave ``index``: the same one (``spec`` None) or another,
        starting as after power-on (INIT, station address 0, its EEPROM's alias)."""
        if spec is not None:
            self.replace_slave(index, spec)
        self._removed.discard(index)
        self.power_on(index)

    def removed(self, index: int) -> bool:
        """Whether slave ``index`` is unplugged."""
        return index in self._removed

    # --- distributed clocks -----------------------------------------------------------

    def set_drift(self, slave: int, drift_ppm: float) -> None:
        """Change a slave's oscillator from now on (``drift_ppm``: deviation from nominal)."""
        self.dc.set_drift(slave, drift_ppm, self.clock.now_ns())

    def latch_input(self, slave: int, unit: int, rising: bool, t_ns: int | None = None) -> None:
        """An edge on DC latch input ``unit`` (0/1) of ``slave`` at segment time ``t_ns`` (now)."""
        self.dc.sync.latch_input(slave, unit, rising, self.clock.now_ns() if t_ns is None else t_ns)

    def dc_report(self) -> list[dict[str, object]]:
        """Per slave: walk time, oscillator drift, learned correction, |0x092C|, last SYNC0 (``DcClocks.report``)."""
        return self.dc.report([s.name for s in self.slaves])

    def reset_slave(self, slave: int) -> None:
        """Power-on reset of one ESC (also the 'RES' sequence in 0x0040)."""
        self.arrival.stop(slave)
        self.dc.reset(slave, self.clock.now_ns())
        self.escs[slave].power_on()
        self.ports.slave_reset(slave)
        self.apps.power_on(slave)
        self.state.invalidate_all()

    def corrupt_frames(self, slave: int, port: int, count: int = 1) -> None:
        """The next ``count`` frames arriving at ``slave``'s ``port`` carry a CRC error."""
        self.ports.peer_key(slave, port)
        self.faults.corrupt_frames(slave, port, count)

    def crc_error_rate(self, slave: int, port: int, rate: float, seed: int | None = None) -> None:
        """A bad cable: frames crossing the cable at ``slave``'s ``port`` (either way) get CRC
        errors with probability ``rate`` (0 mends it)."""
        peer = self.ports.peer_key(slave, port)
        self.faults.set_crc_rate(slave, port, rate, seed)
        if peer is not None:
            self.faults.set_crc_rate(peer[0], peer[1], rate)

    def drop_probability(self, p: float, seed: int | None = None) -> None:
        """Lose each frame with probability ``p`` (before any slave sees it)."""
        self.faults.set_drop_probability(p, seed)

    # --- process data ---------------------------------------------------------------------

    def wire(self, src_slave: int, src_bit: int, dst_slave: int, dst_bit: int, bits: int) -> None:
        """Bits of ``src``'s outputs (SM2 image) appear in ``dst``'s inputs (SM3 image)."""
        self.wiring.add(src_slave, src_bit, dst_slave, dst_bit, bits, len(self.slaves))

    def complete_write_sms(self, slaves: I64) -> None:
        """Buffered write SMs of ``slaves`` got their last byte (``sim.arrival``)."""
        if self.state.sm_dirty:
            self.state.compile_sm()
        if len(slaves):
            self.arrival.completed(slaves)

    # --- time ---------------------------------------------------------------------------------

    def tick(self, now: int | None = None) -> None:
        """Run time-driven work: process-data watchdogs, SYNC0/SYNC1 events."""
        if now is None:
            now = self.clock.now_ns()
        wd = self.watchdogs
        if self.state.watchdog_dirty or self.state.sm_dirty:
            self.state.compile_watchdogs()
        # Deadlines only move later when outputs arrive, so the earliest one
        # computed at the last check is a safe lower bound until then.
        if now > wd.deadline:
            for s in wd.due(now):
                self.arrival.received[s] = False
                self.escs[s].al.watchdog_expired()
        if self._sync:
            self.dc.sync.run_sync(now)
            self.apps.flush()

    # --- frames -------------------------------------------------------------------------------

    def process(self, frame: bytes | bytearray) -> bytes | None:
        """Process one frame from the master (at port A unless :meth:`process_from` chose B).

        The returned frame, or None if it is lost; ``last_exit`` says at which
        master port it came back (in a ring: B when the ring is closed). The
        firmware's reactions to the frame (:attr:`after_frame`) run before it
        returns, unless ``after_frame.hold`` leaves them to the caller."""
        after = self.after_frame
        after.in_frame = True
        try:
            return self._process(frame)
        finally:
            after.in_frame = False
            if after and not after.hold:
                after.run()

    def _process(self, frame: bytes | bytearray) -> bytes | None:
        vclock = self._vclock
        now = vclock.ns if vclock is not None else self._clock.now_ns()
        state = self.state
        # tick() only when time-driven work can be due: watchdog configuration
        # changed, the earliest watchdog deadline passed, or SYNC pulses planned.
        if state.watchdog_dirty or state.sm_dirty or now > self.watchdogs.deadline or self._sync:
            self.tick(now)
        self.frames += 1
        route = state.route
        if route is None or state.topology_dirty:
            route = state.walk()
        self.last_exit = route.exit
        faults = self.faults
        if faults.drop_p and faults.drops():
            self.frames_lost += 1
            return None
        if len(frame) < _MIN_FRAME or not route.live:
            self.frames_lost += 1
            return None
        buf = bytearray(frame)
        # A single-datagram frame is fully described by bytes 12..25 (EtherType,
        # EtherCAT header, datagram header): its parse is looked up, not redone.
        hit = None if self._corrupt or self._rates else self._parsed.get(
            frame[12:26] if type(frame) is bytes else bytes(frame[12:26]))
        if hit is not None and hit[0] <= len(buf):
            heads, any_c = hit[1], hit[2]
        else:
            parsed = self._parse(buf, route)
            if parsed is None or isinstance(parsed, bytes):
                if parsed is not None and route.reopen:
                    self._reopen_ports(route, False)  # a forwarded non-EtherCAT frame
                return parsed
            heads, any_c = parsed
        passes = route.passes
        count = route.count
        destroy = set_c = False
        if route.closed_idx:
            # A closed port 0 loops the frame back: marked circulating, or destroyed.
            done = route.passes_done(any_c)
            if done < count:
                passes, count, destroy = passes[:done], done, True
            else:
                set_c = True
        if faults.crc_cut >= 0:
            # CRC error on a link (sim.faults): the slaves passed before the bad
            # link took the frame; the receiving slave and all after it discard it.
            if faults.crc_cut < count:
                passes, count = passes[: faults.crc_cut], faults.crc_cut
            destroy = True
            faults.crc_cut = -1
            if not route.reopen:
                faults.crc_at = NEVER
        self.dc.frame_t0 = now
        self._cur_passes = passes
        if state.irq_stale:
            state.compile_irq()
        bplan = self._bplan
        fast_key = (count << 32) | (state.entry << 48)
        fplans = self._fplan
        # FPRD plans hold for the whole route. A frame a closed port or a CRC error cut is
        # destroyed anyway, and a topology change earlier in the frame changes no reply of
        # a plain register; both take the general path only so that a plan's meaning stays
        # plain (the slaves it was made for, on the route it was made for).
        fprd_key = -1 if count != route.count else state.entry << 48
        for off, cmd, address, lw, irq, n in heads:
            doff = off + HEADER_SIZE
            if set_c:
                lw |= CIRCULATING_BIT
            if cmd == _FPRD and fprd_key >= 0 and not state.addressing_stale \
                    and not state.topology_dirty:
                # FPRD of a plain register of one slave (the ring diagnosis reads three per
                # slave, mailbox polls one): the bytes copied, no call per datagram.
                key = address | (n << 32) | fprd_key
                fp = fplans.get(key)
                if fp is None:
                    fp = self.commands.fprd_plan(state.stations, route.passes, address & 0xFFFF,
                                                 address >> 16, n)
                    fplans[key] = fp
                if fp and not (fp.clear and fp.event[0] & fp.clear):
                    buf[doff:doff + n] = fp.source
                    HEADER_TAIL.pack_into(buf, off + 2, address, lw, irq | state.irq)
                    wkc_off = doff + n
                    WKC.pack_into(buf, wkc_off, (WKC.unpack_from(buf, wkc_off)[0] + 1) & 0xFFFF)
                    continue
            if cmd == _BRD:
                plan = bplan.get((address & 0xFFFF0000) | n | fast_key)
                if plan is not None and not plan.clear & self.event_bits and not state.topology_dirty:
                    # BRD of a 1/2/4/8-byte register read by every slave of a line
                    # (a topology change earlier in this frame takes the general
                    # path, which first brings DL status up to date).
                    words = plan.words
                    if words is not None:
                        # Short line: OR the column as Python ints (cheaper than a
                        # numpy call). Slaves mostly agree (AL status): one C-level
                        # count settles it.
                        col = words.tolist()
                        v = col[0]
                        if col.count(v) != count:
                            for x in set(col):
                                v |= x
                    else:
                        column = plan.column
                        assert column is not None  # (registered under the int key only with one)
                        v = int(_OR_REDUCE(column))
                    dw = plan.dw
                    d, w = dw.unpack_from(buf, doff)
                    dw.pack_into(buf, doff, d | v, (w + count) & 0xFFFF)
                    HEADER_TAIL.pack_into(buf, off + 2, ((address + count) & 0xFFFF) | (address & 0xFFFF0000),
                                           lw, irq | state.irq)
                    continue
            # The IRQ field passes each slave in the header, before the slave
            # executes the datagram: it shows the events as they were before it.
            irq |= state.irq
            kind = _CLASS.get(cmd)
            if kind is not None:
                if kind == 1:  # (logical: _datagram's first case, without its call)
                    add = self._logical(cmd, address, np.frombuffer(buf, np.uint8, n, doff), n)
                else:
                    add, address = self._datagram(cmd, address, np.frombuffer(buf, np.uint8, n, doff), n)
                if state.irq_stale:
                    state.compile_irq()
            else:
                add = 0  # NOP and unknown commands pass untouched
            HEADER_TAIL.pack_into(buf, off + 2, address, lw, irq)
            wkc_off = doff + n
            WKC.pack_into(buf, wkc_off, (WKC.unpack_from(buf, wkc_off)[0] + add) & 0xFFFF)
        self.frame_done(now, len(buf))
        if route.reopen:
            self._reopen_ports(route, any_c)
        if destroy or not route.returned:
            self.frames_lost += 1
            return None
        buf[6] |= LOCALLY_ADMINISTERED_BIT
        return bytes(buf)

    def _wall_ns(self) -> int | None:
        """Now on real time; None on a virtual clock (time moves by the frames)."""
        return None if self._vclock is not None else self._clock.now_ns()

    def _charge(self, since: int) -> None:
        """Real time spent serving since ``since``. A frame that kept the simulator busy
        long (AL control for a thousand slaves, one ESC after the other in Python) must
        not run out the watchdogs of slaves whose next outputs wait behind it."""
        spent = self._clock.now_ns() - since
        if spent > _SLOW_FRAME_NS:
            self.watchdogs.pause(spent)

    def frame_done(self, now: int, size: int) -> None:
        """The time a frame of ``size`` bytes that entered at ``now`` took: a virtual clock
        moves by its wire time; on real time a slow frame pauses the watchdogs."""
        vclock = self._vclock
        if vclock is None:
            self._charge(now)
        elif self.advance_clock:
            state = self.state
            walk = state.route
            if walk is None or state.topology_dirty:
                walk = state.walk()
            # (no max(): a builtin call costs more than the whole sum)
            vclock.ns += ((size if size > 60 else 60) + FCS_SIZE) * self.mac_wire_ns + walk.delay_ns

    def _parse(self, buf: bytearray, route: Route) -> tuple[list[Head], bool] | bytes | None:
        """Check and parse a frame: (datagram headers, any circulating bit) to process it,
        else what process() returns (the unchanged non-EtherCAT frame, or None if lost).
        A malformed frame is not processed at all (counted as a processing error)."""
        start = ecat_offset(buf)
        if start is None:
            # Non-EtherCAT frames pass unchanged unless the first slave destroys them.
            if len(route.passes) and self.memory.mem[route.passes[0], R.DL_CONTROL] & R.DL_CONTROL_FORWARDING_RULE:
                return None
            return bytes(buf) if route.returned else None  # passed on unchanged
        cut = self.faults.apply_corruption(route) if self._corrupt or self._rates else (-1, NEVER)
        scanned = scan_frame(buf, start)  # all headers first: a malformed frame is not processed
        if isinstance(scanned, int):
            if scanned == MALFORMED:
                self.frames_lost += 1
                self.faults.processing_error(route)
            return None
        end, heads, any_c = scanned
        if start == ETH_HEADER_SIZE and len(heads) == 1:
            if len(self._parsed) >= 1024:
                self._parsed.clear()
            self._parsed[bytes(buf[12:26])] = (end, heads, any_c)
        self.faults.crc_cut, self.faults.crc_at = cut
        return heads, any_c

    def _reopen_ports(self, route: Route, any_c: bool) -> None:
        """A valid frame arrived at latched auto-close ports (``sim.ports``): the next walk has them open."""
        crc_at, self.faults.crc_at = self.faults.crc_at, NEVER
        if self.ports.reopen(route, any_c, crc_at):
            self.state.topology_dirty = True

    # --- datagrams ------------------------------------------------------------------------------

    def _datagram(self, cmd: int, address: int, data: npt.NDArray[np.uint8], n: int) -> tuple[int, int]:
        """Process one datagram over the route; (working counter increment, new address field)."""
        kind = _CLASS.get(cmd, 0)
        if kind == 1:
            return self._logical(cmd, address, data, n), address
        passes = self._cur_passes
        count = len(passes)
        adp = address & 0xFFFF
        ado = address >> 16
        if kind == 2:
            wkc = self.commands.broadcast(cmd, self.route, passes, ado, data, n)
            return wkc, ((adp + count) & 0xFFFF) | (ado << 16)
        if kind == 3:  # auto-increment: the slave that sees ADP 0
            new_address = ((adp + count) & 0xFFFF) | (ado << 16)
            return self.commands.addressed(cmd, passes, [(-adp) & 0xFFFF], ado, data, n), new_address
        if kind == 4:
            state = self.state
            if state.addressing_stale:
                state.compile_addressing()
            return self.commands.addressed(cmd, passes, state.stations.get(adp), ado, data, n), address
        return 0, address  # NOP and unknown commands pass untouched

    def logical_plan(self, cmd: int, address: int, n: int) -> DatagramPlan | None:
        """The plan of a logical datagram of ``n`` bytes (SMs and FMMUs compiled first
        when they changed); None when no FMMU maps anything."""
        state = self.state
        if state.sm_dirty:
            state.compile_sm()
        if state.fmmu_stale or state.lmap is None:
            state.compile_fmmus()
        lmap = state.lmap
        assert lmap is not None
        if lmap.empty or n == 0:
            return None
        return lmap.plan(address & 0xFFFFFFFF, n, cmd != _LWR, cmd != _LRD)

    def _logical(self, cmd: int, address: int, data: npt.NDArray[np.uint8], n: int) -> int:
        plan = self.logical_plan(cmd, address, n)
        fused = None if plan is None else plan.fused
        if plan is None or fused is None:  # (no slave takes part: working counter 0)
            return 0
        memory = self.memory
        flat = memory.flat
        for stage in plan.stages:
            stage.apply(flat, data)
        self.registers_done(fused, flat)
        return plan.wkc

    def registers_done(self, fused: FusedLogical, flat: npt.NDArray[np.uint8]) -> None:
        """A logical datagram's data moved: its register updates and the publish of the
        buffers it completed (one program, ``sim.fused``), and what follows those."""
        if fused.registers(flat, self.memory.shadow_flat):
            self.state.irq_changed()
        done = fused.done
        if len(done):
            self.arrival.published(done, fused.wd_slaves, self.dc.frame_t0)


#: AL states in which a slave takes no outputs (its output arrival is forgotten).
_BELOW_SAFEOP = (AlState.INIT, AlState.PREOP, AlState.BOOT)


class SegmentHost:
    """The segment as its ESCs see it (:class:`EscHost`)."""

    __slots__ = ("_seg",)

    def __init__(self, seg: Segment) -> None:
        self._seg = seg

    @property
    def sii_busy_ns(self) -> int:
        return self._seg.sii_busy_ns

    def now_ns(self) -> int:
        return self._seg.clock.now_ns()

    def invalidate(self, what: Dirty) -> None:
        self._seg.state.invalidate(what)

    def ecat_event_raised(self, bits: int) -> None:
        seg = self._seg
        seg.event_bits |= bits
        seg.state.irq_changed()

    def al_state_changed(self, index: int, old: AlState, new: AlState) -> None:
        if new in _BELOW_SAFEOP:
            self._seg.arrival.stop(index)
        self._seg.apps.state_changed(index, old, new)

    def has_outputs(self, index: int) -> bool:
        return bool(self._seg.arrival.received[index])

    def wait_for_outputs(self, index: int, waiting: bool) -> None:
        pending = self._seg.arrival.pending_op
        if waiting:
            pending.add(index)
        else:
            pending.discard(index)

    def output_buffer_completed(self, index: int) -> None:
        self._seg.complete_write_sms(np.array([index], dtype=np.int64))

    def reset_requested(self, index: int) -> None:
        self._seg.reset_slave(index)

    def loop_control_written(self, index: int, old: int, new: int) -> None:
        self._seg.ports.loop_control_written(index, new)
        self._seg.state.topology_dirty = True

    def dc_written(self, index: int, lo: int, data: bytes) -> None:
        seg = self._seg
        seg.dc.written(np.array([index], dtype=np.int64), lo, data, seg.escs[index].profile.dc_system_time)

    def dc_refresh(self, index: int) -> None:
        self._seg.dc.refresh_one(index)

    def dc_sync_status(self, index: int, lo: int, hi: int, pdi: bool) -> None:
        seg = self._seg
        seg.dc.sync.refresh_sync_status(index, lo, hi, seg.clock.now_ns() if pdi else None)

    def dc_latch_input(self, index: int, unit: int, rising: bool, t_ns: int | None) -> None:
        self._seg.latch_input(index, unit, rising, t_ns)

    def after_frame(self, work: Callable[[], None]) -> None:
        self._seg.after_frame.add(work)
