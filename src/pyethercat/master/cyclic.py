"""Cyclic process-data exchange: the loop, link spells, stale inputs, orderly stop.

``CyclicRunner`` runs the process-data groups of a configured master at
absolute deadlines (``start + k * period``): it sleeps until shortly before
the deadline and busy-waits the last slice, so wake-up jitter is the spin
granularity, not the scheduler's timer slack. Each cycle it copies every due
group's buffer into its datagrams (one LRW, or LWR + LRD, per 1486-byte
chunk), sends them through the master's scheduler (queued acyclic datagrams
ride in the spare room of the frame), checks one working counter per
datagram and copies the replies' input bytes back. No per-slave work
happens on that path.

Inputs come only from an exchange that came back whole: a group's input
bytes are copied when every one of its datagrams returned with the expected
working counter. Otherwise the group keeps its last good inputs and they
age: ``ProcessImage.input_age`` (and ``slave.inputs.age``) counts the
group's exchanges since they were refreshed. SOEM
(``ecx_receive_processdata_group`` in ``ec_main.c``) and IgH
(``ec_master_receive_datagrams`` in ``master/master.c``) copy the data of
every datagram that came back, whatever its working counter, and leave it to
the application to compare the counter (SOEM's return value, IgH's
``ecrt_domain_state`` ``wc_state``); a lost frame leaves the old data in
both.

A cyclic frame has until 90% of the period after its deadline to come back,
but at least 2 ms (``frame_timeout`` overrides); a later one counts as lost,
so at periods from 2.2 ms up a lost frame costs no deadline. While the link
is down each cycle's frames are probes that wait 100 µs at most (a reply
that comes later ends the spell one cycle later), so the loop keeps its
deadlines through the whole spell. When no frame of a cycle comes
back for ``link_timeout`` seconds, or the link says it has no carrier or
refuses to send, the link is *down*: the loop keeps its deadlines, counts
the lost cycles (``CycleStats.down_cycles``), stops the supervision's checks
and marks every slave's state unknown. The first frame that comes back ends
the spell; supervision then reads every slave and the recovery thread
brings those that fell out of OP (process-data watchdog) back.

Several groups may run at different cycle times (as IgH's domains and
TwinCAT's tasks do):
the loop ticks at the shortest period and sends a group every
``period / tick`` ticks.

Supervision and recovery: see :mod:`pyethercat.master.supervision`.
Statistics: :class:`~pyethercat.master.cyclestats.CycleStats`.

Stopping (:meth:`CyclicRunner.stop`) is orderly: for ``safe_cycles``
cycles the outputs sent are the safe ones (``ProcessImage.safe``: zero
unless the application set values there), then, with a ``leave`` callback
(the master gives one), the slaves are requested to SAFEOP while the loop
still runs, the loop ends, and the slaves are taken to ``final_state``
(PREOP by default), so no slave is left to run into its watchdog.
:meth:`CyclicRunner.halt` ends the loop at once.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

from pyethercat.clock import Clock, PerfClock
from pyethercat.errors import ConfigError
from pyethercat.master.config import ProcessDataConfig
from pyethercat.master.cycleplan import (
    FramePlan,
    GroupRuntime,
    group_runtimes,
)
from pyethercat.master.cyclestats import JITTER_BINS_US, CycleStats
from pyethercat.master.dc_loop import DcCycle, SyncEvent
from pyethercat.master.exchange import CycleExchange, DcRider
from pyethercat.master.image import ProcessImage
from pyethercat.master.linkwatch import LinkWatch
from pyethercat.master.ring import FaultBoard
from pyethercat.master.scheduler import CyclicFrame, Scheduler
from pyethercat.master.stopping import LeaveFn, OrderlyStop
from pyethercat.master.supervision import SlaveHealth, Supervisor
from pyethercat.realtime import set_fifo
from pyethercat.wire.al import AlState

__all__ = [
    "CycleStats",
    "Cycle",
    "GroupRuntime",
    "GroupStatus",
    "CyclicRunner",
    "LeaveFn",
    "check_final_state",
    "SlaveHealth",
    "JITTER_BINS_US",
]

_NONE: frozenset[int] = frozenset()

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
    #: False while the link is down (no frame comes back).
    link_up: bool = True


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
    last exchange came back with the expected working counters;
    ``input_age`` how many of the group's exchanges ago its inputs were
    refreshed (0: by the last one), ``inputs_valid`` whether they ever were.
    """

    name: str
    exchanges: int
    wkc_ok: bool
    image: memoryview
    input_age: int = 0
    inputs_valid: bool = True

    @property
    def inputs_stale(self) -> bool:
        return self.input_age > 0 or not self.inputs_valid


class RunnerOptions(TypedDict, total=False):
    """The keyword options of :class:`CyclicRunner`, for runners built on it to pass on."""

    cycle: float
    clock: Clock | None
    callback: Callable[[Cycle], None] | None
    check_interval: float
    target: AlState
    recover: Callable[[list[int]], None] | None
    groups: Sequence[str] | None
    late_fraction: float
    frame_timeout: float | None
    link_timeout: float | None
    state_timeout: float | None
    leave: LeaveFn | None
    final_state: AlState | str
    safe_cycles: int
    dc: DcCycle | None


DEFAULT_CYCLE = 0.001
DEFAULT_CHECK_INTERVAL = 0.1


class CyclicRunner:
    """The cyclic loop over one or more groups (see the module text).

    ``slaves`` are the master's slave objects (``position``,
    ``station_address``); ``recover(positions)`` is called from the recovery
    thread to bring slaves back to ``target``, ``leave(state, positions,
    timeout)`` by :meth:`stop` to take them down (the master passes its own;
    tests may pass fakes). ``link_timeout``: seconds without any frame back
    before the link counts as down (default: 3 periods, at least 20 ms).
    ``state_timeout``: see :meth:`slave_state`.
    """

    def __init__(self, scheduler: Scheduler, config: ProcessDataConfig,
                 images: dict[str, ProcessImage], slaves: Sequence[object], *,
                 cycle: float = DEFAULT_CYCLE, clock: Clock | None = None,
                 callback: Callable[[Cycle], None] | None = None,
                 check_interval: float = DEFAULT_CHECK_INTERVAL, target: AlState = AlState.OP,
                 recover: Callable[[list[int]], None] | None = None,
                 groups: Sequence[str] | None = None, late_fraction: float = 0.25,
                 frame_timeout: float | None = None, link_timeout: float | None = None,
                 state_timeout: float | None = None, leave: LeaveFn | None = None,
                 final_state: AlState | str = AlState.PREOP, safe_cycles: int = 3,
                 dc: DcCycle | None = None) -> None:
        if cycle <= 0:
            raise ConfigError(f"cycle time must be positive, got {cycle}")
        for what, value in (("frame_timeout", frame_timeout), ("link_timeout", link_timeout),
                            ("state_timeout", state_timeout)):
            if value is not None and value <= 0:
                raise ConfigError(f"{what} must be positive, got {value}")
        if safe_cycles < 0:
            raise ConfigError(f"safe_cycles must be >= 0, got {safe_cycles}")
        self.scheduler = scheduler
        self.config = config
        self.images = images
        self.slaves = list(slaves)
        self.clock: Clock = clock or PerfClock()
        self.callback = callback
        self.target = target
        self.frame_timeout = frame_timeout
        tick, self.groups = group_runtimes(config, images, groups, cycle)
        self.period_ns = int(round(tick * 1e9))
        self.stats = CycleStats(self.period_ns)
        self.late_threshold_ns = int(self.period_ns * late_fraction)
        self.events: deque[_Event] = deque(maxlen=200)
        #: The located faults standing now (the log scrolls; these stay until cleared).
        self.fault_board = FaultBoard()
        self.supervisor = Supervisor(scheduler, self.slaves, target=target, recover=recover,
                                     check_interval=check_interval, tick_ns=self.period_ns,
                                     now_ns=self.clock.now_ns, log=self.log,
                                     state_timeout=state_timeout)
        self.cycle = Cycle()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cond = threading.Condition()
        # Threads waiting on _cond for cycles (the loop notifies only when there are):
        # a waiter counts itself before it looks at the loop's state, and the loop
        # updates the state before it looks at the count, so no cycle goes unseen.
        self._waiting = 0
        self.error: BaseException | None = None
        self.consumer_missed = 0
        self._every = tuple(g.every for g in self.groups)
        self._all_due = tuple(range(len(self.groups)))
        self.watch = LinkWatch(scheduler.link, self.stats, self.supervisor, self.log,
                               self.period_ns, link_timeout, heard=self._heard)
        #: SCHED_FIFO priority the loop thread asks for when it starts (0: none).
        self.thread_priority = 0
        #: Objects riding along every cycle (``before_cycle(runner)``,
        #: ``after_cycle(runner, tickets, ok)``, and optionally ``in_flight(runner)``:
        #: work done while the cycle's frames are on the wire): the ring watch, the
        #: isolated engine's rider.
        self.riders: list[Any] = []
        #: Distributed clocks: the FRMW (and in reference mode the time write) in every
        #: cycle's first frame, the phase lock moving the deadlines, the sync monitor.
        self.dc = dc
        self._dc = DcRider(dc, scheduler, self.log) if dc is not None else None
        #: The frames of each cycle (prepared frames, the hot path).
        self.xchg = CycleExchange(scheduler, config, self.groups, self.clock, self.stats,
                                  self.watch, dc, self._dc, frame_timeout)
        self.xchg.in_flight = self._riders_in_flight
        #: Where the next run() continues the cycle grid (with DC).
        self._resume_ns: int | None = None
        if dc is not None and dc.cycle_ns != self.period_ns:
            raise ConfigError(f"DC cycle {dc.cycle_ns} ns differs from the loop period "
                              f"{self.period_ns} ns")
        self.leave = leave
        self.final_state = check_final_state(final_state)
        self.safe_cycles = safe_cycles
        self._stopper = OrderlyStop(self.supervisor, self.stats, leave, self.log,
                                    send_safe=self.send_safe_outputs,
                                    wait_cycles=self.wait_cycles, end_loop=self.halt,
                                    safe_cycles=safe_cycles,
                                    cycles_per_round=max(self._every, default=1),
                                    period_s=self.period_ns / 1e9)
        self._stopping = False
        self._abandoned = False
        #: What the last orderly stop did (one line), for summaries.
        self.stop_report = ""

    # -- control ------------------------------------------------------------------------

    @property
    def health(self) -> dict[int, SlaveHealth]:
        """Supervision state per slave position."""
        return self.supervisor.health

    @property
    def supervising(self) -> bool:
        """False while the master is still walking the slaves up (no checks yet)."""
        return self.supervisor.enabled

    @supervising.setter
    def supervising(self, value: bool) -> None:
        # The master turns supervision on right after it saw every slave reach the
        # target state: that counts as the first confirmation.
        if value and not self.supervisor.enabled:
            self.supervisor.confirm_all()
        self.supervisor.enabled = value

    def start(self) -> CyclicRunner:
        """Run the loop in a background thread."""
        if self._thread is not None and self._thread.is_alive():
            raise ConfigError("the cyclic loop is already running")
        self._stop.clear()
        self.xchg.safe = False
        self._abandoned = False
        self._thread = threading.Thread(target=self._thread_main, name="ecat-cyclic", daemon=True)
        self._thread.start()
        return self

    def _thread_main(self) -> None:
        if self.thread_priority:
            why = set_fifo(self.thread_priority)
            if why is not None:
                self.log(f"real time: {why}")
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

    def stop(self, final_state: AlState | str | None = None, *, timeout: float = 2.0) -> None:
        """Stop in order (see the module text) and wait for the loop to end.

        ``final_state`` overrides the runner's (SAFEOP, PREOP, INIT or BOOT);
        ``timeout`` bounds each state step. Failures to reach a state are
        logged as events and in :attr:`stop_report`, never raised: stopping
        always stops. Called from the loop thread (a callback), it only ends
        the loop.
        """
        final = self.final_state if final_state is None else check_final_state(final_state)
        if threading.current_thread() is self._thread:
            self._stop.set()
            return
        if self.running and not self._stopping and not self._abandoned:
            self._stopping = True
            try:
                self.stop_report = self._stopper.run(final, timeout)
            finally:
                self._stopping = False
        self.halt()

    def halt(self) -> None:
        """End the loop now (no safe outputs, no state changes) and wait for it."""
        self._stop.set()
        self.join()

    def abandon(self) -> None:
        """Give the loop up at once, without waiting (safe in a signal handler): a
        :meth:`stop` already running is cut short, a later one only waits."""
        self._abandoned = True
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout)
        self.supervisor.join(timeout)
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
        """Exchanges so far, last working-counter verdict, input age and a read-only image view."""
        g = self._group(name)
        img = g.image
        return GroupStatus(g.name, g.exchanges, g.wkc_ok, memoryview(img.buffer).toreadonly(),
                           img.input_age, img.inputs_valid)

    def slave_input_age(self, position: int) -> int:
        """Exchanges since the inputs of a slave's group were last refreshed."""
        for g in self.groups:
            if position in g.image.positions:
                return g.image.input_age
        raise ConfigError(f"slave {position} is in none of the runner's groups")

    def slave_state(self, position: int) -> int | None:
        """AL status (state, error flag) supervision confirmed lately; None when unknown.

        Unknown while the link is down, when the slave does not answer, and
        when no check confirmed it within ``state_timeout`` seconds: a stale
        state is never shown as current.
        """
        return self.supervisor.state(position, self.stats.link_up)

    def wait_exchanges(self, name: str, count: int, timeout: float) -> bool:
        """Wait until group ``name`` completed ``count`` more exchanges than now.

        False when they did not come within ``timeout`` seconds, when the loop
        thread (:meth:`start`) is not running, or when called from the loop
        thread itself (its callback would wait for itself).
        """
        g = self._group(name)
        if count <= 0:
            return True
        if threading.current_thread() is self._thread:
            return False
        want = g.exchanges + count
        return self._wait(lambda: g.exchanges >= want, timeout)

    def exchanges_after_now(self) -> int:
        """How many exchanges of a group to wait for until one began after this call: one
        between exchanges, two while one is under way (its frames may have passed the
        slaves before the call)."""
        return 2 if self.xchg.under_way else 1

    def wait_cycles(self, count: int, timeout: float) -> bool:
        """Wait until the loop ran ``count`` more cycles (False: not in time, or it ended)."""
        want = self.stats.cycles + count
        return self._wait(lambda: self.stats.cycles >= want, timeout)

    def _wait(self, done: Callable[[], bool], timeout: float) -> bool:
        limit = time.monotonic() + timeout
        # The loop notifies this condition after every cycle.
        with self._cond:
            self._waiting += 1
            try:
                while not done():
                    left = limit - time.monotonic()
                    if left <= 0 or not self.running:
                        return False
                    self._cond.wait(min(left, 0.05))
            finally:
                self._waiting -= 1
        return True

    def send_safe_outputs(self) -> None:
        """From the next cycle on, send the safe outputs (``ProcessImage.safe``) instead of
        the application's (until :meth:`start`); the cycle callback is not called."""
        self.xchg.safe = True

    def __enter__(self) -> CyclicRunner:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def log(self, text: str) -> None:
        self.events.append(_Event(time.time(), text))
        self.fault_board.take(text)

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
            if self._dc is not None and self._dc.shift:
                # The DC phase lock moved the cycle: every later deadline moves with it.
                start += self._dc.shift
                self._dc.shift = 0
            deadline = start + k * period
            if end is not None and deadline >= end:
                break
            if cycles is not None and done >= cycles:
                break
            clock.sleep_until(deadline)
            t0 = clock.now_ns()
            stats.record_start(deadline, t0, self.late_threshold_ns)
            due = self._due(k)
            ok, lost, rtt, names = self._exchange(due, k, deadline, t0)
            if not lost:
                stats.record_round_trip(rtt)
            cyc.index, cyc.deadline_ns, cyc.start_ns = k, deadline, t0
            cyc.round_trip_ns, cyc.wkc_ok, cyc.lost = rtt, ok, lost
            cyc.groups = names
            cyc.link_up = stats.link_up
            t1 = clock.now_ns()
            callback = None if self.xchg.safe else self.callback
            if callback is not None:
                callback(cyc)
            t2 = clock.now_ns()
            nxt = deadline + period
            if t2 > nxt:
                stats.overruns += 1
                # (without a callback the time between the two clock reads was a
                # preemption, not the callback's)
                if callback is not None and t1 <= nxt:
                    stats.callback_overruns += 1
                    if stats.callback_overruns in (1, 10, 100, 1000):
                        self.log(f"callback overran the cycle ({(t2 - t1) / 1000:.0f} us); "
                                 f"{stats.callback_overruns} so far")
                if t2 - nxt > self.late_threshold_ns:
                    # Too late for the next deadline as well: resume at the first one
                    # still ahead instead of bursting to catch up.
                    steps = -(-(t2 - deadline) // period)
                    stats.skipped += int(steps - 1)
                    k += int(steps - 1)
                    stats.restart_period()
                # (else the next cycle starts at once, less late than a late cycle: as a
                # loop on absolute timers does; a frame a few microseconds late serves the
                # slaves better than none, whose watchdogs and SYNC-driven outputs wait)
            k += 1
            done += 1
            if self._waiting:
                with self._cond:
                    self._cond.notify_all()
        shift = 0
        if self._dc is not None:
            shift, self._dc.shift = self._dc.shift, 0
        self._resume_ns = start + shift + k * period
        return stats

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
        (without timing statistics, link tracking and supervision). Not while
        the loop runs.
        """
        t = self._thread
        if t is not None and t.is_alive():  # (``self.running``)
            raise ConfigError("the cyclic loop is running: exchange_once() would race it")
        ok, lost, _back, _rtt, _names = self.xchg.exchange(self._all_due, None)
        return ok and not lost

    def _riders_in_flight(self) -> None:
        for rider in self.riders:
            work = getattr(rider, "in_flight", None)
            if work is not None:
                work(self)

    def _exchange(self, due: tuple[int, ...], k: int, deadline: int, t0: int
                  ) -> tuple[bool, bool, int, tuple[str, ...]]:
        """One cycle's frames, the link's state and the supervision riding in them."""
        sup = self.supervisor
        up = self.stats.link_up
        if up:
            sup.before(k)
        for rider in self.riders:
            rider.before_cycle(self)
        xchg = self.xchg
        probes = xchg.tickets
        ok, lost, back, rtt, names = xchg.exchange(due, deadline)
        self.watch.cycle_done(back, t0, probes)
        if back:
            # (Nothing back is a matter for the link, not an incident of the slaves.)
            sup.after(ok and not lost)
            if self._dc is not None:
                self._dc.monitor(self.clock.now_ns())
        if len(xchg.last_tickets) == len(xchg.tickets):  # (none refused by the link)
            for rider in self.riders:
                rider.after_cycle(self, xchg.last_tickets, ok and not lost)
        self.scheduler.step()
        return ok and not lost, lost, rtt, names

    @property
    def last_tickets(self) -> list[CyclicFrame]:
        """The cyclic frames of the last cycle (their replies, copies, IRQ fields)."""
        return self.xchg.last_tickets

    @property
    def last_plans(self) -> list[FramePlan]:
        """Their prepared-frame plans (``takes``: what each datagram carries)."""
        return self.xchg.last_plans

    @property
    def absent(self) -> frozenset[int]:
        """Slaves known to be gone (:meth:`set_absent`)."""
        return self.xchg.absent

    def set_absent(self, positions: Iterable[int]) -> None:
        """Slaves known to be gone (a failed node, a cut branch, one being brought back):
        their share of each working counter is not expected until they are back."""
        self.xchg.set_absent(positions)

    @property
    def takes_new_groups(self) -> bool:
        """Whether :meth:`add_group` can work: the loop runs in this process (the isolated
        engine's plan is fixed when it starts)."""
        return type(self).run is CyclicRunner.run

    def add_group(self, name: str, slaves: Sequence[object] = ()) -> None:
        """Exchange the process-data group ``name``, added to the configuration while the
        loop runs (``ProcessData.add_group``: a hot connect group that appeared), from the
        next cycle on; its ``slaves`` are supervised from then on.

        Call between cycles: from a worker in step with the loop (``master.stepping``),
        or while the loop does not run."""
        if not self.takes_new_groups:
            raise ConfigError("the loop runs in an engine of its own: it takes no new group")
        if any(g.name == name for g in self.groups):
            raise ConfigError(f"the loop exchanges group {name!r} already")
        g = self.config.group(name)
        tick = self.period_ns / 1e9
        every = max(1, int(round((g.cycle or tick) / tick)))
        # (the exchange holds this same list: the new set of due groups gets its own plan)
        self.groups.append(GroupRuntime(g, self.images[name], every))
        self._every = tuple(r.every for r in self.groups)
        self._all_due = tuple(range(len(self.groups)))
        self.slaves.extend(slaves)
        self.supervisor.add(slaves)

    def request_recovery(self, positions: list[int]) -> None:
        """Bring these slaves back now (found present without their address: power-cycled,
        hot-swapped), in step with the loop; ignored while a recovery runs."""
        self.supervisor.request_recovery(positions)

    @property
    def recovering(self) -> frozenset[int]:
        """Slaves a recovery is bringing back now."""
        if self.supervisor.recover_thread is None:
            # (no recovery ever started: nothing can be "recovering"; no per-slave walk
            # on the cycle's path, where the ring watch asks every cycle)
            return _NONE
        return frozenset(p for p, h in self.health.items() if h.status == "recovering")

    # -- the link ---------------------------------------------------------------------------

    def _heard(self) -> int:
        st = self.scheduler.stats
        return st.frames_received + st.stale + st.duplicates + st.malformed

    def down_for(self) -> float:
        """Seconds the link has been down (0.0 while it is up)."""
        return self.stats.down_for_ns(self.clock.now_ns()) / 1e9

    # -- consuming cycles ---------------------------------------------------------------------

    def cycles(self, timeout: float = 1.0) -> Iterator[Cycle]:
        """Yield a snapshot of each cycle as it completes (the loop runs in its thread).

        A slow consumer does not slow the loop: cycles it could not see are
        counted in ``consumer_missed``. Ends when the loop stops.
        """
        return _snapshots(self, timeout)

    def status_lines(self) -> list[str]:
        """Short text for live views and logs."""
        return _status_lines(self)

    @property
    def dc_events(self) -> deque[SyncEvent]:
        """The DC sync monitor's events (empty without DC)."""
        return self._dc.events if self._dc is not None else deque()

    def dc_status_line(self) -> str | None:
        """The distributed clocks' state in one line (None without DC)."""
        return None if self.dc is None else _dc_line(self.dc)


def _status_lines(runner: CyclicRunner) -> list[str]:
    lines = []
    if not runner.stats.link_up:
        lines.append(f"link DOWN for {runner.down_for():.1f} s ({runner.stats.down_cycles} "
                     "cycles lost so far)")
    for g in runner.groups:
        age = g.image.input_age
        lines.append(f"group {g.name}: WKC {g.total_wkc}/{g.expected_wkc} "
                     f"{'ok' if g.wkc_ok else 'BAD'}; errors {g.wkc_errors}, lost {g.lost}"
                     + (f"; inputs {age} cycles old" if age else ""))
    dc = runner.dc_status_line()
    if dc is not None:
        lines.append(dc)
    return lines


def _snapshots(runner: CyclicRunner, timeout: float) -> Iterator[Cycle]:
    last = -1
    cond = runner._cond
    while True:
        with cond:
            runner._waiting += 1  # noqa: SLF001 - (see CyclicRunner.__init__)
            try:
                while runner.cycle.index == last or runner.stats.cycles == 0:
                    if not runner.running:
                        return
                    if not cond.wait(timeout) and not runner.running:
                        return
            finally:
                runner._waiting -= 1  # noqa: SLF001
            c = runner.cycle
            snap = Cycle(c.index, c.deadline_ns, c.start_ns, c.round_trip_ns, c.wkc_ok,
                         c.lost, c.groups, c.link_up)
        if last >= 0 and snap.index > last + 1:
            runner.consumer_missed += snap.index - last - 1
        last = snap.index
        yield snap


def _dc_line(dc: DcCycle) -> str:
    mon = dc.monitor
    text = f"DC {dc.mode.value}: "
    if dc.lock is not None:
        text += f"phase error {dc.lock.error_ns} ns{' (locked)' if dc.lock.locked else ''}, "
    elif dc.master_difference_ns is not None:
        text += f"reference - master {dc.master_difference_ns} ns, "
    last = "-" if mon.last_ns is None else f"{mon.last_ns}"
    return text + (f"|0x092C| <= {last} ns (worst {mon.worst_ns}), "
                   f"{'SYNC UNSTABLE' if mon.unstable else 'in sync'}")


def check_final_state(state: AlState | str) -> AlState:
    """``state`` as the final state of an orderly stop (ConfigError for OP or an unknown name)."""
    try:
        final = AlState.parse(state) if isinstance(state, str) else AlState(int(state))
    except ValueError as exc:
        raise ConfigError(f"final state: {exc}") from None
    if final == AlState.OP:
        raise ConfigError("the final state of a stop must be below OP (SAFEOP, PREOP, INIT "
                          "or BOOT)")
    return final
