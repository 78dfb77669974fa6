"""Link-down spells of the cyclic loop, told from what each cycle got back.

A cycle in which no frame came back starts (or continues) a silence, unless
the scheduler heard a reply meanwhile (``heard()``: replies taken, and late
ones it dropped as stale): a frame that came back after its cycle gave up on
it, or while the loop thread was kept off the CPU, is no sign of a dead
link. The silence becomes a *down spell* at once when the link says why (it
refused to send, reported the interface down, or has no carrier),
otherwise after ``timeout_ns`` and at least three silent cycles (a segment
that stopped answering: powered off, simulator killed). The spell ends with
the first reply heard, including a late reply to one of the previous
cycle's probes. Spells are
counted in the loop's :class:`~pyethercat.master.cyclestats.CycleStats`;
the supervisor hears of both ends (states unknown, then read again).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from pyethercat.errors import EtherCATError
from pyethercat.link.base import Link
from pyethercat.master.cyclestats import CycleStats
from pyethercat.master.scheduler import CyclicFrame
from pyethercat.master.supervision import Supervisor

__all__ = ["LinkWatch"]

# Fraction of the period a cyclic frame has after its deadline to come back, and the
# shortest wait for it (a round trip through a loaded host takes a millisecond or so).
_REPLY_FRACTION = 0.9
_MIN_REPLY_NS = 2_000_000
# How long a frame sent while the link is down waits for its reply (at most P/4).
_PROBE_NS = 100_000


class LinkWatch:
    """Decides when the link is down or up again (called once per cycle by the loop)."""

    def __init__(self, link: Link, stats: CycleStats, supervisor: Supervisor,
                 log: Callable[[str], None], period_ns: int,
                 timeout: float | None = None, heard: Callable[[], int] | None = None) -> None:
        self.link = link
        #: Replies the scheduler received so far (any frame, late ones included).
        self.heard = heard if heard is not None else (lambda: 0)
        self._heard = -1
        self.stats = stats
        self.supervisor = supervisor
        self.log = log
        self.period_ns = period_ns
        #: Silence after which the link counts as down without the link saying so
        #: (default: 3 periods, at least 20 ms).
        self.timeout_ns = (int(timeout * 1e9) if timeout is not None
                           else max(3 * period_ns, 20_000_000))
        #: Set by the loop when the link refused a frame, or a receive failed.
        self.send_error: EtherCATError | None = None
        self.recv_error: EtherCATError | None = None
        self._silent_since: int | None = None
        self._silent_cycles = 0
        self._spell_cycles = 0

    def reply_timeout(self, deadline: int, now: int) -> float:
        """Seconds a cycle's frames may take to come back (sent at ``now``)."""
        if self.stats.link_up:
            # Until 90% of the period after the deadline, or _MIN_REPLY_NS.
            return max(deadline + int(self.period_ns * _REPLY_FRACTION) - now,
                       _MIN_REPLY_NS) / 1e9
        # A probe for the link's return, waiting only briefly: a timer would wake the
        # loop late on a busy host. A later reply is still matched to it and found by
        # the next cycle (see cycle_done).
        return min(_PROBE_NS, self.period_ns // 4) / 1e9

    def cycle_done(self, back: int, now: int, probes: Sequence[CyclicFrame | None]) -> None:
        """``back`` frames of the cycle that started at ``now`` came back.

        ``probes`` are the previous cycle's tickets: while the link is down a
        late reply to one of them ends the spell as well.
        """
        stats = self.stats
        if not back:
            back = sum(1 for t in probes if t is not None and t.raw is not None)
        if not back:
            # A silent cycle: did anything come back since the last one (late)?
            heard, before = self.heard(), self._heard
            self._heard = heard
            if self._silent_cycles and heard > before >= 0:
                back = heard - before
        send_error, recv_error = self.send_error, self.recv_error
        self.send_error = self.recv_error = None
        if back:
            self._silent_since = None
            self._silent_cycles = 0
            self._heard = -1
            if not stats.link_up:
                took = stats.link_came_up(now)
                self.log(f"link up again after {took / 1e9:.2f} s "
                         f"({self._spell_cycles} cycles lost)")
                self._spell_cycles = 0
                self.supervisor.link_up()
            return
        if not stats.link_up:
            stats.down_cycles += 1
            self._spell_cycles += 1
            self._silent_cycles += 1
            return
        if self._silent_since is None:
            self._silent_since = now
        self._silent_cycles += 1
        why = None
        if send_error is not None:
            why = str(send_error)
        elif recv_error is not None:
            why = str(recv_error)
        elif self.link.carrier() is False:
            why = f"no carrier on {self.link.name}"
        elif now - self._silent_since >= self.timeout_ns and self._silent_cycles >= 3:
            why = (f"no frame came back for {(now - self._silent_since) / 1e6:.0f} ms "
                   f"on {self.link.name}")
        if why is None:
            return
        since = self._silent_since
        stats.link_went_down(since)
        stats.down_cycles += self._silent_cycles
        self._spell_cycles = self._silent_cycles
        self.supervisor.link_down(since)
        self.log(f"link down: {why}")
