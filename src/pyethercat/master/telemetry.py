"""Telemetry of a running master: slave health, cycle statistics, DC, events, image snapshots.

A :class:`Telemetry` object is what a dashboard (``pyethercat web``) or any
other observer reads. It never runs in the cyclic thread and never blocks it:

- **statistics** come from the loop's counters and the *last second* of its
  timing samples (:meth:`~pyethercat.master.cyclic.CycleStats.recent`, O(window),
  not a copy of the whole ring), the process images are copied as bytes;
- **registers** the loop does not read (DL status 0x0110 for the ports, AL
  status and code 0x0130, error counters 0x0300-0x0313, the DC system-time
  difference 0x092C) are read with one batch of FPRDs, as acyclic datagrams
  that ride in the cyclic frames' spare room, at most ``register_rate`` times
  a second however many readers ask;
- **events** (the loop's log, DC sync events, CoE emergencies, FoE transfers
  served through the control socket) are numbered, so a reader asks for
  those after the last number it saw;
- a snapshot is taken at most ``max_rate`` times a second: faster readers get
  the last one again (two browsers polling cost what one does).

Everything a snapshot holds is plain typed data (:class:`TelemetrySnapshot`),
so the control socket carries it to another process unchanged
(:mod:`pyethercat.master.control.telemetry_ops`).

What it reads of the cyclic runner is :class:`RunnerView`: an isolated
cyclic engine (its statistics in shared memory) offers the same names.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import struct
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from pyethercat.errors import EtherCATError
from pyethercat.master import diag
from pyethercat.master.cyclestats import JITTER_BINS_US, CycleStats
from pyethercat.master.ringwatch import RingWatch
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.dc import decode_time_difference

if TYPE_CHECKING:
    from pyethercat.master.clocks import DistributedClocks
    from pyethercat.master.coe import EmergencyEvent
    from pyethercat.master.ring import RingService
    from pyethercat.master.slave import Slave

__all__ = [
    "CycleTelemetry", "GroupTelemetry", "SlaveTelemetry", "DcSlaveTelemetry", "DcTelemetry",
    "TelemetryEvent", "TelemetrySnapshot", "Telemetry", "TelemetryMaster", "RunnerView",
    "MAX_RATE", "FoeFile", "telemetry_of",
]

#: Snapshots per second at most (the dashboard refreshes at 20 Hz).
MAX_RATE = 20.0
#: Register readings per second at most.
REGISTER_RATE = 4.0
#: The timing window of the percentiles (seconds of samples).
WINDOW_S = 1.0
_EVENTS = 500
#: Events in one snapshot at most (a reader far behind catches up over several).
_PER_SNAPSHOT = 100


class RunnerView(Protocol):
    """What telemetry reads of a cyclic runner (in-process or an isolated engine's proxy)."""

    stats: CycleStats
    groups: Any
    health: Any
    events: Any
    dc: Any

    @property
    def running(self) -> bool: ...


# --- the typed snapshot -----------------------------------------------------------------


@dataclass(frozen=True)
class CycleTelemetry:
    """The cyclic loop: counters since the start, timing over the last second (µs)."""

    running: bool
    period_us: float
    cycles: int = 0
    late: int = 0
    overruns: int = 0
    skipped: int = 0
    wkc_errors: int = 0
    lost_frames: int = 0
    frames: int = 0
    #: Upper bin edges (µs) of ``histogram`` (the last bin is open).
    bins_us: list[int] = field(default_factory=list)
    #: |period - nominal| counts since the start.
    histogram: list[int] = field(default_factory=list)
    window: int = 0
    period_mean_us: float = math.nan
    period_min_us: float = math.nan
    period_max_us: float = math.nan
    jitter_p50_us: float = math.nan
    jitter_p99_us: float = math.nan
    jitter_max_us: float = math.nan
    rtt_p50_us: float = math.nan
    rtt_p99_us: float = math.nan
    rtt_max_us: float = math.nan
    #: Whether frames come back (None: this master does not tell).
    link_up: bool | None = None
    link_downs: int | None = None


@dataclass(frozen=True)
class GroupTelemetry:
    """One process-data group: working counter and a copy of its image."""

    name: str
    exchanges: int
    wkc: int
    expected_wkc: int
    wkc_ok: bool
    wkc_errors: int
    lost: int
    image: bytes


@dataclass(frozen=True)
class SlaveTelemetry:
    """One slave: AL state as last read, supervision, ports and counters (None: not read)."""

    position: int
    station_address: int
    state: int
    error: bool
    code: int
    #: The slave answered the last register reading.
    answered: bool
    #: Supervision of the cyclic loop: ok, dropped, vanished, recovering ("" without loop).
    supervision: str = ""
    recoveries: int = 0
    dl_status: int | None = None
    #: Error counters 0x0300-0x0313 as read (decode with ``diag.decode_error_counters``).
    counters: bytes | None = None
    #: |0x092C| in ns (None: no DC system time, or not read).
    dc_difference_ns: int | None = None
    #: The master port its answers come back on ("A", "B"; None: no answer).
    side: str | None = None


@dataclass(frozen=True)
class DcSlaveTelemetry:
    """What the DC set-up found for one slave."""

    position: int
    kind: str
    reference: bool
    delay_ns: int | None
    offset_ns: int | None


@dataclass(frozen=True)
class DcTelemetry:
    """Distributed clocks: the set-up's results and the cyclic loop's phase lock and monitor."""

    set_up: bool
    reference: int | None = None
    slaves: list[DcSlaveTelemetry] = field(default_factory=list)
    mode: str | None = None
    phase_error_ns: int | None = None
    locked: bool | None = None
    monitor_last_ns: int | None = None
    monitor_worst_ns: int | None = None
    unstable: bool | None = None


@dataclass(frozen=True)
class TelemetryEvent:
    """Something that happened: ``kind`` cycle, dc, emergency, foe; numbered by ``seq``."""

    seq: int
    time: float
    kind: str
    text: str
    position: int | None = None
    #: Emergencies: error code, error register and data (hex).
    code: int | None = None
    register: int | None = None
    data: str = ""


@dataclass(frozen=True)
class FaultTelemetry:
    """A fault the ring service located (``master.locate``): kind, place, the cable's ends."""

    kind: str
    text: str
    #: (position, port) of each end of the cable; position -1 is the master.
    ends: list[list[int]] = field(default_factory=list)
    slaves: list[int] = field(default_factory=list)
    detail: str = ""


@dataclass(frozen=True)
class PortTelemetry:
    """One master port of a ring (cable redundancy)."""

    name: str
    carrier: bool | None
    returning: bool
    sent: int
    received: int
    missing: int


@dataclass(frozen=True)
class TelemetrySnapshot:
    """Everything a dashboard shows that changes, taken at ``time`` (seconds, wall clock)."""

    time: float
    seq: int
    cycle: CycleTelemetry
    groups: list[GroupTelemetry]
    slaves: list[SlaveTelemetry]
    dc: DcTelemetry
    events: list[TelemetryEvent]
    #: When the registers in ``slaves`` were read (0: never).
    registers_time: float = 0.0
    registers_error: str = ""
    #: The master has two ports (cable redundancy): the segment is a ring.
    redundant: bool = False
    #: Faults located by the ring service's last diagnosis, and the master ports of a ring.
    faults: list[FaultTelemetry] = field(default_factory=list)
    ports: list[PortTelemetry] = field(default_factory=list)
    ring_state: str = ""


@dataclass(frozen=True)
class FoeFile:
    """A file moved over FoE through this master (FoE itself has no directory service)."""

    position: int
    name: str
    size: int
    direction: str
    time: float


# --- the reader ---------------------------------------------------------------------------


@dataclass
class _Row:
    """What one register reading found for one slave."""

    answered: bool
    dl_status: int | None = None
    counters: bytes | None = None
    dc_difference_ns: int | None = None
    al: tuple[int, bool, int] | None = None
    side: str | None = None


@dataclass
class _Reading:
    """One register reading of every slave (see :meth:`Telemetry._read_registers`)."""

    at: float
    rows: dict[int, _Row]
    error: str = ""
    faults: list[FaultTelemetry] = field(default_factory=list)
    ports: list[PortTelemetry] = field(default_factory=list)
    ring_state: str = ""


class TelemetryMaster(Protocol):
    """What the telemetry reads of a master (:class:`~pyethercat.master.master.Master` is one).

    Also ``runner`` when it has one (the cyclic runner, :class:`RunnerView`).
    """

    slaves: list[Slave]
    ring: RingService
    dc: DistributedClocks

    def transact(self, datagrams: Sequence[Datagram]) -> list[Datagram]: ...
    def poll_mailboxes(self) -> int: ...
    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None: ...


class Telemetry:
    """Reads a master for observers at a bounded rate (see the module text)."""

    def __init__(self, master: TelemetryMaster, *, max_rate: float = MAX_RATE,
                 register_rate: float = REGISTER_RATE,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.master = master
        self.min_interval = 1.0 / max_rate if max_rate > 0 else 0.0
        self.register_interval = 1.0 / register_rate if register_rate > 0 else 0.0
        self._clock = clock
        self._lock = threading.Lock()
        self._take_lock = threading.Lock()
        self._events: deque[TelemetryEvent] = deque(maxlen=_EVENTS)
        self._seq = 0
        self._last: TelemetrySnapshot | None = None
        self._last_at = -math.inf
        self._last_registers = False
        self._reading: _Reading | None = None
        self._runner_seen: tuple[int, object | None] = (0, None)
        self._dc_seen: tuple[int, object | None] = (0, None)
        #: Snapshots taken (not served from the cache), for tests and the benchmark.
        self.taken = 0
        self._foe: dict[tuple[int, str], FoeFile] = {}
        master.on_emergency(self._on_emergency)

    # -- events ---------------------------------------------------------------------------

    def record(self, kind: str, text: str, *, position: int | None = None,
               code: int | None = None, register: int | None = None, data: bytes = b"",
               at: float | None = None) -> None:
        """Add an event (thread-safe)."""
        with self._lock:
            self._seq += 1
            self._events.append(TelemetryEvent(self._seq, time.time() if at is None else at,
                                               kind, text, position, code, register, data.hex()))

    def _on_emergency(self, ev: EmergencyEvent) -> None:
        self.record("emergency", str(ev), position=ev.position, code=ev.error_code,
                    register=ev.error_register, data=ev.data, at=ev.time)

    def _take_new(self, items: Sequence[Any], seen: tuple[int, object | None]
                  ) -> tuple[list[Any], tuple[int, object | None]]:
        """Items appended to a bounded deque since ``seen`` (its runner id and last item)."""
        owner, last = seen
        if not items:
            return [], seen
        start = 0
        if last is not None:
            for i in range(len(items) - 1, -1, -1):
                if items[i] is last:
                    start = i + 1
                    break
        return list(items[start:]), (owner, items[-1])

    def _collect_runner_events(self, runner: RunnerView | None) -> None:
        if runner is None:
            return
        if self._runner_seen[0] != id(runner):
            self._runner_seen = (id(runner), None)
            self._dc_seen = (id(runner), None)
        new, self._runner_seen = self._take_new(list(runner.events), self._runner_seen)
        for e in new:
            self.record("cycle", e.text, at=e.t)
        dc_events = getattr(runner, "dc_events", None)
        if dc_events is not None:
            new, self._dc_seen = self._take_new(list(dc_events), self._dc_seen)
            for e in new:
                self.record("dc", getattr(e, "text", str(e)))

    def record_foe(self, position: int, name: str, size: int, direction: str) -> None:
        """A file was read ("read") or written ("write") over FoE."""
        with self._lock:
            self._foe[(position, name)] = FoeFile(position, name, size, direction, time.time())
        self.record("foe", f"slave {position}: FoE {direction} of {name!r}, {size} bytes",
                    position=position)

    def foe_files(self, position: int | None = None) -> list[FoeFile]:
        """Files moved over FoE (of one slave), newest first."""
        with self._lock:
            files = [f for f in self._foe.values() if position is None or f.position == position]
        return sorted(files, key=lambda f: -f.time)

    def events_after(self, seq: int) -> list[TelemetryEvent]:
        with self._lock:
            return [e for e in self._events if e.seq > seq]

    # -- snapshots ------------------------------------------------------------------------

    def _runner(self) -> RunnerView | None:
        runner: RunnerView | None = getattr(self.master, "runner", None)
        return runner

    def snapshot(self, since: int = 0, *, registers: bool = True) -> TelemetrySnapshot:
        """The current state, events after number ``since`` (taken at most ``max_rate``/s)."""
        with self._take_lock:
            now = self._clock()
            last = self._last
            if (last is None or now - self._last_at >= self.min_interval
                    or (registers and not self._last_registers)):
                last = self._take(registers, now)
                self._last_registers = registers
        return dataclasses.replace(last, events=self.events_after(since)[:_PER_SNAPSHOT])

    def _take(self, registers: bool, now: float) -> TelemetrySnapshot:
        self._last_at = now
        runner = self._runner()
        self._collect_runner_events(runner)
        reading = self._reading
        if registers and (reading is None or now - reading.at >= self.register_interval):
            reading = self._reading = self._read_registers(now, runner)
        with self._lock:
            seq = self._seq
        snap = TelemetrySnapshot(time.time(), seq, _cycle(runner), _groups(runner),
                                 self._slaves(runner, reading), self._dc(runner), [],
                                 _wall(reading.at, now) if reading is not None else 0.0,
                                 reading.error if reading is not None else "",
                                 self.master.ring.redundant,
                                 reading.faults if reading is not None else [],
                                 reading.ports if reading is not None else [],
                                 reading.ring_state if reading is not None else "")
        self._last = snap
        self.taken += 1
        return snap

    # -- registers --------------------------------------------------------------------------

    def _read_registers(self, now: float, runner: RunnerView | None) -> _Reading:
        """Ports, AL status and counters of every slave, and 0x092C: one batch.

        DL and AL status come from the ring service (``master.ring``). While
        the cyclic loop runs, its ring watch reads them whenever a slave
        reports a change (an event in the datagrams' IRQ field), and reading
        them here would clear the very events it waits for; so the watch's
        last diagnosis is taken, and only registers without side effects
        (error counters, the DC difference) are read. Without a loop, or with
        the loop in an isolated engine (no ring watch rides it), the ring
        service's diagnosis is run here.
        """
        m = self.master
        ring = m.ring
        slaves = list(m.slaves)
        if not slaves:
            return _Reading(now, {})
        # A ring watch rides an in-process loop only (an isolated engine's loop has none:
        # its ``ring.last`` would stay what the last diagnosis found).
        watched = (runner is not None and runner.running
                   and any(isinstance(r, RingWatch) for r in getattr(runner, "riders", ())))
        dc_set_up = getattr(m.dc, "report", None) is not None
        try:
            result = ring.last if watched else None
            if result is None:
                result = ring.start_diagnosis(flush=True, al=True).result()
            dgs: list[Datagram] = []
            plan: list[tuple[int, int]] = []
            for s in slaves:
                first = len(dgs)
                if watched:
                    dgs.append(Datagram.device(Command.FPRD, s.station_address,
                                               reg.RX_ERROR_COUNTER, diag.ERROR_COUNTERS_SIZE))
                if dc_set_up and s.dc_supported:
                    dgs.append(Datagram.device(Command.FPRD, s.station_address,
                                               reg.DC_SYSTEM_TIME_DIFFERENCE, 4))
                plan.append((first, len(dgs) - first))
            replies = m.transact(dgs) if dgs else []
        except EtherCATError as exc:
            return _Reading(now, {}, f"register reading failed: {exc}")
        by_pos = {r.position: r for r in result.readings}
        rows: dict[int, _Row] = {}
        for s, (first, count) in zip(slaves, plan, strict=True):
            r = by_pos.get(s.position)
            row = _Row(answered=r is not None and r.side is not None,
                       side=r.side if r is not None else None)
            if r is not None:
                row.dl_status = r.dl_status
                if r.al_status is not None:
                    row.al = (r.al_status & reg.AL_STATE_MASK, bool(r.al_status & reg.AL_ERROR_FLAG),
                              r.al_code or 0)
                if r.counters is not None and not watched:
                    row.counters = _encode_counters(r.counters)
            k = first
            if watched:
                if replies[k].wkc == 1:
                    row.counters = bytes(replies[k].data)
                k += 1
            if k < first + count and replies[k].wkc == 1:
                row.dc_difference_ns = decode_time_difference(
                    struct.unpack("<I", bytes(replies[k].data))[0])
            rows[s.position] = row
        with contextlib.suppress(EtherCATError):
            m.poll_mailboxes()  # emergencies posted meanwhile come through _on_emergency
        faults = [FaultTelemetry(f.kind, f.text, [list(e) for e in f.ends], list(f.slaves),
                                 f.detail) for f in ring.faults]
        ports = [PortTelemetry(p.name, p.carrier, p.returning, p.sent, p.received, p.missing)
                 for p in ring.ports()]
        return _Reading(now, rows, "", faults, ports,
                        result.ring_state if result.ring else "line")

    def _slaves(self, runner: RunnerView | None, reading: _Reading | None
                ) -> list[SlaveTelemetry]:
        health: Mapping[int, Any] = runner.health if runner is not None else {}
        out: list[SlaveTelemetry] = []
        for s in self.master.slaves:
            h = health.get(s.position)
            row = reading.rows.get(s.position) if reading is not None else None
            state, error, code = int(s.al_state), s.al_error, s.al_status_code
            if row is not None and row.al is not None:
                state, error, code = row.al
            if h is not None and h.state and (row is None or h.status != "ok"):
                # Supervision read it more recently than an event-driven diagnosis.
                state, error, code = h.state, h.error, h.code
            answered = row.answered if row is not None else True
            if h is not None and not h.present:
                answered = False
            out.append(SlaveTelemetry(
                s.position, s.station_address, state, error, code if error else 0, answered,
                h.status if h is not None else "", h.recoveries if h is not None else 0,
                row.dl_status if row is not None else None,
                row.counters if row is not None else None,
                row.dc_difference_ns if row is not None else None,
                row.side if row is not None else None))
        return out

    def _dc(self, runner: RunnerView | None) -> DcTelemetry:
        report = getattr(self.master.dc, "report", None)
        if report is None:
            return DcTelemetry(False)
        slaves = [DcSlaveTelemetry(r.position, r.kind, r.reference, r.delay_ns, r.offset_ns)
                  for r in report.slaves]
        dc = runner.dc if runner is not None else None
        if dc is None:
            return DcTelemetry(True, report.reference, slaves)
        engine = getattr(runner, "dc_status", None)
        published = engine() if engine is not None else None
        if published is not None:
            # An isolated engine's loop: its lock and monitor, not this process's copy.
            return DcTelemetry(True, report.reference, slaves, dc.mode.value,
                               published["phase_error_ns"] if dc.lock is not None else None,
                               published["locked"] if dc.lock is not None else None,
                               published["last_ns"], published["worst_ns"],
                               published["unstable"])
        lock = dc.lock
        mon = dc.monitor
        return DcTelemetry(True, report.reference, slaves, dc.mode.value,
                           lock.error_ns if lock is not None else None,
                           lock.locked if lock is not None else None,
                           mon.last_ns, mon.worst_ns, mon.unstable)


def _encode_counters(c: diag.SlaveCounters) -> bytes:
    """The 0x0300-0x0313 bytes of decoded counters (the snapshot carries the raw form)."""
    raw = bytearray(diag.ERROR_COUNTERS_SIZE)
    for n, p in enumerate(c.ports):
        raw[2 * n] = p.invalid_frames
        raw[2 * n + 1] = p.rx_errors
        raw[reg.FORWARDED_RX_ERROR_COUNTER - reg.RX_ERROR_COUNTER + n] = p.forwarded_rx_errors
        raw[reg.LOST_LINK_COUNTER - reg.RX_ERROR_COUNTER + n] = p.lost_links
    raw[reg.ECAT_PROCESSING_ERROR_COUNTER - reg.RX_ERROR_COUNTER] = c.processing_unit_errors
    raw[reg.PDI_ERROR_COUNTER - reg.RX_ERROR_COUNTER] = c.pdi_errors
    struct.pack_into("<H", raw, reg.PDI_ERROR_CODE - reg.RX_ERROR_COUNTER, c.pdi_error_code)
    return bytes(raw)


def _wall(at: float, now: float) -> float:
    """A monotonic instant ``at`` as wall-clock seconds (``now`` is the same instant's clock)."""
    return time.time() - (now - at)


def _pct(samples: np.ndarray[Any, Any], q: float) -> float:
    return float(np.percentile(samples, q)) / 1000.0 if samples.size else math.nan


def _cycle(runner: RunnerView | None) -> CycleTelemetry:
    if runner is None:
        return CycleTelemetry(False, 0.0, bins_us=list(JITTER_BINS_US))
    st = runner.stats
    window = max(1, int(WINDOW_S * 1e9 / st.period_ns)) if st.period_ns > 0 else 1
    periods, rtts = st.recent(window)
    jitter = np.abs(periods - st.period_ns)
    link_up = getattr(st, "link_up", None)
    downs = getattr(st, "link_downs", None)
    return CycleTelemetry(
        runner.running, st.period_ns / 1000, st.cycles, st.late, st.overruns, st.skipped,
        st.wkc_errors, st.lost_frames, st.frames, list(JITTER_BINS_US), list(st.histogram),
        int(periods.size),
        float(periods.mean()) / 1000 if periods.size else math.nan,
        float(periods.min()) / 1000 if periods.size else math.nan,
        float(periods.max()) / 1000 if periods.size else math.nan,
        _pct(jitter, 50), _pct(jitter, 99), float(jitter.max()) / 1000 if jitter.size else math.nan,
        _pct(rtts, 50), _pct(rtts, 99), float(rtts.max()) / 1000 if rtts.size else math.nan,
        None if link_up is None else bool(link_up), None if downs is None else int(downs))


def _groups(runner: RunnerView | None) -> list[GroupTelemetry]:
    if runner is None:
        return []
    return [GroupTelemetry(g.name, g.exchanges, g.total_wkc, g.expected_wkc, g.wkc_ok,
                           g.wkc_errors, g.lost, bytes(g.image.buffer))
            for g in runner.groups]


_BY_MASTER: weakref.WeakKeyDictionary[TelemetryMaster, Telemetry] = weakref.WeakKeyDictionary()
_REGISTRY_LOCK = threading.Lock()


def telemetry_of(master: TelemetryMaster) -> Telemetry:
    """The one :class:`Telemetry` of ``master`` (made on first use)."""
    with _REGISTRY_LOCK:
        t = _BY_MASTER.get(master)
        if t is None:
            t = _BY_MASTER[master] = Telemetry(master)
        return t
