"""Supervision of the slaves while cyclic exchange runs: checks, health, recovery.

Between cycles and cheap: every ``check_interval`` seconds a BRD of AL status
(2 bytes) rides in a cyclic frame. Its working counter is the number of
slaves that answered and its data the OR of their states; when either is
off, or a group's working counter was wrong, the next frames carry one FPRD
of AL status per slave (the "multiple read"), which names the slaves that
dropped out of the requested state or vanished. A recovery thread (never the
cycle thread) brings them back through the master's ``recover`` callback: a
slave that answers again at position p with station address 0 was
power-cycled, so it gets its address, its sync managers and FMMUs again, and
is walked up to the requested state; a slave that only left OP is
acknowledged and requested again. The master is never restarted.

While the link is down nothing is checked: every slave's state becomes
unknown ("lost"), and the first check after the link returns reads every
slave again. A state is shown as current only while a check confirmed it
within ``state_timeout`` seconds (:meth:`Supervisor.state`); an older one is
unknown, never the last value seen.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pyethercat.errors import EtherCATError
from pyethercat.master.scheduler import Request, Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState, state_name
from pyethercat.wire.datagram import Command, Datagram

__all__ = ["SlaveHealth", "Supervisor", "positions_text"]

# AL status bits a supervised slave must show exactly: the state and no error flag.
_STATE_AND_ERROR = reg.AL_STATE_MASK | reg.AL_ERROR_FLAG
# Up to this many slaves get a line each in the event log; more share one line.
_LINES_EACH = 8


@dataclass
class SlaveHealth:
    """Supervision state of one slave.

    ``state``/``error``/``code`` are what the last per-slave read found and
    ``seen_ns`` when (loop clock); use :meth:`Supervisor.state` for a value
    that is current.
    """

    position: int
    station_address: int
    state: int = 0
    error: bool = False
    code: int = 0
    present: bool = True
    #: "ok", "dropped" (answers, not in the requested state), "vanished",
    #: "recovering", "lost" (the link is down: state unknown)
    status: str = "ok"
    recoveries: int = 0
    lost_since_ns: int | None = None
    seen_ns: int | None = None


def positions_text(positions: Sequence[int]) -> str:
    """``0-3, 5`` for positions 0, 1, 2, 3, 5."""
    out: list[str] = []
    ps = sorted(positions)
    i = 0
    while i < len(ps):
        j = i
        while j + 1 < len(ps) and ps[j + 1] == ps[j] + 1:
            j += 1
        out.append(str(ps[i]) if i == j else f"{ps[i]}-{ps[j]}")
        i = j + 1
    return ", ".join(out)


class Supervisor:
    """Checks riding in the cyclic frames, slave health and the recovery thread.

    ``slaves`` have ``position`` and ``station_address``; ``recover(positions)``
    is called from the recovery thread; ``now_ns`` is the loop's clock and
    ``log`` its event log. ``tick_ns`` is the loop period (checks are counted
    in ticks).
    """

    def __init__(self, scheduler: Scheduler, slaves: Sequence[object], *, target: AlState,
                 recover: Callable[[list[int]], None] | None, check_interval: float,
                 tick_ns: int, now_ns: Callable[[], int], log: Callable[[str], None],
                 state_timeout: float | None = None) -> None:
        self.scheduler = scheduler
        self.target = target
        self.recover_fn = recover
        self.now_ns = now_ns
        self.log = log
        self.health: dict[int, SlaveHealth] = {
            int(getattr(s, "position")): SlaveHealth(int(getattr(s, "position")),  # noqa: B009
                                                     int(getattr(s, "station_address")))  # noqa: B009
            for s in slaves}
        #: False while the master is still walking the slaves up, or stops (no checks).
        self.enabled = True
        self.check_interval = check_interval
        self._check_every = (max(1, int(round(check_interval * 1e9 / tick_ns)))
                             if check_interval > 0 else 0)
        self._check_ns = int(check_interval * 1e9)
        if state_timeout is None:
            state_timeout = max(0.5, 5 * check_interval)
        #: A state confirmed longer ago than this is unknown.
        self.state_timeout_ns = int(state_timeout * 1e9)
        self._brd: Request | None = None
        self._detail: list[Request] | None = None
        self._want_detail = False
        self._last_detail_ns = 0
        # When a BRD last found every slave in the requested state without error.
        self._all_seen_ns: int | None = None
        self.recover_thread: threading.Thread | None = None
        self._recover_lock = threading.Lock()
        self._next_recovery_ns = 0
        self._backoff_ns = 0
        self._last_failure = ""

    def add(self, slaves: Sequence[object]) -> None:
        """Supervise these slaves too (found while the loop runs); between cycles."""
        for s in slaves:
            pos = int(getattr(s, "position"))  # noqa: B009
            self.health[pos] = SlaveHealth(pos, int(getattr(s, "station_address")))  # noqa: B009
        # A per-slave read in flight was made for the slaves before: read anew.
        if self._detail is not None:
            self._detail = None
            self._want_detail = True

    @property
    def active(self) -> bool:
        return bool(self._check_every and self.health and self.enabled)

    # -- riding in the cycle (loop thread) ----------------------------------------------

    def before(self, k: int) -> None:
        """Queue the cheap check (or the per-slave read) so it rides in this cycle's frame."""
        if not self.active:
            return
        sched = self.scheduler
        now = self.now_ns()
        # A fresh incident is looked at at once; a known one once per check interval.
        if (self._want_detail and self._detail is None
                and (not self.any_unhealthy() or now - self._last_detail_ns >= self._check_ns)):
            self._want_detail = False
            self._last_detail_ns = now
            self._detail = sched.submit(
                [Datagram.device(Command.FPRD, h.station_address, reg.AL_STATUS, 6)
                 for h in self.health.values()], flush=False)
        elif self._brd is None and k % self._check_every == 0:
            self._brd = sched.submit([Datagram.device(Command.BRD, 0, reg.AL_STATUS, 2)],
                                     flush=False)[0]

    def after(self, wkc_good: bool) -> None:
        """Look at the checks whose replies came back (and at the cycle's verdict)."""
        # While the master still walks the slaves up, a low WKC is no incident yet.
        if not self.active:
            return
        if not wkc_good and self._detail is None:
            self._want_detail = True
        brd = self._brd
        if brd is not None and brd.done():
            self._brd = None
            if brd.reply is not None:
                state = brd.reply.data[0] if brd.reply.data else 0
                count = brd.reply.wkc
                if (count != len(self.health) or (state & _STATE_AND_ERROR) != int(self.target)
                        or self.any_unhealthy()):
                    self._want_detail = True
                else:
                    self._all_seen_ns = self.now_ns()
        detail = self._detail
        if detail is not None and all(r.done() for r in detail):
            self._detail = None
            self._evaluate(detail)

    def confirm_all(self) -> None:
        """Every slave was just seen in the target state without error (by the caller)."""
        self._all_seen_ns = self.now_ns()

    def any_unhealthy(self) -> bool:
        return any(h.status != "ok" for h in self.health.values())

    # -- the link (loop thread) ---------------------------------------------------------

    def link_down(self, now: int) -> None:
        """No frame comes back: every state is unknown; checks wait for the link."""
        self._brd = None
        self._detail = None
        self._all_seen_ns = None
        for h in self.health.values():
            h.status = "lost"
            if h.lost_since_ns is None:
                h.lost_since_ns = now

    def link_up(self) -> None:
        """Frames come back again: read every slave at once and recover without delay."""
        self._want_detail = True
        self._last_detail_ns = 0
        self._next_recovery_ns = 0
        self._backoff_ns = 0

    # -- reading (any thread) --------------------------------------------------------------

    def state(self, position: int, link_up: bool = True) -> int | None:
        """AL status (state and error flag) of a slave as a check confirmed it lately.

        None when it is not known now: the link is down, the slave did not
        answer, or no check confirmed it within ``state_timeout``.
        """
        h = self.health.get(position)
        if h is None or not link_up:
            return None
        now = self.now_ns()
        limit = self.state_timeout_ns
        seen_all = self._all_seen_ns
        if h.status == "ok" and seen_all is not None and now - seen_all <= limit:
            return int(self.target)
        if h.present and h.seen_ns is not None and now - h.seen_ns <= limit and h.state:
            return h.state | (reg.AL_ERROR_FLAG if h.error else 0)
        return None

    # -- evaluation and recovery -------------------------------------------------------------

    def _evaluate(self, detail: list[Request]) -> None:
        now = self.now_ns()
        bad: list[int] = []
        back: list[tuple[int, str]] = []
        vanished: list[int] = []
        for h, r in zip(self.health.values(), detail, strict=True):
            rep = r.reply
            if rep is None or rep.wkc != 1:
                if h.present:
                    h.present = False
                    if h.lost_since_ns is None:
                        h.lost_since_ns = now
                    vanished.append(h.position)
                if h.status != "recovering":
                    h.status = "vanished"
                bad.append(h.position)
                continue
            status, _res, code = struct.unpack("<HHH", rep.data)
            h.state, h.error, h.code = status & reg.AL_STATE_MASK, bool(status & reg.AL_ERROR_FLAG), code
            h.present = True
            h.seen_ns = now
            if h.state == int(self.target) and not h.error:
                if h.status != "ok":
                    took = "" if h.lost_since_ns is None else \
                        f" after {(now - h.lost_since_ns) / 1e9:.2f} s"
                    back.append((h.position, took))
                    h.recoveries += 1 if h.status == "recovering" else 0
                h.status = "ok"
                h.lost_since_ns = None
                continue
            if h.status in ("ok", "lost"):
                if h.lost_since_ns is None:
                    h.lost_since_ns = now
                self.log(f"slave {h.position} left {state_name(int(self.target))}: now "
                         f"{state_name(status & _STATE_AND_ERROR)}" + (f" (AL code 0x{code:04X})" if h.error else ""))
            if h.status != "recovering":
                h.status = "dropped"
            bad.append(h.position)
        if vanished:
            if len(vanished) <= _LINES_EACH:
                for p in vanished:
                    self.log(f"slave {p} (0x{self.health[p].station_address:04X}) vanished")
            else:
                self.log(f"slaves {positions_text(vanished)} vanished")
        if back:
            name = state_name(int(self.target))
            if len(back) <= _LINES_EACH:
                for p, took in back:
                    self.log(f"slave {p} back in {name}{took}")
            else:
                self.log(f"slaves {positions_text([p for p, _ in back])} back in {name}{back[0][1]}")
        if bad:
            self._start_recovery(bad)

    def request_recovery(self, positions: list[int]) -> None:
        """Bring these slaves back now (found present without their address: power-cycled,
        hot-swapped); ignored while a recovery runs."""
        if self.enabled:
            self._next_recovery_ns = 0  # news: no back-off
            self._start_recovery([p for p in positions if p in self.health])

    def _start_recovery(self, positions: list[int]) -> None:
        if self.recover_fn is None or not self.enabled or not positions:
            return
        r = self.recover_thread
        if r is not None and r.is_alive():
            return
        if self.now_ns() < self._next_recovery_ns:
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
                    failure = f"recovery of slaves {positions_text(positions)} not done yet: {exc}"
                except Exception as exc:  # noqa: BLE001 - a bug must not kill the loop
                    failure = f"recovery of slaves {positions_text(positions)} failed: {exc!r}"
                finally:
                    if failure:
                        # Back off (0.1 s doubling to 2 s) and say it once, not every try.
                        self._backoff_ns = min(2_000_000_000, max(100_000_000, 2 * self._backoff_ns))
                        if failure != self._last_failure:
                            self.log(failure)
                    else:
                        self._backoff_ns = 0
                    self._last_failure = failure
                    self._next_recovery_ns = self.now_ns() + self._backoff_ns
                    # Look again soon; the check decides whether it worked.
                    self._want_detail = True

        # In step with the loop: its requests ride in cyclic frames (master.stepping).
        self.recover_thread = self.scheduler.stepper.run(work, name="ecat-recover")

    def join(self, timeout: float | None = None) -> None:
        """Wait for a recovery in progress."""
        r = self.recover_thread
        if r is not None and r is not threading.current_thread():
            r.join(timeout)
