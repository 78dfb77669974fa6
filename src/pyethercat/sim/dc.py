"""Distributed clocks of a simulated segment: oscillators, latches, the time-control loop, SYNC.

Every slave with a DC unit has a local clock driven by its own oscillator:
``local(t) = local0 + (t - t0) * rate * (1 + correction)``, where ``rate``
is ``1 + drift_ppm * 1e-6`` (the quartz) and ``correction`` the speed
correction of the time-control loop: a learned part that stays, plus a phase
part for a while after each update; registers read it in 10 ns ticks. All slaves' clock
state lives in arrays indexed by slave, so the DC work of a frame is a fixed
number of array operations whatever the slave count. The registers follow
the ESC datasheet section I, "Distributed Clocks" (the master's side: SOEM
``src/ec_dc.c``):

- a write to receive time port 0 (0x0900) latches, in every slave it passes,
  the local time at which the frame arrived at each port (0x0900-0x090F,
  low 32 bits) and at the processing unit (0x0918, 64 bits);
- the system time 0x0910 reads as local time + system time offset 0x0920;
- a write of a reference time to 0x0910 (the master's FRMW/ARMW drift
  compensation, or the master's time written into the reference) is not
  taken over; it drives the time-control loop (see :meth:`DcClocks.time_loop_write`);
- writing 0x0930 (speed counter start) or the filter depths 0x0934/0x0935
  resets the loop ("the filters are reset by writing the Speed Counter
  Start value", datasheet section I 9.1.4 as quoted in ethercrab ``NOTES.md``);
- the cyclic unit (0x0980-0x09A7) fires SYNC0 from the start time 0x0990
  every 0x09A0 ns (0: once) and SYNC1 0x09A4 ns after a SYNC0 pulse, the
  next SYNC1 waiting for the first SYNC0 after it (as SOEM's ``ecx_dcsync01``
  assumes); a pulse raises its AL event, is recorded with the segment time at
  which it really happened, and reaches device applications that listen for
  it. The SYNC0/SYNC1 status 0x098E/0x098F shows the pulse for the pulse
  length 0x0982 (in 10 ns, from SII word 2); with length 0 (acknowledge mode)
  it stays set until the PDI reads it (ET1100 datasheet section II,
  0x0982 and 0x098E-0x098F);
- latch inputs (0x09A8-0x09CF) stamp the system time of an edge a device
  application reports.

The loop's arithmetic is not published in any public source; this one
keeps the documented registers and behaviour: 0x092C is the difference
filtered with depth 0x0934, the speed correction stays within a bound set by
0x0930 and is learned with a depth set by 0x0935, and it acts between
updates (the clock runs faster or slower, it never jumps).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.wire import registers as R
from pyethercat.wire.dc import sync1_period

__all__ = ["DcClocks", "TICK_NS", "RECORDED_PULSES"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
#: The local clock counts in steps of 10 ns (the receive times in the corpus
#: captures are all multiples of 10).
TICK_NS = 10
#: SYNC0 pulses kept per slave (true time and system time), for spread measurements.
RECORDED_PULSES = 64
_SYSTIME_END = R.DC_SYSTEM_TIME + 8
_CYCLIC_END = R.DC_SYNC1_CYCLE + 4
_LOOP_LO, _LOOP_HI = R.DC_SPEED_COUNTER_START, R.DC_SPEED_FILTER_DEPTH + 1
_U64 = 1 << 64
# Loop model: bandwidth time constant per speed-counter-start unit (0x1000 -> about
# 1 ms), and the bound of the correction per unit above 0x7F (0x1000 -> +-397 ppm).
_TAU_PER_COUNT_NS = 256.0
_TRIM_PER_COUNT = 1e-7


def _grown(arr: npt.NDArray[np.generic], size: int, fill: object) -> npt.NDArray[np.generic]:
    """``arr`` with room for ``size`` entries (capacity doubles; new entries ``fill``)."""
    if size <= arr.shape[0]:
        return arr
    shape = (max(size, 2 * arr.shape[0], 4),) + arr.shape[1:]
    out = np.full(shape, fill, arr.dtype)
    out[: arr.shape[0]] = arr
    return out


def _u64(mem: npt.NDArray[np.uint8], rows: I64, addr: int) -> npt.NDArray[np.uint64]:
    return mem[rows, addr: addr + 8].copy().view("<u8")[:, 0]


def _i64(mem: npt.NDArray[np.uint8], rows: I64, addr: int) -> I64:
    return mem[rows, addr: addr + 8].copy().view("<i8")[:, 0]


def _u16(mem: npt.NDArray[np.uint8], rows: I64, addr: int) -> I64:
    return mem[rows, addr: addr + 2].copy().view("<u2")[:, 0].astype(np.int64)


def _u32(mem: npt.NDArray[np.uint8], rows: I64, addr: int) -> I64:
    return mem[rows, addr: addr + 4].copy().view("<u4")[:, 0].astype(np.int64)


def _put(mem: npt.NDArray[np.uint8], rows: I64, addr: int, values: npt.NDArray[np.generic],
         dtype: str) -> None:
    raw = np.ascontiguousarray(values.astype(dtype))
    mem[rows, addr: addr + raw.itemsize] = raw.view(np.uint8).reshape(-1, raw.itemsize)


class DcClocks:
    """Local clocks and DC register behaviour of all slaves (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc], route: Callable[[], Route]) -> None:
        self.memory = memory
        self.escs = escs
        self._route = route
        self.n = 0
        # clock: local(t) = local0 + rate * ((t - t0) * (1 + learned)
        #                                  + min(t - t0, until) * (trim - learned))
        self.t0: I64 = np.zeros(0, np.int64)
        self.local0: F64 = np.zeros(0, np.float64)
        self.rate: F64 = np.zeros(0, np.float64)
        self.trim: F64 = np.zeros(0, np.float64)       # speed correction until ``until``
        self.until: F64 = np.zeros(0, np.float64)      # ns after t0 the phase part ends
        self.wide = np.zeros(0, bool)           # 64-bit system time
        # time-control loop
        self.filtered: F64 = np.zeros(0, np.float64)   # 0x092C before encoding
        self.learned: F64 = np.zeros(0, np.float64)    # learned speed correction
        self.last_update: F64 = np.zeros(0, np.float64)  # local time of the last update (nan: none)
        self.period: F64 = np.zeros(0, np.float64)       # spacing of the updates (0: unknown)
        # cyclic unit
        self.next0 = np.zeros(0, np.uint64)     # system time of the next SYNC0 pulse
        self.cycle0: I64 = np.zeros(0, np.int64)
        self.cycle1: I64 = np.zeros(0, np.int64)
        self.sync0_on = np.zeros(0, bool)
        self.sync1_on = np.zeros(0, bool)
        self.pulses = np.zeros(0, np.int64)     # SYNC0 pulses fired so far
        # SYNC status (0x098E/0x098F): the last pulse (system time, 0: none since the
        # unit was configured), ``pulses`` when it was configured, and the pulses the
        # PDI acknowledged by reading the status (SYNC0: a ``pulses`` value; SYNC1: a
        # count since the configuration)
        self.last0 = np.zeros(0, np.uint64)
        self.cfg_pulses = np.zeros(0, np.int64)
        self.ack0 = np.zeros(0, np.int64)
        self.ack1 = np.zeros(0, np.int64)
        #: Recorded SYNC0 pulses: ring of (system time, true segment time) per slave.
        self.rec_sys = np.zeros((0, RECORDED_PULSES), np.uint64)
        self.rec_true = np.zeros((0, RECORDED_PULSES), np.float64)
        #: Slaves with a planned pulse (index -> 1): the segment only ticks the unit then.
        self.sync_next: dict[int, int] = {}
        self._active: I64 | None = np.zeros(0, np.int64)
        #: Per slave: its application (per pulse) or its device model wants to hear pulses.
        self.app_listens = np.zeros(0, bool)
        self.model_listens = np.zeros(0, bool)
        self._any_listener = False
        #: Receives each SYNC0 pulse (slave, system time) of a slave whose application
        #: listens; None: the slave's application is called directly.
        self.sync0_sink: Callable[[int, int], None] | None = None
        #: Receives the SYNC0 pulses of one tick of all slaves only their device model
        #: listens to, as arrays (slaves, system time of each one's first pulse): no
        #: Python per slave. None: they go through :attr:`sync0_sink` too.
        self.sync0_models: Callable[[I64, npt.NDArray[np.uint64]], None] | None = None
        #: Segment time at which the current frame entered the first slave.
        self.frame_t0 = 0
        #: The last time-loop update (write key, difference, filter gain, tau, bound):
        #: the same write again within a frame takes a short path.
        self._repeat: tuple[tuple[bytes, int, bytes], F64, F64, F64, F64] | None = None

    def add_slave(self, index: int, now: int, drift_ppm: float) -> None:
        n = index + 1
        for name, fill in (("t0", 0), ("local0", 0.0), ("rate", 1.0), ("trim", 0.0), ("until", 0.0),
                           ("wide", True), ("filtered", 0.0), ("learned", 0.0),
                           ("last_update", np.nan), ("period", 0.0), ("next0", 0), ("cycle0", 0), ("cycle1", 0),
                           ("sync0_on", False), ("sync1_on", False), ("pulses", 0),
                           ("last0", 0), ("cfg_pulses", 0), ("ack0", 0), ("ack1", 0),
                           ("rec_sys", 0), ("rec_true", np.nan), ("app_listens", False),
                           ("model_listens", False)):
            setattr(self, name, _grown(getattr(self, name), n, fill))
        self.n = max(self.n, n)
        self.t0[index] = now
        self.local0[index] = 0.0
        self.rate[index] = 1.0 + drift_ppm * 1e-6
        esc = self.escs[index]
        self.wide[index] = esc.profile.dc_64bit
        app = esc.app
        self.app_listens[index] = app is not None and (
            type(app).on_sync0 is not _base_hook("on_sync0")
            or type(app).on_sync1 is not _base_hook("on_sync1"))
        self.model_listens[index] = False
        self._any_listener = bool(self.app_listens.any() or self.model_listens.any())

    def listen(self, index: int) -> None:
        """``index`` wants its pulses (its device model takes SYNC0 events)."""
        self.model_listens[index] = True
        self._any_listener = True

    def reset(self, index: int, now: int) -> None:
        """Power-on of one slave: its local clock starts again from 0, no loop state, no pulses."""
        self._repeat = None
        self.t0[index] = now
        self.local0[index] = 0.0
        self.trim[index] = self.learned[index] = self.filtered[index] = self.period[index] = 0.0
        self.until[index] = 0.0
        self.last_update[index] = np.nan
        self.cfg_pulses[index] = self.pulses[index]  # no pulse since: the status reads 0
        self.sync_drop(index)

    def set_drift(self, index: int, drift_ppm: float, now: int) -> None:
        """Change a slave's oscillator from now on (a temperature step, a worse quartz)."""
        self._repeat = None
        idx = np.array([index], np.int64)
        self._reanchor(idx, now)
        self.rate[index] = 1.0 + drift_ppm * 1e-6

    def drift_ppm(self) -> F64:
        """Each slave's oscillator drift (ppm) and, after the loop, its effective rate error."""
        n = self.n
        return (self.rate[:n] - 1.0) * 1e6

    # --- clocks ----------------------------------------------------------------------

    def _exact(self, slaves: I64, t: I64 | int) -> F64:
        """Local time (ns, not yet in ticks) of ``slaves`` at segment time ``t`` (any shapes)."""
        dt = np.asarray(t, np.int64) - self.t0[slaves]
        window = np.minimum(np.maximum(dt, 0), self.until[slaves])  # np.clip's wrapper costs more
        out: F64 = self.local0[slaves] + self.rate[slaves] * (
            dt * (1.0 + self.learned[slaves]) + window * (self.trim[slaves] - self.learned[slaves]))
        return out

    def _reanchor(self, slaves: I64, t: I64 | int) -> None:
        """Make ``t`` the anchor of the clocks (before their speed changes)."""
        self.local0[slaves] = self._exact(slaves, t)
        self.until[slaves] = np.maximum(self.until[slaves] - (np.asarray(t, np.int64) - self.t0[slaves]), 0)
        self.t0[slaves] = t

    def local_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """Local time of ``slaves`` at segment time ``t_ns``, as the registers show it (ticks)."""
        exact = self._exact(slaves, t_ns)
        return (np.floor(exact / TICK_NS) * TICK_NS).astype(np.int64)

    def pass_time(self, slaves: I64) -> I64:
        """Segment time at which the current frame passes the processing unit of ``slaves``."""
        return self.frame_t0 + np.maximum(self._route().epu_ns[slaves], 0)

    def system_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """System time (local + offset 0x0920) of ``slaves`` at segment time ``t_ns``."""
        offset = _i64(self.memory.mem, slaves, R.DC_SYSTEM_TIME_OFFSET)
        st = self.local_time(slaves, t_ns) + offset
        wide = self.wide[slaves]
        if not wide.all():
            st = np.where(wide, st, st & 0xFFFF_FFFF)
        return st

    def refresh_system_time(self, slaves: I64) -> I64:
        """Write the system time at the frame's pass into 0x0910 of ``slaves``; return it."""
        st = self.system_time(slaves, self.pass_time(slaves))
        _put(self.memory.mem, slaves, R.DC_SYSTEM_TIME, st, "<i8")
        return st

    # --- register writes ----------------------------------------------------------------

    def written(self, slaves: I64, lo: int, data: bytes, system_time: bool = True) -> None:
        """EtherCAT wrote ``data`` at ``lo`` in ``slaves``: latch, time loop, loop reset, cyclic unit.

        ``system_time``: the chips have the system-time registers (0x0910 on)."""
        hi = lo + len(data)
        if lo < R.DC_RECEIVE_TIME_PORT0 + 16 and hi > R.DC_RECEIVE_TIME_PORT0:
            self.latch_receive_times(slaves)
        if system_time and lo < _SYSTIME_END and hi > R.DC_SYSTEM_TIME:
            a = max(lo, R.DC_SYSTEM_TIME)
            self.time_loop_write(slaves, data[a - lo: min(hi, _SYSTIME_END) - lo], a - R.DC_SYSTEM_TIME)
        if system_time and lo < _LOOP_HI and hi > _LOOP_LO:
            self.loop_reset(slaves)
        if lo < _CYCLIC_END and hi > R.DC_CYCLIC_UNIT_CONTROL:
            for s in slaves.tolist():
                self.sync_config_written(s)
        for unit in (0, 1):
            if lo <= R.DC_LATCH0_CONTROL + unit < hi:
                for s in slaves.tolist():
                    self.latch_control_written(s, unit)

    def latch_receive_times(self, slaves: I64) -> None:
        """A write to 0x0900 passed ``slaves``: latch the port receive times and 0x0918."""
        if not len(slaves):
            return
        route = self._route()
        mem = self.memory.mem
        arrive = route.arrive_ns[slaves]  # (k, 4)
        t = self.frame_t0 + np.maximum(arrive, 0)
        exact = self._exact(slaves[:, None], t)
        local = (np.floor(exact / TICK_NS) * TICK_NS).astype(np.int64)
        cur = mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16].copy().view("<u4")
        new = np.where(arrive >= 0, (local & 0xFFFFFFFF).astype("<u4"), cur)
        mem[slaves, R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 16] = new.astype("<u4").view(
            np.uint8).reshape(-1, 16)
        _put(mem, slaves, R.DC_RECEIVE_TIME_ECAT, self.local_time(slaves, self.pass_time(slaves)), "<i8")

    def time_loop_write(self, slaves: I64, data: bytes, offset: int) -> None:
        """A reference time was written to 0x0910 of ``slaves``: one step of their time-control loop.

        Difference d = (own system time - delay 0x0928) - received time, at
        the moment the datagram passes (32-bit writes compare the low double
        words). 0x092C shows d filtered with depth 0x0934 (depth n: the new
        value moves 1/2^n of the way), sign-magnitude. The clock speed is
        then corrected so that the filtered difference would be gone after
        max(tau, the spacing of the updates), tau = 0x0930 x 256 ns,
        plus a learned part that integrates it over 2^(0x0935 - 8) tau; both
        together stay within +-(0x0930 - 0x7F) x 0.1 ppm, and 0x0932 shows the
        learned part in those 0.1 ppm units.
        """
        if not len(slaves) or offset != 0 or len(data) < 4:
            return
        mem = self.memory.mem
        key = (slaves.tobytes(), self.frame_t0, bytes(data))
        # A run of consecutive slaves (the usual FRMW: all behind the reference) is
        # indexed as a slice: views instead of gathered copies.
        first, count = int(slaves[0]), len(slaves)
        if int(slaves[-1]) - first == count - 1 and (count < 3 or bool(
                (np.diff(slaves) == 1).all())):
            slaves = slice(first, first + count)  # type: ignore[assignment]
        rep = self._repeat
        if rep is not None and rep[0] == key:
            # The same write again in the same frame (the master packs many FRMW
            # per frame): the same difference at the same instant, so only the
            # filter moves on; nothing to learn in zero time.
            _, diff_r, gain, horizon_r, bound_r = rep
            filt = self.filtered[slaves]
            filt = filt + (diff_r - filt) * gain
            self.filtered[slaves] = filt
            mag = np.minimum(np.abs(np.rint(filt)), 0x7FFFFFFF).astype(np.uint32)
            raw = mag | np.where(filt >= 0, np.uint32(0x80000000), np.uint32(0))
            _put(mem, slaves, R.DC_SYSTEM_TIME_DIFFERENCE, raw, "<u4")
            self.trim[slaves] = np.clip(self.learned[slaves] - filt / horizon_r, -bound_r, bound_r)
            self.until[slaves] = horizon_r
            return
        t = self.pass_time(slaves)
        own = self.system_time(slaves, t)
        delay = _u32(mem, slaves, R.DC_SYSTEM_TIME_DELAY)
        if len(data) >= 8:
            received = np.int64(int.from_bytes(data[:8], "little", signed=True))
            diff = own - delay - received
            narrow = ~self.wide[slaves]
            if narrow.any():
                low = (own - delay - (received & 0xFFFF_FFFF)) & 0xFFFF_FFFF
                diff = np.where(narrow, np.where(low >= 1 << 31, low - (1 << 32), low), diff)
        else:
            received = np.int64(int.from_bytes(data[:4], "little"))
            low = (own - delay - received) & 0xFFFF_FFFF
            diff = np.where(low >= 1 << 31, low - (1 << 32), low)
        depth_t = (mem[slaves, R.DC_TIME_FILTER_DEPTH] & 0x0F).astype(np.float64)
        depth_s = (mem[slaves, R.DC_SPEED_FILTER_DEPTH] & 0x0F).astype(np.float64)
        start = _u16(mem, slaves, R.DC_SPEED_COUNTER_START) & 0x7FFF
        filt = self.filtered[slaves]
        filt = filt + (diff - filt) / np.exp2(depth_t)
        self.filtered[slaves] = filt
        mag = np.minimum(np.abs(np.rint(filt)), 0x7FFFFFFF).astype(np.uint32)
        raw = mag | np.where(filt >= 0, np.uint32(0x80000000), np.uint32(0))
        _put(mem, slaves, R.DC_SYSTEM_TIME_DIFFERENCE, raw, "<u4")
        # speed correction
        tau = np.maximum(start, 0x80) * _TAU_PER_COUNT_NS
        bound = np.maximum(start - 0x7F, 1) * _TRIM_PER_COUNT
        exact = self._exact(slaves, t)
        last = self.last_update[slaves]
        since = np.maximum(np.where(np.isnan(last), 0.0, exact - last), 0.0)
        # The time to the next update is guessed from the spacing of the updates;
        # writes bunched in one frame (static compensation) keep the last guess.
        # A burst of frames (two close together, then a pause) is as far apart as
        # its longest gap: the guess follows longer spacings at once and shorter
        # ones slowly.
        prev = self.period[slaves]
        period = np.where(since > 0.1 * tau, np.maximum(since, 0.75 * prev), prev)
        since = np.minimum(since, 16 * tau)  # (a long pause teaches the speed no more)
        self.period[slaves] = period
        horizon = np.maximum(tau, period)
        prop = -filt / horizon
        learned = np.clip(self.learned[slaves] + prop * since / (tau * np.exp2(depth_s - 8)),
                          -bound, bound)
        self.learned[slaves] = learned
        self._reanchor(slaves, t)
        # the phase part runs over the horizon; the learned part stays
        self.trim[slaves] = np.clip(learned + prop, -bound, bound)
        self.until[slaves] = horizon
        self.last_update[slaves] = exact
        counts = np.clip(np.rint(learned / _TRIM_PER_COUNT), -0x7FFF, 0x7FFF)
        _put(mem, slaves, R.DC_SPEED_COUNTER_DIFF, counts, "<i2")
        self._repeat = (key, diff.astype(np.float64), 1.0 / np.exp2(depth_t), horizon, bound)

    def loop_reset(self, slaves: I64) -> None:
        """0x0930/0x0934/0x0935 written: filters, learned speed and 0x092C/0x0932 back to zero."""
        self._repeat = None
        if not len(slaves):
            return
        self._reanchor(slaves, self.pass_time(slaves))
        self.trim[slaves] = self.learned[slaves] = self.filtered[slaves] = 0.0
        self.period[slaves] = self.until[slaves] = 0.0
        self.last_update[slaves] = np.nan
        mem = self.memory.mem
        mem[slaves, R.DC_SYSTEM_TIME_DIFFERENCE: R.DC_SYSTEM_TIME_DIFFERENCE + 4] = 0
        mem[slaves, R.DC_SPEED_COUNTER_DIFF: R.DC_SPEED_COUNTER_DIFF + 2] = 0

    # --- SYNC pulses ---------------------------------------------------------------------

    def sync_config_written(self, index: int) -> None:
        """DC cyclic unit registers written: (re)plan SYNC0/SYNC1 pulses.

        Pulses start at the start time 0x0990 (the low 32 bits on a 32-bit
        clock) once 0x0981 has the cyclic unit and SYNC0 or SYNC1 on; a start
        time already past is never reached (a 64-bit comparator waits for
        equality), which 0x0984 shows as a pending activation.
        """
        esc = self.escs[index]
        act = esc.u8(R.DC_ACTIVATION)
        on0 = bool(act & R.DcActivation.CYCLIC and act & R.DcActivation.SYNC0)
        on1 = bool(act & R.DcActivation.CYCLIC and act & R.DcActivation.SYNC1)
        if not (on0 or on1):
            self.sync_drop(index)
            esc.row[R.DC_ACTIVATION_STATUS] = 0
            return
        start = esc.u64(R.DC_START_TIME)
        if not self.wide[index]:
            start &= 0xFFFF_FFFF
        idx = np.array([index], np.int64)
        now = int(self.system_time(idx, self.pass_time(idx))[0]) % _U64
        # a start time already passed is never reached: the unit stays pending
        self.next0[index] = start if start >= now else _U64 - 1
        self.cycle0[index] = esc.u32(R.DC_SYNC0_CYCLE)
        self.cycle1[index] = esc.u32(R.DC_SYNC1_CYCLE)
        self.sync0_on[index], self.sync1_on[index] = on0, on1
        self.last0[index] = 0
        self.cfg_pulses[index] = self.ack0[index] = self.pulses[index]
        self.ack1[index] = 0
        esc.row[R.DC_SYNC0_STATUS] = esc.row[R.DC_SYNC1_STATUS] = 0
        pending = (R.DcActivationStatus.SYNC0_PENDING if on0 else 0) | (
            R.DcActivationStatus.SYNC1_PENDING if on1 else 0)
        esc.row[R.DC_ACTIVATION_STATUS] = int(pending)
        self.sync_next[index] = 1
        self._active = None

    def sync_drop(self, index: int) -> None:
        """No SYNC pulses planned for ``index`` any more."""
        if self.sync_next.pop(index, None) is not None:
            self._active = None

    def _true_time(self, slaves: I64, sys_times: npt.NDArray[np.uint64]) -> F64:
        """Segment time at which the registers of ``slaves`` show the system time ``sys_times``."""
        offset = _i64(self.memory.mem, slaves, R.DC_SYSTEM_TIME_OFFSET)
        target = sys_times.view(np.int64) - offset
        if not self.wide[slaves].all():
            # 32-bit: the local time nearest the anchor whose low double word matches
            base = self.local0[slaves].astype(np.int64)
            d = (target - base) & 0xFFFF_FFFF
            d = np.where(d >= 1 << 31, d - (1 << 32), d)
            target = np.where(self.wide[slaves], target, base + d)
        # the register reaches the value at the tick where the local time gets there
        local = np.ceil(target / TICK_NS) * TICK_NS
        rate, until, t0 = self.rate[slaves], self.until[slaves], self.t0[slaves]
        fast = rate * (1.0 + self.trim[slaves])
        knee = self.local0[slaves] + until * fast
        return np.where(local <= knee, t0 + (local - self.local0[slaves]) / fast,
                        t0 + until + (local - knee) / (rate * (1.0 + self.learned[slaves])))

    def run_sync(self, now: int) -> None:
        """Fire the SYNC0/SYNC1 pulses due by segment time ``now``.

        One array operation over every slave with planned pulses; Python runs
        per slave only for applications that listen to pulses.
        """
        keys = self._active
        if keys is None:
            keys = self._active = np.fromiter(self.sync_next, np.int64, len(self.sync_next))
        if not len(keys):
            return
        sys_now = self.system_time(keys, now).view(np.uint64)
        due = self.next0[keys]
        hit = sys_now >= due
        if not hit.any():
            return
        slaves = keys[hit]
        first = due[hit]
        cycle = self.cycle0[slaves]
        behind = (sys_now[hit] - first).astype(np.int64)
        count = np.where(cycle > 0, behind // np.maximum(cycle, 1) + 1, 1).astype(np.int64)
        last = first + ((count - 1) * cycle).astype(np.uint64)
        # record each pulse with the time it really fired (one pass per pulse
        # index, not per slave: usually a single one per tick)
        before = self.pulses[slaves].copy()
        step = cycle.astype(np.uint64)
        for j in range(min(int(count.max()), RECORDED_PULSES)):
            m = count > j
            sel = slaves[m]
            at = first[m] + np.uint64(j) * step[m]
            slot = (before[m] + j) % RECORDED_PULSES
            self.rec_sys[sel, slot] = at
            self.rec_true[sel, slot] = self._true_time(sel, at)
        self.pulses[slaves] += count
        self.last0[slaves] = last
        self.next0[slaves] = np.where(cycle > 0, last + cycle.astype(np.uint64), np.uint64(_U64 - 1))
        mem = self.memory.mem
        on0, on1 = self.sync0_on[slaves], self.sync1_on[slaves]
        # (the status registers are worked out when they are read: refresh_sync_status)
        mem[slaves[on0], R.DC_SYNC0_STATUS] = R.DC_SYNC_STATUS_PULSE
        mem[slaves, R.DC_ACTIVATION_STATUS] = 0
        ev = np.where(on0, int(R.AlEvent.SYNC0), 0) | np.where(on1, int(R.AlEvent.SYNC1), 0)
        for byte in range(2):
            part = ((ev >> (8 * byte)) & 0xFF).astype(np.uint8)
            if part.any():
                mem[slaves, R.AL_EVENT_REQUEST + byte] |= part
        single = slaves[cycle == 0]
        for s in single.tolist():
            self.sync_drop(s)
        if self._any_listener:
            self._notify(slaves, first, count, before)

    def _notify(self, slaves: I64, first: npt.NDArray[np.uint64], count: I64, before: I64) -> None:
        """Listeners hear the pulses: device models alone all at once, applications each
        pulse (at most 16 per slave and tick)."""
        app_listens = self.app_listens[slaves]
        per_pulse = app_listens | self.model_listens[slaves]
        models = self.sync0_models
        if models is not None:
            alone = per_pulse & ~app_listens
            on = alone & self.sync0_on[slaves]
            if on.any():
                models(slaves[on], first[on])
            per_pulse = app_listens
        for k in np.flatnonzero(per_pulse).tolist():
            s = int(slaves[k])
            app = self.escs[s].app
            sink = self.sync0_sink
            c0, c1 = int(self.cycle0[s]), int(self.cycle1[s])
            every = sync1_period(c0, c1) // c0 if c0 else 1  # SYNC1 after every n-th SYNC0
            for j in range(min(int(count[k]), 16)):
                t = int(first[k]) + j * c0
                if self.sync0_on[s]:
                    if sink is not None:
                        sink(s, t)
                    elif app is not None:
                        app.on_sync0(t)
                if app is not None and self.sync1_on[s] and (int(before[k]) + j) % every == 0:
                    app.on_sync1(t + c1)

    def refresh_sync_status(self, index: int, lo: int, hi: int, pdi_ns: int | None = None) -> None:
        """Bring 0x098E/0x098F of ``index`` up to date before a read of [lo, hi).

        With a pulse length (0x0982 x 10 ns) the status shows whether a pulse
        is on: set from the pulse's system time for that long. With length 0
        (acknowledge mode) it stays set from a pulse until the PDI reads it
        (``pdi_ns``: the segment time of a PDI read, which then clears what it
        read; None: an EtherCAT read, at the frame's pass, which leaves it). SYNC1 pulses are worked out from the SYNC0 ones:
        0x09A4 after every n-th (see :func:`pyethercat.wire.dc.sync1_period`).
        """
        esc = self.escs[index]
        row = esc.row
        length = esc.u16(R.DC_SYNC_PULSE_LENGTH) * TICK_NS
        s0 = s1 = 0
        fired = int(self.pulses[index] - self.cfg_pulses[index])
        if fired > 0:
            idx = np.array([index], np.int64)
            t = int(self.pass_time(idx)[0]) if pdi_ns is None else pdi_ns
            wrap = _U64 if self.wide[index] else 1 << 32
            now = int(self.system_time(idx, t)[0]) % wrap
            last0 = int(self.last0[index])

            def since(pulse: int) -> int:  # signed: the pulses lie within a few cycles
                d = (now - pulse) % wrap
                return d - wrap if d >= wrap // 2 else d

            if self.sync0_on[index]:
                if length:
                    s0 = int(0 <= since(last0) < length)
                else:
                    s0 = int(int(self.pulses[index]) > int(self.ack0[index]))
            count1 = 0
            last1 = None
            if self.sync1_on[index]:
                c0, c1 = int(self.cycle0[index]), int(self.cycle1[index])
                every = sync1_period(c0, c1) // c0 if c0 else 1
                k = fired - 1                       # index of the last SYNC0 pulse
                k -= k % every                      # the last one SYNC1 follows
                if since((last0 - (fired - 1 - k) * c0) % wrap) < c1:
                    k -= every                      # its SYNC1 is still to come
                if k >= 0:
                    last1 = (last0 - (fired - 1 - k) * c0 + c1) % wrap
                    count1 = k // every + 1
                if last1 is not None:
                    s1 = int(0 <= since(last1) < length) if length else int(
                        count1 > int(self.ack1[index]))
            if pdi_ns is not None and not length:
                if lo <= R.DC_SYNC0_STATUS < hi:
                    self.ack0[index] = self.pulses[index]
                if lo <= R.DC_SYNC1_STATUS < hi:
                    self.ack1[index] = count1
        row[R.DC_SYNC0_STATUS] = s0
        row[R.DC_SYNC1_STATUS] = s1

    def recorded_pulses(self) -> tuple[npt.NDArray[np.uint64], F64]:
        """(system time, true segment time) of the recorded SYNC0 pulses, per slave x slot."""
        n = self.n
        return self.rec_sys[:n], self.rec_true[:n]

    def sync0_spreads(self) -> list[tuple[int, float]]:
        """(system time, spread in ns) of each recorded SYNC0 pulse that every pulsing slave fired.

        The spread is the latest minus the earliest true time at which the
        slaves fired that pulse: how far apart outputs would switch. Pulses
        not (or no longer) recorded by every slave are left out; oldest first.
        """
        n = self.n
        pulsing = np.flatnonzero(self.pulses[:n] > 0)
        if not len(pulsing):
            return []
        rows_sys, rows_true = self.rec_sys[pulsing], self.rec_true[pulsing]
        out: list[tuple[int, float]] = []
        for value in np.unique(rows_sys[0]).tolist():
            hit = rows_sys == np.uint64(value)
            if value == 0 or not hit.any(axis=1).all():
                continue
            times = rows_true[hit]
            if np.isnan(times).any():
                continue
            out.append((int(value), float(times.max() - times.min())))
        return out

    def last_sync0(self) -> list[tuple[int, float] | None]:
        """Per slave: (system time, true segment time) of its last SYNC0 pulse, or None."""
        out: list[tuple[int, float] | None] = []
        for s in range(self.n):
            if not self.pulses[s]:
                out.append(None)
                continue
            slot = (self.pulses[s] - 1) % RECORDED_PULSES
            out.append((int(self.rec_sys[s, slot]), float(self.rec_true[s, slot])))
        return out

    # --- latch inputs --------------------------------------------------------------------

    def latch_input(self, index: int, unit: int, rising: bool, t_ns: int) -> None:
        """A device application saw an edge on latch input ``unit`` at segment time ``t_ns``.

        The system time of the edge goes to 0x09B0 (unit 0 rising), 0x09B8
        (falling), 0x09C0/0x09C8 (unit 1) and the status 0x09AE/0x09AF gets
        the event bit. In single-event mode (0x09A8/0x09A9 bit 0 rising, bit
        1 falling) only the first edge is kept until the control register
        is written again; in continuous mode every edge overwrites.
        """
        if unit not in (0, 1):
            raise ValueError(f"latch unit {unit}: 0 or 1")
        esc = self.escs[index]
        ctrl = esc.u8(R.DC_LATCH0_CONTROL + unit)
        status_addr = R.DC_LATCH0_STATUS + unit
        status = esc.u8(status_addr)
        bit = R.DcLatchStatus.POSITIVE_EDGE if rising else R.DcLatchStatus.NEGATIVE_EDGE
        single = ctrl & (R.DC_LATCH_CONTROL_POSITIVE_SINGLE if rising
                         else R.DC_LATCH_CONTROL_NEGATIVE_SINGLE)
        pin = R.DcLatchStatus.PIN_STATE if rising else 0
        if single and status & bit:
            esc.row[status_addr] = (status & ~R.DcLatchStatus.PIN_STATE) | pin
            return
        idx = np.array([index], np.int64)
        st = int(self.system_time(idx, t_ns)[0])
        base = (R.DC_LATCH0_POSITIVE, R.DC_LATCH0_NEGATIVE, R.DC_LATCH1_POSITIVE,
                R.DC_LATCH1_NEGATIVE)[2 * unit + (0 if rising else 1)]
        esc.row[base: base + 8] = np.frombuffer((st % _U64).to_bytes(8, "little"), np.uint8)
        esc.row[status_addr] = (status & ~R.DcLatchStatus.PIN_STATE) | bit | pin

    def latch_control_written(self, index: int, unit: int) -> None:
        """0x09A8/0x09A9 written: the stored events of that unit are cleared."""
        esc = self.escs[index]
        esc.row[R.DC_LATCH0_STATUS + unit] &= R.DcLatchStatus.PIN_STATE

    def report(self, names: Sequence[str]) -> list[dict[str, object]]:
        """Per slave (``names``): walk time, oscillator drift, learned correction, |0x092C|, last SYNC0 pulse.

        ``last_sync0``: (system time, segment time at which it really fired),
        what tests and benchmarks compare across slaves; ``None`` before any.
        """
        dc = self
        n = len(names)
        out = []
        last = dc.last_sync0()
        epu = self._route().epu_ns
        for s in range(n):
            pulse = last[s]
            out.append({
                "index": s, "name": names[s],
                # when a frame passes the processing unit, ns after it entered the segment:
                # the true delays are the differences of these
                "epu_ns": int(epu[s]),
                "drift_ppm": float((dc.rate[s] - 1.0) * 1e6),
                "correction_ppm": float(dc.trim[s] * 1e6),
                "difference_ns": float(abs(dc.filtered[s])),
                "sync0_pulses": int(dc.pulses[s]),
                "last_sync0": None if pulse is None else [pulse[0], pulse[1]],
            })
        return out


def _base_hook(name: str) -> object:
    from pyethercat.sim.device import DeviceApp

    return getattr(DeviceApp, name)
