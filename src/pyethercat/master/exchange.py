"""One cycle's exchange: fill the prepared frames, send, wait, check, copy inputs back.

:class:`CycleExchange` holds the prepared frames of each set of due groups
(:func:`~pyethercat.master.cycleplan.plan_frames`, built on first use, again
when the slaves known to be gone change) and does the hot path of the loop
(see :mod:`pyethercat.master.cyclic`): no per-slave work, one working-counter
check per datagram, input bytes copied only for groups whose exchange came
back whole. A frame the link refuses, or whose reply does not come in time,
is lost; the loop's :class:`~pyethercat.master.linkwatch.LinkWatch` hears
of refusals and receive failures.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable

from pyethercat.clock import Clock
from pyethercat.errors import LinkError
from pyethercat.master.config import CyclicDatagram, ProcessDataConfig, bus_shares, wkc_share
from pyethercat.master.cycleplan import FramePlan, GroupRuntime, Planned, plan_frames
from pyethercat.master.cyclestats import CycleStats
from pyethercat.master.dc_loop import DcCycle, SyncEvent
from pyethercat.master.linkwatch import LinkWatch
from pyethercat.master.redundancy import ring_gap, split_counts
from pyethercat.master.scheduler import CyclicFrame, Request, Scheduler

__all__ = ["CycleExchange", "DcRider"]

#: Frame indices the loop's frames may hold at once (of 256; the rest for others).
_INDEX_BUDGET = 128


class CycleExchange:
    """The frames of the loop's cycles (see the module text)."""

    def __init__(self, scheduler: Scheduler, config: ProcessDataConfig,
                 groups: list[GroupRuntime], clock: Clock, stats: CycleStats, watch: LinkWatch,
                 dc: DcCycle | None, rider: DcRider | None,
                 frame_timeout: float | None) -> None:
        self.scheduler = scheduler
        self.config = config
        self.groups = groups
        self.clock = clock
        self.stats = stats
        self.watch = watch
        self.dc = dc
        self.rider = rider
        self.frame_timeout = frame_timeout
        #: Prepared frames per set of due groups (built on first use); the safe
        #: plans send ``ProcessImage.safe`` instead of the outputs.
        self._plans: dict[tuple[int, ...], Planned] = {}
        self._safe_plans: dict[tuple[int, ...], Planned] = {}
        #: Send the safe outputs (an orderly stop).
        self.safe = False
        #: The tickets of the last cycle's frames (None: the link refused the frame).
        self.tickets: list[CyclicFrame | None] = []
        #: The frames the last cycle sent and their plans, for the loop's riders.
        self.last_tickets: list[CyclicFrame] = []
        self.last_plans: list[FramePlan] = []
        #: Slaves known to be gone: not expected in working counters.
        self.absent: frozenset[int] = frozenset()
        #: Per (group, datagram): each slave's share of the count, in bus order.
        self._shares: dict[tuple[int, int], list[int]] = {}
        #: Work done while the cycle's frames are on the wire (after the last send,
        #: before the wait for the replies): time the loop would otherwise spin away.
        self.in_flight: Callable[[], None] | None = None
        #: An exchange is under way (its frames may have passed the slaves already).
        self.under_way = False

    def exchange(self, due: tuple[int, ...], deadline: int | None
                 ) -> tuple[bool, bool, int, int, tuple[str, ...]]:
        """Send, wait, check WKC, copy back: prepared frames, no per-slave work.

        Returns (all whole, any lost, frames back, round trip, group names).
        ``under_way`` is set meanwhile (a mailbox waiting for its status byte
        asks: an exchange not yet begun brings a byte newer than its last read).
        """
        self.under_way = True
        try:
            return self._exchange(due, deadline)
        finally:
            self.under_way = False

    def _exchange(self, due: tuple[int, ...], deadline: int | None
                  ) -> tuple[bool, bool, int, int, tuple[str, ...]]:
        cache = self._safe_plans if self.safe else self._plans
        planned = cache.get(due)
        if planned is None:
            planned = cache[due] = plan_frames(
                self.scheduler, [self.groups[i] for i in due], self.safe,
                self.dc.datagrams() if self.dc is not None else [], self._absent_share)
        plans, names, groups = planned
        sched = self.scheduler
        now_ns = self.clock.now_ns
        t0 = now_ns()
        timeout = self.frame_timeout
        life = timeout
        if timeout is None and deadline is not None:
            timeout = self.watch.reply_timeout(deadline, t0)
            life = self._lifetime(timeout, len(plans))
        tickets: list[CyclicFrame | None] = []
        self.tickets = tickets
        sent: list[CyclicFrame] = []
        stats = self.stats
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
            try:
                sending = sched.send_prepared(p.template, timeout=life)
            except LinkError as exc:
                # The interface is down or gone: the frame is lost, the loop goes on.
                stats.send_errors += 1
                self.watch.send_error = exc
                tickets.append(None)
            else:
                tickets.append(sending)
                sent.append(sending)
        self.last_tickets = sent
        self.last_plans = plans
        if self.in_flight is not None:
            self.in_flight()
        until = None if timeout is None else sched.now() + timeout
        lost = False
        back = 0
        bad: set[GroupRuntime] | None = None
        short: set[GroupRuntime] | None = None
        missing: set[GroupRuntime] | None = None
        came: list[tuple[FramePlan, bytes]] = []
        for p, ticket in zip(plans, tickets, strict=True):
            stats.frames += 1
            raw = None
            if ticket is not None:
                raw = ticket.raw
                if raw is None and not ticket.lost:
                    # (``ticket.wait_raw``: its waiter is ``sched``, which sent it)
                    try:
                        sched.wait_ticket(ticket, None if until is None
                                          else max(0.0, until - sched.now()))
                        raw = ticket.raw
                    except LinkError as exc:
                        self.watch.recv_error = exc
            if p.dc_read >= 0:
                assert dc is not None and self.rider is not None
                at = p.dc_read
                self.rider.shift += dc.on_reply(
                    None if raw is None else bytes(raw[at:at + dc.size]), t0)
            if raw is None:
                lost = True
                stats.lost_frames += 1
                for g in p.groups:
                    g.lost += 1
                    g.wkc_ok = g.present_ok = False
                for g, n, _w, _e, _s in p.checks:
                    g.last_wkc[n] = 0  # nothing came back: no stale count shown as current
                missing = set(p.groups) if missing is None else missing | set(p.groups)
                continue
            back += 1
            for g, n, w, expected, share in p.checks:
                wkc = raw[w] | (raw[w + 1] << 8)
                g.last_wkc[n] = wkc
                if wkc != expected:
                    bad = {g} if bad is None else bad | {g}
                    if (wkc < expected - share or wkc > expected) and not (
                            ticket is not None and ticket.copies is not None
                            and self._split_explains(g, n, w, wkc, ticket.copies)):
                        short = {g} if short is None else short | {g}
            came.append((p, raw))
        if bad is None and missing is None:
            for p, raw in came:
                for _g, buf, lo, hi, at in p.copies:
                    buf[lo:hi] = raw[at:at + hi - lo]
            for g in groups:
                g.exchanges += 1
                g.wkc_ok = g.present_ok = True
                img = g.image
                img.input_age = 0
                img.inputs_valid = True
            return True, False, back, now_ns() - t0, names
        # Inputs only from the groups whose exchange came back whole; the others keep
        # their last good inputs, which age. A count short only by the share of slaves
        # known to be gone (set_absent) is whole for the slaves that are there.
        spoilt = (short or set()) | (missing or set())
        for p, raw in came:
            for g, buf, lo, hi, at in p.copies:
                if g not in spoilt:
                    buf[lo:hi] = raw[at:at + hi - lo]
        ok = True
        incomplete = missing is not None
        for g in groups:
            img = g.image
            if g in spoilt:
                img.input_age += 1
            else:
                img.input_age = 0
                img.inputs_valid = True
            if missing is not None and g in missing:
                continue
            good = bad is None or g not in bad
            whole = short is None or g not in short
            g.exchanges += 1
            g.wkc_ok, g.present_ok = good, whole
            if not good:
                g.wkc_errors += 1
                stats.wkc_errors += 1
            if not whole:
                g.incomplete += 1
                incomplete = True
            ok = ok and good
        if incomplete:
            stats.incomplete += 1
        return ok and not lost, lost, back, now_ns() - t0, names

    def _lifetime(self, wait: float, frames: int) -> float:
        """How long a cycle's frame stays in flight: the cycle waits ``wait`` for it, but
        a later reply still completes the requests that rode in it (a mailbox read
        the slave has answered cannot be sent again: its reply would be lost).

        Up to the scheduler's timeout, within a share of the frame indices (the
        frames of every cycle until then are in flight at once while nothing comes
        back). In virtual time a reply is there at once or never; on a ring the
        frame's deadline is when the copies that came are merged, so it stays ``wait``.
        """
        sched = self.scheduler
        if sched.virtual or not self.stats.link_up or sched.core.redundancy is not None:
            return wait
        budget = _INDEX_BUDGET // max(1, frames) * self.stats.period_ns / 1e9
        return max(wait, min(sched.timeout, budget))

    # -- slaves known to be gone ----------------------------------------------------------

    def set_absent(self, positions: Iterable[int]) -> None:
        """Slaves known to be gone (a failed node, a cut branch, one being brought back):
        their share of each working counter is not expected until they are back."""
        absent = frozenset(positions)
        if absent != self.absent:
            self.absent = absent
            self._plans.clear()  # the loop plans its frames again with these expectations
            self._safe_plans.clear()

    def _split_explains(self, g: GroupRuntime, n: int, w: int, wkc: int,
                        copies: dict[int, bytes]) -> bool:
        """Whether a ring's copies show the count short only by slaves neither side of a
        break reached (a node gone): then it is whole for the slaves that are there.

        The cycle that shows a node gone otherwise holds every present slave's inputs
        (the count alone cannot say who is missing); the copies can, at once."""
        counts = split_counts(copies, w, self.scheduler.core.src)
        if counts is None or (counts[0] + counts[1]) & 0xFFFF != wkc:
            return False
        key = (id(g), n)
        shares = self._shares.get(key)
        if shares is None:
            shares = self._shares[key] = [s for _, s in bus_shares(g.plan[n], self.config.slaves)]
        return ring_gap(shares, *counts) is not None

    def _absent_share(self, d: CyclicDatagram) -> int:
        # The share of slaves known to be gone: short by that much is "incomplete only for
        # them" (wkc_ok false, present_ok true).
        if not self.absent:
            return 0
        return wkc_share(d, [self.config.slaves[p] for p in d.positions if p in self.absent])


class DcRider:
    """What distributed clocks add to the loop: the phase lock's deadline shift, and
    the sync monitor's BRD of 0x092C riding in a cyclic frame now and then."""

    def __init__(self, dc: DcCycle, scheduler: Scheduler, log: Callable[[str], None]) -> None:
        self.dc = dc
        self.scheduler = scheduler
        self.log = log
        self.events: deque[SyncEvent] = deque(maxlen=200)
        #: Nanoseconds the next deadlines move (the phase lock's correction).
        self.shift = 0
        self._brd: Request | None = None

    def monitor(self, now: int) -> None:
        dc = self.dc
        brd = self._brd
        if brd is not None and brd.done():
            self._brd = None
            if brd.reply is not None:
                ev = dc.monitor.on_reading(now, bytes(brd.reply.data), brd.reply.wkc)
                if ev is not None:
                    self.events.append(ev)
                    self.log(ev.text)
        if self._brd is None and dc.monitor.due(now):
            self._brd = self.scheduler.submit([dc.monitor.datagram()], flush=False)[0]
