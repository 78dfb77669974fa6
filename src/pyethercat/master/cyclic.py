"""Cyclic process-data exchange: the loop, its statistics, supervision and recovery.

``CyclicRunner`` runs the process-data groups of a configured master at
absolute deadlines (``start + k * period``): it sleeps until shortly before
the deadline and busy-waits the last slice, so wake-up jitter is the spin
granularity, not the scheduler's timer slack. Each cycle it copies every due
group's buffer into its datagrams (one LRW, or LWR + LRD, per 1486-byte
chunk), sends them through the master's scheduler (queued acyclic datagrams
ride in the spare room of the frame), copies the replies' input bytes back
and compares one working counter per datagram. No per-slave work happens on
that path.

Several groups may run at different cycle times (as IgH's domains and
TwinCAT's tasks do):
the loop ticks at the shortest period and sends a group every
``period / tick`` ticks.

Supervision, between cycles and cheap: every ``check_interval`` seconds a
BRD of AL status (2 bytes) rides in a cyclic frame. Its working counter is
the number of slaves that answered and its data the OR of their states; when
either is off, or a group's working counter was wrong, the next frames carry
one FPRD of AL status per slave (the "multiple read"), which names the slaves
that dropped out of the requested state or vanished. A recovery thread (never
the cycle thread) brings them back: a slave that answers again at position p
with station address 0 was power-cycled, so it gets its address, its sync
managers and FMMUs again, and is walked up to the requested state; a slave
that only left OP is acknowledged and requested again. The master is never
restarted.

Statistics (``CycleStats``): cycles, period and wake-up latency percentiles,
a period-jitter histogram, late cycles, overruns (and how many of them the
user callback caused), skipped deadlines, working-counter errors, lost
frames, round-trip times.
"""

from __future__ import annotations

import bisect
import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.clock import Clock, PerfClock
from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.master.config import CyclicDatagram, GroupConfig, ProcessDataConfig, wkc_share
from pyethercat.master.dc_loop import DcCycle, SyncEvent
from pyethercat.master.image import ProcessImage
from pyethercat.master.scheduler import CyclicFrame, CyclicTemplate, Request, Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState, state_name
from pyethercat.wire.datagram import MAX_PAYLOAD, OVERHEAD, Command, Datagram

__all__ = [
    "CycleStats",
    "Cycle",
    "GroupRuntime",
    "GroupStatus",
    "CyclicRunner",
    "SlaveHealth",
    "JITTER_BINS_US",
]

#: Upper edges (µs) of the period-jitter histogram bins; the last bin is open.
JITTER_BINS_US = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)
# AL status bits a supervised slave must show exactly: the state and no error flag.
_STATE_AND_ERROR = reg.AL_STATE_MASK | reg.AL_ERROR_FLAG


# --- statistics ------------------------------------------------------------------------


class CycleStats:
    """Counters and timing samples of a cyclic loop.

    Samples (period, wake-up latency, round trip; nanoseconds) are kept in
    fixed numpy ring buffers of ``capacity`` entries, so memory does not grow
    with run time; percentiles cover the last ``capacity`` cycles.
    """

    def __init__(self, period_ns: int, capacity: int = 1 << 18) -> None:
        self.period_ns = period_ns
        self.capacity = capacity
        self.cycles = 0
        self.late = 0
        self.overruns = 0
        self.callback_overruns = 0
        self.skipped = 0
        self.wkc_errors = 0
        #: Cycles whose working counter was short of even the slaves present
        #: (the ones known to be gone, ``CyclicRunner.set_absent``, not counted).
        self.incomplete = 0
        self.lost_frames = 0
        self.frames = 0
        self._periods = np.zeros(capacity, dtype=np.int64)
        self._latency = np.zeros(capacity, dtype=np.int64)
        self._rtt = np.zeros(capacity, dtype=np.int64)
        self._n_period = 0
        self._n_rtt = 0
        self._last_start: int | None = None
        self.histogram = [0] * (len(JITTER_BINS_US) + 1)
        self._edges_ns = [b * 1000 for b in JITTER_BINS_US]
        self.started_ns: int | None = None
        self.last_ns: int | None = None

    def record_start(self, deadline_ns: int, start_ns: int, late_threshold_ns: int) -> None:
        """One cycle began at ``start_ns`` for ``deadline_ns``."""
        self.cycles += 1
        if self.started_ns is None:
            self.started_ns = start_ns
        self.last_ns = start_ns
        latency = start_ns - deadline_ns
        i = (self.cycles - 1) % self.capacity
        self._latency[i] = latency
        if latency > late_threshold_ns:
            self.late += 1
        if self._last_start is not None:
            period = start_ns - self._last_start
            j = self._n_period % self.capacity
            self._periods[j] = period
            self._n_period += 1
            # Bin k: the first edge the deviation stays below.
            self.histogram[bisect.bisect_right(self._edges_ns, abs(period - self.period_ns))] += 1
        self._last_start = start_ns

    def record_round_trip(self, ns: int) -> None:
        self._rtt[self._n_rtt % self.capacity] = ns
        self._n_rtt += 1

    def restart_period(self) -> None:
        """Forget the previous start (after skipped deadlines the period is not a sample)."""
        self._last_start = None

    # -- views --------------------------------------------------------------------

    def periods(self) -> npt.NDArray[np.int64]:
        return self._periods[:min(self._n_period, self.capacity)].copy()

    def latencies(self) -> npt.NDArray[np.int64]:
        return self._latency[:min(self.cycles, self.capacity)].copy()

    def round_trips(self) -> npt.NDArray[np.int64]:
        return self._rtt[:min(self._n_rtt, self.capacity)].copy()

    @staticmethod
    def _pct(samples: npt.NDArray[np.int64], qs: Sequence[float]) -> dict[str, float]:
        if samples.size == 0:
            return {f"p{q:g}": math.nan for q in qs}
        values = np.percentile(samples, qs)
        return {f"p{q:g}": float(v) / 1000.0 for q, v in zip(qs, values, strict=True)}

    def jitter_us(self, qs: Sequence[float] = (50, 90, 99, 99.9, 100)) -> dict[str, float]:
        """Percentiles of |period - nominal| in µs."""
        return self._pct(np.abs(self.periods() - self.period_ns), qs)

    def latency_us(self, qs: Sequence[float] = (50, 90, 99, 99.9, 100)) -> dict[str, float]:
        """Percentiles of wake-up latency (start - deadline) in µs."""
        return self._pct(self.latencies(), qs)

    def round_trip_us(self, qs: Sequence[float] = (50, 90, 99, 100)) -> dict[str, float]:
        """Percentiles of the process-data round trip in µs."""
        return self._pct(self.round_trips(), qs)

    def period_us(self) -> dict[str, float]:
        p = self.periods()
        if p.size == 0:
            return {"mean": math.nan, "min": math.nan, "max": math.nan}
        return {"mean": float(p.mean()) / 1000, "min": float(p.min()) / 1000,
                "max": float(p.max()) / 1000}

    def summary(self) -> dict[str, object]:
        """Everything as plain numbers (for printing and JSON)."""
        return {
            "cycles": self.cycles, "period_us": self.period_ns / 1000,
            "late": self.late, "overruns": self.overruns,
            "callback_overruns": self.callback_overruns, "skipped": self.skipped,
            "wkc_errors": self.wkc_errors, "incomplete": self.incomplete,
            "lost_frames": self.lost_frames,
            "frames": self.frames,
            "period": self.period_us(), "jitter_us": self.jitter_us(),
            "latency_us": self.latency_us(), "round_trip_us": self.round_trip_us(),
            "histogram": dict(zip([f"<{b}us" for b in JITTER_BINS_US] + [f">={JITTER_BINS_US[-1]}us"],
                                  self.histogram, strict=True)),
        }


# --- groups ----------------------------------------------------------------------------


class GroupRuntime:
    """A group's image plus its precomputed datagram plan and counters."""

    def __init__(self, config: GroupConfig, image: ProcessImage, every: int = 1) -> None:
        self.config = config
        self.image = image
        self.name = config.name
        #: The group is sent every ``every`` loop ticks.
        self.every = every
        self.plan: list[CyclicDatagram] = list(config.datagrams)
        self.expected_wkc = config.expected_wkc
        #: Working counters of the last exchange, per datagram.
        self.last_wkc: list[int] = [0] * len(self.plan)
        self.wkc_ok = False
        #: The last exchange was complete for every slave not known to be gone.
        self.present_ok = False
        self.wkc_errors = 0
        self.incomplete = 0
        self.lost = 0
        self.exchanges = 0

    @property
    def total_wkc(self) -> int:
        return sum(self.last_wkc)


class _FramePlan:
    """One prepared frame of a cycle: where each group's bytes go and come back from.

    ``fills``: (source view of a group buffer, frame offset) for the bytes sent;
    ``takes``: per datagram (group, datagram number, WKC offset, expected WKC,
    reply offset of the input bytes, buffer start, buffer end, the share of
    absent slaves that may count on top of the expected WKC).
    """

    __slots__ = ("template", "fills", "takes", "groups", "dc_fill", "dc_read")

    def __init__(self, template: CyclicTemplate, fills: list[tuple[memoryview, int]],
                 takes: list[tuple[GroupRuntime, int, int, int, int, int, int, int]],
                 groups: list[GroupRuntime]) -> None:
        self.template = template
        self.fills = fills
        self.takes = takes
        self.groups = groups
        #: Frame offsets of the DC datagrams' data (master time written, FRMW read); -1: none.
        self.dc_fill = -1
        self.dc_read = -1


@dataclass
class Cycle:
    """What one cycle did (handed to the callback and yielded by ``cycles()``)."""

    index: int = 0
    deadline_ns: int = 0
    start_ns: int = 0
    round_trip_ns: int = 0
    wkc_ok: bool = True
    lost: bool = False
    groups: tuple[str, ...] = ()


@dataclass
class SlaveHealth:
    """Supervision state of one slave."""

    position: int
    station_address: int
    state: int = 0
    error: bool = False
    code: int = 0
    present: bool = True
    #: "ok", "dropped" (answers, not in the requested state), "vanished", "recovering"
    status: str = "ok"
    recoveries: int = 0
    lost_since_ns: int | None = None


@dataclass
class _Event:
    t: float
    text: str


# --- the runner ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class GroupStatus:
    """A snapshot of one group's exchange state, for readers outside the loop.

    ``image`` is a read-only view of the group's process image (it changes
    with every exchange; copy what must stay). ``wkc_ok`` tells whether the
    last exchange came back with the expected working counters.
    """

    name: str
    exchanges: int
    wkc_ok: bool
    image: memoryview


class CyclicRunner:
    """The cyclic loop over one or more groups (see the module text).

    ``slaves`` are the master's slave objects (``position``,
    ``station_address``, ``al_state``); ``reconfigure(slave)`` is called from
    the recovery thread to rewrite a slave's configuration and bring it back
    to ``target`` (the master passes its own; tests may pass a fake).
    """

    def __init__(self, scheduler: Scheduler, config: ProcessDataConfig,
                 images: dict[str, ProcessImage], slaves: Sequence[object], *,
                 cycle: float = 0.001, clock: Clock | None = None,
                 callback: Callable[[Cycle], None] | None = None,
                 check_interval: float = 0.1, target: AlState = AlState.OP,
                 recover: Callable[[list[int]], None] | None = None,
                 groups: Sequence[str] | None = None, late_fraction: float = 0.25,
                 frame_timeout: float | None = None, dc: DcCycle | None = None) -> None:
        if cycle <= 0:
            raise ConfigError(f"cycle time must be positive, got {cycle}")
        self.scheduler = scheduler
        self.config = config
        self.images = images
        self.slaves = list(slaves)
        self.clock: Clock = clock or PerfClock()
        self.callback = callback
        self.target = target
        self.recover_fn = recover
        self.check_interval = check_interval
        self.frame_timeout = frame_timeout
        names = list(groups) if groups is not None else [g.name for g in config.groups]
        tick = min([cycle] + [config.group(n).cycle or cycle for n in names])
        self.period_ns = int(round(tick * 1e9))
        self.groups: list[GroupRuntime] = []
        for n in names:
            g = config.group(n)
            g_cycle = g.cycle or cycle
            every = max(1, int(round(g_cycle / tick)))
            if abs(every * tick - g_cycle) > 1e-9 + 1e-6 * g_cycle:
                raise ConfigError(f"group {n!r}: cycle {g_cycle} s is not a multiple of the "
                                  f"loop tick {tick} s")
            self.groups.append(GroupRuntime(g, images[n], every))
        self.stats = CycleStats(self.period_ns)
        self.late_threshold_ns = int(self.period_ns * late_fraction)
        self.health: dict[int, SlaveHealth] = {
            int(getattr(s, "position")): SlaveHealth(int(getattr(s, "position")),  # noqa: B009
                                                     int(getattr(s, "station_address")))  # noqa: B009
            for s in self.slaves}
        self.events: deque[_Event] = deque(maxlen=200)
        self.cycle = Cycle()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cond = threading.Condition()
        self._check_every = max(1, int(round(check_interval / tick))) if check_interval > 0 else 0
        self._brd: Request | None = None
        self._detail: list[Request] | None = None
        self._want_detail = False
        self._recover_thread: threading.Thread | None = None
        self._recover_lock = threading.Lock()
        self._check_ns = int(check_interval * 1e9)
        self._last_detail_ns = 0
        self._next_recovery_ns = 0
        self._backoff_ns = 0
        self._last_failure = ""
        self.error: BaseException | None = None
        self.consumer_missed = 0
        #: Prepared frames per set of due groups (built on first use).
        self._plans: dict[tuple[int, ...], tuple[list[_FramePlan], tuple[str, ...],
                                                 tuple[GroupRuntime, ...]]] = {}
        self._every = tuple(g.every for g in self.groups)
        self._all_due = tuple(range(len(self.groups)))
        #: False while the master is still walking the slaves up (no supervision yet).
        self.supervising = True
        #: Distributed clocks: the FRMW (and in reference mode the time write) in every
        #: cycle's first frame, the phase lock moving the deadlines, the sync monitor.
        self.dc = dc
        self.dc_events: deque[SyncEvent] = deque(maxlen=200)
        #: Objects riding along every cycle (``before_cycle(runner)``,
        #: ``after_cycle(runner, tickets, ok)``): the ring watch.
        self.riders: list[Any] = []
        #: The cyclic frames of the last cycle (their replies, copies, IRQ fields).
        self.last_tickets: list[CyclicFrame] = []
        #: Their prepared-frame plans (``takes``: what each datagram carries).
        self.last_plans: list[_FramePlan] = []
        #: Slaves known to be gone (set_absent): not expected in working counters.
        self.absent: frozenset[int] = frozenset()
        self._dc_shift = 0
        self._dc_brd: Request | None = None
        #: Where the next run() continues the cycle grid (with DC).
        self._resume_ns: int | None = None
        if dc is not None and dc.cycle_ns != self.period_ns:
            raise ConfigError(f"DC cycle {dc.cycle_ns} ns differs from the loop period "
                              f"{self.period_ns} ns")

    # -- control ------------------------------------------------------------------------

    def start(self) -> CyclicRunner:
        """Run the loop in a background thread."""
        if self._thread is not None and self._thread.is_alive():
            raise ConfigError("the cyclic loop is already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._thread_main, name="ecat-cyclic", daemon=True)
        self._thread.start()
        return self

    def _thread_main(self) -> None:
        try:
            self.run()
        except BaseException as exc:  # noqa: BLE001 - kept and re-raised by join()
            self.error = exc
            self.log(f"cyclic loop stopped: {exc}")
        finally:
            # Nothing drives stepped workers any more: they go on by themselves.
            self.scheduler.stepper.release()
            with self._cond:
                self._cond.notify_all()

    def stop(self) -> None:
        """Ask the loop to stop and wait for it."""
        self._stop.set()
        self.join()

    def join(self, timeout: float | None = None) -> None:
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout)
        r = self._recover_thread
        if r is not None and r is not threading.current_thread():
            r.join(timeout)
        if self.error is not None and not isinstance(self.error, KeyboardInterrupt):
            err, self.error = self.error, None
            raise err

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _group(self, name: str) -> GroupRuntime:
        for g in self.groups:
            if g.name == name:
                return g
        raise ConfigError(f"the cyclic runner has no group {name!r} "
                          f"(groups: {', '.join(g.name for g in self.groups)})")

    def group_status(self, name: str) -> GroupStatus:
        """Exchanges so far, last working-counter verdict and a read-only image view."""
        g = self._group(name)
        return GroupStatus(g.name, g.exchanges, g.wkc_ok,
                           memoryview(g.image.buffer).toreadonly())

    def wait_exchanges(self, name: str, count: int, timeout: float) -> bool:
        """Wait until group ``name`` completed ``count`` more exchanges than now.

        False when they did not come within ``timeout`` seconds, when the loop
        thread (:meth:`start`) is not running, or when called from the loop
        thread itself (its callback would wait for itself).
        """
        g = self._group(name)
        if count <= 0:
            return True
        if not self.running or threading.current_thread() is self._thread:
            return False
        want = g.exchanges + count
        limit = time.monotonic() + timeout
        # The loop notifies this condition after every cycle.
        with self._cond:
            while g.exchanges < want:
                left = limit - time.monotonic()
                if left <= 0 or not self.running:
                    return False
                self._cond.wait(min(left, 0.05))
        return True

    def __enter__(self) -> CyclicRunner:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def log(self, text: str) -> None:
        self.events.append(_Event(time.time(), text))

    # -- the loop --------------------------------------------------------------------------

    def run(self, seconds: float | None = None, cycles: int | None = None) -> CycleStats:
        """Run in the calling thread until ``stop()``, ``seconds`` or ``cycles``."""
        clock = self.clock
        period = self.period_ns
        start = clock.now_ns() + period
        resume = self._resume_ns
        if self.dc is not None and resume is not None and clock.now_ns() <= resume < start:
            # A run after a run keeps the cycle grid the DC phase lock found.
            start = resume
        end = None if seconds is None else start + int(seconds * 1e9)
        k = 0
        done = 0
        stats = self.stats
        cyc = self.cycle
        while not self._stop.is_set():
            if self._dc_shift:
                # The DC phase lock moved the cycle: every later deadline moves with it.
                start += self._dc_shift
                self._dc_shift = 0
            deadline = start + k * period
            if end is not None and deadline >= end:
                break
            if cycles is not None and done >= cycles:
                break
            clock.sleep_until(deadline)
            t0 = clock.now_ns()
            stats.record_start(deadline, t0, self.late_threshold_ns)
            due = self._due(k)
            ok, lost, rtt, names = self._exchange(due, k)
            stats.record_round_trip(rtt)
            cyc.index, cyc.deadline_ns, cyc.start_ns = k, deadline, t0
            cyc.round_trip_ns, cyc.wkc_ok, cyc.lost = rtt, ok, lost
            cyc.groups = names
            t1 = clock.now_ns()
            if self.callback is not None:
                self.callback(cyc)
            t2 = clock.now_ns()
            nxt = deadline + period
            if t2 > nxt:
                stats.overruns += 1
                if t1 <= nxt:
                    stats.callback_overruns += 1
                    if stats.callback_overruns in (1, 10, 100, 1000):
                        self.log(f"callback overran the cycle ({(t2 - t1) / 1000:.0f} us); "
                                 f"{stats.callback_overruns} so far")
                # Resume at the first deadline still ahead instead of bursting to catch up.
                steps = -(-(t2 - deadline) // period)
                if steps > 1:
                    stats.skipped += int(steps - 1)
                    k += int(steps - 1)
                    stats.restart_period()
            k += 1
            done += 1
            with self._cond:
                self._cond.notify_all()
        self._resume_ns = start + self._dc_shift + k * period
        self._dc_shift = 0
        return stats

    def set_absent(self, positions: Iterable[int]) -> None:
        """Slaves known to be gone (a failed node, a cut branch, one being brought back):
        their share of each working counter is not expected until they are back."""
        absent = frozenset(positions)
        if absent != self.absent:
            self.absent = absent
            self._plans.clear()  # the loop plans its frames again with these expectations

    def _due(self, k: int) -> tuple[int, ...]:
        """Numbers of the groups due at tick ``k``."""
        every = self._every
        if len(every) == 1 and every[0] == 1:
            return self._all_due
        return tuple(i for i, e in enumerate(every) if k % e == 0)

    def exchange_once(self) -> bool:
        """One process-data exchange of every group now (outside the loop); WKC all good?

        For measurements and single-stepping: copies outputs, sends, waits,
        copies inputs back, checks working counters, as one loop cycle does
        (without timing statistics and supervision). Not while the loop runs.
        """
        if self.running:
            raise ConfigError("the cyclic loop is running: exchange_once() would race it")
        ok, lost, _rtt, _names = self._exchange_frames(self._all_due)
        return ok and not lost

    def _exchange(self, due: tuple[int, ...], k: int) -> tuple[bool, bool, int, tuple[str, ...]]:
        """One cycle's frames and the supervision riding in them."""
        self._supervise_before(k)
        if self.dc is not None:
            self._dc_monitor()
        for rider in self.riders:
            rider.before_cycle(self)
        ok, lost, rtt, names = self._exchange_frames(due)
        self._supervise_after(ok and not lost)
        for rider in self.riders:
            rider.after_cycle(self, self.last_tickets, ok and not lost)
        self.scheduler.step()
        return ok and not lost, lost, rtt, names

    def _dc_monitor(self) -> None:
        """The sync monitor's BRD of 0x092C rides in a cyclic frame now and then."""
        dc = self.dc
        assert dc is not None
        brd = self._dc_brd
        now = self.clock.now_ns()
        if brd is not None and brd.done():
            self._dc_brd = None
            if brd.reply is not None:
                ev = dc.monitor.on_reading(now, bytes(brd.reply.data), brd.reply.wkc)
                if ev is not None:
                    self.dc_events.append(ev)
                    self.log(ev.text)
        if self._dc_brd is None and dc.monitor.due(now):
            self._dc_brd = self.scheduler.submit([dc.monitor.datagram()], flush=False)[0]

    def _exchange_frames(self, due: tuple[int, ...]
                         ) -> tuple[bool, bool, int, tuple[str, ...]]:
        """Send, wait, copy back, check WKC: prepared frames, no per-slave work."""
        planned = self._plans.get(due)
        if planned is None:
            planned = self._plans[due] = self._plan([self.groups[i] for i in due])
        plans, names, groups = planned
        sched = self.scheduler
        now_ns = self.clock.now_ns
        timeout = self.frame_timeout
        t0 = now_ns()
        tickets: list[CyclicFrame] = []
        dc = self.dc
        for p in plans:
            frame = p.template.frame
            for view, to in p.fills:
                frame[to:to + len(view)] = view
            if p.dc_fill >= 0:
                assert dc is not None
                value = dc.fill(now_ns())
                if value is not None:
                    frame[p.dc_fill:p.dc_fill + len(value)] = value
            tickets.append(sched.send_prepared(p.template, timeout=timeout))
        self.last_tickets = tickets
        self.last_plans = plans
        stats = self.stats
        lost = False
        bad: set[GroupRuntime] | None = None
        short: set[GroupRuntime] | None = None
        missing: set[GroupRuntime] | None = None
        for p, ticket in zip(plans, tickets, strict=True):
            stats.frames += 1
            raw = ticket.raw if ticket.raw is not None else ticket.wait_raw()
            if p.dc_read >= 0:
                assert dc is not None
                at = p.dc_read
                self._dc_shift += dc.on_reply(None if raw is None else bytes(raw[at:at + dc.size]),
                                              t0)
            if raw is None:
                lost = True
                stats.lost_frames += 1
                for g in p.groups:
                    g.lost += 1
                    g.wkc_ok = g.present_ok = False
                missing = set(p.groups) if missing is None else missing | set(p.groups)
                continue
            for g, n, w, expected, at, lo, hi, share in p.takes:
                wkc = raw[w] | (raw[w + 1] << 8)
                g.last_wkc[n] = wkc
                if wkc != expected:
                    bad = {g} if bad is None else bad | {g}
                    if wkc < expected - share or wkc > expected:
                        short = {g} if short is None else short | {g}
                if hi > lo:
                    g.image.buffer[lo:hi] = raw[at:at + hi - lo]
        if bad is None and missing is None:
            for g in groups:
                g.exchanges += 1
                g.wkc_ok = g.present_ok = True
            return True, False, now_ns() - t0, names
        ok = True
        incomplete = missing is not None
        for g in groups:
            if missing is not None and g in missing:
                continue
            good = bad is None or g not in bad
            whole = short is None or g not in short
            self._account(g, good, whole)
            ok = ok and good
            incomplete = incomplete or not whole
        if incomplete:
            stats.incomplete += 1
        return ok and not lost, lost, now_ns() - t0, names

    def _plan(self, due: list[GroupRuntime]
              ) -> tuple[list[_FramePlan], tuple[str, ...], tuple[GroupRuntime, ...]]:
        """Pack the due groups' datagrams into prepared frames (once per set of groups)."""
        frames: list[list[tuple[GroupRuntime, int]]] = []
        cur: list[tuple[GroupRuntime, int]] = []
        used = 0
        for g in due:
            items = [(g, n) for n in range(len(g.plan))]
            size = sum(d.length + OVERHEAD for d in g.plan)
            if cur and used + size > MAX_PAYLOAD:
                frames.append(cur)
                cur, used = [], 0
            if size > MAX_PAYLOAD:
                # A split group: one frame per datagram (each fits by construction).
                frames += [[item] for item in items]
                continue
            cur += items
            used += size
        if cur:
            frames.append(cur)
        # The DC datagrams lead the first frame (they belong to no group); a frame of
        # their own when the first one is full.
        dc_dgs = self.dc.datagrams() if self.dc is not None else []
        if dc_dgs and (not frames or sum(d.size for d in dc_dgs) + sum(
                g.plan[n].length + OVERHEAD for g, n in frames[0]) > MAX_PAYLOAD):
            frames.insert(0, [])
        plans: list[_FramePlan] = []
        for fi, items in enumerate(frames):
            lead = dc_dgs if fi == 0 else []
            dgs = list(lead)
            for g, n in items:
                d = g.plan[n]
                dgs.append(Datagram(d.command, 0, d.logical_address, bytes(d.length)))
            template = self.scheduler.prepare_cyclic(dgs)
            if any(g.config.cross for g, _ in items):
                template.ordered = True  # cross traffic: the slaves in bus order (a ring)
            fills: list[tuple[memoryview, int]] = []
            takes: list[tuple[GroupRuntime, int, int, int, int, int, int, int]] = []
            groups: list[GroupRuntime] = []
            for i, (g, n) in enumerate(items):
                d = g.plan[n]
                at = template.data_offsets[i + len(lead)]
                fills.append((memoryview(g.image.buffer)[d.offset:d.offset + d.length], at))
                # The share of slaves known to be gone: short by that much is "incomplete
                # only for them" (wkc_ok false, present_ok true).
                share = wkc_share(d, [self.config.slaves[p] for p in d.positions
                                      if p in self.absent]) if self.absent else 0
                takes.append((g, n, template.wkc_offsets[i + len(lead)], d.expected_wkc,
                              at + d.copy_start - d.offset, d.copy_start, d.copy_end, share))
                if g not in groups:
                    groups.append(g)
            plan = _FramePlan(template, fills, takes, groups)
            if lead:
                plan.dc_read = template.data_offsets[len(lead) - 1]
                plan.dc_fill = template.data_offsets[0] if len(lead) > 1 else -1
            plans.append(plan)
        return plans, tuple(g.name for g in due), tuple(due)

    def _account(self, g: GroupRuntime, good: bool, whole: bool = True) -> None:
        g.exchanges += 1
        g.wkc_ok = good
        g.present_ok = whole
        if not good:
            g.wkc_errors += 1
            self.stats.wkc_errors += 1
        if not whole:
            g.incomplete += 1

    # -- supervision ----------------------------------------------------------------------

    def _supervise_before(self, k: int) -> None:
        """Queue the cheap check (or the per-slave read) so it rides in this cycle's frame."""
        if not self._check_every or not self.slaves or not self.supervising:
            return
        sched = self.scheduler
        now = self.clock.now_ns()
        # A fresh incident is looked at at once; a known one once per check interval.
        if (self._want_detail and self._detail is None
                and (not self._any_unhealthy() or now - self._last_detail_ns >= self._check_ns)):
            self._want_detail = False
            self._last_detail_ns = now
            self._detail = sched.submit(
                [Datagram.device(Command.FPRD, h.station_address, reg.AL_STATUS, 6)
                 for h in self.health.values()], flush=False)
        elif self._brd is None and k % self._check_every == 0:
            self._brd = sched.submit([Datagram.device(Command.BRD, 0, reg.AL_STATUS, 2)],
                                     flush=False)[0]

    def _supervise_after(self, wkc_good: bool) -> None:
        # While the master still walks the slaves up, a low WKC is no incident yet.
        if not self._check_every or not self.slaves or not self.supervising:
            return
        if not wkc_good and self._detail is None:
            self._want_detail = True
        brd = self._brd
        if brd is not None and brd.done():
            self._brd = None
            if brd.reply is not None:
                state = brd.reply.data[0] if brd.reply.data else 0
                count = brd.reply.wkc
                want = int(self.target)
                if count != len(self.slaves) or (state & _STATE_AND_ERROR) != want or self._any_unhealthy():
                    self._want_detail = True
        detail = self._detail
        if detail is not None and all(r.done() for r in detail):
            self._detail = None
            self._evaluate(detail)

    def _any_unhealthy(self) -> bool:
        return any(h.status != "ok" for h in self.health.values())

    def _evaluate(self, detail: list[Request]) -> None:
        now = self.clock.now_ns()
        bad: list[int] = []
        for h, r in zip(self.health.values(), detail, strict=True):
            rep = r.reply
            if rep is None or rep.wkc != 1:
                if h.present:
                    h.present = False
                    h.lost_since_ns = now
                    self.log(f"slave {h.position} (0x{h.station_address:04X}) vanished")
                if h.status != "recovering":
                    h.status = "vanished"
                bad.append(h.position)
                continue
            status, _res, code = struct.unpack("<HHH", rep.data)
            h.state, h.error, h.code = status & reg.AL_STATE_MASK, bool(status & reg.AL_ERROR_FLAG), code
            h.present = True
            if h.state == int(self.target) and not h.error:
                if h.status != "ok":
                    took = "" if h.lost_since_ns is None else \
                        f" after {(now - h.lost_since_ns) / 1e9:.2f} s"
                    self.log(f"slave {h.position} back in {state_name(h.state)}{took}")
                    h.recoveries += 1 if h.status == "recovering" else 0
                h.status = "ok"
                h.lost_since_ns = None
                continue
            if h.status == "ok":
                h.lost_since_ns = now
                self.log(f"slave {h.position} left {state_name(int(self.target))}: now "
                         f"{state_name(status & _STATE_AND_ERROR)}" + (f" (AL code 0x{code:04X})" if h.error else ""))
            if h.status != "recovering":
                h.status = "dropped"
            bad.append(h.position)
        if bad:
            self._start_recovery(bad)

    def request_recovery(self, positions: list[int]) -> None:
        """Bring these slaves back now (found present without their address: power-cycled,
        hot-swapped), in step with the loop; ignored while a recovery runs."""
        if self.supervising:
            self._next_recovery_ns = 0  # news: no back-off
            self._start_recovery([p for p in positions if p in self.health])

    @property
    def recovering(self) -> frozenset[int]:
        """Slaves a recovery is bringing back now."""
        return frozenset(p for p, h in self.health.items() if h.status == "recovering")

    def _start_recovery(self, positions: list[int]) -> None:
        if self.recover_fn is None or not positions:
            return
        r = self._recover_thread
        if r is not None and r.is_alive():
            return
        if self.clock.now_ns() < self._next_recovery_ns:
            return
        for p in positions:
            self.health[p].status = "recovering"

        def work() -> None:
            failure = ""
            with self._recover_lock:
                try:
                    assert self.recover_fn is not None
                    self.recover_fn(positions)
                except EtherCATError as exc:
                    failure = f"recovery of slaves {positions} not done yet: {exc}"
                except Exception as exc:  # noqa: BLE001 - a bug must not kill the loop
                    failure = f"recovery of slaves {positions} failed: {exc!r}"
                finally:
                    if failure:
                        # Back off (0.1 s doubling to 2 s) and say it once, not every try.
                        self._backoff_ns = min(2_000_000_000, max(100_000_000, 2 * self._backoff_ns))
                        if failure != self._last_failure:
                            self.log(failure)
                    else:
                        self._backoff_ns = 0
                    self._last_failure = failure
                    self._next_recovery_ns = self.clock.now_ns() + self._backoff_ns
                    # Look again soon; the check decides whether it worked.
                    self._want_detail = True

        # In step with the loop: its requests ride in cyclic frames (master.stepping).
        self._recover_thread = self.scheduler.stepper.run(work, name="ecat-recover")

    # -- consuming cycles ---------------------------------------------------------------------

    def cycles(self, timeout: float = 1.0) -> Iterator[Cycle]:
        """Yield a snapshot of each cycle as it completes (the loop runs in its thread).

        A slow consumer does not slow the loop: cycles it could not see are
        counted in ``consumer_missed``. Ends when the loop stops.
        """
        last = -1
        while True:
            with self._cond:
                while self.cycle.index == last or self.stats.cycles == 0:
                    if not self.running:
                        return
                    if not self._cond.wait(timeout) and not self.running:
                        return
                snap = Cycle(self.cycle.index, self.cycle.deadline_ns, self.cycle.start_ns,
                             self.cycle.round_trip_ns, self.cycle.wkc_ok, self.cycle.lost,
                             self.cycle.groups)
            if last >= 0 and snap.index > last + 1:
                self.consumer_missed += snap.index - last - 1
            last = snap.index
            yield snap

    def status_lines(self) -> list[str]:
        """Short text for live views and logs."""
        lines = []
        for g in self.groups:
            lines.append(f"group {g.name}: WKC {g.total_wkc}/{g.expected_wkc} "
                         f"{'ok' if g.wkc_ok else 'BAD'}; errors {g.wkc_errors}, lost {g.lost}")
        dc = self.dc
        if dc is not None:
            mon = dc.monitor
            text = f"DC {dc.mode.value}: "
            if dc.lock is not None:
                text += f"phase error {dc.lock.error_ns} ns{' (locked)' if dc.lock.locked else ''}, "
            elif dc.master_difference_ns is not None:
                text += f"reference - master {dc.master_difference_ns} ns, "
            last = "-" if mon.last_ns is None else f"{mon.last_ns}"
            text += (f"|0x092C| <= {last} ns (worst {mon.worst_ns}), "
                     f"{'SYNC UNSTABLE' if mon.unstable else 'in sync'}")
            lines.append(text)
        return lines

