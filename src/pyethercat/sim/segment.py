"""A simulated EtherCAT segment: slaves joined port to port (issue 3).

:meth:`Segment.process` takes one Ethernet frame from the master (it enters
the first slave's port 0) and returns the frame as it comes back, or None if
it is lost (open port without link, CRC error, drop, circulating frame).

The frame walk follows the port order 0 -> processing unit -> 3 -> 1 -> 2 ->
0 of every slave; closed ports (no link, or loop control) send the frame
back at once, so a broken link closes the loop at the port before it (seed
000, Bild 5c/5d). The walk is computed once per topology change: the list of
processing-unit passes (the route), the arrival time at every port (DC
receive times) and the total forwarding delay.

Datagrams are processed one after the other, each for all slaves on the
route ("datagram-major"). This is equivalent to the wire order because
slaves share nothing but the frame: the only cross-slave effect inside one
frame is the logical image, which ``sim.fmmu`` keeps in route order.
Logical commands and broadcasts are array operations over the memory array;
configured/positional commands address one slave through its :class:`Esc`.
Broadcast writes to registers with per-slave side effects (AL control, SII,
sync managers, DL control, DC cyclic unit) take a per-slave path: those are
configuration-time writes, never cyclic ones.

Time: :meth:`tick` runs the time-driven parts (process-data watchdogs,
SYNC0/SYNC1 events to device applications); :meth:`process` calls it first.
With a :class:`VirtualClock` (the default) each processed frame advances the
clock by its modelled wire time (frame bytes x ``mac_wire_ns`` plus the
forwarding and cable delays), so DC times move as on a real segment; set
``advance_clock = False`` to drive time only from outside.
"""

from __future__ import annotations

import random
import struct
import sys
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError
from pyethercat.sim.clock import Clock, VirtualClock
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.esc import _WRITE_TRIGGER, SIDE_EFFECT_MASK, Esc, buffer_written
from pyethercat.sim.fmmu import SLAVE_STRIDE, LogicalMap, SmReads, parse_fmmus
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.profiles import EscProfile
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import (
    CIRCULATING_BIT,
    HEADER,
    HEADER_SIZE,
    LEN_MASK,
    MORE_BIT,
    WKC_SIZE,
    Command,
)
from pyethercat.wire.frame import (
    ECAT_HEADER_SIZE,
    ECAT_LENGTH_MASK,
    ECAT_TYPE_SHIFT,
    ETH_HEADER_SIZE,
    ETHERTYPE_ETHERCAT,
    ETHERTYPE_VLAN,
    LOCALLY_ADMINISTERED_BIT,
    FrameType,
)

__all__ = [
    "FCS_SIZE",
    "MASTER",
    "NEXT_PORT",
    "Route",
    "Segment",
    "SimSlave",
    "SlaveSpec",
]

I64 = npt.NDArray[np.int64]

#: Next port in the forwarding order 0 -> 3 -> 1 -> 2 -> 0.
NEXT_PORT = (3, 2, 0, 1)
MASTER = -1
#: Ethernet FCS bytes (on the wire, not in the frames we exchange).
FCS_SIZE = 4
_WKC = struct.Struct("<H")
#: Datagram header from byte 2 on: address, length word, IRQ (patched in the reply).
_HEADER_TAIL = struct.Struct("<IHH")
_BRD = int(Command.BRD)
#: Addressing class of each command code (IntEnum compares cost ~0.1 us each on the
#: frame path): 1 logical, 2 broadcast, 3 auto-increment, 4 configured; NOP and
#: unknown codes are absent (they pass untouched).
_CLASS: dict[int, int] = {
    int(Command.LRD): 1, int(Command.LWR): 1, int(Command.LRW): 1,
    int(Command.BRD): 2, int(Command.BWR): 2, int(Command.BRW): 2,
    int(Command.APRD): 3, int(Command.APWR): 3, int(Command.APRW): 3, int(Command.ARMW): 3,
    int(Command.FPRD): 4, int(Command.FPWR): 4, int(Command.FPRW): 4, int(Command.FRMW): 4,
}
_READS = frozenset((int(Command.APRD), int(Command.FPRD)))
_WRITES = frozenset((int(Command.APWR), int(Command.FPWR)))
_RMW = frozenset((int(Command.ARMW), int(Command.FRMW)))
#: A parsed datagram header: offset, command, address, length word, IRQ, data length.
_Head = tuple[int, int, int, int, int, int]
_DATAGRAMS = int(FrameType.DATAGRAMS)
_MIN_FRAME = ETH_HEADER_SIZE + ECAT_HEADER_SIZE
#: Longest route for which a BRD ORs a register column as Python ints (numpy above).
_BRD_PY_MAX = 64
_OR_REDUCE = np.bitwise_or.reduce
#: Marker: every byte of the range is writable (one slice assignment).
_ALL: I64 = np.arange(1, dtype=np.int64)
_WORD_FORMAT: dict[int, Literal["B", "H", "I", "Q"]] = {1: "B", 2: "H", 4: "I", 8: "Q"}
#: Data word and working counter of a 1/2/4/8-byte datagram, little endian.
_DATA_WKC: dict[int, struct.Struct] = {n: struct.Struct("<" + f + "H") for n, f in _WORD_FORMAT.items()}
_EMPTY = np.zeros(0, np.int64)
_NEVER = 1 << 62
_U64_MAX = (1 << 64) - 1
_WIDE: dict[int, str] = {1: "u1", 2: "<u2", 4: "<u4", 8: "<u8"}
_EV_DL_STATUS = int(R.EcatEvent.DL_STATUS)
_EV_AL_STATUS = int(R.EcatEvent.AL_STATUS)


class _BrdPlan:
    """Cached work of one BRD shape (address, length, route length)."""

    __slots__ = ("slow", "rows", "contiguous", "systime", "block", "column", "clear", "words", "dw")

    def __init__(self) -> None:
        self.slow = False
        self.rows: I64 = _EMPTY
        self.contiguous = False
        self.systime = False
        self.block: npt.NDArray[np.uint8] | None = None
        self.column: npt.NDArray[np.unsignedinteger[Any]] | None = None
        self.clear = 0
        #: Fast path (Segment.process): the register column as a strided
        #: memoryview of native words (all route slaves implement it) and the
        #: little-endian struct of the datagram's data and working counter.
        self.words: memoryview | None = None
        self.dw: struct.Struct = _WKC


def _status_after_write_table() -> npt.NDArray[np.uint8]:
    """SM status byte after an ECAT buffered write completed (read event cleared), by old status."""
    return np.array([buffer_written(old) & ~R.SM_STATUS_READ_EVENT & 0xFF for old in range(256)], np.uint8)


_STATUS_AFTER_WRITE = _status_after_write_table()


def _per_slave_write_mask() -> npt.NDArray[np.bool_]:
    """Register bytes whose ECAT writes need the per-slave path.

    Those with side effects, less the ranges ``Segment._multi_write`` handles
    as array operations (addressing, event mask, FMMUs, DC latch and system
    time, watchdog divider and time)."""
    mask = SIDE_EFFECT_MASK.copy()
    for a, b in ((R.STATION_ADDRESS, R.STATION_ALIAS + 2), (R.ECAT_EVENT_MASK, R.ECAT_EVENT_MASK + 2),
                 (R.FMMU_BASE, R.SM_BASE), (R.DC_RECEIVE_TIME_PORT0, R.DC_SYSTEM_TIME + 8),
                 (R.WATCHDOG_DIVIDER, R.WATCHDOG_STATUS_PROCESS_DATA)):
        mask[a:b] = False
    mask.setflags(write=False)
    return mask


_PER_SLAVE_WRITE = _per_slave_write_mask()


def _byte_and_mask(bit: int) -> tuple[int, int]:
    """Byte offset and in-byte mask of a one-bit register value (e.g. ``R.al_event_sm(n)``)."""
    pos = bit.bit_length() - 1
    return pos >> 3, 1 << (pos & 7)


@dataclass
class SlaveSpec:
    """What a slave is: its EEPROM image, its ESC and its application.

    ``alias`` overrides SII word 4; ``drift_ppm`` makes its local clock run
    fast (positive) or slow; ``forwarding_delay_ns`` overrides the profile's
    delay; ``initial_inputs`` fills the input SM as soon as it is enabled.
    """

    name: str
    sii: bytes
    profile: EscProfile
    app: DeviceApp | None = None
    alias: int | None = None
    drift_ppm: float = 0.0
    forwarding_delay_ns: int | None = None
    initial_inputs: bytes | None = None


class SimSlave:
    """One slave of a segment. ``esc`` is its ESC model; ``read``/``write`` are raw test helpers."""

    def __init__(self, name: str, spec: SlaveSpec, index: int, esc: Esc) -> None:
        self.name = name
        self.spec = spec
        self.index = index
        self.esc = esc

    def read(self, address: int, length: int) -> bytes:
        """Raw memory bytes (no side effects)."""
        return self.esc.row[address: address + length].tobytes()

    def write(self, address: int, data: bytes) -> None:
        """Raw memory write (no side effects; for test set-up)."""
        self.esc.row[address: address + len(data)] = np.frombuffer(bytes(data), np.uint8)

    def u16(self, address: int) -> int:
        return self.esc.u16(address)

    @property
    def al_state(self) -> AlState:
        return self.esc.al_state()

    def __repr__(self) -> str:
        return f"SimSlave({self.index}, {self.name!r}, {self.spec.profile.name})"


@dataclass
class Route:
    """The walk of a frame from the master through the segment (computed per topology)."""

    passes: I64                # slave index of each processing-unit pass, in order
    port0_closed: list[bool]   # per pass: the slave's port 0 is closed (circulating rule)
    #: (slave, port, ns after entry, processing-unit passes before it) of every port arrival
    arrivals: list[tuple[int, int, int, int]]
    arrive_ns: I64             # (slaves x 4) first arrival time per port, -1 = not visited
    epu_ns: I64                # per slave: time of its (first) processing-unit pass, -1 = none
    returned: bool             # the frame comes back to the master
    delay_ns: int              # forwarding + cable delays of the whole walk
    contiguous: bool           # passes == arange(len(passes)) (fast slicing)
    #: (slave, port, arrival index) of arrivals at an auto-close port held closed
    #: after its link came back: a valid frame there re-opens it (facts 3.4).
    reopen: list[tuple[int, int, int]]
    #: Pass indices where the slave's port 0 is closed (derived, for the frame path).
    closed_idx: list[int] = field(init=False)
    #: len(passes), and whether the frame is processed at all (derived).
    count: int = field(init=False)
    live: bool = field(init=False)

    def __post_init__(self) -> None:
        self.closed_idx = [i for i, c in enumerate(self.port0_closed) if c]
        self.count = len(self.passes)
        self.live = bool(self.count or self.returned)


class Segment:
    """A segment of simulated slaves; :meth:`process` answers one frame."""

    def __init__(self, clock: Clock | None = None, mac_wire_ns: int = 80) -> None:
        self._clock: Clock = clock if clock is not None else VirtualClock()
        self.mac_wire_ns = mac_wire_ns
        self._advance_clock = True
        #: The clock if it is a VirtualClock (process() reads and advances it directly).
        self._vclock: VirtualClock | None = self._clock if isinstance(self._clock, VirtualClock) else None
        self.slaves: list[SimSlave] = []
        self.memory = EscMemory()
        #: Duration for which SII commands keep the busy bit (0: done at once).
        self.sii_busy_ns = 0
        self._links: list[list[tuple[int, int] | None]] = []
        self._cable: dict[tuple[int, int], int] = {}
        self._broken: set[tuple[int, int]] = set()
        self._autoclose_latched: set[tuple[int, int]] = set()
        self._had_link: dict[tuple[int, int], bool] = {}
        self._corrupt: dict[tuple[int, int], int] = {}
        self._drop_p = 0.0
        self._rng = random.Random()
        self._wires: list[tuple[int, int, int, int, int]] = []
        # per-slave arrays (grown in add_slave)
        self.outputs_received = np.zeros(0, bool)
        self.wd_last = np.zeros(0, np.int64)
        self.wd_limit = np.zeros(0, np.int64)
        self.wd_expired = np.zeros(0, bool)
        self.wd_armed = np.zeros(0, bool)
        self.dc_t0 = np.zeros(0, np.int64)
        self.dc_rate = np.zeros(0, np.float64)
        self.fwd_delay = np.zeros(0, np.int64)
        self.wants_outputs = np.zeros(0, bool)
        self.profile_id = np.zeros(0, np.int64)
        self._profiles: list[EscProfile] = []
        self.sync_next: dict[int, list[int]] = {}
        #: sync_next's slaves and their next pulse times as arrays (None: rebuild).
        self._sync_keys: I64 | None = None
        self._sync_due: npt.NDArray[np.uint64] = np.zeros(0, np.uint64)
        # dirty flags
        self.topology_dirty = True
        self.addressing_dirty = True
        self.fmmu_dirty = True
        self.sm_dirty = True
        self.irq_dirty = True
        self.watchdog_dirty = True
        self._route: Route | None = None
        self._stations: dict[int, list[int]] = {}
        self._lmap: LogicalMap | None = None
        self._irq = 0
        self._sm_span = (0, 0)
        self._sm_areas = np.zeros(0, bool)
        self._sm_reads = SmReads.empty()
        self._bw: dict[str, Any] = {}
        self._wire_idx: tuple[I64, I64, I64, I64] | None = None
        self._bplan: dict[tuple[int, int, int] | int, _BrdPlan] = {}
        #: Parses of single-datagram frames by bytes 12..25: (end, headers, circulating).
        self._parsed: dict[bytes, tuple[int, list[_Head], bool]] = {}
        # Per-chip answers for multi-slave writes (emptied on slave/power changes;
        # _fast_ok when the SM areas are recompiled).
        self._takes: dict[tuple[int, int, int, bool], bool] = {}
        self._wcols: dict[tuple[int, int, int], I64] = {}
        self._fast_ok: dict[tuple[int, int], bool] = {}
        #: Longest route on which small BRDs take the Python-int path (0: numpy only).
        self._brd_py_max = _BRD_PY_MAX
        #: BRDs of 1/2/4/8-byte registers handled in process() itself (tests compare
        #: with the general path by switching this off).
        self._brd_fast = True
        #: ECAT event bits that may be set in some slave (cleared by vectorised reads).
        self._event_bits = 0xFFFF
        self._cur_passes: I64 = _EMPTY
        #: Passes before a CRC-corrupted arrival in the current frame (-1: none),
        #: and that arrival's index into Route.arrivals.
        self._crc_cut = -1
        self._crc_at = _NEVER
        self._frame_t0 = 0
        self._complete_plans: dict[bytes, tuple[I64, I64, I64, npt.NDArray[np.uint8], I64]] = {}
        #: Slaves with a SAFEOP -> OP request waiting for their first outputs.
        self.pending_op: set[int] = set()
        self._any_output_apps = False
        self._wd_deadline = _NEVER
        self._wd_min_limit = 0
        self._wd_expired_any = False
        self.frames = 0
        self.frames_lost = 0

    @property
    def clock(self) -> Clock:
        """The segment's time source (virtual by default)."""
        return self._clock

    @clock.setter
    def clock(self, clock: Clock) -> None:
        self._clock = clock
        self._vclock = clock if isinstance(clock, VirtualClock) else None

    @property
    def advance_clock(self) -> bool:
        """Whether each processed frame advances a virtual clock by its wire time."""
        return self._advance_clock

    @advance_clock.setter
    def advance_clock(self, on: bool) -> None:
        self._advance_clock = bool(on)

    # --- building --------------------------------------------------------------------

    def add_slave(self, spec: SlaveSpec, parent: int | None = None, port: int | None = None,
                  cable_delay_ns: int = 5) -> int:
        """Add a slave; return its index.

        Without ``parent`` the slave continues the line: it joins the first
        free port (order 3, 1, 2... as the walk goes: 1 first, then 2, then
        3) of the previous slave on its port 0. With ``parent``/``port`` it
        hangs on that port of that slave (a tree branch).
        """
        index = self.memory.add()
        esc = Esc(self, index, spec.name, spec.sii, spec.profile, spec.app, spec.alias,
                  spec.initial_inputs)
        self.slaves.append(SimSlave(spec.name, spec, index, esc))
        self._links.append([None, None, None, None])
        if spec.profile not in self._profiles:
            self._profiles.append(spec.profile)
        pid = self._profiles.index(spec.profile)
        delay = spec.forwarding_delay_ns if spec.forwarding_delay_ns is not None else (
            spec.profile.default_forwarding_delay_ns)
        self.outputs_received = np.append(self.outputs_received, False)
        self.wd_last = np.append(self.wd_last, -1)
        self.wd_limit = np.append(self.wd_limit, 0)
        self.wd_expired = np.append(self.wd_expired, False)
        self.wd_armed = np.append(self.wd_armed, False)
        self.dc_t0 = np.append(self.dc_t0, self.clock.now_ns())
        self.dc_rate = np.append(self.dc_rate, 1.0 + spec.drift_ppm * 1e-6)
        self.fwd_delay = np.append(self.fwd_delay, delay)
        self.wants_outputs = np.append(self.wants_outputs, bool(spec.app and spec.app.wants_output_events))
        self._any_output_apps = bool(self.wants_outputs.any())
        self.profile_id = np.append(self.profile_id, pid)
        if index == 0:
            if parent is not None:
                raise ConfigError("the first slave is connected to the master; it has no parent")
        else:
            if parent is None:
                parent = index - 1
                port = self._free_port(parent)
            if not 0 <= parent < index:
                raise ConfigError(f"slave {spec.name!r}: parent {parent} does not exist yet")
            if port is None:
                port = self._free_port(parent)
            if port not in self.slaves[parent].spec.profile.implemented_ports or port == 0:
                raise ConfigError(f"slave {spec.name!r}: parent {self.slaves[parent].name!r} "
                                  f"has no usable port {port}")
            if self._links[parent][port] is not None:
                raise ConfigError(f"slave {spec.name!r}: port {port} of "
                                  f"{self.slaves[parent].name!r} is already connected")
            self._links[parent][port] = (index, 0)
            self._links[index][0] = (parent, port)
            self._cable[(parent, port)] = cable_delay_ns
            self._cable[(index, 0)] = cable_delay_ns
        esc.power_on()
        if spec.app is not None:
            spec.app.attach(esc.pdi)
            spec.app.on_power_on()
        self._invalidate_all()
        return index

    def _free_port(self, slave: int) -> int:
        prof = self.slaves[slave].spec.profile
        for p in (1, 2, 3):
            if p in prof.implemented_ports and self._links[slave][p] is None:
                return p
        raise ConfigError(f"slave {self.slaves[slave].name!r} has no free port for the next slave")

    def _invalidate_all(self) -> None:
        self.topology_dirty = self.addressing_dirty = self.fmmu_dirty = True
        self.sm_dirty = self.irq_dirty = self.watchdog_dirty = True
        self._bplan.clear()
        self._takes.clear()
        self._wcols.clear()

    def slave(self, key: int | str) -> SimSlave:
        """A slave by index or name."""
        if isinstance(key, int):
            return self.slaves[key]
        for s in self.slaves:
            if s.name == key:
                return s
        raise ConfigError(f"no slave named {key!r}")

    # --- topology ----------------------------------------------------------------------

    def _port_exists(self, s: int, p: int) -> bool:
        return p in self.slaves[s].spec.profile.implemented_ports

    def _link_up(self, s: int, p: int) -> bool:
        if not self.slaves[s].esc.powered or not self._port_exists(s, p):
            return False
        if s == 0 and p == 0:
            return (0, 0) not in self._broken
        peer = self._links[s][p]
        if peer is None or (s, p) in self._broken or peer in self._broken:
            return False
        return self.slaves[peer[0]].esc.powered

    def _loop_closed(self, s: int, p: int, link: bool) -> bool:
        if not self._port_exists(s, p):
            return True
        lc = (int(self.memory.mem[s, R.DL_CONTROL_LOOP]) >> (2 * p)) & 3
        if lc == R.LoopControl.OPEN:
            return False
        if lc == R.LoopControl.CLOSED:
            return True
        if lc == R.LoopControl.AUTO_CLOSE:
            return not link or (s, p) in self._autoclose_latched
        return not link

    def _update_topology(self) -> None:
        n = len(self.slaves)
        links = [[self._link_up(s, p) for p in range(4)] for s in range(n)]
        closed = [[self._loop_closed(s, p, links[s][p]) for p in range(4)] for s in range(n)]
        mem = self.memory.mem
        for s in range(n):
            esc = self.slaves[s].esc
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
                    if lc == R.LoopControl.AUTO_CLOSE:
                        self._autoclose_latched.add(key)
                self._had_link[key] = links[s][p]
                if links[s][p]:
                    dl |= R.dl_status_link(p) | R.dl_status_com(p)
                if closed[s][p]:
                    dl |= R.dl_status_loop(p)
            if dl != esc.u16(R.DL_STATUS):
                esc.set_u16(R.DL_STATUS, dl)
                esc.set_ecat_event(int(R.EcatEvent.DL_STATUS))
        self._route = self._walk(links, closed)
        self.topology_dirty = False
        self.addressing_dirty = self.fmmu_dirty = self.irq_dirty = self.sm_dirty = True
        self._bplan.clear()

    def _walk(self, links: list[list[bool]], closed: list[list[bool]]) -> Route:
        n = len(self.slaves)
        passes: list[int] = []
        port0_closed: list[bool] = []
        arrivals: list[tuple[int, int, int, int]] = []
        arrive = np.full((n, 4), -1, np.int64)
        epu = np.full(n, -1, np.int64)
        returned = False
        t = 0
        if n == 0 or not links[0][0]:
            return Route(np.zeros(0, np.int64), [], [], arrive, epu, False, 0, True, [])
        s, p, via_link = 0, 0, True
        limit = 16 * n + 16
        steps = 0
        reopen: list[tuple[int, int, int]] = []
        latched = self._autoclose_latched
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
                    epu[s] = t
                if sum(port0_closed) >= 2:
                    break  # circulating: destroyed on the second closed-port-0 pass
            q = NEXT_PORT[p]
            if closed[s][q]:
                s, p, via_link = s, q, False
                continue
            if not links[s][q]:
                break  # open port without link: the frame is lost
            t += int(self.fwd_delay[s])
            if s == 0 and q == 0:
                returned = True
                break
            peer = self._links[s][q]
            assert peer is not None
            t += self._cable.get((s, q), 0)
            s, p, via_link = peer[0], peer[1], True
        arr = np.array(passes, dtype=np.int64)
        contiguous = bool(len(arr) == 0 or np.array_equal(arr, np.arange(len(arr))))
        return Route(arr, port0_closed, arrivals, arrive, epu, returned, t, contiguous, reopen)

    @property
    def route(self) -> Route:
        """The current walk (recomputed after topology changes)."""
        if self.topology_dirty or self._route is None:
            self._update_topology()
        assert self._route is not None
        return self._route

    def loop_control_written(self, index: int, old: int, new: int) -> None:
        """DL control loop byte written: auto-close (1) written after the link came back re-opens a latched port.

        Written while the link is still down it re-opens nothing (facts 3.4:
        re-opened only by writing 1 again after link up).
        """
        for p in range(4):
            if (new >> (2 * p)) & 3 == R.LoopControl.AUTO_CLOSE and self._link_up(index, p):
                self._autoclose_latched.discard((index, p))
        self.topology_dirty = True

    def _reopen_ports(self, route: Route, any_c: bool) -> None:
        """A valid frame arrived at latched auto-close ports: they open (facts 3.4).

        Valid: it arrived before the frame got a CRC error (arrival index below
        the corrupted one) and before the circulating-frame rule destroyed it
        (at most that many processing-unit passes before the arrival). The
        frame itself was handled with the port closed; the next walk has it
        open."""
        crc_at, self._crc_at = self._crc_at, _NEVER
        closed = route.closed_idx
        passes_done = route.count
        if closed and (any_c or len(closed) > 1):
            passes_done = closed[0] if any_c else closed[1]
        for s, p, i in route.reopen:
            if i < crc_at and route.arrivals[i][3] <= passes_done:
                self._autoclose_latched.discard((s, p))
                self.topology_dirty = True

    # --- faults ------------------------------------------------------------------------

    def _peer_key(self, slave: int, port: int) -> tuple[int, int] | None:
        """The far end of the cable at ``slave``'s ``port`` (None: the master's cable).

        A fault on a port the chip does not have, or on one without a cable,
        would do nothing at all; it is refused instead (ConfigError naming the
        slave and the port)."""
        n = len(self.slaves)
        if not 0 <= slave < n:
            raise ConfigError(f"no slave {slave} (the segment has {n})")
        name = f"slave {self.slaves[slave].name!r} (index {slave})"
        ports = self.slaves[slave].spec.profile.implemented_ports
        if port not in ports:
            raise ConfigError(f"{name} has no port {port} (ports {', '.join(map(str, ports))})")
        peer = self._links[slave][port]
        if peer is None and not (slave == 0 and port == 0):
            raise ConfigError(f"{name}: port {port} has no cable")
        return peer

    def break_link(self, slave: int, port: int) -> None:
        """Cut the cable at ``slave``'s ``port`` (both ends lose the link)."""
        self._peer_key(slave, port)
        self._broken.add((slave, port))
        self.topology_dirty = True

    def restore_link(self, slave: int, port: int) -> None:
        """Reconnect a cable cut with :meth:`break_link`."""
        peer = self._peer_key(slave, port)
        self._broken.discard((slave, port))
        if peer is not None:
            self._broken.discard(peer)
        self.topology_dirty = True

    def power_off(self, slave: int) -> None:
        """Switch a slave off: it disappears, its neighbours lose their links."""
        esc = self.slaves[slave].esc
        esc.powered = False
        self.memory.clear(slave)
        self.outputs_received[slave] = False
        self.wd_last[slave] = -1
        self._sync_drop(slave)
        self._invalidate_all()

    def power_on(self, slave: int) -> None:
        """Switch a slave on: INIT, station address 0, alias from the SII."""
        self.reset_slave(slave)
        self._invalidate_all()

    def reset_slave(self, slave: int) -> None:
        """Power-on reset of one ESC (also the 'RES' sequence in 0x0040)."""
        esc = self.slaves[slave].esc
        self.outputs_received[slave] = False
        self.wd_last[slave] = -1
        self.wd_expired[slave] = False
        self.dc_t0[slave] = self.clock.now_ns()
        self._sync_drop(slave)
        esc.power_on()
        for p in range(4):
            self._autoclose_latched.discard((slave, p))
            self._had_link[(slave, p)] = False
        app = self.slaves[slave].spec.app
        if app is not None:
            app.on_power_on()
        self._invalidate_all()

    def corrupt_frames(self, slave: int, port: int, count: int = 1) -> None:
        """The next ``count`` frames arriving at ``slave``'s ``port`` carry a CRC error."""
        self._peer_key(slave, port)
        self._corrupt[(slave, port)] = self._corrupt.get((slave, port), 0) + count

    def drop_probability(self, p: float, seed: int | None = None) -> None:
        """Lose each frame with probability ``p`` (before any slave sees it)."""
        if not 0.0 <= p <= 1.0:
            raise ConfigError(f"drop probability {p} is not within 0..1")
        self._drop_p = p
        if seed is not None:
            self._rng.seed(seed)

    # --- process-data wiring -------------------------------------------------------------

    def wire(self, src_slave: int, src_bit: int, dst_slave: int, dst_bit: int, bits: int) -> None:
        """Bits of ``src``'s outputs (SM2 image) appear in ``dst``'s inputs (SM3 image)."""
        n = len(self.slaves)
        if not (0 <= src_slave < n and 0 <= dst_slave < n) or bits <= 0 or src_bit < 0 or dst_bit < 0:
            raise ConfigError(f"bad wire {src_slave}.{src_bit} -> {dst_slave}.{dst_bit} ({bits} bits)")
        self._wires.append((src_slave, src_bit, dst_slave, dst_bit, bits))
        self._wire_idx = None

    def _sm_start(self, slave: int, n: int, default_from_sii: bool = True) -> int | None:
        esc = self.slaves[slave].esc
        if n < esc.profile.sm_count:
            s = esc.sm(n)
            if s.enabled:
                return int(s.start)
        if default_from_sii and esc.sii_info is not None:
            sms = esc.sii_info.sync_managers
            if n < len(sms):
                return int(sms[n].start)
        return None

    def _compile_wires(self) -> tuple[I64, I64, I64, I64]:
        sb, ss, db, ds = [], [], [], []
        for src, sbit, dst, dbit, bits in self._wires:
            s0 = self._sm_start(src, self.slaves[src].esc.output_sm)
            d0 = self._sm_start(dst, self.slaves[dst].esc.input_sm)
            if s0 is None or d0 is None:
                continue
            k = np.arange(bits, dtype=np.int64)
            sbits = s0 * 8 + sbit + k
            dbits = d0 * 8 + dbit + k
            sb.append(src * SLAVE_STRIDE + (sbits >> 3))
            ss.append(sbits & 7)
            db.append(dst * SLAVE_STRIDE + (dbits >> 3))
            ds.append(dbits & 7)

        def cat(x: list[I64]) -> I64:
            return np.concatenate(x) if x else _EMPTY

        return cat(sb), cat(ss), cat(db), cat(ds)

    def apply_wires(self) -> None:
        """Copy wired output bits (complete buffers) into the inputs they drive."""
        if not self._wires:
            return
        if self._wire_idx is None:
            self._wire_idx = self._compile_wires()
        sb, ss, db, ds = self._wire_idx
        if not len(sb):
            return
        flat = self.memory.flat
        vals = ((self.memory.shadow_flat[sb] >> ss) & 1).astype(np.uint8)
        np.bitwise_and.at(flat, db, (~np.left_shift(1, ds)).astype(np.uint8))
        np.bitwise_or.at(flat, db, (vals << ds).astype(np.uint8))

    # --- compiled state ------------------------------------------------------------------

    def _refresh_sm_state(self) -> None:
        """Recompile what depends on the SM registers (buffer completion, SM areas)."""
        n = len(self.slaves)
        idx_parts, owner_parts = [], []
        pair_slave, pair_n, pair_status, pair_al, pair_wd = [], [], [], [], []
        lo, hi = R.ADDRESS_SPACE, 0
        complete: dict[int, set[int]] = {}
        # ECAT-read SMs, for logical access (sim.fmmu.SmReads): refused write
        # ranges, and per buffered one its last byte, status and event bytes.
        refused: dict[int, list[tuple[int, int]]] = {}
        last: dict[int, dict[int, int]] = {}
        rd: list[tuple[int, int, int, int, int]] = []
        for s in range(n):
            esc = self.slaves[s].esc
            if not esc.powered:
                continue
            for k in range(esc.profile.sm_count):
                sm = esc.sm(k)
                if not sm.enabled:
                    continue
                lo, hi = min(lo, sm.start), max(hi, sm.end)
                if not sm.ecat_writes:
                    refused.setdefault(s, []).append((sm.start, min(sm.end, R.ADDRESS_SPACE)))
                    if sm.mode != R.SmMode.MAILBOX and sm.end <= R.ADDRESS_SPACE:
                        # (the mailbox's read completion stays on the ESC's own path)
                        last.setdefault(s, {})[sm.end - 1] = len(rd)
                        base = s * SLAVE_STRIDE
                        al_off, al_mask = _byte_and_mask(R.al_event_sm(k))
                        ev_off, ev_mask = _byte_and_mask(R.ecat_event_sm(k))
                        rd.append((
                            base + R.sm_address(k) + R.SM_STATUS,
                            base + R.AL_EVENT_REQUEST + al_off,
                            al_mask if sm.control & R.SM_CONTROL_AL_EVENT else 0,
                            base + R.ECAT_EVENT_REQUEST + ev_off,
                            ev_mask if sm.control & R.SM_CONTROL_ECAT_EVENT and ev_off < 2 else 0))
                if sm.mode == R.SmMode.BUFFERED and sm.ecat_writes:
                    idx_parts.append(np.arange(sm.start, min(sm.end, R.ADDRESS_SPACE)) + s * SLAVE_STRIDE)
                    owner_parts.append(np.full(len(idx_parts[-1]), s, np.int64))
                    pair_slave.append(s)
                    pair_n.append(k)
                    pair_status.append(s * SLAVE_STRIDE + R.sm_address(k) + R.SM_STATUS)
                    pair_al.append(1 << k if sm.control & R.SM_CONTROL_AL_EVENT and k < 8 else 0)
                    pair_wd.append(bool(sm.control & R.SM_CONTROL_WATCHDOG))
                    complete.setdefault(s, set()).add(sm.end - 1)
        self._bw = {
            "idx": np.concatenate(idx_parts).astype(np.int64) if idx_parts else _EMPTY,
            "owner": np.concatenate(owner_parts) if owner_parts else _EMPTY,
            "slave": np.array(pair_slave, np.int64),
            "status": np.array(pair_status, np.int64),
            "al": np.array(pair_al, np.uint8),
            "wd": np.array(pair_wd, bool),
            "complete": complete,
        }
        cols = list(zip(*rd, strict=True)) if rd else [(), (), (), (), ()]
        self._sm_reads = SmReads(refused, last, np.array(cols[0], np.int64), np.array(cols[1], np.int64),
                                 np.array(cols[2], np.uint8), np.array(cols[3], np.int64),
                                 np.array(cols[4], np.uint8))
        self._sm_span = (lo, hi) if hi > lo else (0, 0)
        self._fast_ok.clear()
        self._complete_plans.clear()
        self.sm_dirty = False
        self.fmmu_dirty = True
        self.watchdog_dirty = True
        self._wire_idx = None
        self._bplan.clear()

    def _refresh_fmmus(self) -> None:
        route = self.route
        if self.sm_dirty:
            self._refresh_sm_state()
        configs = []
        mem = self.memory.mem
        for pos, s in enumerate(route.passes.tolist()):
            esc = self.slaves[s].esc
            count = esc.profile.fmmu_count
            raw = mem[s, R.FMMU_BASE: R.FMMU_BASE + count * R.FMMU_SIZE].tobytes()
            configs.extend(parse_fmmus(raw, count, pos, s))
        writable = [sl.esc.writable for sl in self.slaves]
        impl = [sl.esc.impl for sl in self.slaves]
        self._lmap = LogicalMap(configs, writable, self._bw["complete"], impl, self._sm_reads)
        self.fmmu_dirty = False

    def _refresh_addressing(self) -> None:
        route = self.route
        stations: dict[int, list[int]] = {}
        mem = self.memory.mem
        for pos, s in enumerate(route.passes.tolist()):
            st = int(mem[s, R.STATION_ADDRESS]) | (int(mem[s, R.STATION_ADDRESS + 1]) << 8)
            stations.setdefault(st, []).append(pos)
            if mem[s, R.DL_CONTROL_ALIAS] & 1:
                alias = int(mem[s, R.STATION_ALIAS]) | (int(mem[s, R.STATION_ALIAS + 1]) << 8)
                if alias != st:
                    stations.setdefault(alias, []).append(pos)
        self._stations = stations
        self.addressing_dirty = False

    def _refresh_irq(self) -> None:
        passes = self.route.passes
        mem = self.memory.mem
        if len(passes):
            req = mem[passes, R.ECAT_EVENT_REQUEST: R.ECAT_EVENT_REQUEST + 2]
            mask = mem[passes, R.ECAT_EVENT_MASK: R.ECAT_EVENT_MASK + 2]
            v = np.bitwise_or.reduce(req & mask, axis=0)
            self._irq = int(v[0]) | (int(v[1]) << 8)
        else:
            self._irq = 0
        self.irq_dirty = False

    def _refresh_watchdogs(self) -> None:
        n = len(self.slaves)
        mem = self.memory.mem[:n]
        div = mem[:, R.WATCHDOG_DIVIDER].astype(np.int64) | (mem[:, R.WATCHDOG_DIVIDER + 1].astype(np.int64) << 8)
        wt = (mem[:, R.WATCHDOG_TIME_PROCESS_DATA].astype(np.int64)
              | (mem[:, R.WATCHDOG_TIME_PROCESS_DATA + 1].astype(np.int64) << 8))
        armed = np.zeros(n, bool)
        for k in range(16):
            base = R.sm_address(k)
            armed |= ((mem[:, base + R.SM_CONTROL] & R.SM_CONTROL_WATCHDOG) != 0) & (
                (mem[:, base + R.SM_ACTIVATE] & R.SM_ACTIVATE_ENABLE) != 0)
        self.wd_limit = (div + 2) * R.WATCHDOG_TICK_NS * wt
        self.wd_armed = armed & (wt > 0)
        self._wd_min_limit = int(self.wd_limit[self.wd_armed].min()) if self.wd_armed.any() else 0
        self.watchdog_dirty = False

    # --- ESC callbacks -------------------------------------------------------------------

    def state_changed(self, index: int, old: AlState, new: AlState) -> None:
        """Called by an ESC when its AL state changed."""
        if new in (AlState.INIT, AlState.PREOP, AlState.BOOT):
            self.outputs_received[index] = False
            self.wd_last[index] = -1
            self.wd_expired[index] = False
            self.pending_op.discard(index)

    def complete_write_sms(self, slaves: I64) -> None:
        """Buffered write SMs of ``slaves`` got their last byte: publish the buffers.

        Copies the buffers into the shadow (what the PDI sees), advances the SM
        status (buffer index, write event), raises the AL events, re-triggers
        the process-data watchdogs and applies the wiring. The index arrays
        for a given set of slaves are computed once and cached.
        """
        if self.sm_dirty:
            self._refresh_sm_state()
        if not len(slaves):
            return
        key = slaves.tobytes()
        plan = self._complete_plans.get(key)
        if plan is None:
            plan = self._complete_plan(slaves)
            if len(self._complete_plans) > 1024:
                self._complete_plans.clear()
            self._complete_plans[key] = plan
        idx, st, al_idx, al_val, wd_slaves = plan
        flat = self.memory.flat
        self.memory.shadow_flat[idx] = flat[idx]
        if len(st):
            flat[st] = _STATUS_AFTER_WRITE[flat[st]]
        if len(al_idx):
            flat[al_idx] |= al_val
        if len(wd_slaves):
            now = self.clock.now_ns()
            self.wd_last[wd_slaves] = now
            if self._wd_expired_any:
                self.wd_expired[wd_slaves] = False
                flat[wd_slaves * SLAVE_STRIDE + R.WATCHDOG_STATUS_PROCESS_DATA] |= 1
                self._wd_expired_any = bool(self.wd_expired.any())
            # A watchdog (re)started here expires no earlier than now + the shortest limit.
            soonest = now + self._wd_min_limit
            if soonest < self._wd_deadline:
                self._wd_deadline = soonest
        self.outputs_received[slaves] = True
        if self.pending_op:
            for s in sorted(self.pending_op & set(slaves.tolist())):
                self.slaves[s].esc.outputs_arrived()
        if self._any_output_apps:
            # Only the applications that asked are called (one mask, no scan of the rest).
            for s in slaves[self.wants_outputs[slaves]].tolist():
                app = self.slaves[s].spec.app
                if app is not None:
                    app.on_outputs()
        if self._wires:
            self.apply_wires()

    def _complete_plan(self, slaves: I64) -> tuple[I64, I64, I64, npt.NDArray[np.uint8], I64]:
        bw = self._bw
        sel_mask = np.zeros(len(self.slaves), bool)
        sel_mask[slaves] = True
        idx = bw["idx"][sel_mask[bw["owner"]]]
        psel = sel_mask[bw["slave"]]
        st = bw["status"][psel]
        ps = bw["slave"][psel]
        al = bw["al"][psel]
        # One OR per slave: combine the SM event bits of slaves with several write SMs.
        al_bits: dict[int, int] = {}
        for s_, a in zip(ps.tolist(), al.tolist(), strict=True):
            if a:
                al_bits[s_] = al_bits.get(s_, 0) | a
        al_idx = np.array([s_ * SLAVE_STRIDE + R.AL_EVENT_REQUEST + 1 for s_ in al_bits], np.int64)
        al_val = np.array(list(al_bits.values()), np.uint8)
        wd_slaves = np.unique(ps[bw["wd"][psel]]).astype(np.int64)
        return idx, st, al_idx, al_val, wd_slaves

    # --- DC -------------------------------------------------------------------------------

    def local_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """Local (free-running, drifting) time of ``slaves`` at segment time ``t_ns``."""
        return ((np.asarray(t_ns, np.int64) - self.dc_t0[slaves]) * self.dc_rate[slaves]).astype(np.int64)

    def _pass_time(self, slaves: I64) -> I64:
        route = self.route
        t = route.epu_ns[slaves]
        return self._frame_t0 + np.maximum(t, 0)

    def refresh_system_time(self, slaves: I64) -> I64:
        """Write the system time (local time + offset 0x0920) into 0x0910 of ``slaves``; return it."""
        mem = self.memory.mem
        # local_time(slaves, _pass_time(slaves)), inlined: this runs for every FRMW/ARMW
        # of the DC cycle.
        route = self._route if self._route is not None and not self.topology_dirty else self.route
        t = self._frame_t0 + np.maximum(route.epu_ns[slaves], 0)
        local = ((t - self.dc_t0[slaves]) * self.dc_rate[slaves]).astype(np.int64)
        offset = mem[slaves, R.DC_SYSTEM_TIME_OFFSET: R.DC_SYSTEM_TIME_OFFSET + 8].copy().view("<i8")[:, 0]
        st: I64 = (local + offset).astype("<i8")
        mem[slaves, R.DC_SYSTEM_TIME: R.DC_SYSTEM_TIME + 8] = st.view(np.uint8).reshape(-1, 8)
        return st

    def latch_receive_times(self, slaves: I64) -> None:
        """A write to 0x0900 passed ``slaves``: latch the port receive times and 0x0918."""
        if not len(slaves):
            return
        route = self.route
        mem = self.memory.mem
        arrive = route.arrive_ns[slaves]  # (k, 4)
        t = self._frame_t0 + np.maximum(arrive, 0)
        local = ((t - self.dc_t0[slaves, None]) * self.dc_rate[slaves, None]).astype(np.int64)
        cur = mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16].copy().view("<u4")
        new = np.where(arrive >= 0, (local & 0xFFFFFFFF).astype("<u4"), cur)
        mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16] = new.astype("<u4").view(
            np.uint8).reshape(-1, 16)
        epu_local = self.local_time(slaves, self._pass_time(slaves)).astype("<i8")
        mem[slaves, R.DC_RECEIVE_TIME_ECAT: R.DC_RECEIVE_TIME_ECAT + 8] = epu_local.view(
            np.uint8).reshape(-1, 8)

    def time_loop_write(self, slaves: I64, data: bytes, offset: int) -> None:
        """A reference time was written to 0x0910: store the difference in 0x092C.

        The value is not taken over (facts 11.7). The difference is
        (local copy of system time - system time delay) - received time,
        sign-magnitude; drift correction of the local clock comes with the
        DC issue.
        """
        if not len(slaves) or offset != 0 or len(data) < 4:
            return
        mem = self.memory.mem
        own = self.refresh_system_time(slaves)  # what 0x0910 now holds
        if len(data) >= 8:
            received = np.int64(int.from_bytes(data[:8], "little", signed=True))
        else:
            received = np.int64(int.from_bytes(data[:4], "little"))
            own = own & 0xFFFFFFFF  # the low double word, as an unsigned value
        delay = mem[slaves, R.DC_SYSTEM_TIME_DELAY: R.DC_SYSTEM_TIME_DELAY + 4].copy().view("<u4")[:, 0]
        diff = own - delay.astype(np.int64) - received
        mag = np.minimum(np.abs(diff), 0x7FFFFFFF).astype(np.uint32)
        value = (mag | np.where(diff >= 0, np.uint32(0x80000000), np.uint32(0))).astype("<u4")
        mem[slaves, R.DC_SYSTEM_TIME_DIFFERENCE: R.DC_SYSTEM_TIME_DIFFERENCE + 4] = value.view(
            np.uint8).reshape(-1, 4)

    def sync_config_written(self, index: int) -> None:
        """DC cyclic unit registers written: (re)plan SYNC0/SYNC1 events."""
        esc = self.slaves[index].esc
        act = esc.u8(R.DC_ACTIVATION)
        cycle0 = esc.u32(R.DC_SYNC0_CYCLE)
        if act & R.DcActivation.CYCLIC and act & (R.DcActivation.SYNC0 | R.DcActivation.SYNC1):
            start = esc.u64(R.DC_START_TIME)
            self.sync_next[index] = [start, cycle0, esc.u32(R.DC_SYNC1_CYCLE), act]
            self._sync_keys = None
        else:
            self._sync_drop(index)

    def _run_sync(self, now: int) -> None:
        """Fire the SYNC0/SYNC1 pulses that are due.

        The system times of all slaves with planned pulses are one array
        operation (keys and next pulse times cached until ``sync_next``
        changes); Python runs only for the slaves whose pulse is due."""
        sync = self.sync_next
        keys, due = self._sync_keys, self._sync_due
        if keys is None:
            keys = np.fromiter(sync, np.int64, len(sync))
            due = np.array([p[0] for p in sync.values()], np.uint64)
            self._sync_keys, self._sync_due = keys, due
        local = self.local_time(keys, now)
        offset = self.memory.mem[keys, R.DC_SYSTEM_TIME_OFFSET: R.DC_SYSTEM_TIME_OFFSET + 8].copy().view("<i8")[:, 0]
        systimes = (local + offset).view(np.uint64)  # (wraps like the 64-bit register)
        hits = np.nonzero(systimes >= due)[0]
        for j in hits.tolist():
            index = int(keys[j])
            plan = sync.get(index)
            if plan is None:
                continue  # dropped by an earlier pulse's application in this tick
            _, cycle0, cycle1, act = plan
            systime = int(systimes[j])
            esc = self.slaves[index].esc
            app = esc.app
            fired = 0
            while systime >= plan[0] and fired < 16:
                t = plan[0]
                if act & R.DcActivation.SYNC0:
                    esc.row[R.DC_SYNC0_STATUS] = 1
                    esc.set_al_event(int(R.AlEvent.SYNC0))
                    if app is not None:
                        app.on_sync0(t)
                if act & R.DcActivation.SYNC1:
                    esc.row[R.DC_SYNC1_STATUS] = 1
                    esc.set_al_event(int(R.AlEvent.SYNC1))
                    if app is not None:
                        app.on_sync1(t + cycle1)
                fired += 1
                if cycle0 == 0:
                    self._sync_drop(index)  # single shot
                    break
                plan[0] = t + cycle0
            if cycle0 and systime >= plan[0]:
                # Far behind (no ticks for a long time): skip the missed pulses.
                missed = (systime - plan[0]) // cycle0 + 1
                plan[0] += missed * cycle0
            due[j] = min(plan[0], _U64_MAX)  # (a stale copy if the plans changed meanwhile: rebuilt then)

    def _sync_drop(self, index: int) -> None:
        """No SYNC pulses planned for ``index`` any more."""
        if self.sync_next.pop(index, None) is not None:
            self._sync_keys = None

    # --- time ---------------------------------------------------------------------------------

    def tick(self, now: int | None = None) -> None:
        """Run time-driven work: process-data watchdogs, SYNC0/SYNC1 events."""
        if now is None:
            now = self.clock.now_ns()
        if self.watchdog_dirty or self.sm_dirty:
            if self.sm_dirty:
                self._refresh_sm_state()
            self._refresh_watchdogs()
            self._wd_deadline = -1
        # Deadlines only move later when outputs arrive, so the earliest one
        # computed at the last check is a safe lower bound until then.
        if now > self._wd_deadline and len(self.wd_last):
            eligible = self.wd_armed & ~self.wd_expired & (self.wd_last >= 0)
            expiry = self.wd_last + self.wd_limit
            due = eligible & (now > expiry)
            if due.any():
                for s in np.nonzero(due)[0].tolist():
                    self.wd_expired[s] = True
                    self._wd_expired_any = True
                    self.outputs_received[s] = False
                    self.slaves[s].esc.watchdog_expired()
            rest = eligible & ~due
            self._wd_deadline = int(expiry[rest].min()) if rest.any() else _NEVER
        if self.sync_next:
            self._run_sync(now)

    # --- frames -------------------------------------------------------------------------------

    def wire_time_ns(self, frame_len: int) -> int:
        """Modelled time for a frame of ``frame_len`` bytes (without FCS) to go round."""
        route = self.route
        return (max(frame_len, 60) + FCS_SIZE) * self.mac_wire_ns + route.delay_ns

    def process(self, frame: bytes | bytearray) -> bytes | None:
        """Process one frame from the master; the returned frame, or None if it is lost."""
        # VirtualClock is part of the simulator: the frame path reads and moves its
        # counter directly (two method calls cost ~10% of a small frame).
        vclock = self._vclock
        now = vclock._now if vclock is not None else self._clock.now_ns()
        # tick() only when time-driven work can be due: watchdog configuration
        # changed, the earliest watchdog deadline passed, or SYNC pulses planned.
        if self.watchdog_dirty or self.sm_dirty or now > self._wd_deadline or self.sync_next:
            self.tick(now)
        self.frames += 1
        route = self._route
        if route is None or self.topology_dirty:
            route = self.route
        if self._drop_p and self._rng.random() < self._drop_p:
            self.frames_lost += 1
            return None
        if len(frame) < _MIN_FRAME or not route.live:
            self.frames_lost += 1
            return None
        buf = bytearray(frame)
        # A single-datagram frame is fully described by bytes 12..25 (EtherType,
        # EtherCAT header, datagram header): its parse is looked up, not redone.
        hit = None if self._corrupt else self._parsed.get(
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
        destroy = False
        set_c = False
        closed_idx = route.closed_idx
        if closed_idx:
            if any_c:
                passes, destroy = passes[: closed_idx[0]], True
                count = len(passes)
            elif len(closed_idx) > 1:
                passes, destroy = passes[: closed_idx[1]], True
                count = len(passes)
            else:
                set_c = True
        if self._crc_cut >= 0:
            # CRC error on a link (facts 3.7, seed 000 'Sicherungsmassnahmen'): the
            # slaves passed before the bad link took the frame (FCS good there);
            # the receiving slave and all after it discard it; the master's NIC
            # drops it for its bad FCS.
            if self._crc_cut < count:
                passes = passes[: self._crc_cut]
                count = self._crc_cut
            destroy = True
            self._crc_cut = -1
            if not route.reopen:
                self._crc_at = _NEVER
        self._frame_t0 = now
        self._cur_passes = passes
        if self.irq_dirty:
            self._refresh_irq()
        bplan = self._bplan
        fast_key = count << 32
        for off, cmd, address, lw, irq, n in heads:
            doff = off + HEADER_SIZE
            if set_c:
                lw |= CIRCULATING_BIT
            if cmd == _BRD:
                plan = bplan.get((address & 0xFFFF0000) | n | fast_key)
                if plan is not None and not plan.clear & self._event_bits and not self.topology_dirty:
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
                    _HEADER_TAIL.pack_into(buf, off + 2, ((address + count) & 0xFFFF) | (address & 0xFFFF0000),
                                           lw, irq | self._irq)
                    continue
            if cmd in _CLASS:
                add, address = self._datagram(cmd, address, np.frombuffer(buf, np.uint8, n, doff), n)
                if self.irq_dirty:
                    self._refresh_irq()
            else:
                add = 0  # NOP and unknown commands pass untouched
            _HEADER_TAIL.pack_into(buf, off + 2, address, lw, irq | self._irq)
            wkc_off = doff + n
            _WKC.pack_into(buf, wkc_off, (_WKC.unpack_from(buf, wkc_off)[0] + add) & 0xFFFF)
        if vclock is not None and self._advance_clock:
            walk = self._route
            if walk is None or self.topology_dirty:
                walk = self.route
            size = len(buf)  # (no max(): a builtin call costs more than the whole sum)
            vclock._now += ((size if size > 60 else 60) + FCS_SIZE) * self.mac_wire_ns + walk.delay_ns
        if route.reopen:
            self._reopen_ports(route, any_c)
        if destroy or not route.returned:
            self.frames_lost += 1
            return None
        buf[6] |= LOCALLY_ADMINISTERED_BIT
        return bytes(buf)

    def _parse(self, buf: bytearray, route: Route) -> tuple[list[_Head], bool] | bytes | None:
        """Check and parse a frame: (datagram headers, any circulating bit) to process it,
        else what process() returns (the unchanged non-EtherCAT frame, or None if lost).
        A malformed frame is not processed at all (counted as a processing error)."""
        start = ETH_HEADER_SIZE
        ethertype = (buf[12] << 8) | buf[13]
        if ethertype == ETHERTYPE_VLAN and len(buf) >= 18:
            ethertype = (buf[16] << 8) | buf[17]
            start += 4
        if ethertype != ETHERTYPE_ETHERCAT:
            # Non-EtherCAT frames pass unchanged unless the first slave destroys them.
            if len(route.passes) and self.memory.mem[route.passes[0], R.DL_CONTROL] & R.DL_CONTROL_FORWARDING_RULE:
                return None
            return bytes(buf) if route.returned else None  # passed on unchanged
        cut, cut_at = self._apply_corruption(route) if self._corrupt else (-1, _NEVER)
        word = buf[start] | (buf[start + 1] << 8)
        length = word & ECAT_LENGTH_MASK
        if word >> ECAT_TYPE_SHIFT != _DATAGRAMS:
            return None  # mailbox-gateway and other types are not for the slaves
        body = start + ECAT_HEADER_SIZE
        end = body + length
        if end > len(buf):
            self._processing_error(route)
            return None
        # Parse all headers first (a malformed frame is not processed at all).
        heads: list[_Head] = []
        off = body
        any_c = False
        while True:
            if off + HEADER_SIZE + WKC_SIZE > end:
                self._processing_error(route)
                return None
            cmd, _idx, address, lw, irq = HEADER.unpack_from(buf, off)
            n = lw & LEN_MASK
            if off + HEADER_SIZE + n + WKC_SIZE > end:
                self._processing_error(route)
                return None
            heads.append((off, cmd, address, lw, irq, n))
            if lw & CIRCULATING_BIT:
                any_c = True
            off += HEADER_SIZE + n + WKC_SIZE
            if not lw & MORE_BIT:
                break
        if start == ETH_HEADER_SIZE and len(heads) == 1:
            if len(self._parsed) >= 1024:
                self._parsed.clear()
            self._parsed[bytes(buf[12:26])] = (end, heads, any_c)
        self._crc_cut, self._crc_at = cut, cut_at
        return heads, any_c

    def _processing_error(self, route: Route) -> None:
        """A malformed EtherCAT frame: counted by the first slave's processing unit."""
        self.frames_lost += 1
        if len(route.passes):
            s = int(route.passes[0])
            c = int(self.memory.mem[s, R.ECAT_PROCESSING_ERROR_COUNTER])
            self.memory.mem[s, R.ECAT_PROCESSING_ERROR_COUNTER] = min(255, c + 1)

    def _apply_corruption(self, route: Route) -> tuple[int, int]:
        """Count CRC errors along the walk.

        Returns the number of processing-unit passes made before the corrupted
        arrival (those slaves execute the frame) and that arrival's index in
        ``route.arrivals``, or (-1, never) if no pending fault hit this frame. The receiving port counts an invalid frame; every later
        arrival counts a forwarded error (the detecting port counts only the
        first)."""
        mem = self.memory.mem
        corrupted = False
        cut, at = -1, _NEVER
        for i, (s, p, _t, before) in enumerate(route.arrivals):
            if not corrupted:
                left = self._corrupt.get((s, p), 0)
                if left:
                    corrupted = True
                    cut, at = before, i
                    if left == 1:
                        del self._corrupt[(s, p)]
                    else:
                        self._corrupt[(s, p)] = left - 1
                    a = R.RX_ERROR_COUNTER + 2 * p
                    mem[s, a] = min(255, int(mem[s, a]) + 1)
            else:
                a = R.FORWARDED_RX_ERROR_COUNTER + p
                mem[s, a] = min(255, int(mem[s, a]) + 1)
        return cut, at

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
            wkc = self._broadcast(cmd, ado, data, n)
            return wkc, ((adp + count) & 0xFFFF) | (ado << 16)
        if kind == 3:
            pos = (-adp) & 0xFFFF
            new_address = ((adp + count) & 0xFFFF) | (ado << 16)
            if cmd in _RMW:
                return self._rmw(pos if pos < count else None, ado, data, n), new_address
            if pos >= count:
                return 0, new_address
            return self._single(cmd, int(passes[pos]), ado, data, n), new_address
        if kind == 4:
            if self.addressing_dirty:
                self._refresh_addressing()
            hits = self._stations.get(adp)
            if cmd in _RMW:
                return self._rmw(hits[0] if hits and hits[0] < count else None, ado, data, n), address
            if not hits:
                return 0, address
            wkc = 0
            for pos in hits:
                if pos < count:
                    wkc += self._single(cmd, int(passes[pos]), ado, data, n)
            return wkc, address
        return 0, address  # NOP and unknown commands pass untouched

    def _single(self, cmd: int, s: int, ado: int, data: npt.NDArray[np.uint8], n: int) -> int:
        esc = self.slaves[s].esc
        if cmd in _READS:
            r = esc.ecat_read(ado, n)
            if r is None:
                return 0
            data[:] = np.frombuffer(r, np.uint8)
            return 1
        if cmd in _WRITES:
            return 1 if esc.ecat_write(ado, data.tobytes()) else 0
        # APRW / FPRW: read the old content into the frame, store the data as received.
        if not esc.profile.rw_supported:
            return 0
        incoming = data.tobytes()
        wkc = 0
        r = esc.ecat_read(ado, n)
        if r is not None:
            data[:] = np.frombuffer(r, np.uint8)
            wkc += 1
        if esc.ecat_write(ado, incoming):
            wkc += 2
        return wkc

    def _rmw(self, reader: int | None, ado: int, data: npt.NDArray[np.uint8], n: int) -> int:
        """ARMW/FRMW: the addressed slave reads, every other slave writes (facts 2.2)."""
        passes = self._cur_passes
        wkc = 0
        if reader is None:
            return self._multi_write(passes, ado, data.tobytes())
        before = passes[:reader]
        after = passes[reader + 1:]
        original = data.tobytes()
        wkc += self._multi_write(before, ado, original)
        r = self.slaves[int(passes[reader])].esc.ecat_read(ado, n)
        if r is not None:
            data[:] = np.frombuffer(r, np.uint8)
            wkc += 1
        wkc += self._multi_write(after, ado, data.tobytes())
        return wkc

    def _rows_implementing(self, rows: I64, lo: int, hi: int, write: bool = False) -> I64:
        """The slaves of ``rows`` whose chip implements (or, for writes, takes) a byte of [lo, hi)."""
        if not len(rows):
            return _EMPTY
        if len(self._profiles) == 1:
            return rows if self._profile_takes(0, lo, hi, write) else _EMPTY
        keep = np.zeros(len(rows), bool)
        pids = self.profile_id[rows]
        for pid in range(len(self._profiles)):
            sel = pids == pid
            if sel.any() and self._profile_takes(pid, lo, hi, write):
                keep |= sel
        return rows[keep]

    def _profile_esc(self, pid: int) -> Esc:
        prof = self._profiles[pid]
        return next(sl.esc for sl in self.slaves if sl.spec.profile == prof)

    def _profile_takes(self, pid: int, lo: int, hi: int, write: bool) -> bool:
        """Whether chips of profile ``pid`` implement (write: take) a byte of [lo, hi); cached."""
        key = (pid, lo, hi, write)
        hit = self._takes.get(key)
        if hit is None:
            esc = self._profile_esc(pid)
            if write:
                hit = bool(esc.writable[lo:hi].any() or (_WRITE_TRIGGER[lo:hi] & esc.impl[lo:hi]).any())
            else:
                hit = bool(esc.impl[lo:hi].any())
            self._takes[key] = hit
        return hit

    def _fast_write_ok(self, lo: int, hi: int) -> bool:
        """Whether a multi-slave write over [lo, hi) can be one array operation.

        Depends on the SM areas (the cache is emptied when they are recompiled)
        and on static masks only."""
        if self.sm_dirty:
            self._refresh_sm_state()
        ok = self._fast_ok.get((lo, hi))
        if ok is not None:
            return ok
        sm_lo, sm_hi = self._sm_span
        ok = not (lo < sm_hi and hi > sm_lo) and not _PER_SLAVE_WRITE[lo:hi].any()
        self._fast_ok[(lo, hi)] = ok
        return ok

    def _multi_write(self, rows: I64, ado: int, data: bytes) -> int:
        """Write ``data`` at ``ado`` into every slave of ``rows`` (in route order)."""
        if not len(rows):
            return 0
        lo, hi = ado, ado + len(data)
        if hi > R.ADDRESS_SPACE:
            return 0
        if not self._fast_write_ok(lo, hi):
            wkc = 0
            for s in rows.tolist():
                if self.slaves[s].esc.ecat_write(ado, data):
                    wkc += 1
            return wkc
        rows = self._rows_implementing(rows, lo, hi, write=True)
        if not len(rows):
            return 0
        mem = self.memory.mem
        new = np.frombuffer(data, np.uint8)
        for pid in range(len(self._profiles)):
            key = (pid, lo, hi)
            cols = self._wcols.get(key)
            if cols is None:
                wmask = self._profile_esc(pid).writable[lo:hi]
                cols = _ALL if wmask.all() else np.nonzero(wmask)[0]
                self._wcols[key] = cols
            if not len(cols):
                continue  # nothing writable here for this chip
            sel = rows if len(self._profiles) == 1 else rows[self.profile_id[rows] == pid]
            if not len(sel):
                continue
            if cols is _ALL:
                mem[sel, lo:hi] = new
            else:
                mem[np.ix_(sel, cols + lo)] = new[cols]
        if lo < R.STATION_ALIAS + 2 and hi > R.STATION_ADDRESS:
            self.addressing_dirty = True
        if lo < R.ECAT_EVENT_MASK + 2 and hi > R.ECAT_EVENT_MASK:
            self.irq_dirty = True
        if lo < R.SM_BASE and hi > R.FMMU_BASE:
            self.fmmu_dirty = True
        if lo < R.WATCHDOG_STATUS_PROCESS_DATA and hi > R.WATCHDOG_DIVIDER:
            self.watchdog_dirty = True
        if lo < R.DC_RECEIVE_TIME_PORT0 + 16 and hi > R.DC_RECEIVE_TIME_PORT0:
            self.latch_receive_times(rows)
        if lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME:
            a = max(lo, R.DC_SYSTEM_TIME)
            self.time_loop_write(rows, data[a - lo: min(hi, R.DC_SYSTEM_TIME + 8) - lo], a - R.DC_SYSTEM_TIME)
        return len(rows)

    def _broadcast(self, cmd: int, ado: int, data: npt.NDArray[np.uint8], n: int) -> int:
        route = self.route
        passes = self._cur_passes
        if not len(passes) or n == 0:
            return 0
        lo, hi = ado, ado + n
        if hi > R.ADDRESS_SPACE:
            return 0
        if cmd == Command.BWR:
            return self._multi_write(passes, ado, data.tobytes())
        if cmd == Command.BRW:
            wkc = 0
            for s in passes.tolist():
                esc = self.slaves[s].esc
                if not esc.profile.rw_supported:
                    continue
                incoming = data.tobytes()  # the data as it arrives at this slave
                r = esc.ecat_read(ado, n)
                if r is not None:
                    data |= np.frombuffer(r, np.uint8)
                    wkc += 1
                if esc.ecat_write(ado, incoming):
                    wkc += 2
            return wkc
        # BRD
        key = (lo, hi, len(passes))
        plan = self._bplan.get(key)
        if plan is None:
            plan = self._brd_plan(route, passes, lo, hi)
            self._bplan[key] = plan
            if plan.column is not None and not plan.slow and not plan.systime and self._brd_fast:
                # Also under the int key Segment.process looks up (ado, length, passes).
                self._bplan[(ado << 16) | n | (len(passes) << 32)] = plan
        if plan.slow:
            wkc = 0
            for s in passes.tolist():
                r = self.slaves[s].esc.ecat_read(ado, n)
                if r is not None:
                    data |= np.frombuffer(r, np.uint8)
                    wkc += 1
            return wkc
        rows = plan.rows
        if not len(rows):
            return 0
        if plan.systime:
            self.refresh_system_time(rows)
        if plan.column is not None:
            # 1/2/4/8-byte reads: OR one strided column of wide integers.
            red = np.bitwise_or.reduce(plan.column)
            if red:
                dv = data.view(plan.column.dtype.str)
                dv |= red
        else:
            data |= np.bitwise_or.reduce(plan.block if plan.block is not None
                                         else self.memory.mem[rows, lo:hi], axis=0)
        clear = plan.clear
        if clear and self._event_bits & clear:
            mem = self.memory.mem
            if plan.contiguous:
                mem[: len(rows), R.ECAT_EVENT_REQUEST] &= np.uint8(~clear & 0xFF)
            else:
                mem[rows, R.ECAT_EVENT_REQUEST] &= np.uint8(~clear & 0xFF)
            self._event_bits &= ~clear
            self.irq_dirty = True
        return len(rows)

    def _brd_plan(self, route: Route, passes: I64, lo: int, hi: int) -> _BrdPlan:
        if self.sm_dirty:
            self._refresh_sm_state()
        sm_lo, sm_hi = self._sm_span
        plan = _BrdPlan()
        sii_timed = self.sii_busy_ns > 0 or any(p.sii_read_ns or p.sii_write_ns for p in self._profiles)
        plan.slow = bool((lo < sm_hi and hi > sm_lo) or (
            sii_timed and lo < R.SII_CONTROL + 2 and hi > R.SII_CONTROL))
        plan.rows = rows = self._rows_implementing(passes, lo, hi)
        plan.contiguous = contiguous = bool(route.contiguous and len(rows) == len(passes))
        plan.systime = lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME
        mem = self.memory.mem
        n = hi - lo
        if contiguous and len(rows):
            plan.block = mem[: len(rows), lo:hi]
            if n in _WIDE:
                plan.column = plan.block.view(_WIDE[n])[:, 0]
                plan.dw = _DATA_WKC[n]
            if (n in _WORD_FORMAT and lo % n == 0 and len(rows) <= self._brd_py_max and not plan.slow
                    and not plan.systime and sys.byteorder == "little"):
                # Row stride is a multiple of every word size, so slot lo // n of
                # row k is element k * (stride // n) + lo // n of the flat words.
                step = SLAVE_STRIDE // n
                words = self.memory.flat.data.cast(_WORD_FORMAT[n])
                plan.words = words[lo // n: lo // n + len(rows) * step: step]
        clear = 0
        if lo < R.DL_STATUS + 2 and hi > R.DL_STATUS:
            clear |= _EV_DL_STATUS
        if lo < R.AL_STATUS + 2 and hi > R.AL_STATUS:
            clear |= _EV_AL_STATUS
        plan.clear = clear
        return plan

    def _logical(self, cmd: int, address: int, data: npt.NDArray[np.uint8], n: int) -> int:
        if self.sm_dirty:
            self._refresh_sm_state()
        if self.fmmu_dirty or self._lmap is None:
            self._refresh_fmmus()
        lmap = self._lmap
        assert lmap is not None
        if lmap.empty or n == 0:
            return 0
        reads = cmd != Command.LWR
        writes = cmd != Command.LRD
        wkc, done, events = lmap.run(self.memory.flat, address & 0xFFFFFFFF, data, reads, writes)
        if events:
            self.irq_dirty = True
        if len(done):
            self.complete_write_sms(done)
        return wkc
