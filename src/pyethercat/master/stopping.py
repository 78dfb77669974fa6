"""The orderly stop of the cyclic loop (:meth:`CyclicRunner.stop`).

1. Supervision stops (no recovery starts; one in progress is waited for).
2. For ``safe_cycles`` cycles of every group the frames carry the safe
   outputs (``ProcessImage.safe``: zero unless the application set values)
   instead of the application's.
3. With a ``leave`` callback (the master gives one) the slaves are requested
   to SAFEOP while the cycles still run, so the outputs stay valid until they
   are there; then the loop ends and the slaves go on to the final state
   (PREOP by default). No slave is left in OP to run into its watchdog.

While the link is down the states are left alone (nothing would reach the
slaves). Failures to reach a state are reported, never raised: stopping
always stops.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from pyethercat.errors import EtherCATError
from pyethercat.master.cyclestats import CycleStats
from pyethercat.master.supervision import Supervisor
from pyethercat.wire.al import AlState, state_name

__all__ = ["LeaveFn", "OrderlyStop"]

#: ``leave(state, positions, timeout)``: take those slaves to ``state`` and wait.
LeaveFn = Callable[[AlState, list[int], float], None]


class OrderlyStop:
    """The stop sequence of one runner (see the module text).

    ``send_safe()`` switches the loop to the safe outputs,
    ``wait_cycles(count, timeout)`` waits for loop cycles, ``end_loop()``
    ends the loop thread; ``cycles_per_round`` is the tick count in which
    every group is sent once.
    """

    def __init__(self, supervisor: Supervisor, stats: CycleStats, leave: LeaveFn | None,
                 log: Callable[[str], None], *, send_safe: Callable[[], None],
                 wait_cycles: Callable[[int, float], bool], end_loop: Callable[[], None],
                 safe_cycles: int, cycles_per_round: int, period_s: float) -> None:
        self.supervisor = supervisor
        self.stats = stats
        self.leave = leave
        self.log = log
        self._send_safe = send_safe
        self._wait_cycles = wait_cycles
        self._end_loop = end_loop
        self.safe_cycles = safe_cycles
        self._round = cycles_per_round
        self._period_s = period_s

    def run(self, final: AlState, timeout: float) -> str:
        """Stop; returns one line saying what was done (also logged)."""
        t0 = time.monotonic()
        sup = self.supervisor
        sup.enabled = False
        sup.join(timeout)  # a recovery in progress first
        self._send_safe()
        ticks = self.safe_cycles * self._round
        if self.stats.link_up and ticks:
            # (+1: the cycle under way may have filled its frame before the switch)
            self._wait_cycles(ticks + 1, timeout + (ticks + 1) * self._period_s)
        done = [f"safe outputs for {self.safe_cycles} cycles"]
        if self.leave is not None:
            present = [h.position for h in sup.health.values() if h.present]
            if not self.stats.link_up:
                done.append(f"slaves not taken to {state_name(int(final))}: the link is down")
            else:
                ok = self._step(AlState.SAFEOP, present, timeout)
                self._end_loop()
                if ok and final != AlState.SAFEOP:
                    ok = self._step(final, present, timeout)
                if ok:
                    done.append(f"slaves in {state_name(int(final))}")
        report = f"stopped: {', '.join(done)} ({(time.monotonic() - t0) * 1000:.0f} ms)"
        self.log(report)
        return report

    def _step(self, state: AlState, positions: list[int], timeout: float) -> bool:
        assert self.leave is not None
        if not positions:
            return True
        try:
            self.leave(state, positions, timeout)
        except EtherCATError as exc:
            self.log(f"stop: not every slave reached {state_name(int(state))}: {exc}")
            return False
        return True
