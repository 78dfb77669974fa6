"""Output buffers arriving at slaves: what a completed write of the master sets in motion.

When the master writes the last byte of a slave's buffered write SM (the
outputs), in one frame for any number of slaves:

- the buffers are published to the PDI side and the SM status and AL events
  advance (``sim.syncman.SmAreas.publish``);
- the process-data watchdogs of those SMs are re-triggered (``sim.watchdog``);
- the slave has received outputs: a SAFEOP -> OP request waiting for them
  completes (``sim.al_state``);
- the device models and applications that asked are called (``sim.apps``);
- wired outputs drive the inputs they feed (``sim.wiring``).

:class:`OutputArrival` keeps the per-slave "outputs received" flags (cleared
when a slave goes below SAFEOP, its watchdog runs out or it powers off) and
the slaves whose SAFEOP -> OP request waits.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import numpy.typing as npt

from pyethercat.sim.apps import DeviceApps
from pyethercat.sim.esc import Esc
from pyethercat.sim.syncman import SmAreas
from pyethercat.sim.watchdog import Watchdogs
from pyethercat.sim.wiring import Wiring

__all__ = ["OutputArrival"]

I64 = npt.NDArray[np.int64]


class OutputArrival:
    """Per-slave output state and the work of completed output buffers (see the module docstring)."""

    def __init__(self, escs: Sequence[Esc], sm: SmAreas, watchdogs: Watchdogs, apps: DeviceApps,
                 wiring: Wiring, now_ns: Callable[[], int],
                 after_frame: Callable[[Callable[[], None]], None]) -> None:
        self.escs = escs
        self.sm = sm
        self.watchdogs = watchdogs
        self.apps = apps
        self.wiring = wiring
        self.now_ns = now_ns
        #: Where the applications' work goes: after the frame (``Segment.after_frame``).
        self.after_frame = after_frame
        #: Per slave: a complete output buffer arrived (since it last went below SAFEOP).
        self.received = np.zeros(0, bool)
        #: Slaves with a SAFEOP -> OP request waiting for their first outputs.
        self.pending_op: set[int] = set()

    def add_slave(self) -> None:
        self.received = np.append(self.received, False)

    def stop(self, slave: int) -> None:
        """No outputs any more (below SAFEOP, power off, reset): watchdog stopped, no pending OP."""
        self.received[slave] = False
        self.watchdogs.stop(slave)
        self.pending_op.discard(slave)

    def completed(self, slaves: I64) -> None:
        """The buffered write SMs of ``slaves`` (unique) got their last byte in this frame."""
        self.published(slaves, self.sm.publish(slaves), self.now_ns())

    def published(self, slaves: I64, wd_slaves: I64, now: int) -> None:
        """What follows the publish of the buffers of ``slaves`` (done by the caller):
        the watchdogs of ``wd_slaves`` retriggered at ``now``, OP requests waiting for
        outputs, the applications, the wires."""
        if len(wd_slaves):
            self.watchdogs.retrigger(wd_slaves, now)
        self.received[slaves] = True
        if self.pending_op:
            for s in sorted(self.pending_op & set(slaves.tolist())):
                self.escs[s].al.outputs_arrived()
        apps = self.apps
        if apps.listening:
            # The applications take the new outputs through the PDI once the frame has passed.
            self.after_frame(partial(apps.outputs_completed, slaves))
        if self.wiring.wires:
            self.wiring.apply()
