"""How ``run`` and ``demo`` end: signals, the give-up rule, the last lines.

Both commands cycle until their time is up, until SIGINT (Ctrl-C) or
SIGTERM, or until the segment stayed unreachable for ``--give-up`` seconds.
Every end is an orderly stop (:meth:`CyclicRunner.stop`: safe outputs,
SAFEOP, then ``--final-state``), followed by the final statistics; the
capture file is closed when the master closes. A second signal while the
stop runs gives the loop up (:meth:`CyclicRunner.abandon`) and ends the
program at once (KeyboardInterrupt; the capture is still closed).

Before cycling starts (scan, bring-up) a signal interrupts as usual: the
master is closed on the way out, which stops an exchange already running in
the same orderly way.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any, Self

from pyethercat.errors import EtherCATError, LinkDownError, StateTimeoutError
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.master.supervision import positions_text
from pyethercat.wire.al import state_name

__all__ = ["StopSignals", "cycle_until", "FINAL_STATES", "segment_lost_error", "SETTLE"]

#: Seconds a spell or a recovery under way at the end of a run gets to end.
SETTLE = 2.0

#: States a run may leave the slaves in (``--final-state``).
FINAL_STATES = ("SAFEOP", "PREOP", "INIT", "BOOT")


class StopSignals:
    """SIGINT/SIGTERM handlers for the cycling phase (a context manager).

    While :attr:`cycling` is False a signal raises KeyboardInterrupt (the
    default for SIGINT, and SIGTERM behaves the same); while it is True the
    first signal only sets :attr:`received` (the loop then stops in order)
    and a second one raises KeyboardInterrupt. Outside the main thread
    nothing is installed.
    """

    def __init__(self) -> None:
        self.cycling = False
        #: The running loop: a second signal gives it up.
        self.runner: CyclicRunner | None = None
        self.received: str | None = None
        self._event = threading.Event()
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[int(sig)] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if not self.cycling or self.received is not None:
            if self.runner is not None:
                self.runner.abandon()
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name
        self._event.set()

    def cycling_with(self, runner: CyclicRunner) -> None:
        """The loop runs from now on: a signal stops it in order (a second gives it up)."""
        self.runner = runner
        self.cycling = True

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds``; True as soon as a stop signal came."""
        return self._event.wait(seconds)


def cycle_until(runner: CyclicRunner, signals: StopSignals, seconds: float | None,
                give_up: float, refresh: Callable[[], None], period: float = 0.25) -> str:
    """Let the loop run; returns why it ends: "time", "signal", "gave up" or "loop ended".

    ``refresh`` redraws the live view every ``period`` seconds. ``give_up``
    > 0 ends the run when the link has been down that long.
    """
    signals.cycling_with(runner)
    end = None if seconds is None else time.monotonic() + seconds
    while True:
        if not runner.running:
            return "loop ended"
        left = period if end is None else min(period, end - time.monotonic())
        if left <= 0:
            return "time"
        if signals.wait(left):
            return "signal"
        refresh()
        if give_up > 0 and runner.down_for() >= give_up:
            return "gave up"


def _settled(runner: CyclicRunner) -> bool:
    return runner.stats.link_up and all(h.status == "ok" for h in runner.health.values())


def segment_lost_error(runner: CyclicRunner, master: Master,
                       settle: float = 0.0) -> EtherCATError | None:
    """The error a run ends with when the segment did not come back (whole), else None.

    Called while the loop still runs. A spell or a recovery under way when the
    time is up is given up to ``settle`` seconds to end (a stall of a few cycles
    at the last moment is no lost segment); slaves that supervision has not
    seen back yet (a recovery that just finished) are then read once more.
    """
    end = time.monotonic() + settle
    while runner.running and not _settled(runner) and time.monotonic() < end:
        time.sleep(0.01)
    where = master.link.name
    if not runner.stats.link_up:
        return LinkDownError(
            f"the segment on {where} did not come back: no frame returned for "
            f"{runner.down_for():.1f} s ({runner.stats.down_cycles} cycles lost)")
    missing = [h.position for h in runner.health.values() if h.status != "ok"]
    if missing:
        try:
            readings = master.read_states(missing)
        except EtherCATError:
            readings = []
        target = int(runner.target)
        back = {p for p, r in zip(missing, readings, strict=False)
                if r.answered and r.state == target and not r.error}
        missing = [p for p in missing if p not in back]
    if missing:
        why = sorted({runner.health[p].status for p in missing})
        return StateTimeoutError(
            f"slave{'s' if len(missing) > 1 else ''} {positions_text(missing)} on {where} not "
            f"back in {state_name(int(runner.target))} when the run ended ({', '.join(why)})")
    return None
