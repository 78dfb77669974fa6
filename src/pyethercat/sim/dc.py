"""Distributed clocks of a simulated segment: local clocks, latches, system time, SYNC pulses.

Every slave with a DC unit has a free-running local clock derived from the
segment's clock: ``local = (t - t0) * rate``, ``t0`` its power-on time and
``rate`` ``1 + drift_ppm * 1e-6``. All slaves' clock state lives in arrays
indexed by slave, so the DC work of a frame is a few array operations
whatever the slave count. The registers follow ETG.1000.4 section 5.5
"Distributed clocks" and the ET1100 datasheet section I, "Distributed Clocks":

- a write to receive time port 0 (0x0900) latches, in every slave it passes,
  the local time at which the frame arrived at each port (0x0900-0x090F,
  low 32 bits) and at the processing unit (0x0918, 64 bits);
- the system time 0x0910 reads as local time + system time offset 0x0920;
- a write of a reference time to 0x0910 (the master's FRMW/ARMW drift
  compensation) is not taken over: the ESC stores the difference
  (local copy of system time - system time delay 0x0928) - received time in
  0x092C, sign-magnitude (bit 31 set: local copy larger);
- the cyclic unit (0x0980-0x09A7) plans SYNC0/SYNC1 pulses from the start
  time 0x0990 with the cycle times 0x09A0/0x09A4; a pulse sets its status
  (0x098E/0x098F), its AL event and calls the device application.

Times of a frame are the segment time at which the frame entered (set by the
segment per frame, :attr:`DcClocks.frame_t0`) plus the walk's arrival times.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.wire import registers as R

__all__ = ["DcClocks"]

I64 = npt.NDArray[np.int64]
_U64_MAX = (1 << 64) - 1
_SYSTIME_END = R.DC_SYSTEM_TIME + 8
_CYCLIC_END = R.DC_SYNC1_CYCLE + 4


def _grown(arr: npt.NDArray[np.generic], size: int, fill: object) -> npt.NDArray[np.generic]:
    """``arr`` with room for ``size`` entries (capacity doubles; new entries ``fill``)."""
    if size <= len(arr):
        return arr
    out = np.full(max(size, 2 * len(arr), 4), fill, arr.dtype)
    out[: len(arr)] = arr
    return out


class DcClocks:
    """Local clocks and DC register behaviour of all slaves (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc], route: Callable[[], Route]) -> None:
        self.memory = memory
        self.escs = escs
        self._route = route
        #: Local clock origin (segment time of power-on) and rate, per slave.
        self.t0: I64 = np.zeros(0, np.int64)
        self.rate: npt.NDArray[np.float64] = np.zeros(0, np.float64)
        #: Segment time at which the current frame entered the first slave.
        self.frame_t0 = 0
        #: Planned pulses per slave: [next start, SYNC0 cycle, SYNC1 cycle, activation].
        self.sync_next: dict[int, list[int]] = {}
        #: sync_next's slaves and their next pulse times as arrays (None: rebuild).
        self._sync_keys: I64 | None = None
        self._sync_due: npt.NDArray[np.uint64] = np.zeros(0, np.uint64)
        #: Receives each SYNC0 pulse (slave, system time); None: the slave's application does.
        self.sync0_sink: Callable[[int, int], None] | None = None

    def add_slave(self, index: int, now: int, drift_ppm: float) -> None:
        self.t0 = _grown(self.t0, index + 1, 0)  # type: ignore[assignment]
        self.rate = _grown(self.rate, index + 1, 1.0)  # type: ignore[assignment]
        self.t0[index] = now
        self.rate[index] = 1.0 + drift_ppm * 1e-6

    def reset(self, index: int, now: int) -> None:
        """Power-on of one slave: its local clock starts again, no pulses planned."""
        self.t0[index] = now
        self.sync_drop(index)

    # --- clocks ----------------------------------------------------------------------

    def local_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """Local (free-running, drifting) time of ``slaves`` at segment time ``t_ns``."""
        return ((np.asarray(t_ns, np.int64) - self.t0[slaves]) * self.rate[slaves]).astype(np.int64)

    def pass_time(self, slaves: I64) -> I64:
        """Segment time at which the current frame passes the processing unit of ``slaves``."""
        return self.frame_t0 + np.maximum(self._route().epu_ns[slaves], 0)

    def refresh_system_time(self, slaves: I64) -> I64:
        """Write the system time (local time + offset 0x0920) into 0x0910 of ``slaves``; return it."""
        mem = self.memory.mem
        t = self.frame_t0 + np.maximum(self._route().epu_ns[slaves], 0)
        local = ((t - self.t0[slaves]) * self.rate[slaves]).astype(np.int64)
        offset = mem[slaves, R.DC_SYSTEM_TIME_OFFSET: R.DC_SYSTEM_TIME_OFFSET + 8].copy().view("<i8")[:, 0]
        st: I64 = (local + offset).astype("<i8")
        mem[slaves, R.DC_SYSTEM_TIME: _SYSTIME_END] = st.view(np.uint8).reshape(-1, 8)
        return st

    # --- register writes ----------------------------------------------------------------

    def written(self, slaves: I64, lo: int, data: bytes, system_time: bool = True) -> None:
        """EtherCAT wrote ``data`` at ``lo`` in ``slaves``: latch, time loop, cyclic unit.

        ``system_time``: the chips have the system-time registers (0x0910 on)."""
        hi = lo + len(data)
        if lo < R.DC_RECEIVE_TIME_PORT0 + 16 and hi > R.DC_RECEIVE_TIME_PORT0:
            self.latch_receive_times(slaves)
        if system_time and lo < _SYSTIME_END and hi > R.DC_SYSTEM_TIME:
            a = max(lo, R.DC_SYSTEM_TIME)
            self.time_loop_write(slaves, data[a - lo: min(hi, _SYSTIME_END) - lo], a - R.DC_SYSTEM_TIME)
        if lo < _CYCLIC_END and hi > R.DC_CYCLIC_UNIT_CONTROL:
            for s in slaves.tolist():
                self.sync_config_written(s)

    def latch_receive_times(self, slaves: I64) -> None:
        """A write to 0x0900 passed ``slaves``: latch the port receive times and 0x0918."""
        if not len(slaves):
            return
        route = self._route()
        mem = self.memory.mem
        arrive = route.arrive_ns[slaves]  # (k, 4)
        t = self.frame_t0 + np.maximum(arrive, 0)
        local = ((t - self.t0[slaves, None]) * self.rate[slaves, None]).astype(np.int64)
        cur = mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16].copy().view("<u4")
        new = np.where(arrive >= 0, (local & 0xFFFFFFFF).astype("<u4"), cur)
        mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16] = new.astype("<u4").view(
            np.uint8).reshape(-1, 16)
        epu_local = self.local_time(slaves, self.pass_time(slaves)).astype("<i8")
        mem[slaves, R.DC_RECEIVE_TIME_ECAT: R.DC_RECEIVE_TIME_ECAT + 8] = epu_local.view(
            np.uint8).reshape(-1, 8)

    def time_loop_write(self, slaves: I64, data: bytes, offset: int) -> None:
        """A reference time was written to 0x0910: store the difference in 0x092C (see the module docstring)."""
        if not len(slaves) or offset != 0 or len(data) < 4:
            return
        mem = self.memory.mem
        own = self.refresh_system_time(slaves)  # what 0x0910 now holds
        if len(data) >= 8:
            received = np.int64(int.from_bytes(data[:8], "little", signed=True))
        else:
            received = np.int64(int.from_bytes(data[:4], "little"))
            own = own & 0xFFFFFFFF  # the low double word, as an unsigned value
        delay = mem[slaves, R.DC_SYSTEM_TIME_DELAY: R.DC_SYSTEM_TIME_DELAY + 4].copy().view("<u4")[:, 0]
        diff = own - delay.astype(np.int64) - received
        mag = np.minimum(np.abs(diff), 0x7FFFFFFF).astype(np.uint32)
        value = (mag | np.where(diff >= 0, np.uint32(0x80000000), np.uint32(0))).astype("<u4")
        mem[slaves, R.DC_SYSTEM_TIME_DIFFERENCE: R.DC_SYSTEM_TIME_DIFFERENCE + 4] = value.view(
            np.uint8).reshape(-1, 4)

    # --- SYNC pulses ---------------------------------------------------------------------

    def sync_config_written(self, index: int) -> None:
        """DC cyclic unit registers written: (re)plan SYNC0/SYNC1 events."""
        esc = self.escs[index]
        act = esc.u8(R.DC_ACTIVATION)
        cycle0 = esc.u32(R.DC_SYNC0_CYCLE)
        if act & R.DcActivation.CYCLIC and act & (R.DcActivation.SYNC0 | R.DcActivation.SYNC1):
            start = esc.u64(R.DC_START_TIME)
            self.sync_next[index] = [start, cycle0, esc.u32(R.DC_SYNC1_CYCLE), act]
            self._sync_keys = None
        else:
            self.sync_drop(index)

    def sync_drop(self, index: int) -> None:
        """No SYNC pulses planned for ``index`` any more."""
        if self.sync_next.pop(index, None) is not None:
            self._sync_keys = None

    def run_sync(self, now: int) -> None:
        """Fire the SYNC0/SYNC1 pulses that are due.

        The system times of all slaves with planned pulses are one array
        operation (keys and next pulse times cached until ``sync_next``
        changes); Python runs only for the slaves whose pulse is due."""
        sync = self.sync_next
        keys, due = self._sync_keys, self._sync_due
        if keys is None:
            keys = np.fromiter(sync, np.int64, len(sync))
            due = np.array([p[0] for p in sync.values()], np.uint64)
            self._sync_keys, self._sync_due = keys, due
        local = self.local_time(keys, now)
        offset = self.memory.mem[keys, R.DC_SYSTEM_TIME_OFFSET: R.DC_SYSTEM_TIME_OFFSET + 8].copy().view("<i8")[:, 0]
        systimes = (local + offset).view(np.uint64)  # (wraps like the 64-bit register)
        hits = np.nonzero(systimes >= due)[0]
        for j in hits.tolist():
            index = int(keys[j])
            plan = sync.get(index)
            if plan is None:
                continue  # dropped by an earlier pulse's application in this tick
            self._fire(index, plan, int(systimes[j]))
            due[j] = min(plan[0], _U64_MAX)  # (a stale copy if the plans changed meanwhile: rebuilt then)

    def _fire(self, index: int, plan: list[int], systime: int) -> None:
        _, cycle0, cycle1, act = plan
        esc = self.escs[index]
        app = esc.app
        fired = 0
        while systime >= plan[0] and fired < 16:
            t = plan[0]
            if act & R.DcActivation.SYNC0:
                esc.row[R.DC_SYNC0_STATUS] = 1
                esc.set_al_event(int(R.AlEvent.SYNC0))
                if self.sync0_sink is not None:
                    self.sync0_sink(index, t)
                elif app is not None:
                    app.on_sync0(t)
            if act & R.DcActivation.SYNC1:
                esc.row[R.DC_SYNC1_STATUS] = 1
                esc.set_al_event(int(R.AlEvent.SYNC1))
                if app is not None:
                    app.on_sync1(t + cycle1)
            fired += 1
            if cycle0 == 0:
                self.sync_drop(index)  # single shot
                return
            plan[0] = t + cycle0
        if cycle0 and systime >= plan[0]:
            # Far behind (no ticks for a long time): skip the missed pulses.
            missed = (systime - plan[0]) // cycle0 + 1
            plan[0] += missed * cycle0
