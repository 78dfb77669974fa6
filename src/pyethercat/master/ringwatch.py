"""The ring watch: a rider of the cyclic loop that notices, locates and names events.

Event-driven, not polled: every slave ORs its pending ECAT events (masked
by 0x0200; the scan enables AL-status and DL-status changes) into the IRQ
field of each datagram that passes it (ETG.1000.4 section 5.3, the datagram
header's IRQ word; ESC datasheet section II, registers 0x0200/0x0210). The
watch ORs the IRQ fields of each cycle's replies; it also notices when the
copies of a ring frame change the ports they come back on (a cable pulled,
a master port dead) and when a cycle's working counter is wrong or its
frame lost. Any of these queues one diagnosis read (``master.ring``: DL
status, AL status, counters of every slave; riding in the next cyclic
frame), so the slave that changed is named one cycle after the event
reached the master, and the reading clears the events it reported
(reading 0x0110 and 0x0130 clears the DL- and AL-status events).

What it reports:

- :class:`StatusEvent` per slave whose AL state/error or port links changed
  ("slave 3: OP -> SAFEOP + error, 0x001B", "slave 4 port 1: link lost"),
  in ``events``;
- :class:`~pyethercat.master.ring.FaultEvent` from the ring service when a
  fault is located or gone ("link between slave 4 port 1 and slave 5 port 0"),
  one line each in the loop's event log (``log``).

It also keeps the loop's expectations right: slaves located as gone (a
failed node, a silent branch) are marked absent in the runner (their share
of the working counter is not expected), and slaves found present but
without their station address (power-cycled, hot-swapped) are handed to the
runner's recovery, which brings them back in step with the loop. A node
that fails in a ring is found already from the cycle's own working
counters: the copy back on A carries the share of the slaves before the
break, the copy back on B the share of those after it, so the slaves whose
share is missing between the two lie in the gap (marked absent at once, the
diagnosis then names them).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pyethercat.master.config import bus_shares
from pyethercat.master.redundancy import ring_gap, split_counts
from pyethercat.master.ring import Diagnosis, PendingDiagnosis, RingService
from pyethercat.wire import registers as reg
from pyethercat.wire.al import state_name
from pyethercat.wire.frame import WIRE_NS_PER_BYTE

if TYPE_CHECKING:
    from pyethercat.master.pdu import CyclicFrame

__all__ = ["RingWatch", "StatusEvent"]

_EVENTS = int(reg.EcatEvent.DL_STATUS | reg.EcatEvent.AL_STATUS)
#: A reading asked for by a cycle that did not come back whole waits this many times the
#: last reading's cost after it (the watch's share of the loop's thread: a tenth at most).
_DUTY = 10
#: The share of the cycle's wire time an interval reading takes (see RingWatch._pace): a
#: whole reading at once put three datagrams per slave (300 at 100 slaves, 6.4 KB) into
#: the next cyclic frames, every interval.
_PACE_SHARE = 0.1


@dataclass(frozen=True)
class StatusEvent:
    """A slave's AL state or port link changed (``kind`` ``"al"`` or ``"dl"``).

    ``noticed_cycle``: the cycle whose replies showed the change (IRQ field,
    ports, working counter); ``named_cycle``: the cycle after which the
    slave was named.
    """

    position: int
    name: str
    kind: str
    text: str
    time_ns: int
    noticed_cycle: int
    named_cycle: int


class RingWatch:
    """Rides in a :class:`~pyethercat.master.cyclic.CyclicRunner` (see the module text).

    ``interval``: seconds between diagnoses when nothing happens (CRC
    counters are compared at each); ``log`` receives one line per event.
    """

    def __init__(self, ring: RingService, *, interval: float = 0.2,
                 log: Callable[[str], None] | None = None, recover: bool = True,
                 on_reading: Callable[[Diagnosis, frozenset[int]], None] | None = None) -> None:
        self.ring = ring
        self.interval_ns = int(interval * 1e9)
        self.log = log or (lambda _text: None)
        self.recover = recover
        #: Called after each reading with the slaves then marked absent (hot connect groups).
        self.on_reading = on_reading
        self.events: deque[StatusEvent] = deque(maxlen=500)
        self.pending: PendingDiagnosis | None = None
        self.diagnoses = 0
        self.last: Diagnosis | None = None
        self._want = False
        self._noticed: int | None = None
        self._next_ns = 0
        self._cycle = 0
        self._signature: tuple[int, ...] | None = None
        self._known: dict[int, tuple[int | None, int | None, int | None]] = {}
        self._irq_heads: dict[int, tuple[int, ...]] = {}
        self._published = ring.published
        self._recovering: frozenset[int] = frozenset()
        self._share_cache: dict[tuple[str, int], list[tuple[int, int]]] = {}
        #: A cycle that did not come back whole asks for a reading (``_bad``), but not
        #: sooner than :data:`_DUTY` times the last reading's cost after it: reading
        #: and evaluating every slave is Python work in the loop's thread (2-3 ms at
        #: 100 slaves), and a reading after every late cycle made cycles late, which
        #: asked for more readings (measured: 245 readings and 258 lost frames in
        #: 3000 cycles at 1 kHz).
        self._bad = False
        self._read_at = 0
        self._read_cost = 0
        self._start_cost = 0

    def refresh(self) -> None:
        """Read every slave in the next cycle (a new baseline, e.g. after the master itself
        changed states: its own reads took the events)."""
        self._want = True

    # -- riding in the loop -------------------------------------------------------------

    def before_cycle(self, runner: Any) -> None:
        """Queue a diagnosis when something was noticed (or the interval passed)."""
        self._cycle += 1
        pending = self.pending
        if pending is not None:
            if pending.unsent:
                # A paced reading: the next slice, or all of it when something was noticed
                # meanwhile (the reading that follows it names what that was).
                pending.feed(None if self._want else self._pace(runner))
            return
        now = runner.clock.now_ns()
        due = now >= self._next_ns
        if (self._want or due
                or (self._bad and now >= self._read_at + _DUTY * self._read_cost)):
            # Only the reading of the interval is paced: one that something asked for
            # should name it in the next cycle.
            paced = due and not self._want and not self._bad
            self.pending = self.ring.start_diagnosis(
                flush=False, al=True, pace=self._pace(runner) if paced else None)
            self._want = self._bad = False
            self._next_ns = now + self.interval_ns
            self._read_at = now
            self._start_cost = runner.clock.now_ns() - now

    @staticmethod
    def _pace(runner: Any) -> int:
        """Datagram bytes of an interval reading per cycle: their wire time at 100 Mbit/s is
        :data:`_PACE_SHARE` of the period (a reading of 100 slaves takes 5 ms at any rate)."""
        period_ns = int(getattr(runner, "period_ns", 0) or 1_000_000)
        return max(1, int(period_ns * _PACE_SHARE / WIRE_NS_PER_BYTE))

    def after_cycle(self, runner: Any, tickets: list[CyclicFrame], ok: bool) -> None:
        """Look at the cycle's replies; evaluate a finished diagnosis."""
        irq = 0
        signature: list[int] = []
        for t in tickets:
            raw = t.raw
            if raw is None:
                ok = False
                continue
            irq |= self._irq(t, raw)
            if t.copies:
                # Which ports brought copies back, and which of those went through slaves.
                for port, c in sorted(t.copies.items()):
                    worked = any(c[w] or c[w + 1] for w in t.template.wkc_offsets) \
                        if t.template is not None and len(c) >= t.template.end else True
                    signature.append(2 * port + worked)
        sig = tuple(signature)
        if not ok and signature:
            gap = self._gap(runner, tickets)
            if gap:
                runner.set_absent(set(runner.absent) | gap)
        recovering: frozenset[int] = getattr(runner, "recovering", frozenset())
        if recovering != self._recovering:
            # A recovery began or ended: its own reads took the slaves' events.
            self._recovering = recovering
            self._want = True
        changed = irq & _EVENTS or (self._signature is not None and sig != self._signature)
        if changed or not ok:
            if self._noticed is None:
                self._noticed = self._cycle
            if changed:
                self._want = True  # a slave said so: read at once
            else:
                self._bad = True
        self._signature = sig
        pending = self.pending
        if pending is not None and pending.done():
            self.pending = None
            t0 = runner.clock.now_ns()
            self._evaluate(runner, pending)
            # (the reading's datagrams rode in the cycles' frames: its cost in the loop
            # is the queueing and the evaluation)
            self._read_cost = self._start_cost + runner.clock.now_ns() - t0

    def _gap(self, runner: Any, tickets: list[CyclicFrame]) -> set[int]:
        """Slaves neither side of a break reached, from the copies back on A and on B
        (``master.redundancy.split_counts``/``ring_gap``).

        Frames handed out with an awaited copy missing (late: a busy host) carry no
        copies (``master.redundancy.hand_copies``): the slaves only that copy reached
        would look gone."""
        gap: set[int] = set()
        src = self.ring.scheduler.core.src
        for plan, t in zip(getattr(runner, "last_plans", ()), tickets, strict=False):
            copies = t.copies
            if not copies or t.template is None:
                continue
            end = t.template.end
            if any(len(c) < end for c in copies.values()):
                continue
            for take in plan.takes:
                g, n, w = take[0], take[1], take[2]
                counts = split_counts(copies, w, src)
                if counts is None:
                    continue  # a closed ring: every slave had its turn
                shares = self._shares(runner, g, n)
                span = ring_gap([share for _, share in shares], *counts)
                if span is not None:
                    gap |= {p for p, share in shares[span[0]:span[1]] if share}
        return gap

    def _shares(self, runner: Any, group: Any, n: int) -> list[tuple[int, int]]:
        key = (group.name, n)
        got = self._share_cache.get(key)
        if got is None:
            got = self._share_cache[key] = bus_shares(group.plan[n], runner.config.slaves)
        return got

    def _irq(self, ticket: CyclicFrame, raw: bytes) -> int:
        template = ticket.template
        if template is None:
            return 0
        heads = self._irq_heads.get(id(template))
        if heads is None:
            if len(self._irq_heads) > 64:
                self._irq_heads.clear()
            heads = self._irq_heads[id(template)] = tuple(h + 8 for h, *_ in template.checks)
        v = 0
        for at in heads:
            v |= raw[at] | (raw[at + 1] << 8)
        return v

    # -- naming -------------------------------------------------------------------------

    def _evaluate(self, runner: Any, pending: PendingDiagnosis) -> None:
        result = pending.result()
        if not result.sides_known:
            self._want = True  # read again in frames of its own kind
            return
        self.diagnoses += 1
        self.last = result
        noticed = self._noticed if self._noticed is not None else self._cycle
        self._noticed = None
        now = self.ring.now_ns()
        for r in result.readings:
            name = result.names.get(r.position, "")
            old = self._known.get(r.position)
            new = (r.al_status, r.al_code, r.dl_status)
            self._known[r.position] = new
            if old is None:
                continue
            for kind, text in _changes(r.position, old, new):
                self.events.append(StatusEvent(r.position, name, kind, text, now, noticed,
                                               self._cycle))
        fresh = self.ring.published - self._published
        self._published = self.ring.published
        for fev in list(self.ring.events)[-fresh:] if fresh > 0 else []:
            self.log(fev.text)
        gone = {p for f in result.faults if f.kind in ("node", "cut") for p in f.slaves}
        back = [p for f in result.faults if f.kind == "unaddressed" for p in f.slaves]
        absent = frozenset(gone | set(back) | set(getattr(runner, "recovering", ())))
        if hasattr(runner, "set_absent"):
            runner.set_absent(absent)
        if self.on_reading is not None:
            self.on_reading(result, absent)
        if back and self.recover and getattr(runner, "supervising", False):
            runner.request_recovery(back)


def _changes(position: int, old: tuple[int | None, int | None, int | None],
             new: tuple[int | None, int | None, int | None]) -> list[tuple[str, str]]:
    """What changed in one slave's AL status and port links, as event texts."""
    out: list[tuple[str, str]] = []
    (al0, _code0, dl0), (al1, code1, dl1) = old, new
    if al0 != al1 and al1 is not None:
        state = state_name(al1 & reg.AL_STATE_MASK)
        err = f" + error, 0x{code1 or 0:04X}" if al1 & reg.AL_ERROR_FLAG else ""
        before = "?" if al0 is None else state_name(al0 & reg.AL_STATE_MASK)
        out.append(("al", f"slave {position}: {before} -> {state}{err}"))
    elif al0 is not None and al1 is None:
        out.append(("al", f"slave {position}: no answer"))
    if dl0 is not None and dl1 is not None and dl0 != dl1:
        for p in range(4):
            was, now = dl0 & reg.dl_status_link(p), dl1 & reg.dl_status_link(p)
            if was and not now:
                out.append(("dl", f"slave {position} port {p}: link lost"))
            elif now and not was:
                out.append(("dl", f"slave {position} port {p}: link back"))
    return out
