"""Process-data watchdogs of all slaves of a segment, as arrays.

The process-data watchdog of an ESC (ET1100 datasheet section I,
"Watchdog"; registers 0x0400 divider, 0x0420 time, 0x0440 status, 0x0442
counter) is re-triggered by every completed write of a buffered SM with the
watchdog trigger bit (SM control bit 6). It runs out after
``(divider + 2) * 40 ns * time`` without a trigger: the status bit clears,
the counter counts, and a slave in OP falls back to SAFEOP with AL status
code 0x001B.

All watchdogs are three arrays (last trigger, limit, armed); the segment
asks :meth:`Watchdogs.due` only once the earliest deadline has passed.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.sim.memory import EscMemory
from pyethercat.wire import registers as R

__all__ = ["NEVER", "Watchdogs"]

I64 = npt.NDArray[np.int64]
#: A deadline that never comes.
NEVER = 1 << 62


class Watchdogs:
    """The process-data watchdogs (see the module docstring)."""

    def __init__(self, memory: EscMemory) -> None:
        self.memory = memory
        self.last: I64 = np.zeros(0, np.int64)
        self.limit: I64 = np.zeros(0, np.int64)
        self.expired = np.zeros(0, bool)
        self.armed = np.zeros(0, bool)
        #: No watchdog can expire before this time (a lower bound).
        self.deadline = NEVER
        self._min_limit = 0
        self.expired_any = False

    def add_slave(self) -> None:
        self.last = np.append(self.last, -1)
        self.limit = np.append(self.limit, 0)
        self.expired = np.append(self.expired, False)
        self.armed = np.append(self.armed, False)

    def stop(self, index: int) -> None:
        """The slave's watchdog stops (power off, reset, below SAFEOP)."""
        self.last[index] = -1
        self.expired[index] = False

    def refresh(self, count: int) -> None:
        """Recompute limits and armed flags from the registers of ``count`` slaves."""
        mem = self.memory.mem[:count]
        div = mem[:, R.WATCHDOG_DIVIDER].astype(np.int64) | (mem[:, R.WATCHDOG_DIVIDER + 1].astype(np.int64) << 8)
        wt = (mem[:, R.WATCHDOG_TIME_PROCESS_DATA].astype(np.int64)
              | (mem[:, R.WATCHDOG_TIME_PROCESS_DATA + 1].astype(np.int64) << 8))
        armed = np.zeros(count, bool)
        for k in range(16):
            base = R.sm_address(k)
            armed |= ((mem[:, base + R.SM_CONTROL] & R.SM_CONTROL_WATCHDOG) != 0) & (
                (mem[:, base + R.SM_ACTIVATE] & R.SM_ACTIVATE_ENABLE) != 0)
        self.limit = (div + 2) * R.WATCHDOG_TICK_NS * wt
        self.armed = armed & (wt > 0)
        self._min_limit = int(self.limit[self.armed].min()) if self.armed.any() else 0
        self.deadline = -1

    def due(self, now: int) -> list[int]:
        """Slaves whose watchdog ran out by ``now`` (marked expired); updates the deadline."""
        if not len(self.last):
            return []
        eligible = self.armed & ~self.expired & (self.last >= 0)
        expiry = self.last + self.limit
        due = eligible & (now > expiry)
        out: list[int] = []
        if due.any():
            out = np.nonzero(due)[0].tolist()
            self.expired[due] = True
            self.expired_any = True
        rest = eligible & ~due
        self.deadline = int(expiry[rest].min()) if rest.any() else NEVER
        return out

    def pause(self, ns: int) -> None:
        """Every running watchdog loses ``ns`` (the simulator's own time on one frame:
        a real ESC answers within the frame's passage, so those ``ns`` were no
        silence of the master)."""
        running = self.last >= 0
        self.last[running] += ns
        if self.deadline < NEVER:
            self.deadline += ns

    def retrigger(self, slaves: I64, now: int) -> None:
        """Completed write buffers of ``slaves`` trigger their watchdogs."""
        self.last[slaves] = now
        if self.expired_any:
            self.expired[slaves] = False
            flat = self.memory.flat
            flat[slaves * self.memory.stride + R.WATCHDOG_STATUS_PROCESS_DATA] |= 1
            self.expired_any = bool(self.expired.any())
        # A watchdog (re)started here expires no earlier than now + the shortest limit.
        soonest = now + self._min_limit
        if soonest < self.deadline:
            self.deadline = soonest
