"""The isolated cyclic engine's process: ``python -m pyethercat.master.engine.child``.

Started by :class:`~pyethercat.master.engine.runner.IsolatedRunner` with the
pickled :class:`~pyethercat.master.engine.plan.EnginePlan` on its standard
input. It asks for its real-time settings (and publishes what it got), then
runs the same :class:`~pyethercat.master.cyclic.CyclicRunner` as the
in-process mode, in its main thread, on the master's link, over images of
its own. :class:`EngineRider` rides along every cycle: it takes the outputs
the user's process wrote in shared memory, publishes the inputs, the
statistics, the events and the slaves' health there, carries the user's
acyclic requests (:mod:`~pyethercat.master.engine.router`) and answers the
control channel. Between cycles the engine waits on the control channel and
the user's requests (:class:`EngineClock`), then busy-waits the last slice
before the deadline.

It has no other thread but the recovery worker, and nothing of the user's
runs in it: the user's threads, their CPU burning and their C calls holding
the GIL are in another process and do not move its deadlines.

When the user's process goes (its end of the control channel closes, its
pid is gone, the kernel's parent-death signal, or SIGTERM), the engine sends the safe outputs for a few
cycles, requests SAFEOP of every slave (one BWR of AL control, riding in the
cyclic frames, IgH's and SOEM's way of addressing all slaves), waits until
no slave reports OP (2 s at most) and exits. SIGINT is ignored: a Ctrl-C in
a terminal reaches the whole process group, and the user's process decides
how to stop. The parent is watched in every cycle, also while the link
refuses frames (an interface gone or down): with nothing reachable, the
engine gives up the leave after its limit and exits all the same.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import struct
import sys
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.clock import PerfClock
from pyethercat.errors import EtherCATError
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.engine.channel import recv_message, send_message
from pyethercat.master.engine.plan import EnginePlan, loads
from pyethercat.master.engine.router import Router
from pyethercat.master.engine.shared import HEALTH_STATUS, SharedArea
from pyethercat.master.engine.status import (
    NONE,
    EngineState,
    group_values,
    stats_values,
)
from pyethercat.master.image import ProcessImage
from pyethercat.master.scheduler import Request, Scheduler
from pyethercat.realtime import (
    RealtimeReport,
    SpinBudget,
    apply_realtime,
    die_with_parent,
    idle_halt_hint,
    quiet_collector,
    set_timer_slack,
)
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram

__all__ = ["PARENT_DEATH_SIGNAL", "EngineClock", "EngineRider", "main", "run_engine"]

# How often the engine looks whether its parent is still there (one getppid).
_PARENT_CHECK_NS = 100_000_000
# The status block (counters) is published at least this often (every cycle up to 1 kHz).
_PUBLISH_NS = 950_000
# The health table is published after events and at least this often.
_HEALTH_NS = 500_000_000
# How long the engine waits for the slaves to leave OP when the user has gone.
_LEAVE_NS = 2_000_000_000
# The whole leave (safe outputs, SAFEOP) ends by this much past its own limits even when
# no frame comes back (the link is down or gone): the engine exits regardless.
_GIVE_UP_NS = 1_000_000_000
# Sent by the kernel when the parent dies (prctl PR_SET_PDEATHSIG); SIGTERM stays the
# user's own "stop" and is not confused with it.
PARENT_DEATH_SIGNAL = signal.SIGUSR1
_STATUS = {name: i for i, name in enumerate(HEALTH_STATUS)}


class _Slave:
    """What the runner needs of a slave: its position and station address."""

    __slots__ = ("position", "station_address")

    def __init__(self, position: int, station_address: int) -> None:
        self.position = position
        self.station_address = station_address


class EngineClock(PerfClock):
    """The loop's clock: between cycles it serves the control channel and the user's
    requests (``serve(time_left_ns)``, when one of ``fds`` is readable) and hands the
    user the replies of frames sent for it as they come (``replies()``: the link's
    descriptor while there are any, ``take_replies()``), then spins."""

    def __init__(self, fds: list[int], serve: Callable[[int], None], spin_ns: int,
                 budget: SpinBudget | None = None,
                 replies: Callable[[], int | None] | None = None,
                 take_replies: Callable[[], None] | None = None) -> None:
        super().__init__(spin_ns=spin_ns)
        self.fds = fds
        self.serve = serve
        self.replies = replies
        self.take_replies = take_replies
        #: The share of each second the spin (and the scheduler's reply poll) may take.
        self.budget = budget

    def sleep_until(self, deadline_ns: int) -> None:
        now = time.perf_counter_ns
        spin = self.spin_ns
        budget = self.budget
        if budget is not None and not budget.allowed(time.monotonic()):
            spin = 0  # (this second's share of spinning is spent: sleep to the deadline)
        fds = self.fds
        replies = self.replies
        while True:
            left = deadline_ns - now()
            if left <= spin:
                break
            link = None if replies is None else replies()
            try:
                ready, _, _ = select.select(fds if link is None else [*fds, link], [], [],
                                            (left - spin) / 1e9)
            except InterruptedError:
                continue
            if not ready:
                continue
            if link is not None and link in ready:
                assert self.take_replies is not None
                self.take_replies()
                if len(ready) == 1:
                    continue
            self.serve(deadline_ns - now())
        began = now()
        while now() < deadline_ns:
            pass
        if budget is not None:
            budget.spent((now() - began) * 1e-9)


class EngineRider:
    """Everything the engine adds to a cycle (see the module text)."""

    def __init__(self, plan: EnginePlan, runner: CyclicRunner, area: SharedArea, router: Router,
                 control: socket.socket, report: RealtimeReport) -> None:
        self.plan = plan
        self.runner = runner
        self.area = area
        self.router = router
        self.control = control
        self.report = report
        self.groups = [(g, runner.images[g.name], area.images[g.name], area.seqs[g.name],
                        bytearray(g.image.group.output_bytes)) for g in runner.groups]
        self.fields = area.status.fields
        self._hist_at = len(plan.stats_fields) - len(runner.stats.histogram)
        self._in_seq = {g.name: 0 for g, *_ in self.groups}
        self.state = EngineState.STARTING
        self.user_gone = ""
        self._leave_started = 0
        self._give_up_at = 0
        self._leave_brd: Request | None = None
        #: The descriptors the clock waits on (its list): closed ones leave it, or a
        #: select on an end of file would return at once and the wait would spin.
        self.fds: list[int] = []
        self._control_open = True
        self._after = True
        self._safe_left = 0
        self._last_event: object = None
        self._events = 0
        self._health_at = 0
        self._published_at = 0
        self._parent_at = 0
        self._cpu0 = time.process_time_ns()
        self._wall0 = time.perf_counter_ns()
        self._answers: dict[int, str | None] = {}
        self._next_request = 0
        #: A publish the last cycle owes: done while the next cycle's frames are out.
        self._publish_due = False
        self._link_fd = runner.scheduler.link.fileno()

    # -- the cycle ----------------------------------------------------------------------------

    def before_cycle(self, runner: CyclicRunner) -> None:
        """Take the outputs the user wrote (or the safe ones) into the loop's images."""
        # (here, not after the cycle: a cycle whose frames the link refused has no after,
        # and the user must still see the link's state and events)
        now = time.perf_counter_ns()
        self.watch_parent(now)
        done = runner.stats.cycles - 1  # (this cycle is counted from its start)
        if done > self.area.read_tick():
            # The last cycle had no after (the link refused its frames): it is done all the same.
            self.area.write_tick(done)
        self.area.write_begun(done + 1)
        if not self._after and now - self._published_at >= _PUBLISH_NS:
            self._published_at = now
            self.publish()
            if runner.events and runner.events[-1] is not self._last_event:
                self._post_events()
        self._after = False
        if runner.xchg.safe:
            # (the frames carry the images' safe outputs, the shared ones)
            if self.router.open:
                self.router.take(flush=False)
            return
        for _g, image, shared, seq, staging in self.groups:
            n = len(staging)
            if not n:
                continue
            before = seq.output_seq()
            if before & 1:
                continue  # being written: the last whole outputs go again
            staging[:] = shared[:n]
            if seq.output_seq() == before:
                image.buffer[:n] = staging
        if self.router.open:
            self.router.take(flush=False)

    def after_cycle(self, runner: CyclicRunner, tickets: object, ok: bool) -> None:
        """Publish inputs, statistics, events, health; answer the user's requests."""
        self._after = True
        for g, image, shared, seq, staging in self.groups:
            lo = len(staging)
            s = self._in_seq[g.name] + 1
            seq.set_input_seq(s)
            shared[lo:] = memoryview(image.buffer)[lo:]
            seq.set_exchange(g.exchanges, g.wkc_ok)
            self._in_seq[g.name] = s + 1
            seq.set_input_seq(s + 1)
        # The tick first, then the replies: the user's side, woken by a reply, finds the
        # cycle that carried it done (and runs its callback at once, not a period later).
        self.area.write_tick(runner.stats.cycles)
        self.router.answer()
        now = time.perf_counter_ns()
        if not ok or now - self._published_at >= _PUBLISH_NS:
            # (every cycle up to 1 kHz; faster loops publish every millisecond and after
            # a cycle that did not come back whole, so the inputs' age is never old)
            self._published_at = now
            self._publish_due = True
        events = runner.events
        if events and events[-1] is not self._last_event:
            self._post_events()
        if self.user_gone:
            self._leave_step(now)

    def in_flight(self, runner: CyclicRunner) -> None:
        """The statistics and health the last cycle owes, published while this cycle's
        frames are on the wire (25 us and more of Python that would otherwise lengthen
        the cycle: at 10 kHz every tenth one ran past the next deadline)."""
        if self.router.carrying:
            sched = runner.scheduler
            if sched.queued:
                # The user's datagrams the cyclic frames had no room for go right behind
                # them, in a frame of their own (as the in-process EoE service sends its
                # own), not a cycle later. (A link that refuses fails those requests, which
                # the user's scheduler sends again; the cycles deal with the link itself.)
                with contextlib.suppress(EtherCATError):
                    sched.flush()
        if self._publish_due:
            self._publish_due = False
            self.publish()
        now = time.perf_counter_ns()
        if now - self._health_at >= _HEALTH_NS:
            self.publish_health(now)

    def watch_parent(self, now: int) -> None:
        """Whether the user's process is still this process's parent; the leave's last limit."""
        if now - self._parent_at >= _PARENT_CHECK_NS:
            self._parent_at = now
            self.check_parent()
        if self.user_gone and now > self._give_up_at:
            self.runner.log("no slave could be reached to leave OP; the engine ends anyway")
            self.runner.abandon()

    def look_at_parent(self) -> None:
        """Check the parent at the next cycle's start (the parent-death signal's handler)."""
        self._parent_at = -_PARENT_CHECK_NS

    def check_parent(self) -> None:
        """The user's process is gone when this process has another parent (re-parented)."""
        if os.getppid() != self.plan.parent_pid and not self.user_gone:
            self.user_left("the user's process has gone (parent changed)")

    # -- publishing ----------------------------------------------------------------------------

    def publish(self) -> None:
        runner = self.runner
        values = stats_values(runner.stats, self.plan.stats_fields, self._hist_at)
        for g, image, *_ in self.groups:
            values += group_values(g, image)
        dc = runner.dc
        mon = dc.monitor if dc is not None else None
        lock = dc.lock if dc is not None else None
        values += [self.state, os.getpid(), time.perf_counter_ns(),
                   time.process_time_ns() - self._cpu0, time.perf_counter_ns() - self._wall0,
                   self.report.priority, -1 if self.report.cpu is None else self.report.cpu,
                   int(self.report.locked), int(runner.supervising), int(runner.xchg.safe),
                   self._events, self.router.frames, self.router.datagrams, self.router.dropped,
                   NONE if lock is None else lock.error_ns, int(lock is not None and lock.locked),
                   NONE if mon is None or mon.last_ns is None else mon.last_ns,
                   0 if mon is None else mon.worst_ns, int(mon is not None and mon.unstable),
                   NONE if dc is None or dc.master_difference_ns is None
                   else dc.master_difference_ns]
        self.area.status.write(values)

    def _post_events(self) -> None:
        events = list(self.runner.events)
        if not events:
            return
        new = []
        for e in reversed(events):
            if e is self._last_event:
                break
            new.append(e)
        for e in reversed(new):
            self.area.post_event(e.t, e.text)
            self._events += 1
        self._last_event = events[-1]
        # A health change is logged: show it at once.
        self._health_at = 0
        self._published_at = 0

    def publish_health(self, now: int) -> None:
        self._health_at = now
        runner = self.runner
        health = runner.health

        def fill(table: npt.NDArray[np.void]) -> None:
            rows = [(h.position, h.station_address, h.state, int(h.error), h.code,
                     int(h.present), _STATUS.get(h.status, 0), h.recoveries,
                     runner.slave_state(h.position) or 0)
                    for h in health.values()]
            table[:len(rows)] = np.array(rows, dtype=table.dtype)

        self.area.write_health(fill)

    # -- between cycles ---------------------------------------------------------------------

    def serve(self, left_ns: int) -> None:
        """A descriptor is readable between cycles: control messages, the user's frames."""
        self.read_control()
        if not self.router.open:
            self._forget(self.router.sock.fileno())
        if self.router.open:
            # Time for a frame of their own before the deadline: send them now (their
            # replies wake the clock's wait and go back at once).
            self.router.take(flush=self._time_for_a_frame(left_ns))

    def reply_fd(self) -> int | None:
        """The link's descriptor while frames sent for the user are on their way."""
        if not self.router.carrying:
            return None
        sched = self.runner.scheduler
        return self._link_fd if sched.in_flight else None

    def take_replies(self) -> None:
        """The link is readable between cycles: a reply the user waits for, handed over now."""
        with contextlib.suppress(EtherCATError):  # (the next cycle meets the link's trouble)
            self.runner.scheduler.receive_ready()
        self.router.answer()

    def _time_for_a_frame(self, left_ns: int) -> bool:
        # (sent this long before the deadline, a frame is back before the cyclic one is
        # due: round trips through a simulator on a loaded VM are 100-250 us)
        return left_ns > max(self.runner.period_ns // 4, 300_000)

    def _forget(self, fd: int) -> None:
        if fd in self.fds:
            self.fds.remove(fd)

    def read_control(self) -> None:
        while self._control_open:
            try:
                msg = recv_message(self.control)
            except BlockingIOError:
                return
            except (EOFError, OSError):
                self._control_open = False
                self._forget(self.control.fileno())
                if not self.user_gone:
                    self.user_left("the user's process has gone (control channel closed)")
                return
            self.handle(msg)

    def handle(self, msg: dict[str, Any]) -> None:
        op = msg.get("op")
        runner = self.runner
        if op == "supervise":
            runner.supervising = bool(msg["on"])
        elif op == "safe":
            # The user's orderly stop: its requests to SAFEOP follow, riding in our frames.
            runner.supervising = False
            runner.send_safe_outputs()
        elif op == "halt":
            self.state = EngineState.STOPPING
            runner.abandon()  # (the loop runs in this thread: it ends after this cycle)
        elif op == "answer":
            self._answers[int(msg["id"])] = msg.get("error")
        elif op == "recover":
            runner.request_recovery([int(p) for p in msg["positions"]])
        elif op == "health":
            self.publish_health(time.perf_counter_ns())

    def recover(self, positions: list[int]) -> None:
        """The runner's recovery (a stepped worker): the user's master does the work.

        Bringing a slave back is configuration (addresses, SII, mailbox and CoE
        start-up, sync managers, DC) that the user's master holds; its
        requests ride in this engine's frames. The worker waits in step with
        the loop until the user's process answers.
        """
        if self.user_gone:
            raise EcTimeoutError("no recovery: the user's process has gone")
        ident = self._next_request = self._next_request + 1
        try:
            send_message(self.control, {"op": "recover", "id": ident, "positions": positions})
        except OSError:
            raise EcTimeoutError("no recovery: the user's process does not listen") from None
        sched = self.runner.scheduler
        if not sched.stepper.wait(lambda: ident in self._answers, sched.now() + 60.0):
            raise EcTimeoutError("the user's process did not bring the slaves back within 60 s")
        error = self._answers.pop(ident)
        if error:
            raise EtherCATError(error)

    # -- the user has gone: safe outputs, SAFEOP, exit ---------------------------------------

    def user_left(self, why: str) -> None:
        self.user_gone = why
        self.runner.log(f"{why}: safe outputs, then SAFEOP")
        self.state = EngineState.STOPPING
        self.runner.supervising = False
        self.runner.send_safe_outputs()
        every = max((g.every for g in self.runner.groups), default=1)
        self._safe_left = max(1, self.plan.safe_cycles) * every + 1
        self._leave_started = 0
        self._give_up_at = (time.perf_counter_ns() + self._safe_left * self.runner.period_ns
                            + _LEAVE_NS + _GIVE_UP_NS)

    def _leave_step(self, now: int) -> None:
        runner = self.runner
        if self._safe_left > 0:
            self._safe_left -= 1
            return
        sched = runner.scheduler
        if not self._leave_started:
            self._leave_started = now
            sched.submit([Datagram.device(Command.BWR, 0, reg.AL_CONTROL,
                                          struct.pack("<H", int(AlState.SAFEOP)))], flush=False)
            return
        brd = self._leave_brd
        if brd is not None and brd.done():
            self._leave_brd = None
            rep = brd.reply
            if rep is not None and rep.wkc and not rep.data[0] & int(AlState.OP):
                total = len(self.plan.slaves)
                if rep.wkc >= total:
                    runner.log(f"slaves in SAFEOP ({rep.wkc} answered)")
                else:
                    # (a BRD counts the slaves it reached; the others are cut off, and
                    # only their own watchdog takes them down: see docs/realtime.md)
                    runner.log(f"{rep.wkc} of {total} slaves in SAFEOP; {total - rep.wkc} "
                               "did not answer and stay as they were")
                runner.abandon()
                return
        if now - self._leave_started > _LEAVE_NS:
            runner.log("not every slave left OP within 2 s; the engine ends anyway")
            runner.abandon()
            return
        if self._leave_brd is None:
            self._leave_brd = sched.submit(
                [Datagram.device(Command.BRD, 0, reg.AL_STATUS, 2)], flush=False)[0]


def run_engine(plan: EnginePlan, area: SharedArea, report: RealtimeReport) -> int:
    """Build the loop and run it until halted or the user has gone; the exit status."""
    control = socket.socket(fileno=plan.control_fd)
    frames = socket.socket(fileno=plan.frames_fd)
    control.setblocking(False)
    sched = Scheduler(plan.link, timeout=plan.timeout, retries=plan.retries,
                      max_in_flight=plan.max_in_flight, src=plan.src)
    images = {g.name: ProcessImage(g, safe=area.safe[g.name]) for g in plan.config.groups}
    slaves = [_Slave(p, a) for p, a in plan.slaves]
    router = Router(frames, sched)
    holder: list[EngineRider] = []

    def serve(left: int) -> None:
        holder[0].serve(left)

    # Spinning before each deadline and polling for each reply must leave the kernel's
    # real-time share some room: at 10 kHz they fill every cycle, and a throttled
    # SCHED_FIFO task stops for the rest of the second (gaps of 50 ms were measured).
    budget = SpinBudget.below_rt_throttle()
    clock = EngineClock([control.fileno(), frames.fileno()], serve, plan.spin_ns, budget)
    sched.spin_budget = budget

    def recover(positions: list[int]) -> None:
        holder[0].recover(positions)

    runner = CyclicRunner(sched, plan.config, images, slaves, cycle=plan.cycle, clock=clock,
                          check_interval=plan.check_interval, target=plan.target,
                          recover=recover if plan.recover else None, groups=plan.groups,
                          late_fraction=plan.late_fraction, frame_timeout=plan.frame_timeout,
                          link_timeout=plan.link_timeout, state_timeout=plan.state_timeout,
                          safe_cycles=plan.safe_cycles, dc=plan.dc)
    # The samples go straight into the shared rings, where any reader finds them.
    runner.stats.keep_samples_in(area.rings["periods"], area.rings["latency"], area.rings["rtt"])
    runner.supervising = plan.supervising
    rider = EngineRider(plan, runner, area, router, control, report)
    rider.fds = clock.fds
    holder.append(rider)
    # (the rider's own methods, no closure in between: the clock calls them every cycle)
    clock.replies, clock.take_replies = rider.reply_fd, rider.take_replies
    runner.riders.append(rider)
    for why in report.missing:
        runner.log(f"real time: {why}")

    def on_term(signum: int, frame: object) -> None:
        if not rider.user_gone:
            rider.user_left("SIGTERM")

    def on_parent_death(signum: int, frame: object) -> None:
        # Look at the next cycle's start, not in the middle of this one. (The signal also
        # comes when only the thread that started the engine ends: the look tells.)
        rider.look_at_parent()

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(PARENT_DEATH_SIGNAL, on_parent_death)
    refused = die_with_parent(PARENT_DEATH_SIGNAL)
    if refused is not None:
        runner.log(f"parent watch: {refused}")
    # (the parent may have died before the request: the loop's first cycle looks)
    # Everything built so far lives as long as the engine: the collector need not walk
    # it again, and no full collection starts on its own (one over the interpreter's and
    # numpy's objects stalls a cycle for milliseconds; see quiet_collector).
    quiet_collector()
    rider.state = EngineState.RUNNING
    rider.publish()
    rider.publish_health(time.perf_counter_ns())
    send_message(control, {"op": "ready", "pid": os.getpid(), "realtime": report.text(),
                           "missing": report.missing})
    status = 0
    try:
        runner.run()
    except BaseException as exc:  # noqa: BLE001 - reported to the user, then the exit status
        status = 1
        runner.log(f"engine failed: {exc!r}")
        traceback.print_exc(file=sys.stderr)
    rider.state = EngineState.FAILED if status else EngineState.STOPPED
    if rider.user_gone:
        rider.state = EngineState.STOPPED
    rider._post_events()  # noqa: SLF001
    rider.publish_health(time.perf_counter_ns())
    rider.publish()
    sched.stepper.release()
    with contextlib.suppress(OSError):
        send_message(control, {"op": "stopped", "status": status})
    return status


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    data = sys.stdin.buffer.read()
    plan = loads(data)
    report = apply_realtime(plan.priority, plan.cpu, plan.lock_memory)
    # (the engine sleeps in select to just before each deadline: without SCHED_FIFO the
    # default 50 us slack would eat half of the spin before a 10 kHz deadline)
    slack = set_timer_slack(1)
    if slack is not None:
        report.missing.append(slack)
    host = idle_halt_hint(plan.cycle)
    if host is not None:
        report.missing.append(host)
    area = SharedArea.attach(plan.area_path, plan.layout)
    try:
        return run_engine(plan, area, report)
    finally:
        plan.link.close()
        if not os.path.exists(f"/proc/{plan.parent_pid}"):
            area.unlink()


if __name__ == "__main__":
    sys.exit(main())
