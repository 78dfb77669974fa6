"""CiA 402 drives over a running master: device control, modes, set-point streaming, moves, homing.

A :class:`DriveGroup` works on the process image of the drives it holds
(their controlword 0x6040 and statusword 0x6041 must be mapped; targets,
actual values, modes and 0x603F are used when mapped, else reached by SDO
where that makes sense). Its cyclic part, :meth:`DriveGroup.on_cycle`, runs
in the master's cycle (it chains itself to the runner's callback) and does a
fixed number of numpy operations for any number of drives:

- the statusword of every drive in one gather, decoded with the standard's
  masks (``wire.cia402.decode_states``);
- the controlword that takes each drive one transition towards its goal
  (Switch on disabled, Ready to switch on, Switched on, Operation enabled,
  Quick stop), the fault reset as a rising edge of bit 7;
- the mode-specific handshakes (profile position: new set-point, acknowledge;
  homing: start, attained) as bit arrays;
- set-point streaming: one row of a trajectory per cycle into the targets of
  all drives (one scatter), the actual values recorded (one gather);
- while a drive is not enabled its position target follows its actual
  position, so enabling in CSP does not jump.

The blocking methods (:meth:`DriveGroup.enable`, :meth:`~DriveGroup.set_mode`,
:meth:`~DriveGroup.move_to`, :meth:`~DriveGroup.home`, :meth:`~DriveGroup.follow`
...) wait for cycles: with the runner's thread running (``master.start``)
they wait for its exchanges; with a runner that is not running (virtual time
in tests, a single-threaded tool) they run its cycles themselves. Time-outs
count cycles, so they mean the same in both. A drive that faults meanwhile
raises :class:`~pyethercat.errors.DriveFaultError` with its error code; every
fault and every emergency of a group's drives is also a typed event
(:class:`DriveFault`, :class:`DriveEmergency`) in :attr:`DriveGroup.events`.

    with Master.open(iface="eth1") as m:
        m.scan(); m.configure()
        m.dc.setup(); m.dc.configure_sync(1_000_000)
        m.start(cycle=0.001, dc="master")
        axes = DriveGroup(m)                       # every slave with 0x6040/0x6041 mapped
        axes.set_mode("csp"); axes.enable()
        axes.follow(s_curve(axes.positions(), [100_000, -50_000], 4e5, 4e6, 8e7, 0.001))
"""

from __future__ import annotations

import functools
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from pyethercat.errors import (
    ConfigError,
    DriveError,
    DriveFaultError,
    DriveTimeoutError,
    EtherCATError,
)
from pyethercat.master.image import ProcessImage, Variable
from pyethercat.trajectory import Trajectory
from pyethercat.wire.cia402 import DriveState, OperationMode, decode_states, parse_mode
from pyethercat.wire.mailbox.coe import emergency_error_name
from pyethercat.wire.mailbox.objects import Cia402Object, StandardObject

if TYPE_CHECKING:
    from pyethercat.master.coe import EmergencyEvent
    from pyethercat.master.config import ProcessDataConfig
    from pyethercat.master.cyclic import Cycle, CyclicRunner
    from pyethercat.master.mailboxes import MailboxService
    from pyethercat.master.slave import Slave

__all__ = ["Drive", "DriveEmergency", "DriveErrorRecord", "DriveEvent", "DriveFault", "DriveGroup",
           "DriveMaster", "MotionRecord", "read_error_history"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]
_O = Cia402Object
S = DriveState
OM = OperationMode

# Controlword that moves a drive one transition towards a goal: [state + 1, goal + 1];
# -1 keeps the last one. Goals: -1 none, 1 switch on disabled, 2 ready, 3 switched on,
# 4 operation enabled, 5 quick stop. (A fault is reset by the edge logic, not the table.)
_CW = np.full((9, 7), 0, np.int64)
_CW[:, 0] = -1
for _st, _row in {
        S.SWITCH_ON_DISABLED: (0x00, 0x06, 0x06, 0x06, 0x02),
        S.READY_TO_SWITCH_ON: (0x00, 0x06, 0x07, 0x07, 0x02),
        S.SWITCHED_ON: (0x00, 0x06, 0x07, 0x0F, 0x02),
        S.OPERATION_ENABLED: (0x00, 0x06, 0x07, 0x0F, 0x02),
        S.QUICK_STOP_ACTIVE: (0x00, 0x00, 0x00, 0x0F, 0x02)}.items():
    _CW[int(_st) + 1, 2:] = _row
_DEVICE_BITS = 0x008F
_NO_GOAL = -1
_GOAL_QUICK_STOP = 5
# profile position / homing handshake phases
_IDLE, _SEND, _ACKED, _DONE, _FAILED = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class DriveFault:
    """A drive went to Fault (seen in its statusword)."""

    position: int
    code: int | None
    """0x603F when mapped, else the code of the drive's last emergency (None: unknown yet)."""
    text: str


@dataclass(frozen=True)
class DriveEmergency:
    """An emergency a drive sent."""

    position: int
    code: int
    register: int
    data: bytes
    text: str


DriveEvent = DriveFault | DriveEmergency


@dataclass(frozen=True)
class DriveErrorRecord:
    """One entry of a drive's error history 0x1003 (newest first)."""

    code: int
    info: int
    text: str


@dataclass
class MotionRecord:
    """What a streamed move did, one row per cycle: (cycles, drives) arrays."""

    commanded: I64
    actual: I64
    following_error: I64 | None
    statusword: I64
    cycle_s: float

    @property
    def t(self) -> F64:
        out: F64 = np.arange(len(self.commanded), dtype=np.float64) * self.cycle_s
        return out


class _Column:
    """One PDO entry of every drive as a numpy column of the image (strided view or fancy index)."""

    def __init__(self, buffer: bytearray | memoryview, variables: Sequence[Variable], dtype: str) -> None:
        size = np.dtype(dtype).itemsize
        offsets = []
        for v in variables:
            if v.bit_offset % 8 or v.bit_length != 8 * size:
                raise ConfigError(f"{v.name}: {v.bit_length} bits at bit {v.bit_offset} is not a "
                                  f"byte-aligned {8 * size}-bit entry")
            offsets.append(v.bit_offset // 8)
        self.dtype = np.dtype(dtype)
        self._raw = np.frombuffer(buffer, np.uint8)
        off = np.array(offsets, np.int64)
        steps = np.diff(off)
        self._view: npt.NDArray[Any] | None = None
        if len(off) == 1 or (len(set(steps.tolist())) == 1 and steps[0] >= size):
            stride = int(steps[0]) if len(off) > 1 else size
            self._view = np.ndarray((len(off),), self.dtype, buffer=buffer, offset=int(off[0]),
                                    strides=(stride,))
        self._idx = off[:, None] + np.arange(size)

    @classmethod
    def of(cls, buffer: bytearray | memoryview, slaves: Sequence[Slave], key: Cia402Object,
           out: bool, dtype: str, need: bool = False) -> _Column | None:
        """Entry ``key`` of the slaves' outputs (``out``) or inputs as a column; None when a
        slave does not map it (with ``need``, a :class:`ConfigError` naming the slave)."""
        io = [(s.outputs if out else s.inputs) for s in slaves]
        if not all(_has(x, key) for x in io):
            if need:
                missing = [s.position for s, x in zip(slaves, io, strict=True) if not _has(x, key)]
                raise ConfigError(f"slave {missing[0]} does not map 0x{int(key):04X} "
                                  f"({key.name.lower()}) into its {'outputs' if out else 'inputs'}")
            return None
        return cls(buffer, [x.variable((int(key), 0)) for x in io], dtype)

    def get(self) -> I64:
        if self._view is not None:
            out: I64 = self._view.astype(np.int64)
            return out
        raw: I64 = self._raw[self._idx].copy().view(self.dtype)[:, 0].astype(np.int64)
        return raw

    def set(self, values: npt.ArrayLike, mask: B | None = None) -> None:
        vals = np.asarray(values)
        if self._view is not None:
            if mask is None:
                self._view[:] = vals
            else:
                self._view[mask] = vals if vals.ndim == 0 else vals[mask]
            return
        cur = self.get()
        new = np.where(mask, vals, cur) if mask is not None else np.broadcast_to(vals, cur.shape)
        self._raw[self._idx] = np.asarray(new).astype(self.dtype).view(np.uint8).reshape(
            len(cur), self.dtype.itemsize)


class _Chain:
    """The runner's callback: the group's cycle first, then whatever was there before."""

    def __init__(self, group: DriveGroup, before: Callable[[Cycle], None] | None) -> None:
        self.group = group
        self.before = before

    def __call__(self, cycle: Cycle) -> None:
        self.group.on_cycle(cycle)
        if self.before is not None:
            self.before(cycle)


class _Handshakes:
    """The controlword bit-4 handshakes of two modes, per drive: profile position (bit 4
    until the set-point is acknowledged, then target reached) and homing (bit 4 until
    homing attained or a homing error)."""

    def __init__(self, n: int, bits: I64) -> None:
        #: The mode-specific controlword bits 4-6, 8, 9 of every drive.
        self.bits = bits
        self.pp = np.zeros(n, np.int64)
        self.hm = np.zeros(n, np.int64)
        #: Exchanges that carried the homing start bit so far.
        self.hm_sent = np.zeros(n, np.int64)

    def on_statusword(self, sw: I64) -> None:
        """Advance the handshakes with the statuswords of the last exchange."""
        pp, hm = self.pp, self.hm
        if pp.any():
            ack = (sw & 0x1000) != 0
            acked = (pp == _SEND) & ack
            pp[acked] = _ACKED
            done = (pp == _ACKED) & ~ack & ((sw & 0x0400) != 0)
            pp[done] = _DONE
            self.bits = np.where(pp == _SEND, self.bits | 0x10, self.bits & ~0x10)
        if hm.any():
            # A drive homed before still shows "homing attained" (bits 12 and 10) and one
            # that failed "homing error" (bit 13) until it sees the new start, and a method
            # without motion (35, 37) may finish in the cycle it starts, so no statusword
            # shows it running. Count statuswords only from the exchange after the first
            # one that carried bit 4: the inputs of that one were latched before the drive
            # read its outputs.
            seen = (hm == _SEND) & (self.hm_sent >= 2)
            attained = seen & ((sw & 0x1000) != 0) & ((sw & 0x0400) != 0)
            failed = seen & ((sw & 0x2000) != 0)
            hm[attained] = _DONE
            hm[failed] = _FAILED
            self.bits = np.where(hm == _SEND, self.bits | 0x10,
                                 np.where(hm > _SEND, self.bits & ~0x10, self.bits))

    def sent(self, out: I64) -> None:
        """The controlwords ``out`` go out with the next exchange."""
        if self.hm.any():
            self.hm_sent += (self.hm == _SEND) & ((out & 0x10) != 0)

    def fail(self, i: int) -> None:
        """Drive ``i`` went to Fault: a handshake under way failed."""
        self.pp[i] = _FAILED if self.pp[i] in (_SEND, _ACKED) else self.pp[i]
        self.hm[i] = _FAILED if self.hm[i] == _SEND else self.hm[i]


class DriveMaster(Protocol):
    """What a drive group needs of a master (:class:`~pyethercat.master.master.Master` is one)."""

    slaves: list[Slave]
    mailboxes: MailboxService

    @property
    def process_data(self) -> ProcessDataConfig | None: ...
    @property
    def images(self) -> dict[str, ProcessImage]: ...
    @property
    def runner(self) -> CyclicRunner | None: ...
    def poll_mailboxes(self) -> int: ...
    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None: ...


class DriveGroup:
    """CiA 402 drives of one master, driven together (see the module docstring).

    ``positions``: ring positions of the drives (default: every slave with a
    mapped controlword and statusword). All must be in one process-data group.
    ``runner``: the cyclic runner to work with when it is not the master's own
    (one built by hand, e.g. on virtual time).
    """

    def __init__(self, master: DriveMaster, positions: Sequence[int] | None = None, *,
                 runner: CyclicRunner | None = None) -> None:
        self.master = master
        #: The runner to step (default: the master's, :meth:`Master.start`).
        self.runner = runner
        if master.process_data is None:
            raise ConfigError("the master has no process-data configuration: configure() first")
        if positions is None:
            positions = [s.position for s in master.slaves if _has(s.outputs, _O.CONTROLWORD)
                         and _has(s.inputs, _O.STATUSWORD)]
            if not positions:
                raise ConfigError("no slave maps a controlword 0x6040 and statusword 0x6041")
        self.positions = [int(p) for p in positions]
        slaves = [master.slaves[p] for p in self.positions]
        self.image = _image_of(master, self.positions)
        column = functools.partial(_Column.of, self.image.buffer, slaves)
        self._cw = column(_O.CONTROLWORD, True, "<u2", need=True)
        self._sw = column(_O.STATUSWORD, False, "<u2", need=True)
        self._mode = column(_O.MODES_OF_OPERATION, True, "i1")
        self._mode_disp = column(_O.MODES_OF_OPERATION_DISPLAY, False, "i1")
        self._target = column(_O.TARGET_POSITION, True, "<i4")
        self._target_v = column(_O.TARGET_VELOCITY, True, "<i4")
        self._target_t = column(_O.TARGET_TORQUE, True, "<i2")
        self._pos = column(_O.POSITION_ACTUAL_VALUE, False, "<i4")
        self._vel = column(_O.VELOCITY_ACTUAL_VALUE, False, "<i4")
        self._torque = column(_O.TORQUE_ACTUAL_VALUE, False, "<i2")
        self._fe = column(_O.FOLLOWING_ERROR_ACTUAL_VALUE, False, "<i4")
        self._err = column(_O.ERROR_CODE, False, "<u2")
        n = len(self.positions)
        # what the image shows now (a group made on a running master knows its drives at once)
        self._state = decode_states(self._sw.get()).astype(np.int64)  # type: ignore[union-attr]
        #: In Fault or Fault reaction active; a fault reset was asked for.
        self._bad = (self._state == S.FAULT) | (self._state == S.FAULT_REACTION_ACTIVE)
        self._reset = np.zeros(n, bool)
        self._goal = np.full(n, _NO_GOAL, np.int64)
        # the controlword the image holds goes on unchanged until the group is asked to act
        cw = self._cw.get()  # type: ignore[union-attr]
        self._dc = cw & _DEVICE_BITS              # device-control part of the controlword
        self._hs = _Handshakes(n, cw & ~_DEVICE_BITS & 0xFFFF)
        self._prev = cw
        self._stream: tuple[I64, _Column, MotionRecord | None] | None = None
        self._row = 0
        self._last_emcy: dict[int, int] = {}
        #: Faults and emergencies of the group's drives, newest last (the oldest drop off).
        self.events: deque[DriveEvent] = deque(maxlen=1024)
        self._callbacks: list[Callable[[DriveEvent], None]] = []
        self._lock = threading.Lock()
        self._runner: CyclicRunner | None = None
        master.on_emergency(self._on_emergency)

    def __len__(self) -> int:
        return len(self.positions)

    def drive(self, index: int) -> Drive:
        """The ``index``-th drive of the group as a :class:`Drive`."""
        return Drive(self, index)

    # --- events ----------------------------------------------------------------------------

    def on_event(self, callback: Callable[[DriveEvent], None]) -> None:
        """Call ``callback(event)`` for every fault and emergency of the group's drives."""
        self._callbacks.append(callback)

    def _emit(self, event: DriveEvent) -> None:
        self.events.append(event)
        for cb in list(self._callbacks):
            cb(event)

    def _on_emergency(self, event: EmergencyEvent) -> None:
        if event.position not in self.positions:
            return
        e = event.emergency
        if e.error_code:
            self._last_emcy[event.position] = e.error_code
        self._emit(DriveEmergency(event.position, e.error_code, e.error_register, e.data,
                                  emergency_error_name(e.error_code)))

    # --- the cycle -----------------------------------------------------------------------------

    def attach(self, runner: CyclicRunner | None = None) -> DriveGroup:
        """Run :meth:`on_cycle` in ``runner``'s cycle (default: the master's runner)."""
        runner = runner or self._current()
        cb = runner.callback
        if not (isinstance(cb, _Chain) and cb.group is self):
            runner.callback = _Chain(self, cb)
        self._runner = runner
        return self

    def detach(self) -> None:
        """Take :meth:`on_cycle` out of the runner's cycle again."""
        runner = self._runner
        if runner is not None and isinstance(runner.callback, _Chain) and runner.callback.group is self:
            runner.callback = runner.callback.before
        self._runner = None

    def on_cycle(self, cycle: Cycle | None = None) -> None:
        """The cyclic part (see the module docstring); called by the runner after each exchange."""
        sw = self._sw.get()  # type: ignore[union-attr]
        st = decode_states(sw).astype(np.int64)
        bad = (st == S.FAULT) | (st == S.FAULT_REACTION_ACTIVE)
        new_fault = bad & ~self._bad
        self._bad = bad
        self._state = st
        if new_fault.any():
            self._faulted(np.nonzero(new_fault)[0])
        self._reset &= bad
        goal = self._goal
        dc = _CW[st + 1, goal + 1]
        dc = np.where(dc < 0, self._dc, dc)
        reset = (st == S.FAULT) & self._reset
        dc = np.where(reset, np.where(self._prev & 0x80, 0, 0x80), dc)
        self._dc = dc
        self._hs.on_statusword(sw)
        out = (dc & _DEVICE_BITS) | self._hs.bits
        stream = self._stream
        if stream is not None:
            values, col, rec = stream
            k = self._row
            if k < len(values):
                col.set(values[k])
                if rec is not None:
                    rec.commanded[k] = values[k]
                    rec.statusword[k] = sw
                    if self._pos is not None:
                        rec.actual[k] = self._pos.get()
                    if rec.following_error is not None and self._fe is not None:
                        rec.following_error[k] = self._fe.get()
                self._row = k + 1
        elif self._target is not None and self._pos is not None:
            idle = st != S.OPERATION_ENABLED
            if idle.any():
                self._target.set(self._pos.get(), idle)
        self._cw.set(out & 0xFFFF)  # type: ignore[union-attr]
        self._prev = out
        self._hs.sent(out)

    def _faulted(self, idx: I64) -> None:
        """Drives that went to Fault: no goal any more (nothing re-enables them), an event."""
        codes = self._err.get() if self._err is not None else None
        for i in idx.tolist():
            self._goal[i] = _NO_GOAL
            self._hs.fail(i)
            pos = self.positions[i]
            code = int(codes[i]) if codes is not None and codes[i] else self._last_emcy.get(pos)
            text = emergency_error_name(code) if code else "fault"
            self._emit(DriveFault(pos, code, text))

    # --- stepping and waiting ---------------------------------------------------------------

    def _current(self) -> CyclicRunner:
        runner = self.runner or self.master.runner
        if runner is None:
            raise DriveError("no cyclic exchange: start it first (master.start(...))")
        return runner

    @property
    def cycle_s(self) -> float:
        """The runner's cycle time (s)."""
        return self._current().period_ns * 1e-9

    def step(self, cycles: int = 1) -> None:
        """Let ``cycles`` cycles pass (wait for the runner's thread, or run them)."""
        runner = self._current()
        if self._runner is not runner:
            self.attach(runner)
        if runner.running:
            if not runner.wait_exchanges(self.image.name, cycles, timeout=cycles * self.cycle_s * 20 + 2):
                raise DriveError("the cyclic exchange stopped (or does not keep up)")
        else:
            runner.run(cycles=cycles)
        if self._err is None or self._bad.any():  # emergencies: the code, a fault's events
            self.master.mailboxes.poll([self.master.slaves[p] for p in self.positions])

    def _wait(self, done: Callable[[], bool], timeout: float, what: str, sel: B,
              expect_fault: bool = False) -> None:
        """Step until ``done()``; a fault of a selected drive or the time-out raises."""
        cycles = max(1, int(round(timeout / self.cycle_s)))
        chunk = max(1, min(10, cycles // 20 or 1))
        waited = 0
        while not done():
            if not expect_fault:
                bad = sel & self._bad
                if bad.any():
                    i = int(np.nonzero(bad)[0][0])
                    self._raise_fault(i, what)
            if waited >= cycles:
                i = int(np.nonzero(sel)[0][0])
                raise DriveTimeoutError(f"{self._name(i)}: {what} not done within {timeout:g} s "
                                        f"({self._describe(i)})")
            self.step(chunk)
            waited += chunk

    def _raise_fault(self, i: int, what: str) -> None:
        code = self._code(i)
        text = f" 0x{code:04X} ({emergency_error_name(code)})" if code else ""
        raise DriveFaultError(f"{self._name(i)}: fault{text} while {what}", code)

    def _code(self, i: int) -> int | None:
        if self._err is not None:
            value = int(self._err.get()[i])
            if value:
                return value
        self.master.poll_mailboxes()
        code = self._last_emcy.get(self.positions[i])
        if code is None:
            try:
                code = int(self.master.slaves[self.positions[i]].sdo_read(int(_O.ERROR_CODE), 0, "uint16"))
            except EtherCATError:
                return None
        return code or None

    def _name(self, i: int) -> str:
        return f"drive {self.positions[i]}"

    def _describe(self, i: int) -> str:
        sw = int(self._sw.get()[i])  # type: ignore[union-attr]
        st = self._state[i]
        label = DriveState(int(st)).label if st >= 0 else "undefined state"
        return f"{label}, statusword 0x{sw:04X}"

    def _select(self, drives: Sequence[int] | None) -> B:
        return _selection(len(self.positions), drives)

    # --- reading ----------------------------------------------------------------------------

    def statuswords(self) -> I64:
        """Statusword of every drive (as the last cycle read it)."""
        return self._sw.get()  # type: ignore[union-attr]

    def states(self) -> list[DriveState | None]:
        """Decoded state of every drive (None: a pattern the standard does not define)."""
        return [DriveState(int(s)) if s >= 0 else None for s in decode_states(self.statuswords())]

    def positions_actual(self) -> I64:
        """Position actual value 0x6064 of every drive."""
        return self._need(self._pos, "position actual value 0x6064").get()

    def velocities(self) -> I64:
        return self._need(self._vel, "velocity actual value 0x606C").get()

    def torques(self) -> I64:
        return self._need(self._torque, "torque actual value 0x6077").get()

    def following_errors(self) -> I64:
        return self._need(self._fe, "following error actual value 0x60F4").get()

    def modes(self) -> list[OperationMode | int]:
        """Mode display 0x6061 of every drive (PDO, else SDO)."""
        if self._mode_disp is not None:
            raw = self._mode_disp.get().tolist()
        else:
            raw = [int(self.master.slaves[p].sdo_read(int(_O.MODES_OF_OPERATION_DISPLAY), 0, "int8"))
                   for p in self.positions]
        out: list[OperationMode | int] = []
        for v in raw:
            try:
                out.append(OperationMode(v))
            except ValueError:
                out.append(v)
        return out

    @staticmethod
    def _need(col: _Column | None, what: str) -> _Column:
        if col is None:
            raise ConfigError(f"the drives do not map the {what} into their PDOs")
        return col

    # --- device control -------------------------------------------------------------------

    def _goal_to(self, goal: int, states: tuple[DriveState, ...], timeout: float, what: str,
                 drives: Sequence[int] | None, expect_fault: bool = False) -> None:
        sel = self._select(drives)
        self._goal[sel] = goal
        wanted = np.array([int(s) for s in states])
        self._wait(lambda: bool(np.isin(self._state[sel], wanted).all()), timeout, what, sel,
                   expect_fault)

    def enable(self, timeout: float = 1.0, drives: Sequence[int] | None = None) -> None:
        """Walk the drives to Operation enabled (0x06, 0x07, 0x0F: one transition per answer)."""
        self._goal_to(int(S.OPERATION_ENABLED), (S.OPERATION_ENABLED,), timeout, "enabling", drives)

    def switch_on(self, timeout: float = 1.0, drives: Sequence[int] | None = None) -> None:
        """To Switched on (power stage on, no motion)."""
        self._goal_to(int(S.SWITCHED_ON), (S.SWITCHED_ON,), timeout, "switching on", drives)

    def shutdown(self, timeout: float = 1.0, drives: Sequence[int] | None = None) -> None:
        """To Ready to switch on (0x06)."""
        self._goal_to(int(S.READY_TO_SWITCH_ON), (S.READY_TO_SWITCH_ON,), timeout, "shutting down",
                      drives)

    def disable(self, timeout: float = 1.0, drives: Sequence[int] | None = None) -> None:
        """To Switch on disabled (disable voltage, 0x00)."""
        self._goal_to(int(S.SWITCH_ON_DISABLED), (S.SWITCH_ON_DISABLED,), timeout, "disabling",
                      drives)

    def quick_stop(self, timeout: float = 2.0, drives: Sequence[int] | None = None) -> None:
        """Quick stop (0x02): waits for Quick stop active (stay options) or Switch on disabled."""
        self._goal_to(_GOAL_QUICK_STOP, (S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED), timeout,
                      "quick stop", drives)

    def fault_reset(self, timeout: float = 1.0, drives: Sequence[int] | None = None) -> None:
        """Reset faults with a rising edge of bit 7; the drives end in Switch on disabled."""
        sel = self._select(drives)
        faulted = sel & self._bad
        self._goal[faulted] = int(S.SWITCH_ON_DISABLED)
        self._reset |= faulted
        self._wait(lambda: not bool((sel & self._bad).any()), timeout, "fault reset", sel,
                   expect_fault=True)

    # --- modes --------------------------------------------------------------------------------

    def set_mode(self, mode: OperationMode | int | str, timeout: float = 1.0,
                 drives: Sequence[int] | None = None) -> None:
        """Write 0x6060 (PDO or SDO) and wait until 0x6061 shows it.

        For CSP, CSV and CST the target starts where the axes are first (in the
        PDOs, else by SDO): position actual value, zero velocity, zero torque.
        """
        want = parse_mode(mode) if isinstance(mode, str) else OperationMode(int(mode))
        sel = self._select(drives)
        self._start_targets(want, sel)
        if self._mode is not None:
            self._mode.set(int(want), sel)
        else:
            for i in np.nonzero(sel)[0].tolist():
                self.master.slaves[self.positions[i]].sdo_write(int(_O.MODES_OF_OPERATION), 0,
                                                               int(want), "int8")

        def shown() -> bool:
            modes = self.modes()
            return all(modes[i] == want for i in np.nonzero(sel)[0].tolist())

        self._wait(shown, timeout, f"mode {want.short}", sel)

    def _start_targets(self, want: OperationMode, sel: B) -> None:
        """The cyclic modes' targets start where the axes are, so nothing jumps.

        A drive takes 0x607A/0x60FF/0x6071 as its set-point from the first
        cycle in CSP/CSV/CST (IEC 61800-7-201), whether the object is in the
        PDOs or not: an unmapped one still holds whatever was written last (a
        profile move's target, a position from before homing redefined the
        origin), so it is written by SDO: the position actual value, zero
        velocity, zero torque.
        """
        if want == OM.CYCLIC_SYNC_POSITION:
            col, index, dtype = self._target, _O.TARGET_POSITION, "int32"
        elif want == OM.CYCLIC_SYNC_VELOCITY:
            col, index, dtype = self._target_v, _O.TARGET_VELOCITY, "int32"
        elif want == OM.CYCLIC_SYNC_TORQUE:
            col, index, dtype = self._target_t, _O.TARGET_TORQUE, "int16"
        else:
            return
        idx = np.nonzero(sel)[0].tolist()
        if want == OM.CYCLIC_SYNC_POSITION:
            if self._pos is not None:
                values = self._pos.get()
            else:
                values = np.zeros(len(self), np.int64)
                for i in idx:
                    values[i] = int(self.master.slaves[self.positions[i]].sdo_read(
                        int(_O.POSITION_ACTUAL_VALUE), 0, "int32"))
        else:
            values = np.zeros(len(self), np.int64)
        if col is not None:
            col.set(values, sel)
            return
        for i in idx:
            self.master.slaves[self.positions[i]].sdo_write(int(index), 0, int(values[i]), dtype)

    # --- cyclic synchronous set-points -------------------------------------------------------

    def stream(self, values: npt.ArrayLike, *, kind: str = "position", record: bool = True,
               settle: int = 0) -> MotionRecord | None:
        """Send one row of ``values`` (cycles x drives) per cycle as targets; blocks until done.

        ``kind``: "position" (0x607A, CSP), "velocity" (0x60FF, CSV) or
        "torque" (0x6071, CST). ``settle`` more cycles hold the last row and
        are recorded too. Returns the :class:`MotionRecord` (``record``).
        """
        arr = np.asarray(values)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.shape[1] != len(self.positions):
            raise ConfigError(f"{arr.shape[1]} columns of set-points for {len(self.positions)} drives")
        col = {"position": self._target, "velocity": self._target_v, "torque": self._target_t}.get(kind)
        if col is None:
            raise ConfigError(f"stream kind {kind!r}: position, velocity or torque (and mapped)")
        rows = np.rint(arr).astype(np.int64)
        if settle:
            rows = np.vstack([rows, np.repeat(rows[-1:], settle, axis=0)])
        n = len(rows)
        rec = None
        if record:
            rec = MotionRecord(np.zeros((n, len(self)), np.int64), np.zeros((n, len(self)), np.int64),
                               np.zeros((n, len(self)), np.int64) if self._fe is not None else None,
                               np.zeros((n, len(self)), np.int64), self.cycle_s)
        all_sel = self._select(None)
        self._row = 0
        self._stream = (rows, col, rec)
        try:
            self._wait(lambda: self._row >= n, n * self.cycle_s * 2 + 1.0, f"streaming {kind}s", all_sel)
        finally:
            self._stream = None
        return rec

    def follow(self, trajectory: Trajectory, *, settle: int = 0, record: bool = True) -> MotionRecord | None:
        """Stream a trajectory's positions (CSP)."""
        return self.stream(trajectory.position_counts(), kind="position", settle=settle,
                           record=record)

    # --- profile position and homing -------------------------------------------------------

    def _sdo_params(self, sel: B, params: Sequence[tuple[int, float | None, str]]) -> None:
        for index, value, dtype in params:
            if value is None:
                continue
            for i in np.nonzero(sel)[0].tolist():
                self.master.slaves[self.positions[i]].sdo_write(index, 0, int(round(value)), dtype)

    def _need_enabled(self, sel: B, what: str) -> None:
        off = sel & (self._state != S.OPERATION_ENABLED)
        if off.any():
            i = int(np.nonzero(off)[0][0])
            raise DriveError(f"{self._name(i)} is not enabled ({self._describe(i)}): "
                             f"enable it before {what}")

    def move_to(self, targets: npt.ArrayLike, *, velocity: float | None = None,
                acceleration: float | None = None, deceleration: float | None = None,
                relative: bool = False, immediate: bool = True, timeout: float = 10.0,
                drives: Sequence[int] | None = None) -> None:
        """Profile position move: target, new set-point, acknowledge, target reached.

        ``velocity``/``acceleration``/``deceleration`` (0x6081/0x6083/0x6084)
        are written by SDO first when given. The mode becomes PP if it is not.
        """
        sel = self._select(drives)
        self._need_enabled(sel, "a move")
        if any(m != OM.PROFILE_POSITION for i, m in enumerate(self.modes()) if sel[i]):
            self.set_mode(OM.PROFILE_POSITION, drives=[int(i) for i in np.nonzero(sel)[0]])
        self._sdo_params(sel, ((int(_O.PROFILE_VELOCITY), velocity, "uint32"),
                               (int(_O.PROFILE_ACCELERATION), acceleration, "uint32"),
                               (int(_O.PROFILE_DECELERATION), deceleration, "uint32")))
        tgt = np.broadcast_to(np.rint(np.asarray(targets, np.float64)).astype(np.int64), (len(self),))
        if self._target is not None:
            self._target.set(tgt, sel)
        else:  # a profile move may take its target by SDO (not cyclic)
            for i in np.nonzero(sel)[0].tolist():
                self.master.slaves[self.positions[i]].sdo_write(int(_O.TARGET_POSITION), 0,
                                                               int(tgt[i]), "int32")
        extra = (0x20 if immediate else 0) | (0x40 if relative else 0)
        self._hs.bits = np.where(sel, (self._hs.bits & ~0x60) | extra, self._hs.bits)
        self._hs.pp[sel] = _SEND
        self._wait(lambda: bool((self._hs.pp[sel] == _DONE).all()), timeout, "profile position move",
                   sel)
        self._hs.pp[sel] = _IDLE

    def home(self, method: int | None = None, timeout: float = 30.0,
             drives: Sequence[int] | None = None) -> None:
        """Homing: method 0x6098 (by SDO when given), mode HM, start; waits for "homing attained"."""
        sel = self._select(drives)
        self._need_enabled(sel, "homing")
        if method is not None:
            self._sdo_params(sel, ((int(_O.HOMING_METHOD), method, "int8"),))
        if any(m != OM.HOMING for i, m in enumerate(self.modes()) if sel[i]):
            self.set_mode(OM.HOMING, drives=[int(i) for i in np.nonzero(sel)[0]])
        self._hs.hm_sent[sel] = 0
        self._hs.hm[sel] = _SEND

        def finished() -> bool:
            states = self._hs.hm[sel]
            if (states == _FAILED).any():
                i = int(np.nonzero(sel & (self._hs.hm == _FAILED))[0][0])
                raise DriveError(f"{self._name(i)}: homing error ({self._describe(i)})")
            return bool((states == _DONE).all())

        self._wait(finished, timeout, "homing", sel)
        self._hs.hm[sel] = _IDLE

    # --- error history ----------------------------------------------------------------------

    def error_history(self, index: int = 0) -> list[DriveErrorRecord]:
        """0x1003 of drive ``index`` (newest first), by SDO."""
        return read_error_history(self.master.slaves[self.positions[index]])


class Drive:
    """One drive of a :class:`DriveGroup` (or of its own group of one)."""

    def __init__(self, group: DriveGroup | DriveMaster, index: int = 0) -> None:
        if not isinstance(group, DriveGroup):
            group = DriveGroup(group, [index])
            index = 0
        self.group = group
        self.index = index
        self.position = group.positions[index]

    @property
    def statusword(self) -> int:
        return int(self.group.statuswords()[self.index])

    @property
    def state(self) -> DriveState | None:
        return self.group.states()[self.index]

    @property
    def mode(self) -> OperationMode | int:
        return self.group.modes()[self.index]

    @property
    def actual_position(self) -> int:
        return int(self.group.positions_actual()[self.index])

    def enable(self, timeout: float = 1.0) -> None:
        self.group.enable(timeout, [self.index])

    def disable(self, timeout: float = 1.0) -> None:
        self.group.disable(timeout, [self.index])

    def quick_stop(self, timeout: float = 2.0) -> None:
        self.group.quick_stop(timeout, [self.index])

    def fault_reset(self, timeout: float = 1.0) -> None:
        self.group.fault_reset(timeout, [self.index])

    def set_mode(self, mode: OperationMode | int | str, timeout: float = 1.0) -> None:
        self.group.set_mode(mode, timeout, [self.index])

    def move_to(self, target: int, **options: Any) -> None:
        self.group.move_to(target, drives=[self.index], **options)

    def home(self, method: int | None = None, timeout: float = 30.0) -> None:
        self.group.home(method, timeout, [self.index])

    def error_history(self) -> list[DriveErrorRecord]:
        return self.group.error_history(self.index)

    def __repr__(self) -> str:
        st = self.state
        return f"<Drive {self.position} {st.label if st is not None else '?'}>"


def read_error_history(slave: Slave) -> list[DriveErrorRecord]:
    """The pre-defined error field 0x1003 of ``slave`` (newest first), by SDO."""
    count = int(slave.sdo_read(int(StandardObject.ERROR_HISTORY), 0, "uint8"))
    out = []
    for sub in range(1, count + 1):
        word = int(slave.sdo_read(int(StandardObject.ERROR_HISTORY), sub, "uint32"))
        code = word & 0xFFFF
        out.append(DriveErrorRecord(code, word >> 16, emergency_error_name(code)))
    return out


def _selection(n: int, drives: Sequence[int] | None) -> B:
    """Drives ``drives`` (indices in the group; None: all) of a group of ``n`` as a mask."""
    sel = np.zeros(n, bool)
    if drives is None:
        sel[:] = True
        return sel
    for d in drives:
        if not 0 <= d < n:
            raise ConfigError(f"no drive {d} in a group of {n}")
        sel[d] = True
    return sel


def _image_of(master: DriveMaster, positions: Sequence[int]) -> ProcessImage:
    """The one group image that holds every drive of ``positions``."""
    for image in master.images.values():
        if all(p in image.positions for p in positions):
            return image
    raise ConfigError(f"drives {list(positions)} are not all in one process-data group")


def _has(io: Any, key: Cia402Object) -> bool:
    try:
        return (int(key), 0) in io
    except ConfigError:
        return False

