"""Distributed clocks of a simulated segment: oscillators, receive-time latches, the time-control loop.

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
- the cyclic unit (SYNC0/SYNC1, 0x0980-0x09A7) and the latch inputs
  (0x09A8-0x09CF) are :class:`~pyethercat.sim.dc_sync.SyncUnits`
  (``DcClocks.sync``), in :mod:`pyethercat.sim.dc_sync`; writes to their
  registers are passed on to it.

The loop's arithmetic is not published in any public source; this one
keeps the documented registers and behaviour: 0x092C is the difference
filtered with depth 0x0934, the speed correction stays within a bound set by
0x0930 and is learned with a depth set by 0x0935, and it acts between
updates (the clock runs faster or slower, it never jumps).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.sim.dc_sync import TICK_NS, SyncUnits, grown
from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.wire import registers as R

__all__ = ["DcClocks"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
_SYSTIME_END = R.DC_SYSTEM_TIME + 8
_CYCLIC_END = R.DC_SYNC1_CYCLE + 4
_LOOP_LO, _LOOP_HI = R.DC_SPEED_COUNTER_START, R.DC_SPEED_FILTER_DEPTH + 1
_MAG_MAX, _SIGN_BIT = float(0x7FFFFFFF), float(0x80000000)
_I64_HALF, _U64_SPAN = 1 << 63, 1 << 64
#: The loop's settings in a memory row: delay 0x0928, speed counter start 0x0930,
#: filter depths 0x0934/0x0935 (not the loop's own outputs 0x092C and 0x0932).
_SETTINGS = np.array([R.DC_SYSTEM_TIME_DELAY + i for i in range(4)] + [
    R.DC_SPEED_COUNTER_START, R.DC_SPEED_COUNTER_START + 1, R.DC_TIME_FILTER_DEPTH,
    R.DC_SPEED_FILTER_DEPTH]) - R.DC_SYSTEM_TIME_DELAY  # (in the bytes from 0x0928 on)
# Loop model: bandwidth time constant per speed-counter-start unit (0x1000 -> about
# 1 ms), and the bound of the correction per unit above 0x7F (0x1000 -> +-397 ppm).
_TAU_PER_COUNT_NS = 256.0
_TRIM_PER_COUNT = 1e-7
#: The widest bound of the speed correction (0x0930 = 0x7FFF): no loop state makes a
#: clock run faster than ``rate * (1 + _TRIM_MAX)``.
_TRIM_MAX = (0x7FFF - 0x7F) * _TRIM_PER_COUNT
# Columns of DcClocks._clk (one gather fetches a slave's clock parameters at once).
_LOCAL0, _RATE, _TRIM, _UNTIL, _LEARNED = range(5)
# 64-bit words of a memory row: the system time 0x0910 and its offset 0x0920.
_SYSTIME_W, _OFFSET_W = R.DC_SYSTEM_TIME // 8, R.DC_SYSTEM_TIME_OFFSET // 8
assert R.DC_SYSTEM_TIME % 8 == 0 and R.DC_SYSTEM_TIME_OFFSET % 8 == 0


def _u16(mem: npt.NDArray[np.uint8], rows: I64 | slice, addr: int) -> I64:
    return mem[rows, addr: addr + 2].copy().view("<u2")[:, 0].astype(np.int64)


def _u32(mem: npt.NDArray[np.uint8], rows: I64 | slice, addr: int) -> I64:
    return mem[rows, addr: addr + 4].copy().view("<u4")[:, 0].astype(np.int64)


def _put(mem: npt.NDArray[np.uint8], rows: I64, addr: int, values: npt.NDArray[np.generic],
         dtype: str) -> None:
    raw = np.ascontiguousarray(values.astype(dtype))
    mem[rows, addr: addr + raw.itemsize] = raw.view(np.uint8).reshape(-1, raw.itemsize)


def _as_rows(slaves: I64) -> I64 | slice:
    """``slaves`` as a row index: a slice for a run of consecutive slaves (the usual
    FRMW: every slave behind the reference), so that the rows are views, not copies."""
    first, count = int(slaves[0]), len(slaves)
    if int(slaves[-1]) - first == count - 1 and (count < 3 or bool((np.diff(slaves) == 1).all())):
        return slice(first, first + count)
    return slaves


def _sign_magnitude(values: F64) -> F64:
    """0x092C's sign-magnitude encoding of ``values`` (integral, as floats to be stored as
    u32): bit 31 set for >= 0 (as KickCAT's emulator; the public sources disagree on
    the sense, see the facts sheet), the magnitude below."""
    out: F64 = np.minimum(np.abs(np.rint(values)), _MAG_MAX)
    out += (values >= 0) * _SIGN_BIT
    return out


@dataclass(frozen=True, slots=True)
class _LoopParams:
    """The time-control loop's settings of some slaves, from their registers (per slave)."""

    delay: I64          # 0x0928
    gain: F64           # the time filter's step, 1 / 2^depth (0x0934)
    tau: F64            # bandwidth time constant, ns (0x0930)
    tau_tenth: F64
    tau_16: F64
    learn_time: F64     # tau x 2^(0x0935 - 8)
    bound: F64          # of the speed correction (0x0930)
    low: F64            # -bound
    narrow: npt.NDArray[np.bool_] | None  # 32-bit system times (None: all 64-bit)


class DcClocks:
    """Local clocks and DC register behaviour of all slaves (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc], route: Callable[[], Route]) -> None:
        self.memory = memory
        self.escs = escs
        self._route = route
        self.n = 0
        # clock: local(t) = local0 + rate * ((t - t0) * (1 + learned)
        #                                  + min(t - t0, until) * (trim - learned))
        # local0, rate, trim, until and learned are columns of one array ``_clk``
        # (slave x 5; see _views): the clock maths gathers a slave's row once.
        self.t0: I64 = np.zeros(0, np.int64)
        self._clk: F64 = np.zeros((0, 5), np.float64)
        self.local0: F64
        self.rate: F64
        self.trim: F64                                 # speed correction until ``until``
        self.until: F64                                # ns after t0 the phase part ends
        self.learned: F64                              # learned speed correction
        self._views()
        self.wide = np.zeros(0, bool)           # 64-bit system time
        self._narrow = False                    # some slave has a 32-bit system time
        # time-control loop
        self.filtered: F64 = np.zeros(0, np.float64)   # 0x092C before encoding
        self.last_update: F64 = np.zeros(0, np.float64)  # local time of the last update (nan: none)
        self.period: F64 = np.zeros(0, np.float64)       # spacing of the updates (0: unknown)
        #: The cyclic unit (SYNC0/SYNC1) and the latch inputs, on these clocks.
        self.sync = SyncUnits(memory, escs, self)
        #: Segment time at which the current frame entered the first slave.
        self.frame_t0 = 0
        #: The last time-loop update (write key, difference, filter gain, tau, bound):
        #: the same write again within a frame takes a short path.
        self._repeat: tuple[tuple[bytes, int, bytes], F64, F64, F64, F64] | None = None
        #: Row indexes of the slave sets the loop was written in (by their bytes).
        self._rows: dict[bytes, I64 | slice] = {}
        #: The last loop settings worked out: (slave set, their register bytes, settings);
        #: forgotten when a slave is added or put in another's place (add_slave).
        self._params: tuple[bytes, bytes, _LoopParams] | None = None
        # memory and its 64-bit view (rows of little-endian words; the stride is a multiple of 8)
        self._mem8: npt.NDArray[np.uint8] | None = None
        self._mem64: I64 = np.zeros((0, 1), np.int64)
        self._typed: dict[str, npt.NDArray[Any]] = {}

    def _views(self) -> None:
        clk = self._clk
        self.local0, self.rate, self.trim = clk[:, _LOCAL0], clk[:, _RATE], clk[:, _TRIM]
        self.until, self.learned = clk[:, _UNTIL], clk[:, _LEARNED]

    def words(self) -> I64:
        """The segment's memory as rows of 64-bit little-endian words (a view)."""
        mem = self.memory.mem
        if mem is not self._mem8:
            self._mem8 = mem
            self._mem64 = mem.view("<i8")
            self._typed.clear()
        return self._mem64

    def _store(self, rows: I64 | slice, addr: int, values: npt.NDArray[np.generic], dtype: str) -> None:
        """Write ``values`` as ``dtype`` at ``addr`` of ``rows``: one store through a typed
        view of the memory (``addr`` is aligned to the type's size)."""
        self.words()  # (the views follow a regrown memory)
        view = self._typed.get(dtype)
        if view is None:
            view = self._typed[dtype] = self.memory.mem.view(dtype)
        view[rows, addr // view.itemsize] = values

    def add_slave(self, index: int, now: int, drift_ppm: float) -> None:
        n = index + 1
        for name, fill in (("t0", 0), ("wide", True), ("filtered", 0.0),
                           ("last_update", np.nan), ("period", 0.0)):
            setattr(self, name, grown(getattr(self, name), n, fill))
        size = self._clk.shape[0]
        if n > size:
            clk = np.zeros((max(n, 2 * size, 4), 5), np.float64)
            clk[:, _RATE] = 1.0
            clk[:size] = self._clk
            self._clk = clk
            self._views()
        self.n = max(self.n, n)
        self.t0[index] = now
        self.local0[index] = 0.0
        self.rate[index] = 1.0 + drift_ppm * 1e-6
        self.wide[index] = self.escs[index].profile.dc_64bit
        self._narrow = not bool(self.wide[: self.n].all())
        # (a chip put in the place of another may count 32 bits where it counted 64)
        self._repeat = self._params = None
        self.sync.add_slave(index)
        self.sync.clock_changed()

    def reset(self, index: int, now: int) -> None:
        """Power-on of one slave: its local clock starts again from 0, no loop state, no pulses."""
        self._repeat = None
        self.t0[index] = now
        self.local0[index] = 0.0
        self.trim[index] = self.learned[index] = self.filtered[index] = self.period[index] = 0.0
        self.until[index] = 0.0
        self.last_update[index] = np.nan
        self.sync.reset(index)
        self.sync.clock_changed()

    def set_drift(self, index: int, drift_ppm: float, now: int) -> None:
        """Change a slave's oscillator from now on (a temperature step, a worse quartz)."""
        self._repeat = None
        idx = np.array([index], np.int64)
        self._reanchor(idx, now)
        self.rate[index] = 1.0 + drift_ppm * 1e-6
        self.sync.clock_changed()

    def drift_ppm(self) -> F64:
        """Each slave's oscillator drift (ppm) and, after the loop, its effective rate error."""
        n = self.n
        return (self.rate[:n] - 1.0) * 1e6

    # --- clocks ----------------------------------------------------------------------

    def _exact(self, slaves: I64, t: I64 | int) -> F64:
        """Local time (ns, not yet in ticks) of ``slaves`` at segment time ``t`` (any shapes)."""
        c = self._clk[slaves]  # (..., 5): all parameters in one gather
        dt = np.asarray(t, np.int64) - self.t0[slaves]
        learned = c[..., _LEARNED]
        window = np.minimum(np.maximum(dt, 0), c[..., _UNTIL])  # np.clip's wrapper costs more
        out: F64 = c[..., _LOCAL0] + c[..., _RATE] * (
            dt * (1.0 + learned) + window * (c[..., _TRIM] - learned))
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

    def max_rate(self, slaves: I64) -> F64:
        """An upper bound of the speed of the local clocks of ``slaves`` (local ns per segment ns)
        whatever the time-control loop does until their drift changes or they are reset."""
        # (a rate <= 0, a clock standing or running backwards, is bounded by a small speed)
        out: F64 = np.maximum(self.rate[slaves], 1e-3) * (1.0 + _TRIM_MAX)
        return out

    def pass_time(self, slaves: I64 | slice) -> I64:
        """Segment time at which the current frame passes the processing unit of ``slaves``."""
        return self.frame_t0 + self._route().epu_at_ns[slaves]

    def system_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """System time (local + offset 0x0920) of ``slaves`` at segment time ``t_ns``."""
        st: I64 = self.local_time(slaves, t_ns) + self.words()[slaves, _OFFSET_W]
        if self._narrow:
            wide = self.wide[slaves]
            if not wide.all():
                st = np.where(wide, st, st & 0xFFFF_FFFF)
        return st

    def true_time(self, slaves: I64, sys_times: npt.NDArray[np.uint64]) -> F64:
        """Segment time at which the registers of ``slaves`` show the system time ``sys_times``."""
        target = sys_times.view(np.int64) - self.words()[slaves, _OFFSET_W]
        c = self._clk[slaves]
        local0 = c[:, _LOCAL0]
        if self._narrow and not self.wide[slaves].all():
            # 32-bit: the local time nearest the anchor whose low double word matches
            base = local0.astype(np.int64)
            d = (target - base) & 0xFFFF_FFFF
            d = np.where(d >= 1 << 31, d - (1 << 32), d)
            target = np.where(self.wide[slaves], target, base + d)
        # the register reaches the value at the tick where the local time gets there
        local = np.ceil(target / TICK_NS) * TICK_NS
        rate, until, t0 = c[:, _RATE], c[:, _UNTIL], self.t0[slaves]
        fast = rate * (1.0 + c[:, _TRIM])
        knee = local0 + until * fast
        out: F64 = np.where(local <= knee, t0 + (local - local0) / fast,
                            t0 + until + (local - knee) / (rate * (1.0 + c[:, _LEARNED])))
        return out

    def refresh_system_time(self, slaves: I64) -> I64:
        """Write the system time at the frame's pass into 0x0910 of ``slaves``; return it."""
        st = self.system_time(slaves, self.pass_time(slaves))
        self.words()[slaves, _SYSTIME_W] = st
        return st

    def refresh_one(self, index: int) -> int:
        """:meth:`refresh_system_time` of one slave (a read of 0x0910: the reference's
        in every FRMW) in Python floats: the same operations in the same order as the
        array path, so the same bits, without a dozen numpy calls on one element."""
        t = self.frame_t0 + int(self._route().epu_at_ns[index])
        local0, rate, trim, until, learned = self._clk[index].tolist()
        dt = t - int(self.t0[index])
        window = min(float(max(dt, 0)), until)
        exact = local0 + rate * (dt * (1.0 + learned) + window * (trim - learned))
        local = int(float(math.floor(exact / TICK_NS)) * TICK_NS)
        words = self.words()
        st = (local + int(words[index, _OFFSET_W]) + _I64_HALF) % _U64_SPAN - _I64_HALF  # (int64 wrap)
        if not self.wide[index]:
            st &= 0xFFFF_FFFF
        words[index, _SYSTIME_W] = st
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
                self.sync.sync_config_written(s)
        for unit in (0, 1):
            if lo <= R.DC_LATCH0_CONTROL + unit < hi:
                for s in slaves.tolist():
                    self.sync.latch_control_written(s, unit)

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
        raw_rows = slaves.tobytes()
        key = (raw_rows, self.frame_t0, bytes(data))
        rows = self._rows.get(raw_rows)
        if rows is None:
            if len(self._rows) >= 64:
                self._rows.clear()  # (a bound whatever the master sends)
            rows = self._rows[raw_rows] = _as_rows(slaves)
        rep = self._repeat
        if rep is not None and rep[0] == key:
            # The same write again in the same frame (the master packs many FRMW
            # per frame): the same difference at the same instant, so only the
            # filter moves on; nothing to learn in zero time.
            _, diff_r, gain, horizon_r, bound_r = rep
            filt = self.filtered[rows]
            filt = filt + (diff_r - filt) * gain
            self.filtered[rows] = filt
            self._store(rows, R.DC_SYSTEM_TIME_DIFFERENCE, _sign_magnitude(filt), "<u4")
            self.trim[rows] = np.clip(self.learned[rows] - filt / horizon_r, -bound_r, bound_r)
            self.until[rows] = horizon_r
            return
        p = self._loop_params(raw_rows, rows)
        t = self.pass_time(rows)
        # The local time now, under the clock parameters in force until this update
        # (what the system time shows, and the new anchor of the clock).
        c = self._clk[rows]
        dt = t - self.t0[rows]
        old_learned = c[:, _LEARNED]
        window = np.minimum(np.maximum(dt, 0), c[:, _UNTIL])
        exact = c[:, _LOCAL0] + c[:, _RATE] * (
            dt * (1.0 + old_learned) + window * (c[:, _TRIM] - old_learned))
        own = (np.floor(exact / TICK_NS) * TICK_NS).astype(np.int64) + self.words()[rows, _OFFSET_W]
        if p.narrow is not None:
            own = np.where(p.narrow, own & 0xFFFF_FFFF, own)
        if len(data) >= 8:
            received = np.int64(int.from_bytes(data[:8], "little", signed=True))
            diff = own - p.delay - received
            if p.narrow is not None:
                low = (own - p.delay - (received & 0xFFFF_FFFF)) & 0xFFFF_FFFF
                diff = np.where(p.narrow, np.where(low >= 1 << 31, low - (1 << 32), low), diff)
        else:
            received = np.int64(int.from_bytes(data[:4], "little"))
            low = (own - p.delay - received) & 0xFFFF_FFFF
            diff = np.where(low >= 1 << 31, low - (1 << 32), low)
        filt = self.filtered[rows]
        filt = filt + (diff - filt) * p.gain
        self.filtered[rows] = filt
        self._store(rows, R.DC_SYSTEM_TIME_DIFFERENCE, _sign_magnitude(filt), "<u4")
        # speed correction; nan - the time of no update yet: no time since (fmax drops nan)
        since = np.fmax(exact - self.last_update[rows], 0.0)
        # The time to the next update is guessed from the spacing of the updates;
        # writes bunched in one frame (static compensation) keep the last guess.
        # A burst of frames (two close together, then a pause) is as far apart as
        # its longest gap: the guess follows longer spacings at once and shorter
        # ones slowly.
        prev = self.period[rows]
        period = np.where(since > p.tau_tenth, np.maximum(since, 0.75 * prev), prev)
        since = np.minimum(since, p.tau_16)  # (a long pause teaches the speed no more)
        self.period[rows] = period
        horizon = np.maximum(p.tau, period)
        prop = -filt / horizon
        learned = np.minimum(np.maximum(old_learned + prop * since / p.learn_time, p.low), p.bound)
        # the clock anchored now; the phase part runs over the horizon, the learned part stays
        self.t0[rows] = t
        self.local0[rows] = exact
        self.learned[rows] = learned
        self.trim[rows] = np.minimum(np.maximum(learned + prop, p.low), p.bound)
        self.until[rows] = horizon
        self.last_update[rows] = exact
        counts = np.minimum(np.maximum(np.rint(learned / _TRIM_PER_COUNT), -0x7FFF), 0x7FFF)
        self._store(rows, R.DC_SPEED_COUNTER_DIFF, counts, "<i2")
        self._repeat = (key, diff.astype(np.float64), p.gain, horizon, p.bound)

    def _loop_params(self, raw_rows: bytes, rows: I64 | slice) -> _LoopParams:
        """The loop settings of ``rows`` from their registers 0x0928-0x0935, worked out once
        for as long as those bytes stay the same (whatever path writes them)."""
        regs = self.memory.mem[rows, R.DC_SYSTEM_TIME_DELAY: _LOOP_HI][:, _SETTINGS].tobytes()
        hit = self._params
        if hit is not None and hit[0] == raw_rows and hit[1] == regs:
            return hit[2]
        mem = self.memory.mem
        depth_t = (mem[rows, R.DC_TIME_FILTER_DEPTH] & 0x0F).astype(np.float64)
        depth_s = (mem[rows, R.DC_SPEED_FILTER_DEPTH] & 0x0F).astype(np.float64)
        start = _u16(mem, rows, R.DC_SPEED_COUNTER_START) & 0x7FFF
        tau = np.maximum(start, 0x80) * _TAU_PER_COUNT_NS
        bound = np.maximum(start - 0x7F, 1) * _TRIM_PER_COUNT
        wide = self.wide[rows]
        p = _LoopParams(
            delay=_u32(mem, rows, R.DC_SYSTEM_TIME_DELAY),
            gain=1.0 / np.exp2(depth_t),  # (a power of two: the same as dividing by it)
            tau=tau, tau_tenth=0.1 * tau, tau_16=16 * tau,
            learn_time=tau * np.exp2(depth_s - 8),
            bound=bound, low=-bound,
            narrow=None if wide.all() else ~wide)
        self._params = (raw_rows, regs, p)
        return p

    def loop_reset(self, slaves: I64) -> None:
        """0x0930/0x0934/0x0935 written: filters, learned speed and 0x092C/0x0932 back to zero."""
        self._repeat = None
        if not len(slaves):
            return
        self.sync.clock_changed()
        self._reanchor(slaves, self.pass_time(slaves))
        self.trim[slaves] = self.learned[slaves] = self.filtered[slaves] = 0.0
        self.period[slaves] = self.until[slaves] = 0.0
        self.last_update[slaves] = np.nan
        mem = self.memory.mem
        mem[slaves, R.DC_SYSTEM_TIME_DIFFERENCE: R.DC_SYSTEM_TIME_DIFFERENCE + 4] = 0
        mem[slaves, R.DC_SPEED_COUNTER_DIFF: R.DC_SPEED_COUNTER_DIFF + 2] = 0

    def report(self, names: Sequence[str]) -> list[dict[str, object]]:
        """Per slave (``names``): walk time, oscillator drift, learned correction, |0x092C|, last SYNC0 pulse.

        ``last_sync0``: (system time, segment time at which it really fired),
        what tests and benchmarks compare across slaves; ``None`` before any.
        """
        dc = self
        n = len(names)
        out = []
        last = dc.sync.last_sync0()
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
                "sync0_pulses": int(dc.sync.pulses[s]),
                "last_sync0": None if pulse is None else [pulse[0], pulse[1]],
            })
        return out

