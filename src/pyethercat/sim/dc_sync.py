"""The cyclic unit (SYNC0/SYNC1) and the latch unit of the simulated DC slaves.

The clocks these units read are :class:`pyethercat.sim.dc.DcClocks` (which
holds a :class:`SyncUnits` as ``sync`` and passes the register writes on);
as there, all slaves' state lives in arrays indexed by slave. The registers
follow the ESC datasheet section I, "Distributed Clocks":

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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
import numpy.typing as npt

from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.wire import registers as R
from pyethercat.wire.dc import sync1_period

__all__ = ["SyncUnits", "SyncClock", "TICK_NS", "RECORDED_PULSES", "grown"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
#: The local clock counts in steps of 10 ns (the receive times in the corpus
#: captures are all multiples of 10); the pulse length 0x0982 counts in them too.
TICK_NS = 10
#: SYNC0 pulses kept per slave (true time and system time), for spread measurements.
RECORDED_PULSES = 64
_U64 = 1 << 64
# The AL event request byte with the SYNC0/SYNC1 events (both lie in it) and their bits there.
_EV_BYTE = (int(R.AlEvent.SYNC0).bit_length() - 1) // 8
_SYNC0_EV, _SYNC1_EV = int(R.AlEvent.SYNC0) >> (8 * _EV_BYTE), int(R.AlEvent.SYNC1) >> (8 * _EV_BYTE)
assert _SYNC0_EV < 0x100 and 0 < _SYNC1_EV < 0x100
_OFFSET_LO, _OFFSET_HI = R.DC_SYSTEM_TIME_OFFSET, R.DC_SYSTEM_TIME_OFFSET + 8
#: Share of the shortest possible time to the next pulse that run_sync may skip unchecked.
_QUIET_SHARE = 0.95


def grown(arr: npt.NDArray[np.generic], size: int, fill: object) -> npt.NDArray[np.generic]:
    """``arr`` with room for ``size`` entries (capacity doubles; new entries ``fill``)."""
    if size <= arr.shape[0]:
        return arr
    shape = (max(size, 2 * arr.shape[0], 4),) + arr.shape[1:]
    out = np.full(shape, fill, arr.dtype)
    out[: arr.shape[0]] = arr
    return out


class SyncClock(Protocol):
    """What the units read of the clocks (:class:`pyethercat.sim.dc.DcClocks`)."""

    @property
    def wide(self) -> npt.NDArray[np.bool_]:
        """Per slave: a 64-bit system time."""
        ...

    def pass_time(self, slaves: I64) -> I64:
        """Segment time at which the current frame passes the processing unit of ``slaves``."""
        ...

    def system_time(self, slaves: I64, t_ns: I64 | int) -> I64:
        """System time of ``slaves`` at segment time ``t_ns``."""
        ...

    def true_time(self, slaves: I64, sys_times: npt.NDArray[np.uint64]) -> F64:
        """Segment time at which the registers of ``slaves`` show the system time ``sys_times``."""
        ...

    def max_rate(self, slaves: I64) -> F64:
        """Upper bound of the local clock speed of ``slaves`` until :meth:`SyncUnits.clock_changed`."""
        ...


class SyncUnits:
    """SYNC0/SYNC1 pulses, their status and record, and the latch inputs of all slaves.

    See the module docstring.
    """

    def __init__(self, memory: EscMemory, escs: Sequence[Esc], clock: SyncClock) -> None:
        self.memory = memory
        self.escs = escs
        self.clock = clock
        self.n = 0
        # cyclic unit
        self.next0 = np.zeros(0, np.uint64)     # system time of the next SYNC0 pulse
        self.cycle0: I64 = np.zeros(0, np.int64)
        self.cycle1: I64 = np.zeros(0, np.int64)
        self.sync0_on = np.zeros(0, bool)
        self.sync1_on = np.zeros(0, bool)
        self._ev = np.zeros(0, np.uint8)        # their AL event bits (in byte _EV_BYTE)
        self.pulses = np.zeros(0, np.int64)     # SYNC0 pulses fired so far
        # SYNC status (0x098E/0x098F): the last pulse (system time, 0: none since the
        # unit was configured), ``pulses`` when it was configured, and the pulses the
        # PDI acknowledged by reading the status (SYNC0: a ``pulses`` value; SYNC1: a
        # count since the configuration)
        self.last0 = np.zeros(0, np.uint64)
        self.cfg_pulses = np.zeros(0, np.int64)
        self.ack0 = np.zeros(0, np.int64)
        self.ack1 = np.zeros(0, np.int64)
        self._ones: I64 = np.ones(0, np.int64)  # (a pulse each: the counts of a usual tick)
        #: Recorded SYNC0 pulses: ring of (system time, true segment time) per slave.
        self.rec_sys = np.zeros((0, RECORDED_PULSES), np.uint64)
        self.rec_true = np.zeros((0, RECORDED_PULSES), np.float64)
        #: Slaves with a planned pulse (index -> 1): the segment only ticks the unit then.
        self.sync_next: dict[int, int] = {}
        self._active: I64 | None = np.zeros(0, np.int64)
        #: Per slave: its application (per pulse) or its device model wants to hear pulses.
        self.app_listens = np.zeros(0, bool)
        self.model_listens = np.zeros(0, bool)
        self._model_only = np.zeros(0, bool)    # model_listens and not app_listens
        self._any_listener = False
        self._any_app = False
        #: run_sync need not look before this segment time (and not after its last look):
        #: (from, until, slaves, their offsets 0x0920 as bytes); None: look.
        self._quiet: tuple[int, int, I64, bytes] | None = None
        self._gen = 0  # counts clock_changed (a run_sync that saw one leaves _quiet None)
        self._speed: tuple[int, I64 | None, F64] = (-1, None, np.zeros(0))  # (gen, keys, max_rate)
        #: Receives each SYNC0 pulse (slave, system time) of a slave whose application
        #: listens; None: the slave's application is called directly.
        self.sync0_sink: Callable[[int, int], None] | None = None
        #: Receives the SYNC0 pulses of one tick of all slaves only their device model
        #: listens to, as arrays (slaves, system time of each one's first pulse): no
        #: Python per slave. None: they go through :attr:`sync0_sink` too.
        self.sync0_models: Callable[[I64, npt.NDArray[np.uint64]], None] | None = None

    def add_slave(self, index: int) -> None:
        """Room for slave ``index`` (its ESC in ``escs``): no pulses, listening as its application does."""
        n = index + 1
        for name, fill in (("next0", 0), ("cycle0", 0), ("cycle1", 0),
                           ("sync0_on", False), ("sync1_on", False), ("pulses", 0),
                           ("last0", 0), ("cfg_pulses", 0), ("ack0", 0), ("ack1", 0),
                           ("rec_sys", 0), ("rec_true", np.nan), ("app_listens", False),
                           ("model_listens", False), ("_model_only", False), ("_ev", 0)):
            setattr(self, name, grown(getattr(self, name), n, fill))
        self.n = max(self.n, n)
        app = self.escs[index].app
        self.app_listens[index] = app is not None and (
            type(app).on_sync0 is not _base_hook("on_sync0")
            or type(app).on_sync1 is not _base_hook("on_sync1"))
        self.model_listens[index] = False
        self._listeners_changed()
        self.clock_changed()

    def listen(self, index: int) -> None:
        """``index`` wants its pulses (its device model takes SYNC0 events)."""
        self.model_listens[index] = True
        self._listeners_changed()

    def _listeners_changed(self) -> None:
        self._any_app = bool(self.app_listens.any())
        self._any_listener = self._any_app or bool(self.model_listens.any())
        np.logical_and(self.model_listens, ~self.app_listens, out=self._model_only)

    def clock_changed(self) -> None:
        """A clock of some slave jumped, changed its oscillator, or pulses were (re)planned:
        :meth:`run_sync` looks again at its next call."""
        self._quiet = None
        self._gen += 1

    def reset(self, index: int) -> None:
        """Power-on of one slave: no pulses planned, the status reads 0."""
        self.cfg_pulses[index] = self.pulses[index]  # no pulse since: the status reads 0
        self.sync_drop(index)

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
        if not self.clock.wide[index]:
            start &= 0xFFFF_FFFF
        idx = np.array([index], np.int64)
        now = int(self.clock.system_time(idx, self.clock.pass_time(idx))[0]) % _U64
        # a start time already passed is never reached: the unit stays pending
        self.next0[index] = start if start >= now else _U64 - 1
        self.cycle0[index] = esc.u32(R.DC_SYNC0_CYCLE)
        self.cycle1[index] = esc.u32(R.DC_SYNC1_CYCLE)
        self.sync0_on[index], self.sync1_on[index] = on0, on1
        self._ev[index] = (_SYNC0_EV if on0 else 0) | (_SYNC1_EV if on1 else 0)
        self.last0[index] = 0
        self.cfg_pulses[index] = self.ack0[index] = self.pulses[index]
        self.ack1[index] = 0
        esc.row[R.DC_SYNC0_STATUS] = esc.row[R.DC_SYNC1_STATUS] = 0
        pending = (R.DcActivationStatus.SYNC0_PENDING if on0 else 0) | (
            R.DcActivationStatus.SYNC1_PENDING if on1 else 0)
        esc.row[R.DC_ACTIVATION_STATUS] = int(pending)
        self.sync_next[index] = 1
        self._active = None
        self.clock_changed()

    def sync_drop(self, index: int) -> None:
        """No SYNC pulses planned for ``index`` any more."""
        if self.sync_next.pop(index, None) is not None:
            self._active = None
            self.clock_changed()

    def run_sync(self, now: int) -> None:
        """Fire the SYNC0/SYNC1 pulses due by segment time ``now``.

        One array operation over every slave with planned pulses; Python runs
        per slave only for applications that listen to pulses. Each look also
        works out a segment time before which no pulse can be due (the clocks
        run no faster than ``max_rate``); until then, and while no clock
        changed (:meth:`clock_changed`) and no offset 0x0920 was written,
        calls return at once.
        """
        quiet = self._quiet
        if quiet is not None and quiet[0] <= now < quiet[1] and (
                self.memory.mem[quiet[2], _OFFSET_LO:_OFFSET_HI].tobytes() == quiet[3]):
            # No pulse can be due yet: the clocks run no faster than max_rate, and
            # nothing changed them or the plans since the last look (an offset 0x0920
            # written by any path shows in the memory compared here).
            return
        self._quiet = None
        gen = self._gen
        keys = self._active
        if keys is None:
            keys = self._active = np.fromiter(self.sync_next, np.int64, len(self.sync_next))
        if not len(keys):
            return
        clock = self.clock
        sys_now = clock.system_time(keys, now).view(np.uint64)
        due = self.next0[keys]
        hit = sys_now >= due
        fired = np.count_nonzero(hit)
        if fired:
            self._fire(keys, sys_now, due, hit, fired == len(keys))
            if gen != self._gen or self._active is not keys:
                return
            due = self.next0[keys]
            if (due < sys_now).any():  # (a next pulse past 2^64 wrapped round)
                return
        # The earliest segment time at which a next pulse could be due: each system
        # time must still advance by next0 - its value now, less up to a tick lost
        # to rounding (two, to be safe), at no more than max_rate.
        ahead = (due - sys_now).astype(np.float64) - 2 * TICK_NS
        speed = self._speed
        if speed[0] != gen or speed[1] is not keys:
            speed = self._speed = (gen, keys, clock.max_rate(keys))
        lead = float((ahead / speed[2]).min()) * _QUIET_SHARE
        if lead >= 1.0:
            t = int(now)
            self._quiet = (t, t + int(min(lead, 2.0**62)), keys,
                           self.memory.mem[keys, _OFFSET_LO:_OFFSET_HI].tobytes())

    def _fire(self, keys: I64, sys_now: npt.NDArray[np.uint64], due: npt.NDArray[np.uint64],
              hit: npt.NDArray[np.bool_], every: bool) -> None:
        """The pulses of the ``hit`` slaves among ``keys`` are due (``every``: all of them)."""
        if every:
            slaves, first, at_now = keys, due, sys_now
        else:
            slaves, first, at_now = keys[hit], due[hit], sys_now[hit]
        cycle = self.cycle0[slaves]
        gap = at_now - first
        step = cycle.astype(np.uint64)
        before = self.pulses[slaves]
        # record each pulse with the time it really fired (one pass per pulse
        # index, not per slave: usually a single one per tick)
        if (gap < step).all():
            # one pulse each, all cyclic (the usual tick)
            if len(self._ones) < len(slaves):
                self._ones = np.ones(2 * len(slaves), np.int64)
            count: I64 = self._ones[: len(slaves)]  # (read only)
            last = first
            cyclic = None
            slot = before % RECORDED_PULSES
            self.rec_sys[slaves, slot] = first
            self.rec_true[slaves, slot] = self.clock.true_time(slaves, first)
            many = 0
        else:
            cyclic = cycle > 0
            behind = gap.astype(np.int64)
            count = np.where(cyclic, behind // np.maximum(cycle, 1) + 1, 1)
            last = first + ((count - 1) * cycle).astype(np.uint64)
            many = min(int(count.max()), RECORDED_PULSES)
        for j in range(many):
            m = count > j
            sel = slaves[m]
            at = first[m] + np.uint64(j) * step[m]
            slot = (before[m] + j) % RECORDED_PULSES
            self.rec_sys[sel, slot] = at
            self.rec_true[sel, slot] = self.clock.true_time(sel, at)
        self.pulses[slaves] = before + count
        self.last0[slaves] = last
        self.next0[slaves] = last + step if cyclic is None else np.where(
            cyclic, last + step, np.uint64(_U64 - 1))
        mem = self.memory.mem
        on0 = self.sync0_on[slaves]
        # (the status registers are worked out when they are read: refresh_sync_status)
        mem[slaves[on0], R.DC_SYNC0_STATUS] = R.DC_SYNC_STATUS_PULSE
        mem[slaves, R.DC_ACTIVATION_STATUS] = 0
        mem[slaves, R.AL_EVENT_REQUEST + _EV_BYTE] |= self._ev[slaves]
        if cyclic is not None and not cyclic.all():
            for s in slaves[~cyclic].tolist():
                self.sync_drop(s)
        if self._any_listener:
            self._notify(slaves, first, count, before, on0)

    def _notify(self, slaves: I64, first: npt.NDArray[np.uint64], count: I64, before: I64,
                on0: npt.NDArray[np.bool_]) -> None:
        """Listeners hear the pulses: device models alone all at once, applications each
        pulse (at most 16 per slave and tick). ``on0``: the slaves' SYNC0 is on."""
        models = self.sync0_models
        if models is not None:
            on = self._model_only[slaves] & on0
            n_on = np.count_nonzero(on)
            if n_on == len(slaves):
                models(slaves, first)
            elif n_on:
                models(slaves[on], first[on])
            if not self._any_app:
                return
            per_pulse = self.app_listens[slaves]
        else:
            per_pulse = self.app_listens[slaves] | self.model_listens[slaves]
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
            t = int(self.clock.pass_time(idx)[0]) if pdi_ns is None else pdi_ns
            wrap = _U64 if self.clock.wide[index] else 1 << 32
            now = int(self.clock.system_time(idx, t)[0]) % wrap
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
        st = int(self.clock.system_time(idx, t_ns)[0])
        base = (R.DC_LATCH0_POSITIVE, R.DC_LATCH0_NEGATIVE, R.DC_LATCH1_POSITIVE,
                R.DC_LATCH1_NEGATIVE)[2 * unit + (0 if rising else 1)]
        esc.row[base: base + 8] = np.frombuffer((st % _U64).to_bytes(8, "little"), np.uint8)
        esc.row[status_addr] = (status & ~R.DcLatchStatus.PIN_STATE) | bit | pin

    def latch_control_written(self, index: int, unit: int) -> None:
        """0x09A8/0x09A9 written: the stored events of that unit are cleared."""
        esc = self.escs[index]
        esc.row[R.DC_LATCH0_STATUS + unit] &= R.DcLatchStatus.PIN_STATE


def _base_hook(name: str) -> object:
    from pyethercat.sim.device import DeviceApp

    return getattr(DeviceApp, name)
