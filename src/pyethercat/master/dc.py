"""Distributed-clock set-up as a sans-IO state machine, and SYNC0/SYNC1 configuration.

:class:`DcSetup` knows nothing of links or clocks: it hands out batches of
datagrams (:meth:`DcSetup.next_request`), takes their replies
(:meth:`DcSetup.receive`) and ends with a :class:`DcReport`. The driver
(:func:`run_dc_setup`, or a test, or the isolated engine) does the I/O and
gives the master's time, in ns since 2000, with each request. The steps:

1. latch: one broadcast write to 0x0900 makes every DC slave latch its port
   receive times (IgH ``fsm_master.c``, SOEM ``ecx_configdc``); the
   master time sampled just before it is the time base of the offsets;
2. read: 0x0900-0x090F and 0x0918 of every DC slave, batched into as few
   frames as fit; a slave whose 0x0918 does not answer has receive times
   only (Beckhoff EL2828/EL1004: no system time, offset or delay);
3. compute the tree, delays and offsets (:mod:`pyethercat.wire.dc`);
4. write 0x0920 (offset) and 0x0928 (delay) of every slave with a system
   time, a 12-byte write per 64-bit slave as IgH does;
5. reset the time-control loops (filter depths 0x0934/0x0935, then 0x0930:
   "the filters are reset by writing the Speed Counter Start value", ESC
   datasheet section I 9.1.4 as quoted in ethercrab ``NOTES.md``);
6. static drift compensation: ``static_sync`` FRMW of the reference's 0x0910,
   many per frame;
7. check: 0x092C of every slave, by magnitude (the sources disagree on the
   sign bit).

:func:`sync_config_writes` gives the register writes that start a slave's
SYNC0/SYNC1 (cyclic unit off, cycle times, start time on the cycle grid,
AssignActivate), in the order IgH's ``fsm_slave_config.c`` uses.
"""

from __future__ import annotations

import enum
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import MAX_PAYLOAD, OVERHEAD, Command, Datagram
from pyethercat.wire.dc import (
    AssignActivate,
    DcPorts,
    decode_time_difference,
    propagation_delays,
    sync1_period,
    sync_start_time,
    system_time_offset,
    unix_to_ethercat_ns,
)

__all__ = [
    "DEFAULT_STATIC_SYNC",
    "MAX_SYNC_DIFF_NS",
    "DcError",
    "DcReport",
    "DcRequest",
    "DcSettings",
    "DcSetup",
    "DcSlaveInfo",
    "DcSlaveResult",
    "SyncSettings",
    "ecat_time_ns",
    "run_dc_setup",
    "sync_config_writes",
]

#: FRMW of the reference's system time sent for the static drift compensation
#: (KickCAT attributes the figure to the documentation; ethercrab: "the spec
#: recommends about 15000").
DEFAULT_STATIC_SYNC = 15_000
#: A slave farther off than this after the compensation is reported (IgH
#: ``EC_DC_MAX_SYNC_DIFF_NS``).
MAX_SYNC_DIFF_NS = 10_000
#: Filter depths during the compensation: no filtering of the time
#: difference, 2^12 for the speed counter (SOEM, KickCAT: 0x0C00 at 0x0934).
_FILTER_DEPTHS = bytes([0, R.DC_SPEED_FILTER_DEPTH_DEFAULT])
# Requests hold up to this many frames' worth of datagrams (the scheduler keeps
# several in flight); static compensation goes out in such chunks.
_FRAMES_PER_REQUEST = 2


class DcError(EtherCATError):
    """Distributed clocks could not be set up (no DC slave, a slave did not answer...)."""


def ecat_time_ns() -> int:
    """The host's real-time clock as EtherCAT system time (ns since 2000-01-01)."""
    return unix_to_ethercat_ns(time.time_ns())


# --- inputs and results -------------------------------------------------------------


@dataclass(frozen=True)
class DcSlaveInfo(R.EscFeaturesMixin):
    """What the set-up needs of a scanned slave (``features``: ESC register 0x0008)."""

    position: int
    station_address: int
    features: int
    active_ports: frozenset[int]  # from DL status 0x0110
    name: str = ""


@dataclass
class DcSettings:
    """Options of the DC set-up.

    ``reference``: ring position of the reference clock (default: the first
    DC slave with a system time). ``static_sync``: FRMW for the static drift
    compensation (0: none). ``max_difference_ns``: a slave farther off after
    the compensation is listed in ``DcReport.unsynchronised``.
    """

    reference: int | None = None
    static_sync: int = DEFAULT_STATIC_SYNC
    max_difference_ns: int = MAX_SYNC_DIFF_NS
    #: Time between two requests of the compensation (2 frames each): 203 frames
    #: then take about 0.2 s, long enough for the slaves' loops to learn their
    #: clock's rate (in 30 ms of back-to-back frames they learn a fraction of it).
    #: 0: as fast as the link goes.
    static_spacing_ns: int = 2_000_000
    #: Read every following slave's 0x092C after each this many FRMW of the
    #: compensation (0: not at all); kept in ``DcReport.trace`` for plots.
    trace_every: int = 0


@dataclass
class DcSlaveResult:
    """The DC view of one slave after the set-up (``None``: not applicable)."""

    position: int
    station_address: int
    name: str
    supported: bool
    bits: int | None                      # 32 or 64 (None without DC)
    system_time: bool = False             # 0x0910-0x0935 exist (not receive times only)
    reference: bool = False
    receive_times: tuple[int, int, int, int] | None = None
    entry_port: int = 0
    parent: int | None = None
    parent_port: int | None = None
    delay_ns: int | None = None
    offset_ns: int | None = None          # written to 0x0920 (signed)
    difference_ns: int | None = None      # |0x092C| after the compensation
    before_reference: bool = False        # passed before the reference: cannot follow it

    @property
    def kind(self) -> str:
        """``64-bit``, ``32-bit``, ``latch-only`` or ``no``."""
        if not self.supported:
            return "no"
        if not self.system_time:
            return "latch-only"
        return f"{self.bits}-bit"


@dataclass
class DcReport:
    """Outcome of :class:`DcSetup`."""

    slaves: list[DcSlaveResult]
    reference: int | None
    master_time_ns: int = 0
    static_sync: int = 0
    static_frames: int = 0
    #: Master time from the latch to the last request (the driver's clock).
    duration_s: float = 0.0
    warnings: list[str] = field(default_factory=list)
    max_difference_ns: int = MAX_SYNC_DIFF_NS
    #: (master time ns, FRMW sent so far, |0x092C| per following slave) during the compensation.
    trace: list[tuple[int, int, tuple[int | None, ...]]] = field(default_factory=list)

    @property
    def reference_slave(self) -> DcSlaveResult | None:
        return None if self.reference is None else self.slaves[self.reference]

    @property
    def synchronised(self) -> list[DcSlaveResult]:
        """Slaves with a system time that follow the reference."""
        return [s for s in self.slaves if s.system_time and not s.before_reference]

    @property
    def worst_difference_ns(self) -> int | None:
        diffs = [s.difference_ns for s in self.synchronised if s.difference_ns is not None]
        return max(diffs) if diffs else None

    @property
    def unsynchronised(self) -> list[DcSlaveResult]:
        """Slaves still farther off than ``max_difference_ns`` after the compensation."""
        return [s for s in self.synchronised
                if s.difference_ns is not None and s.difference_ns > self.max_difference_ns]


# --- the sans-IO set-up ------------------------------------------------------------


class _Stage(enum.Enum):
    LATCH = "latch receive times"
    READ = "read receive times"
    WRITE = "write offsets and delays"
    RESET = "reset time-control loops"
    STATIC = "static drift compensation"
    TRACE = "trace system time difference"
    CHECK = "check system time difference"
    DONE = "done"


@dataclass(frozen=True)
class DcRequest:
    """One batch of datagrams to send; ``stage`` names the step for progress output."""

    stage: str
    datagrams: list[Datagram]
    done: int = 0
    total: int = 0
    #: Wait this long (ns of master time) before sending.
    wait_ns: int = 0


class DcSetup:
    """The DC set-up sequence (module text); bytes in, report out, no I/O.

    ``DcError`` is raised when no slave supports DC, when the latching write
    reaches none, or when a slave with a system time refuses its offset.
    """

    def __init__(self, slaves: Sequence[DcSlaveInfo], settings: DcSettings | None = None) -> None:
        self.settings = settings or DcSettings()
        self.infos = list(slaves)
        self.results = [DcSlaveResult(s.position, s.station_address, s.name, s.dc_supported,
                                      (64 if s.dc_64bit else 32) if s.dc_supported else None)
                        for s in self.infos]
        self._dc = [s for s in self.infos if s.dc_supported]
        if not self._dc:
            raise DcError("no DC found: no slave supports distributed clocks (0x0008 bit 2)")
        self._stage = _Stage.LATCH
        self._pending: _Stage | None = None
        self._master_time = 0
        self._reference: int | None = None
        self._static_left = max(0, int(self.settings.static_sync))
        self._static_frames = 0
        self._frmw_size = 8
        self._started: int | None = None
        self._last_now = 0
        self._trace_at: int | None = None   # FRMW count of a pending trace read
        self._trace_time = 0
        self._next_trace = self.settings.trace_every
        self.report = DcReport(self.results, None, max_difference_ns=self.settings.max_difference_ns)

    # -- driving --------------------------------------------------------------------

    @property
    def done(self) -> bool:
        return self._stage is _Stage.DONE

    def next_request(self, now_ns: int) -> DcRequest | None:
        """The next batch to send (``None`` when finished); ``now_ns``: master time, ns since 2000."""
        if self._pending is not None:
            raise ConfigError("DcSetup: receive() the replies of the last request first")
        if self._started is None:
            self._started = now_ns
        self._last_now = now_ns
        stage = self._stage
        if stage is _Stage.DONE:
            return None
        if self._trace_at is not None:
            self._trace_time = now_ns
            self._pending = _Stage.TRACE
            return DcRequest(_Stage.TRACE.value, self._difference_reads())
        if stage is _Stage.LATCH:
            # Sampled before the latching frame leaves (the master's time just
            # before the latch); the offsets make every system time equal it
            # at the moment the frame passed the reference.
            self._master_time = now_ns
            dgs = [Datagram.device(Command.BWR, 0, R.DC_RECEIVE_TIME_PORT0, bytes(4))]
        elif stage is _Stage.READ:
            dgs = []
            for s in self._dc:
                dgs.append(Datagram.device(Command.FPRD, s.station_address,
                                           R.DC_RECEIVE_TIME_PORT0, 16))
                dgs.append(Datagram.device(Command.FPRD, s.station_address,
                                           R.DC_RECEIVE_TIME_ECAT, 8))
        elif stage is _Stage.WRITE:
            dgs = self._offset_writes()
        elif stage is _Stage.RESET:
            dgs = [Datagram.device(Command.BWR, 0, R.DC_TIME_FILTER_DEPTH, _FILTER_DEPTHS),
                   Datagram.device(Command.BWR, 0, R.DC_SPEED_COUNTER_START,
                                   struct.pack("<H", R.DC_SPEED_COUNTER_START_DEFAULT))]
        elif stage is _Stage.STATIC:
            per_frame = MAX_PAYLOAD // (OVERHEAD + self._frmw_size)
            n = min(self._static_left, per_frame * _FRAMES_PER_REQUEST)
            ref = self.results[self._ref()].station_address
            dgs = [Datagram.device(Command.FRMW, ref, R.DC_SYSTEM_TIME, bytes(self._frmw_size))
                   for _ in range(n)]
            wait = self.settings.static_spacing_ns if self._static_frames else 0
            self._static_frames += -(-n // per_frame)
            self._pending = stage
            total = self.settings.static_sync
            return DcRequest(stage.value, dgs, total - self._static_left, total, wait)
        else:  # CHECK
            dgs = self._difference_reads()
        self._pending = stage
        return DcRequest(stage.value, dgs)

    def _difference_reads(self) -> list[Datagram]:
        return [Datagram.device(Command.FPRD, r.station_address, R.DC_SYSTEM_TIME_DIFFERENCE, 4)
                for r in self.report.synchronised]

    def receive(self, replies: Sequence[Datagram]) -> None:
        """The replies of the last request, in order."""
        stage, self._pending = self._pending, None
        if stage is None:
            raise ConfigError("DcSetup: no request is waiting for replies")
        if stage is _Stage.TRACE:
            assert self._trace_at is not None
            values = tuple(decode_time_difference(struct.unpack("<I", d.data)[0])
                           if d.wkc == 1 else None for d in replies)
            self.report.trace.append((self._trace_time, self._trace_at, values))
            self._trace_at = None
            return
        if stage is _Stage.LATCH:
            if replies[0].wkc == 0:
                raise DcError("no DC found: the latching write to 0x0900 reached no slave")
            if replies[0].wkc != len(self._dc):
                self.report.warnings.append(
                    f"the latching write counted {replies[0].wkc} DC slaves, "
                    f"{len(self._dc)} expected")
            self._stage = _Stage.READ
        elif stage is _Stage.READ:
            self._take_times(replies)
            self._stage = _Stage.WRITE
        elif stage is _Stage.WRITE:
            for d in replies:
                if d.wkc != 1:
                    r = self._by_station(d.adp)
                    raise DcError(f"slave {r.position} (0x{r.station_address:04X}) did not take "
                                  f"its DC offset/delay (0x{d.ado:04X}, working counter {d.wkc})")
            self._stage = _Stage.RESET if self.settings.static_sync > 0 else _Stage.CHECK
        elif stage is _Stage.RESET:
            self._stage = _Stage.STATIC
        elif stage is _Stage.STATIC:
            self._static_left -= len(replies)
            sent = self.settings.static_sync - self._static_left
            every = self.settings.trace_every
            if every > 0 and (sent >= self._next_trace or self._static_left <= 0):
                self._trace_at = sent
                self._next_trace = (sent // every + 1) * every
            expected = len(self.report.synchronised)
            low = [d.wkc for d in replies if d.wkc != expected]
            if low and not any("static drift" in w for w in self.report.warnings):
                self.report.warnings.append(
                    f"static drift compensation: FRMW working counter {low[0]}, {expected} expected")
            if self._static_left <= 0:
                self._stage = _Stage.CHECK
        elif stage is _Stage.CHECK:
            for r, d in zip(self.report.synchronised, replies, strict=True):
                if d.wkc == 1:
                    r.difference_ns = decode_time_difference(struct.unpack("<I", d.data)[0])
            self._finish()

    # -- steps ----------------------------------------------------------------------

    def _by_station(self, station: int) -> DcSlaveResult:
        for r in self.results:
            if r.station_address == station:
                return r
        raise DcError(f"reply from unknown station 0x{station:04X}")

    def _ref(self) -> int:
        assert self._reference is not None
        return self._reference

    def _take_times(self, replies: Sequence[Datagram]) -> None:
        epu: dict[int, int] = {}
        for k, s in enumerate(self._dc):
            ports_reply, epu_reply = replies[2 * k], replies[2 * k + 1]
            r = self.results[s.position]
            if ports_reply.wkc != 1:
                raise DcError(f"slave {s.position} (0x{s.station_address:04X}) did not answer the "
                              "read of its receive times")
            r.receive_times = struct.unpack("<4I", ports_reply.data)
            r.system_time = epu_reply.wkc == 1
            if r.system_time:
                value = struct.unpack("<Q", epu_reply.data)[0]
                epu[s.position] = value if s.dc_64bit else value & 0xFFFF_FFFF
        ports = [DcPorts(s.active_ports, self.results[s.position].receive_times)
                 for s in self.infos]
        ref = self.settings.reference
        if ref is None:
            ref = next((r.position for r in self.results if r.system_time), None)
            if ref is None:
                raise DcError("no DC found: no slave has a system time (receive times only)")
        elif not (0 <= ref < len(self.results)) or not self.results[ref].system_time:
            raise ConfigError(f"reference clock: slave {ref} has no DC system time")
        self._reference = ref
        self.report.reference = ref
        delays = propagation_delays(ports, ref)
        self.results[ref].reference = True
        self._frmw_size = 8 if self.infos[ref].dc_64bit else 4
        before = []
        for d, r, info in zip(delays, self.results, self.infos, strict=True):
            r.entry_port, r.parent, r.parent_port = d.entry_port, d.parent, d.parent_port
            r.delay_ns = d.delay_ns
            r.before_reference = d.before_reference
            if r.system_time and d.before_reference:
                before.append(r)
            if r.system_time and d.delay_ns is not None:
                bits = 64 if info.dc_64bit else 32
                raw = system_time_offset(self._master_time, epu[r.position], d.delay_ns, bits)
                r.offset_ns = raw - (1 << bits) if raw >= 1 << (bits - 1) else raw
        if before:
            names = ", ".join(f"slave {r.position}" for r in before)
            raise ConfigError(f"reference clock: {names} with a system time would be passed before "
                              f"the reference (slave {ref}) and could not follow it; name a "
                              "reference earlier in the ring")

    def _offset_writes(self) -> list[Datagram]:
        dgs = []
        for r, info in zip(self.results, self.infos, strict=True):
            if r.offset_ns is None or r.delay_ns is None:
                continue
            delay = struct.pack("<I", r.delay_ns & 0xFFFF_FFFF)
            if info.dc_64bit:
                # offset and delay in one write (IgH ``fsm_master.c``: 12 bytes at 0x0920)
                data = struct.pack("<q", r.offset_ns) + delay
                dgs.append(Datagram.device(Command.FPWR, r.station_address,
                                           R.DC_SYSTEM_TIME_OFFSET, data))
            else:
                dgs.append(Datagram.device(Command.FPWR, r.station_address, R.DC_SYSTEM_TIME_OFFSET,
                                           struct.pack("<I", r.offset_ns & 0xFFFF_FFFF)))
                dgs.append(Datagram.device(Command.FPWR, r.station_address, R.DC_SYSTEM_TIME_DELAY,
                                           delay))
        return dgs

    def _finish(self) -> None:
        self._stage = _Stage.DONE
        rep = self.report
        rep.master_time_ns = self._master_time
        rep.static_sync = self.settings.static_sync
        rep.static_frames = self._static_frames
        rep.duration_s = (self._last_now - (self._started or self._last_now)) / 1e9
        for r in rep.unsynchronised:
            rep.warnings.append(f"slave {r.position}: system time difference {r.difference_ns} ns "
                                f"after the compensation (more than {rep.max_difference_ns} ns)")


Transact = Callable[[Sequence[Datagram]], Sequence[Datagram]]
Progress = Callable[[str, int, int], None]


def run_dc_setup(transact: Transact, slaves: Sequence[DcSlaveInfo],
                 settings: DcSettings | None = None, *,
                 master_time: Callable[[], int] = ecat_time_ns,
                 progress: Progress | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> DcReport:
    """Drive :class:`DcSetup` with a datagram transport (e.g. ``scheduler.transact``).

    ``sleep(seconds)`` waits where a request asks for it (the master passes
    its scheduler's, which moves a virtual clock instead)."""
    setup = DcSetup(slaves, settings)
    while True:
        req = setup.next_request(master_time())
        if req is None:
            return setup.report
        if req.wait_ns > 0:
            sleep(req.wait_ns / 1e9)
        if progress is not None:
            progress(req.stage, req.done, req.total)
        setup.receive(transact(req.datagrams))


# --- SYNC0 / SYNC1 ---------------------------------------------------------------------


@dataclass(frozen=True)
class SyncSettings:
    """SYNC0/SYNC1 of one slave (times in ns).

    ``assign_activate``: the 16-bit value from the ESI/SII (0x0300 SYNC0,
    0x0700 SYNC0 + SYNC1); ``cycle0``/``shift0``: SYNC0 cycle and its shift on
    the cycle grid (0 up to below one cycle); ``cycle1``: the 0x09A4 value (see
    :func:`pyethercat.wire.dc.sync1_cycle_register`).
    """

    assign_activate: int
    cycle0: int
    shift0: int = 0
    cycle1: int = 0

    def __post_init__(self) -> None:
        AssignActivate(self.assign_activate)  # range check
        if not 0 <= self.cycle0 < 1 << 32 or not 0 <= self.cycle1 < 1 << 32:
            raise ConfigError(f"SYNC cycle times must fit 32 bits: {self.cycle0}, {self.cycle1}")
        # The start time is the cycle grid plus the shift: a shift of a cycle or more
        # names the same pulses as a smaller one, a negative one falls before the grid.
        if self.shift0 < 0 or (self.cycle0 and self.shift0 >= self.cycle0):
            raise ConfigError(f"SYNC0 shift {self.shift0} ns must lie within the cycle "
                              f"(0 to {max(self.cycle0 - 1, 0)} ns)")

    @property
    def activate(self) -> AssignActivate:
        return AssignActivate(self.assign_activate)

    @property
    def grid(self) -> int:
        """The period on which start times are aligned (the SYNC1 period when SYNC1 is a multiple)."""
        if self.activate.sync1 and self.cycle1 >= self.cycle0 > 0:
            return sync1_period(self.cycle0, self.cycle1)
        return self.cycle0

    def start_time(self, system_time_ns: int, margin_ns: int | None = None) -> int:
        """First pulse time for a reference system time read just now."""
        if margin_ns is None:
            return sync_start_time(system_time_ns, self.grid, self.shift0)
        return sync_start_time(system_time_ns, self.grid, self.shift0, margin_ns=margin_ns)


def sync_config_writes(settings: SyncSettings | None, start_time_ns: int = 0,
                       dc_64bit: bool = True) -> list[tuple[int, bytes]]:
    """Register writes that (re)start a slave's cyclic unit, in order.

    Cyclic unit off (0x0980/0x0981 = 0), then, if ``settings`` asks for
    pulses: SYNC0/SYNC1 cycle times (0x09A0, 8 bytes), the start time
    (0x0990, 8 bytes or the low 4 on a 32-bit clock) and the AssignActivate
    (0x0980, 2 bytes), which starts the unit (IgH ``fsm_slave_config.c``).
    """
    writes = [(R.DC_CYCLIC_UNIT_CONTROL, bytes(2))]
    if settings is None or not settings.activate.active:
        return writes
    writes.append((R.DC_SYNC0_CYCLE, struct.pack("<II", settings.cycle0, settings.cycle1)))
    if dc_64bit:
        writes.append((R.DC_START_TIME, struct.pack("<Q", start_time_ns & 0xFFFF_FFFF_FFFF_FFFF)))
    else:
        writes.append((R.DC_START_TIME, struct.pack("<I", start_time_ns & 0xFFFF_FFFF)))
    writes.append((R.DC_CYCLIC_UNIT_CONTROL, struct.pack("<H", settings.assign_activate)))
    return writes
