"""One control cycle of many simulated CiA 402 drives: power state machine, modes, statusword.

:meth:`DriveEngine.step` runs a cycle for a set of instances with a constant
number of numpy operations (a few more only for modes some axis is in):

1. the mechanics and inner loops over the past interval (``sim.cia402.axis``);
2. actual values: encoder count, velocity, following error, switches;
3. supervision: following error (0x6065 for longer than 0x6066 ms in a
   position mode), limit switches hit outside homing;
4. the power state machine of IEC 61800-7-201 from the controlword (only in
   EtherCAT OP: in SAFE-OP the outputs are not valid and the drive takes no
   commands), with the fault-reset rising edge, quick stop by 0x605A, the
   stop option codes 0x605B/0x605C/0x605E and halt 0x605D;
5. the set-point of the next cycle by mode of operation (CSP/CSV/CST take
   the targets as they come; PP, PV, homing and every stop ramp generate
   it); software position limits 0x607D clamp position targets;
6. the statusword with the mode-dependent bits and the other inputs.

Faults found here are returned to the caller (the device model), which
sends the emergencies: rare events, plain Python per instance.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import IntEnum
from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cia402.axis import (
    CTRL_OFF,
    CTRL_POSITION,
    CTRL_TORQUE,
    CTRL_VELOCITY,
    AxisModel,
    Rows,
)
from pyethercat.sim.cia402.homing import HOMING, Phase, Rule, Signal
from pyethercat.sim.cia402.objects import AXIS_OBJECT, DRIVE_MODES, AxisSub
from pyethercat.sim.cia402.profile import profile_move, ramp_velocity
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire.cia402 import (
    DriveCommand,
    DriveErrorCode,
    DriveState,
    OperationMode,
    StopOption,
    decode_command,
)
from pyethercat.wire.mailbox.objects import Cia402Object, StandardObject
from pyethercat.wire.sii import SiiInfo

__all__ = ["DRIVE_FIELDS", "DriveEngine", "Faults"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]


def _ints(enum: type[IntEnum]) -> Any:
    """An enum's members as plain ints: IntEnum attribute lookups cost microseconds each,
    and the drive cycle makes hundreds of them."""
    return SimpleNamespace(**{m.name: int(m) for m in enum})


_O = _ints(Cia402Object)
S = _ints(DriveState)
OM = _ints(OperationMode)
_PH = _ints(Phase)
_RU = _ints(Rule)
_SG = _ints(Signal)
_AX = _ints(AxisSub)
_SO = _ints(StopOption)
_DE = _ints(DriveErrorCode)
#: What a cycle found: (instances, error codes, detail values) of new faults, and the
#: instances whose fault was reset.
Faults = tuple[I64, I64, I64, I64]

#: Parameter entries the engine reads (beyond the PDO-mappable ones and the axis').
DRIVE_FIELDS: tuple[tuple[int, int], ...] = (
    (_O.ERROR_CODE, 0), (_O.QUICK_STOP_OPTION_CODE, 0), (_O.SHUTDOWN_OPTION_CODE, 0),
    (_O.DISABLE_OPERATION_OPTION_CODE, 0), (_O.HALT_OPTION_CODE, 0),
    (_O.FAULT_REACTION_OPTION_CODE, 0), (_O.FOLLOWING_ERROR_WINDOW, 0),
    (_O.FOLLOWING_ERROR_TIMEOUT, 0), (_O.POSITION_WINDOW, 0), (_O.POSITION_WINDOW_TIME, 0),
    (_O.VELOCITY_WINDOW, 0), (_O.VELOCITY_WINDOW_TIME, 0), (_O.VELOCITY_THRESHOLD, 0),
    (_O.VELOCITY_THRESHOLD_TIME, 0), (_O.HOME_OFFSET, 0), (_O.SOFTWARE_POSITION_LIMIT, 1),
    (_O.SOFTWARE_POSITION_LIMIT, 2), (_O.MAX_PROFILE_VELOCITY, 0), (_O.PROFILE_VELOCITY, 0),
    (_O.PROFILE_ACCELERATION, 0), (_O.PROFILE_DECELERATION, 0), (_O.QUICK_STOP_DECELERATION, 0),
    (_O.MAX_ACCELERATION, 0), (_O.MAX_DECELERATION, 0), (_O.HOMING_METHOD, 0),
    (_O.HOMING_SPEEDS, 1), (_O.HOMING_SPEEDS, 2), (_O.HOMING_ACCELERATION, 0),
    (_O.TARGET_POSITION, 0), (_O.TARGET_VELOCITY, 0), (_O.TARGET_TORQUE, 0),
    (_O.POSITION_OFFSET, 0), (_O.VELOCITY_OFFSET, 0), (_O.TORQUE_OFFSET, 0),
    (_O.CONTROLWORD, 0), (_O.MODES_OF_OPERATION, 0), (_O.STATUSWORD, 0),
    (_O.MODES_OF_OPERATION_DISPLAY, 0), (_O.POSITION_ACTUAL_VALUE, 0),
    (_O.VELOCITY_ACTUAL_VALUE, 0), (_O.TORQUE_ACTUAL_VALUE, 0), (_O.POSITION_DEMAND_VALUE, 0),
    (_O.VELOCITY_DEMAND_VALUE, 0), (_O.TORQUE_DEMAND, 0), (_O.FOLLOWING_ERROR_ACTUAL_VALUE, 0),
    (_O.DIGITAL_INPUTS, 0), (StandardObject.ERROR_SETTINGS, 2),
)

# Supported modes by the int8 value of 0x6060 (+128).
_SUPPORTED = np.zeros(256, bool)
for _m in DRIVE_MODES:
    _SUPPORTED[int(_m) + 128] = True
# Statusword bits 0-6 by state.
_STATE_BITS = np.array([0x00, 0x40, 0x21, 0x23, 0x27, 0x07, 0x0F, 0x08], np.int64)
_VOLTAGE_REMOTE = 0x0010 | 0x0200
# Device-control commands by the controlword's low byte (COMMAND_MASKS: bit 7 must be 0).
_NONE_CMD, _SHUTDOWN, _SWITCH_ON, _ENABLE, _DISABLE_VOLTAGE, _QUICK_STOP = range(6)
_CMD = np.zeros(256, np.int64)
for _cw in range(256):
    _c = decode_command(_cw)
    _CMD[_cw] = {None: _NONE_CMD, DriveCommand.SHUTDOWN: _SHUTDOWN,
                 DriveCommand.SWITCH_ON: _SWITCH_ON, DriveCommand.ENABLE_OPERATION: _ENABLE,
                 DriveCommand.DISABLE_VOLTAGE: _DISABLE_VOLTAGE,
                 DriveCommand.QUICK_STOP: _QUICK_STOP}[_c]
# Transitions by (state, command); the ones that depend on option codes, stops, edges
# and faults are handled beside the table.
_TRANS = np.repeat(np.arange(8, dtype=np.int64)[:, None], 6, axis=1)
_TRANS[DriveState.SWITCH_ON_DISABLED, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
for _st in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCHED_ON):
    _TRANS[_st, _ENABLE] = DriveState.OPERATION_ENABLED          # 3 and 4 at once from ready
    _TRANS[_st, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
    _TRANS[_st, _DISABLE_VOLTAGE] = _TRANS[_st, _QUICK_STOP] = DriveState.SWITCH_ON_DISABLED
_TRANS[DriveState.READY_TO_SWITCH_ON, _SWITCH_ON] = DriveState.SWITCHED_ON
_TRANS[DriveState.OPERATION_ENABLED, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
_TRANS[DriveState.OPERATION_ENABLED, _SWITCH_ON] = DriveState.SWITCHED_ON
_TRANS[DriveState.OPERATION_ENABLED, _DISABLE_VOLTAGE] = DriveState.SWITCH_ON_DISABLED
_TRANS[DriveState.OPERATION_ENABLED, _QUICK_STOP] = DriveState.QUICK_STOP_ACTIVE
_TRANS[DriveState.QUICK_STOP_ACTIVE, _DISABLE_VOLTAGE] = DriveState.SWITCH_ON_DISABLED
_NONE = np.zeros(0, np.int64)
# The entries the cycle reads and writes, as (index, subindex).
_K_CW, _K_MODE, _K_MODE_DISPLAY = (0x6040, 0), (0x6060, 0), (0x6061, 0)
_K_ERROR, _K_STATUSWORD = (0x603F, 0), (0x6041, 0)
_K_FE_WINDOW, _K_FE_TIMEOUT = (0x6065, 0), (0x6066, 0)
_K_NEG_LIMIT, _K_POS_LIMIT, _K_HOME = ((AXIS_OBJECT, int(AxisSub.NEGATIVE_LIMIT_SWITCH)),
                                       (AXIS_OBJECT, int(AxisSub.POSITIVE_LIMIT_SWITCH)),
                                       (AXIS_OBJECT, int(AxisSub.HOME_SWITCH)))
_K_POSITION, _K_VELOCITY, _K_TORQUE = (0x6064, 0), (0x606C, 0), (0x6077, 0)
_K_TORQUE_DEMAND, _K_POSITION_DEMAND, _K_VELOCITY_DEMAND = (0x6074, 0), (0x6062, 0), (0x606B, 0)
_K_FE, _K_INPUTS, _K_RATED = (0x60F4, 0), (0x60FD, 0), (0x6076, 0)
_K_QS_OPTION, _K_SHUTDOWN_OPTION, _K_DISABLE_OPTION = (0x605A, 0), (0x605B, 0), (0x605C, 0)
_K_FAULT_OPTION = (0x605E, 0)
_K_POS_WINDOW, _K_POS_WINDOW_TIME = (0x6067, 0), (0x6068, 0)
_K_V_WINDOW, _K_V_WINDOW_TIME = (0x606D, 0), (0x606E, 0)
_K_V_THRESHOLD, _K_V_THRESHOLD_TIME = (0x606F, 0), (0x6070, 0)
_K_TARGET_VELOCITY = (0x60FF, 0)
_K_TARGET_POSITION, _K_POSITION_OFFSET = (0x607A, 0), (0x60B0, 0)
_K_VELOCITY_OFFSET, _K_TORQUE_OFFSET = (0x60B1, 0), (0x60B2, 0)
_K_LIMIT_MIN, _K_LIMIT_MAX = (0x607D, 1), (0x607D, 2)
_FALSE = np.zeros(1 << 16, bool)
#: Actual values written when a PDO maps them, else when an SDO reads them.
_LAZY = frozenset({_K_POSITION, _K_VELOCITY, _K_TORQUE, _K_TORQUE_DEMAND, _K_POSITION_DEMAND,
                   _K_VELOCITY_DEMAND, _K_FE, _K_INPUTS})
_NO_STOP = -1
_STAY = -1
_THRESH_EPS = 1e-9
# States with the power stage on (the loops run, a set-point generator may move).
_POWERED = np.zeros(8, bool)
_POWERED[[DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE,
          DriveState.FAULT_REACTION_ACTIVE]] = True


class DriveEngine(AxisModel):
    """CiA 402 behaviour of a drive kind over its axes (see the module docstring)."""

    def __init__(self, dictionary: Callable[[SiiInfo, MailboxDevice], SimObjectDictionary], *,
                 details: int, capacity_out: int = 128, capacity_in: int = 128) -> None:
        super().__init__(dictionary, details=details, capacity_out=capacity_out,
                         capacity_in=capacity_in, fields=DRIVE_FIELDS)
        arr = self.array
        self.state = arr("state", np.int8, int(S.SWITCH_ON_DISABLED))
        self.prev_cw = arr("prev_cw", np.int64, 0)
        #: The slave is in EtherCAT OP (its outputs are valid).
        self.al_op = arr("al_op", bool, False)
        #: Stop in progress: deceleration option (-1 none) and the state it ends in (-1: stay).
        self.stop_opt = arr("stop_opt", np.int8, _NO_STOP)
        self.stop_goal = arr("stop_goal", np.int8, _STAY)
        #: Set-point generator: demand position (raw inc) and velocity (inc/s).
        self.g_p: F64 = arr("g_p", np.float64, 0.0)
        self.g_v: F64 = arr("g_v", np.float64, 0.0)
        #: Raw encoder position of user position 0 (homing moves it).
        self.origin: F64 = arr("origin", np.float64, 0.0)
        # profile position: goal, buffered set-point, set-point acknowledge
        self.pp_goal: F64 = arr("pp_goal", np.float64, 0.0)
        self.pp_buf: F64 = arr("pp_buf", np.float64, 0.0)
        self.pp_active = arr("pp_active", bool, False)
        self.pp_buffered = arr("pp_buffered", bool, False)
        self.pp_ack = arr("pp_ack", bool, False)
        # homing
        self.hm_phase = arr("hm_phase", np.int8, int(_PH.IDLE))
        self.hm_method = arr("hm_method", np.int64, 0)
        self.hm_var = arr("hm_var", np.int8, 0)
        self.hm_home: F64 = arr("hm_home", np.float64, 0.0)
        self.hm_attained = arr("hm_attained", bool, False)
        self.hm_error = arr("hm_error", bool, False)
        # window timers (s)
        self.fe_t: F64 = arr("fe_t", np.float64, 0.0)
        self.win_t: F64 = arr("win_t", np.float64, 0.0)
        self.vwin_t: F64 = arr("vwin_t", np.float64, 0.0)
        self.vzero_t: F64 = arr("vzero_t", np.float64, 0.0)
        self.limited = arr("limited", bool, False)
        #: Actual velocity (encoder, inc/s) and following error of the last cycle.
        self.v_act: F64 = arr("v_act", np.float64, 0.0)
        self.fe_val: F64 = arr("fe_val", np.float64, 0.0)
        #: Warning bit (statusword bit 7): sync fallback, missed SM events.
        self.warn = arr("warn", bool, False)
        #: Skip the cycle of axes at rest with the power off while nothing they read changes
        #: (see :meth:`step`); off runs every cycle in full (the tests compare both).
        self.idle_fast_path = True
        #: The last cycle was a fixed point: (instances, their image rows, warning bits).
        self._quiet: tuple[bytes, bytes, bytes] | None = None

    def unquiet(self) -> None:
        """Something outside the cycle changed a drive's state: the next cycle runs in full."""
        self._quiet = None

    # --- the cycle ------------------------------------------------------------------------

    def step(self, inst: I64, dt: F64) -> Faults:
        """One cycle of ``inst`` (sorted instances) after ``dt`` seconds: faults found, resets.

        Idle fast path: a cycle of axes that stand with the power off (no state change, no
        stop, no plan, no motion, no fault, mode unchanged) leaves every array as it was, so
        the next cycle on the same image rows (outputs, parameters, inputs) and warning bits
        computes nothing new and is skipped; a change of any of them, or :meth:`unquiet`,
        runs the cycle in full again.
        """
        r = self.rows(inst)
        quiet = self._quiet
        if quiet is not None:
            if (quiet[0] == inst.tobytes() and quiet[1] == self.image[r].tobytes()
                    and quiet[2] == self.warn[r].tobytes()):
                return _NONE, _NONE, _NONE, _NONE
            self._quiet = None
        f, col = self.field, self.col
        # a fixed point needs the power off and the axes at rest already on the way in
        rest_in = (self.idle_fast_path and len(dt) > 0 and dt.min() > 0
                   and not self.plan_mode[r].any() and not self.v[r].any())
        self.integrate(r, dt)
        safe_dt = dt if dt.min(initial=1.0) > 0 else np.where(dt > 0, dt, 1.0)
        enc = self.encoder(r)
        v_act = (enc - self.enc_prev[r]) / safe_dt
        self.enc_prev[r] = enc
        p = self.p[r]
        state = self.state[r].astype(np.int64)
        cw = f(*_K_CW)[r].astype(np.int64)
        al = self.al_op[r]
        if not al.all():
            cw = np.where(al, cw, 0)  # outputs count in OP only
        prev = self.prev_cw[r].copy()
        self.prev_cw[r] = cw
        # --- supervision ----------------------------------------------------------------
        enabled = state == S.OPERATION_ENABLED
        fe = (self.plan_to[r] - p) * (self.plan_mode[r] == CTRL_POSITION)
        over = (np.abs(fe) > col(*_K_FE_WINDOW, r)) & enabled
        fe_t = (self.fe_t[r] + dt) * over
        self.fe_t[r] = fe_t
        fe_fault = over & (fe_t * 1000.0 > col(*_K_FE_TIMEOUT, r) - _THRESH_EPS)
        neg = p <= col(*_K_NEG_LIMIT, r)
        posl = p >= col(*_K_POS_LIMIT, r)
        home = p >= col(*_K_HOME, r)
        faulted: B | None = None
        code = detail = None
        switch = neg | posl
        if fe_fault.any() or switch.any():
            homing = self.hm_phase[r] >= 0
            moving_neg = (self.g_v[r] < 0) | (self.v[r] < -1.0)
            moving_pos = (self.g_v[r] > 0) | (self.v[r] > 1.0)
            lim_fault = enabled & ~homing & ((neg & moving_neg) | (posl & moving_pos))
            faulted = fe_fault | lim_fault
            code = np.where(fe_fault, _DE.FOLLOWING_ERROR, np.where(lim_fault, _DE.REFERENCE_LIMIT, 0))
            detail = np.where(fe_fault, np.round(fe), np.where(neg, 1, 2)).astype(np.int64)
            if not faulted.any():
                faulted = None
        # --- power state machine ----------------------------------------------------------
        cmd = _CMD[cw & 0xFF]
        stopping = self.stop_opt[r] >= 0
        if faulted is None and enabled.all() and (cmd == _ENABLE).all() and not stopping.any():
            new, start_stop = state, None  # the usual cycle: enabled, stays enabled
        else:
            new, start_stop = self._transitions(r, state, cmd, cw, prev, stopping, faulted)
        reset = None if new is state else (state == S.FAULT) & (new == S.SWITCH_ON_DISABLED)
        # --- modes and the next set-point -------------------------------------------------
        shown = f(*_K_MODE_DISPLAY)[r]
        rest_in = rest_in and faulted is None and not _POWERED[new].any() and bool(
            (new == state).all()) and not v_act.any() and bool((f(*_K_MODE)[r] == shown).all())
        mode = self._mode(r, inst)
        self._plan(r, inst, new, mode, cw, prev, dt, safe_dt, start_stop, (neg, posl, home))
        if self.stop_opt[r].max(initial=-1) >= 0:
            new = self._stops_done(r, new, v_act)
        self.state[r] = new
        # --- inputs: the ones a PDO maps now; the others when an SDO reads them -------------
        self.v_act[r] = v_act
        self.fe_val[r] = fe
        self.inputs(r, self.tx_keys())
        self._statusword(r, new, mode, cw, fe, v_act, dt)
        clear = _NONE if reset is None else inst[reset]
        if len(clear):
            f(*_K_ERROR)[clear] = 0
        elif rest_in and not self.v[r].any():
            self._quiet = (inst.tobytes(), self.image[r].tobytes(), self.warn[r].tobytes())
        if faulted is None:
            return _NONE, _NONE, _NONE, clear
        assert code is not None and detail is not None
        hit = np.nonzero(faulted & (state != S.FAULT) & (state != S.FAULT_REACTION_ACTIVE))[0]
        return inst[hit], code[hit], detail[hit], clear

    def inputs(self, r: Rows, keys: frozenset[tuple[int, int]] | None) -> None:
        """Actual values into the image: the ``keys`` among them (None: all of them)."""
        f, col = self.field, self.col
        origin = self.origin[r]
        if keys is None or _K_POSITION in keys:
            f(*_K_POSITION)[r] = self.enc_prev[r] - origin
        if keys is None or _K_VELOCITY in keys:
            f(*_K_VELOCITY)[r] = np.round(self.v_act[r])
        if keys is None or _K_TORQUE in keys or _K_TORQUE_DEMAND in keys:
            per_mille = np.round(self.torque[r] * (1e6 / np.maximum(col(*_K_RATED, r), 1e-9)))
            f(*_K_TORQUE)[r] = per_mille
            f(*_K_TORQUE_DEMAND)[r] = per_mille
        if keys is None or _K_POSITION_DEMAND in keys:
            f(*_K_POSITION_DEMAND)[r] = np.round(self.plan_from[r] - origin)
        if keys is None or _K_VELOCITY_DEMAND in keys:
            f(*_K_VELOCITY_DEMAND)[r] = np.round(self.g_v[r])
        if keys is None or _K_FE in keys:
            f(*_K_FE)[r] = np.round(self.fe_val[r])
        if keys is None or _K_INPUTS in keys:
            p = self.p[r]
            f(*_K_INPUTS)[r] = ((p <= col(*_K_NEG_LIMIT, r)) * 1 + (p >= col(*_K_POS_LIMIT, r)) * 2
                                + (p >= col(*_K_HOME, r)) * 4)

    def _read(self, instance: int, key: tuple[int, int]) -> bytes:
        if key in _LAZY and key not in self.tx_keys():
            self.inputs(np.array([instance], np.int64), None)
        return super()._read(instance, key)

    def _transitions(self, r: Rows, state: I64, cmd: I64, cw: I64, prev: I64, stopping: B,
                     faulted: B | None) -> tuple[I64, I64]:
        """New states and the stops they start (-1: none; else a stop option)."""
        col = self.col
        new = _TRANS[state, cmd]
        start = np.full(len(state), _NO_STOP, np.int64)
        goal = self.stop_goal[r].astype(np.int64)
        goal_new = goal.copy()
        sod, rdy, son = S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON
        op, qsa, fra, flt = (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE,
                             S.FAULT)
        m = state == op
        if m.any():
            qs_code = self._qs_code(r)
            go_qs = m & (cmd == _QUICK_STOP)
            new[go_qs & (qs_code == 0)] = sod         # option 0: torque off at once
            ramp_qs = go_qs & (qs_code != 0)
            start[ramp_qs] = np.where(qs_code > 4, qs_code - 4, qs_code)[ramp_qs]
            goal_new[ramp_qs] = np.where(qs_code > 4, _STAY, sod)[ramp_qs]
            # shutdown / disable operation with a ramp (0x605B / 0x605C = 1) keep the state
            # until the axis stands; a stop already on its way is not started again
            for command, key, target in ((_SHUTDOWN, _K_SHUTDOWN_OPTION, rdy),
                                         (_SWITCH_ON, _K_DISABLE_OPTION, son)):
                asked = m & (cmd == command)
                if asked.any():
                    ramp = col(*key, r) == 1
                    keep = asked & (ramp | stopping)
                    new[keep] = op
                    sel = asked & ramp & ~stopping
                    start[sel] = _SO.SLOW_DOWN_RAMP
                    goal_new[sel] = target
            # Enable operation takes back a stop towards Switched on / Ready
            back = m & stopping & (cmd == _ENABLE) & ((goal == son) | (goal == rdy))
            if back.any():
                self.stop_opt[r] = np.where(back, _NO_STOP, self.stop_opt[r])
        m = state == qsa
        if m.any():
            qs_code = self._qs_code(r)
            back = m & (cmd == _ENABLE) & (qs_code >= 5) & ~stopping
            new[back] = op
        edge = ((cw & 0x80) != 0) & ((prev & 0x80) == 0)
        new[(state == flt) & edge] = sod
        if faulted is not None:
            react = col(*_K_FAULT_OPTION, r).astype(np.int64)
            powered = (state == op) | (state == qsa)
            f_ramp = faulted & powered & (react != 0)
            new[faulted & (state != flt) & (state != fra)] = flt
            new[f_ramp] = fra
            start[f_ramp] = react[f_ramp]
            goal_new[f_ramp] = flt
        # power off ends any stop
        off = (new != op) & (new != qsa) & (new != fra)
        start[off] = _NO_STOP
        self.stop_opt[r] = np.where(start >= 0, start, np.where(off, _NO_STOP, self.stop_opt[r]))
        self.stop_goal[r] = goal_new
        return new, start

    def _qs_code(self, r: Rows) -> I64:
        """0x605A; negative (manufacturer-specific) values act as 2, the quick stop ramp."""
        code = self.col(*_K_QS_OPTION, r).astype(np.int64)
        out: I64 = np.where(code < 0, 2, code)
        return out

    def _mode(self, r: Rows, inst: I64) -> I64:
        """Mode display after this cycle (0x6061 follows 0x6060 when the mode is supported)."""
        f = self.field
        want = f(*_K_MODE)[r].astype(np.int64)
        shown = f(*_K_MODE_DISPLAY)[r].astype(np.int64)
        take = (want != shown) & _SUPPORTED[want + 128]
        if not take.any():
            return shown
        mode: I64 = np.where(take, want, shown)
        f(*_K_MODE_DISPLAY)[r] = mode
        # a new mode starts from where the axis stands, with its sub-states cleared
        changed = inst[take]
        self.pp_active[changed] = self.pp_buffered[changed] = self.pp_ack[changed] = False
        self.hm_phase[changed] = _PH.IDLE
        self.g_p[changed] = self.plan_to[changed]
        return mode

    def _plan(self, r: Rows, inst: I64, state: I64, mode: I64, cw: I64, prev: I64, dt: F64,
              safe_dt: F64, start_stop: I64 | None, switches: tuple[B, B, B]) -> None:
        """The next cycle's plan of every axis (see :class:`~pyethercat.sim.cia402.axis.AxisModel`)."""
        if (start_stop is None and (state == S.OPERATION_ENABLED).all()
                and (mode == OM.CYCLIC_SYNC_POSITION).all()
                and (self.plan_mode[r] == CTRL_POSITION).all()
                and self.stop_opt[r].max(initial=-1) < 0):
            self._plan_csp(r, safe_dt)  # the usual cycle of a CSP group: its own short path
            return
        col = self.col
        p, v = self.p[r], self.v[r]
        powered = (state == S.OPERATION_ENABLED) | (state == S.QUICK_STOP_ACTIVE) | (
            state == S.FAULT_REACTION_ACTIVE)
        stop = self.stop_opt[r].astype(np.int64)
        stopping = powered & (stop >= 0)
        just_on = powered & (self.plan_mode[r] == CTRL_OFF)
        # a stop brakes from where the axis is and how fast it moves (after a following
        # error the demand may be far away)
        fresh = just_on if start_stop is None else just_on | (start_stop >= 0)
        if powered.all() and not fresh.any():
            g_p, g_v = self.g_p[r].copy(), self.g_v[r].copy()
        else:
            g_p = np.where(powered & ~fresh, self.g_p[r], p)
            g_v = np.where(powered & ~fresh, self.g_v[r], np.where(powered & ~just_on, v, 0.0))
        origin = self.origin[r]
        ctrl = np.where(powered, CTRL_POSITION, CTRL_OFF)
        new_p, new_v = g_p.copy(), g_v.copy()
        vcmd = np.zeros_like(p)
        tcmd = np.zeros_like(p)
        vff_extra = np.zeros_like(p)
        tff = np.zeros_like(p)
        running = powered & ~stopping & (state == S.OPERATION_ENABLED)
        halt = ((cw & 0x100) != 0) & running & (
            (mode == OM.PROFILE_POSITION) | (mode == OM.PROFILE_VELOCITY) | (mode == OM.HOMING))
        # stop ramps (quick stop, fault reaction, disable with ramp) and halt
        ramp_to_zero = stopping | halt
        if ramp_to_zero.any():
            opt = np.where(stopping, stop, col(_O.HALT_OPTION_CODE, 0, r).astype(np.int64))
            dec = self._stop_deceleration(r, opt)
            rv = ramp_velocity(g_v, np.zeros_like(g_v), dec, dec, dt)
            new_v = np.where(ramp_to_zero, rv, new_v)
            new_p = np.where(ramp_to_zero, g_p + (g_v + rv) * 0.5 * dt, new_p)
        active = running & ~halt
        lo, hi = col(_O.SOFTWARE_POSITION_LIMIT, 1, r), col(_O.SOFTWARE_POSITION_LIMIT, 2, r)
        limits = lo < hi
        limited = np.zeros(len(p), bool)
        m = active & (mode == OM.CYCLIC_SYNC_POSITION)
        if m.any():
            tgt = col(_O.TARGET_POSITION, 0, r) + col(_O.POSITION_OFFSET, 0, r)
            clamped = np.where(limits, np.clip(tgt, lo, hi), tgt)
            limited |= m & (clamped != tgt)
            raw = clamped + origin
            new_v = np.where(m, (raw - g_p) / safe_dt, new_v)
            new_p = np.where(m, raw, new_p)
            vff_extra = np.where(m, col(_O.VELOCITY_OFFSET, 0, r), vff_extra)
            tff = np.where(m, self._torque(r, col(_O.TORQUE_OFFSET, 0, r)), tff)
        m = active & (mode == OM.CYCLIC_SYNC_VELOCITY)
        if m.any():
            vel = col(_O.TARGET_VELOCITY, 0, r) + col(_O.VELOCITY_OFFSET, 0, r)
            ctrl = np.where(m, CTRL_VELOCITY, ctrl)
            vcmd = np.where(m, vel, vcmd)
            new_v = np.where(m, vel, new_v)
            new_p = np.where(m, p, new_p)
        m = active & (mode == OM.CYCLIC_SYNC_TORQUE)
        if m.any():
            ctrl = np.where(m, CTRL_TORQUE, ctrl)
            tcmd = np.where(m, self._torque(r, col(_O.TARGET_TORQUE, 0, r)
                                           + col(_O.TORQUE_OFFSET, 0, r)), tcmd)
            new_v = np.where(m, v, new_v)
            new_p = np.where(m, p, new_p)
        m = running & (mode == OM.PROFILE_POSITION)
        if m.any():
            new_p, new_v, lim = self._profile_position(r, inst, m, halt, cw, prev, g_p, g_v,
                                                        new_p, new_v, dt, lo, hi, limits)
            limited |= lim
        m = active & (mode == OM.PROFILE_VELOCITY)
        if m.any():
            goal = np.clip(col(_O.TARGET_VELOCITY, 0, r), -self._vmax(r), self._vmax(r))
            acc, dec = self._acc_dec(r)
            rv = ramp_velocity(g_v, goal, acc, dec, dt)
            ctrl = np.where(m, CTRL_VELOCITY, ctrl)
            vcmd = np.where(m, rv, vcmd)
            new_v = np.where(m, rv, new_v)
            new_p = np.where(m, p, new_p)
        m = running & (mode == OM.HOMING)
        if m.any():
            g_p, g_v, new_p, new_v = self._homing(r, inst, m, halt, cw, prev, p, g_p, g_v, new_p,
                                                  new_v, dt, switches)
        # commit the plan
        self.plan_mode[r] = ctrl
        self.plan_from[r] = np.where(powered, g_p, p)
        self.plan_to[r] = np.where(powered, new_p, p)
        position = ctrl == CTRL_POSITION
        vff = ((new_p - g_p) / safe_dt + vff_extra) * position
        # acceleration feed-forward: the torque the demanded change of velocity needs
        # (inertia), as servo drives add it to the velocity loop's output
        accel = (vff - self.plan_vff[r]) / safe_dt * (position & (self.plan_mode[r] == CTRL_POSITION))
        consts = self.constants(r)
        inertia = consts.inertia / consts.counts_per_rad
        self.plan_vff[r] = vff
        self.plan_tff[r] = tff + inertia * accel
        self.plan_v[r] = vcmd
        self.plan_t[r] = tcmd
        self.g_p[r] = np.where(powered, new_p, p)
        self.g_v[r] = np.where(powered, new_v, v)
        self.limited[r] = limited

    def _plan_csp(self, r: Rows, safe_dt: F64) -> None:
        """Every axis enabled in CSP and running: the target is the next demand."""
        col = self.col
        g_p = self.g_p[r].copy()
        tgt = col(*_K_TARGET_POSITION, r) + col(*_K_POSITION_OFFSET, r)
        lo, hi = col(*_K_LIMIT_MIN, r), col(*_K_LIMIT_MAX, r)
        limits = lo < hi
        limited = np.zeros(len(g_p), bool)
        if limits.any():
            clamped = np.where(limits, np.minimum(np.maximum(tgt, lo), hi), tgt)
            limited = clamped != tgt
            tgt = clamped
        raw = tgt + self.origin[r]
        vff = (raw - g_p) / safe_dt + col(*_K_VELOCITY_OFFSET, r)
        consts = self.constants(r)
        accel = (vff - self.plan_vff[r]) / safe_dt
        self.plan_from[r] = g_p
        self.plan_to[r] = raw
        self.plan_vff[r] = vff
        self.plan_tff[r] = (col(*_K_TORQUE_OFFSET, r) * col(*_K_RATED, r) * 1e-6
                            + consts.inertia / consts.counts_per_rad * accel)
        self.g_p[r] = raw
        self.g_v[r] = (raw - g_p) / safe_dt
        self.limited[r] = limited

    # --- helpers of the plan ---------------------------------------------------------------

    def _torque(self, r: Rows, per_mille: F64) -> F64:
        out: F64 = per_mille * self.col(_O.MOTOR_RATED_TORQUE, 0, r) * 1e-6
        return out

    def _vmax(self, r: Rows) -> F64:
        cap = self.col(_O.MAX_PROFILE_VELOCITY, 0, r)
        out: F64 = np.where(cap > 0, cap, np.inf)
        return out

    def _acc_dec(self, r: Rows) -> tuple[F64, F64]:
        col = self.col
        acc = col(_O.PROFILE_ACCELERATION, 0, r)
        dec = col(_O.PROFILE_DECELERATION, 0, r)
        amax, dmax = col(_O.MAX_ACCELERATION, 0, r), col(_O.MAX_DECELERATION, 0, r)
        acc = np.where(amax > 0, np.minimum(acc, amax), acc)
        dec = np.where(dmax > 0, np.minimum(dec, dmax), dec)
        return np.maximum(acc, 1.0), np.maximum(dec, 1.0)

    def _stop_deceleration(self, r: Rows, option: I64) -> F64:
        """Deceleration of a stop by :class:`StopOption` (inc/s²)."""
        col = self.col
        _acc, slow = self._acc_dec(r)
        quick = np.maximum(col(_O.QUICK_STOP_DECELERATION, 0, r), 1.0)
        limit = np.maximum(self.max_acceleration(r), 1.0)
        out: F64 = np.select([option == _SO.SLOW_DOWN_RAMP,
                              option == _SO.QUICK_STOP_RAMP], [slow, quick], limit)
        return out

    def _stops_done(self, r: Rows, new: I64, v_act: F64) -> I64:
        """States after stops that finished this cycle (the axis stands)."""
        stop = self.stop_opt[r]
        still = (self.g_v[r] == 0) & (np.abs(v_act) <= self.col(_O.VELOCITY_THRESHOLD, 0, r))
        done = (stop >= 0) & still
        if done.any():
            goal = self.stop_goal[r].astype(np.int64)
            new = np.where(done & (goal >= 0), goal, new)
            self.stop_opt[r] = np.where(done, _NO_STOP, stop)
        return new

    def _profile_position(self, r: Rows, inst: I64, m: B, halt: B, cw: I64, prev: I64,
                          g_p: F64, g_v: F64, new_p: F64, new_v: F64, dt: F64, lo: F64, hi: F64,
                          limits: B) -> tuple[F64, F64, B]:
        """Profile position: set-point handshake (bits 4, 5, 6, 9 / status bit 12) and the move."""
        col = self.col
        origin = self.origin[r]
        edge = m & ((cw & 0x10) != 0) & ((prev & 0x10) == 0)
        ack, active = self.pp_ack[r], self.pp_active[r]
        buffered = self.pp_buffered[r]
        goal, buf = self.pp_goal[r], self.pp_buf[r]
        tgt = col(_O.TARGET_POSITION, 0, r)
        relative = (cw & 0x40) != 0
        base = np.where(active, goal - origin, g_p - origin)
        user = np.where(relative, base + tgt, tgt)
        clamped = np.where(limits, np.clip(user, lo, hi), user)
        raw = clamped + origin
        take = edge & ~ack
        now = take & (((cw & 0x20) != 0) | ~active)
        later = take & ~now
        goal = np.where(now, raw, goal)
        active = active | now
        buf = np.where(later, raw, buf)
        buffered = buffered | later
        ack = ack | take
        vmax = np.minimum(col(_O.PROFILE_VELOCITY, 0, r), self._vmax(r))
        acc, dec = self._acc_dec(r)
        move = m & active & ~halt
        pp, pv, arrived = profile_move(g_p, g_v, goal, np.maximum(vmax, 1.0), acc, dec, dt)
        new_p = np.where(move, pp, new_p)
        new_v = np.where(move, pv, new_v)
        done = move & arrived
        active = active & ~done
        chain = done & buffered
        goal = np.where(chain, buf, goal)
        active = active | chain
        buffered = buffered & ~chain
        # the acknowledge drops with bit 4 once a set-point can be taken again
        ack = ack & ~(m & ((cw & 0x10) == 0) & ~buffered)
        hold = m & ~move & ~halt
        new_p = np.where(hold, g_p, new_p)
        new_v = np.where(hold, 0.0, new_v)
        sel = inst[m]
        self.pp_ack[sel], self.pp_active[sel] = ack[m], active[m]
        self.pp_buffered[sel], self.pp_goal[sel], self.pp_buf[sel] = buffered[m], goal[m], buf[m]
        return new_p, new_v, m & (clamped != user) & take

    def _homing(self, r: Rows, inst: I64, m: B, halt: B, cw: I64, prev: I64, p: F64, g_p: F64,
                g_v: F64, new_p: F64, new_v: F64, dt: F64,
                switches: tuple[B, B, B]) -> tuple[F64, F64, F64, F64]:
        """Homing: start on the rising edge of bit 4, run the method's program (``sim.cia402.homing``).

        Returns the demand at the start of the cycle (re-referenced where a method homed
        on the current position) and at its end: (g_p, g_v, new_p, new_v).
        """
        col = self.col
        neg, posl, home = switches
        phase = self.hm_phase[r].astype(np.int64)
        method = HOMING.method_index(col(_O.HOMING_METHOD, 0, r).astype(np.int64))
        start = m & ((cw & 0x10) != 0) & ((prev & 0x10) == 0) & ((phase < 0) | (phase >= _PH.DONE))
        if start.any():
            sel = inst[start]
            self.hm_method[sel] = method[start]
            self.hm_var[sel] = home[start]
            self.hm_attained[sel] = False
            self.hm_error[sel] = ~HOMING.valid[method[start]]
            phase = np.where(start, np.where(HOMING.valid[method], 0, _PH.ERROR), phase)
        meth = self.hm_method[r]
        var = self.hm_var[r].astype(np.int64)
        # bit 4 dropping interrupts the homing (as does halt): stop where it is
        aborted = m & (((cw & 0x10) == 0) | halt) & (phase >= 0) & (phase < _PH.STOP)
        phase = np.where(aborted, _PH.STOP, phase)
        steps = HOMING.steps[meth, var].astype(np.int64)
        searching = m & (phase >= 0) & (phase < steps)
        k = np.clip(phase, 0, 2)
        prog = HOMING.step[meth, var, k].astype(np.int64)
        direction, speed_sel, sig, level = prog[:, 0], prog[:, 1], prog[:, 2], prog[:, 3]
        signals = np.stack([np.ones_like(neg), neg, posl, home], axis=1)
        met = searching & (signals[np.arange(len(p)), sig] == (level == 1))
        # a limit switch the method does not search for ends it with an error
        bad = m & (phase >= 0) & (phase < _PH.STOP) & (
            (neg & HOMING.forbidden[meth, _SG.NEGATIVE_LIMIT])
            | (posl & HOMING.forbidden[meth, _SG.POSITIVE_LIMIT]))
        phase = np.where(met, phase + 1, phase)
        # steps done: where is home?
        ready = m & (phase >= 0) & (phase == steps) & ~bad
        if ready.any():
            rule = HOMING.rule[meth]
            edge_sig = HOMING.edge_signal[meth, var]
            positions = np.stack([p, col(AXIS_OBJECT, _AX.NEGATIVE_LIMIT_SWITCH, r),
                                  col(AXIS_OBJECT, _AX.POSITIVE_LIMIT_SWITCH, r),
                                  col(AXIS_OBJECT, _AX.HOME_SWITCH, r)], axis=1)
            edge = positions[np.arange(len(p)), edge_sig]
            # "current position": the encoder's count now, which the position actual value
            # shows (the drive knows no finer position than its encoder's)
            edge = np.where(rule == _RU.EDGE, edge, np.where(rule == _RU.INDEX, np.where(
                edge_sig > 0, edge, p), self.enc_prev[r]))
            cpr = col(_O.POSITION_ENCODER_RESOLUTION, 1, r) / np.maximum(
                col(_O.POSITION_ENCODER_RESOLUTION, 2, r), 1.0)
            idir = HOMING.index_dir[meth]
            index = np.where(idir > 0, (np.floor(edge / cpr) + 1) * cpr,
                             (np.ceil(edge / cpr) - 1) * cpr)
            home_at = np.where(rule == _RU.INDEX, index, edge)
            sel = inst[ready]
            self.hm_home[sel] = home_at[ready]
            nxt = np.where(rule == _RU.INDEX, _PH.APPROACH,
                           np.where(rule == _RU.CURRENT, _PH.DONE, _PH.STOP))
            phase = np.where(ready, nxt, phase)
            fin = ready & (rule == _RU.CURRENT)
            if fin.any():
                self._home_found(inst[fin], home_at[fin], r, fin)
                # Homing without motion: the drive holds the position it took as home. The
                # demand of the mode before (a profile move's target the axis may still be
                # settling onto, inside the position window) is dropped; kept, the axis
                # would come to rest that far from home.
                g_p = np.where(fin, home_at, g_p)
                g_v = np.where(fin, 0.0, g_v)
        hm_home = self.hm_home[r]
        approach = m & (phase == _PH.APPROACH)
        idir = HOMING.index_dir[meth].astype(np.float64)
        passed = approach & ((p - hm_home) * idir >= 0)
        phase = np.where(passed, _PH.STOP, phase)
        phase = np.where(bad, _PH.ERROR, phase)
        if bad.any():
            self.hm_error[inst[bad]] = True
        speeds = np.stack([np.zeros_like(p), col(_O.HOMING_SPEEDS, 1, r), col(_O.HOMING_SPEEDS, 2, r)],
                          axis=1)
        goal_v = np.where(searching & (phase < steps),
                          direction * speeds[np.arange(len(p)), speed_sel], 0.0)
        goal_v = np.where(approach & ~passed, idir * col(_O.HOMING_SPEEDS, 2, r), goal_v)
        acc = np.maximum(col(_O.HOMING_ACCELERATION, 0, r), 1.0)
        moving = m & ~halt
        rv = ramp_velocity(g_v, goal_v, acc, acc, dt)
        new_v = np.where(moving, rv, new_v)
        new_p = np.where(moving, g_p + (g_v + rv) * 0.5 * dt, new_p)
        stopped = m & ((phase == _PH.STOP) | (phase == _PH.ERROR)) & (rv == 0)
        done = stopped & (phase == _PH.STOP) & ~aborted
        if done.any():
            self._home_found(inst[done], self.hm_home[inst[done]], r, done)
        phase = np.where(done, _PH.DONE, phase)
        phase = np.where(stopped & aborted, _PH.IDLE, phase)
        self.hm_phase[inst[m]] = phase[m]
        return g_p, g_v, new_p, new_v

    def _home_found(self, sel: I64, home_raw: F64, r: Rows, mask: B) -> None:
        """Homing attained: user position of the home position = -home offset (IEC 61800-7-201:
        "the zero position is offset from the home position by adding the home offset")."""
        offset = self.col(_O.HOME_OFFSET, 0, r)[mask]
        self.origin[sel] = home_raw + offset
        self.hm_attained[sel] = True
        self.hm_phase[sel] = int(_PH.DONE)

    # --- statusword ------------------------------------------------------------------------

    def _statusword(self, r: Rows, state: I64, mode: I64, cw: I64, fe: F64, v_act: F64,
                    dt: F64) -> None:
        col, f = self.col, self.field
        sw = _STATE_BITS[state] | _VOLTAGE_REMOTE
        warn, limited = self.warn[r], self.limited[r]
        if warn.any():
            sw |= warn * 0x0080
        if limited.any():
            sw |= limited * 0x0800
        op = state == S.OPERATION_ENABLED
        if not op.any():
            f(*_K_STATUSWORD)[r] = sw
            return
        if op.all() and (mode == OM.CYCLIC_SYNC_POSITION).all():
            # the usual cycle of a CSP group, the general case below without the other modes
            in_win = (self.g_v[r] == 0) & (np.abs((self.plan_to[r] - self.origin[r])
                                                  - (self.enc_prev[r] - self.origin[r]))
                                           <= col(*_K_POS_WINDOW, r))
            win_t = (self.win_t[r] + dt) * in_win
            self.win_t[r] = win_t
            reached = in_win & (win_t * 1000.0 >= col(*_K_POS_WINDOW_TIME, r) - _THRESH_EPS)
            sw |= (reached * 0x0400 | (self.stop_opt[r] < 0) * 0x1000
                   | (np.abs(fe) > col(*_K_FE_WINDOW, r)) * 0x2000)
            f(*_K_STATUSWORD)[r] = sw
            return
        halted = op & ((cw & 0x100) != 0)
        steady = self.g_v[r] == 0
        pp, pv, hm = mode == OM.PROFILE_POSITION, mode == OM.PROFILE_VELOCITY, mode == OM.HOMING
        csp = mode == OM.CYCLIC_SYNC_POSITION
        csx = csp | (mode == OM.CYCLIC_SYNC_VELOCITY) | (mode == OM.CYCLIC_SYNC_TORQUE)
        zero = _FALSE[: len(sw)] if isinstance(r, slice) else np.zeros(len(sw), bool)
        reached, bit12, bit13 = zero, zero, zero
        if (pp | csp).any():
            user_act = self.enc_prev[r] - self.origin[r]
            tgt_user = self.plan_to[r] - self.origin[r]
            in_win = steady & (np.abs(tgt_user - user_act) <= col(*_K_POS_WINDOW, r))
            win_t = (self.win_t[r] + dt) * in_win
            self.win_t[r] = win_t
            pos_reached = in_win & (win_t * 1000.0 >= col(*_K_POS_WINDOW_TIME, r) - _THRESH_EPS)
            fe_bit = np.abs(fe) > col(*_K_FE_WINDOW, r)
            reached = reached | (csp & pos_reached)
            bit13 = bit13 | ((pp | csp) & fe_bit)
        if (pp | pv | hm).any():
            stand = np.abs(v_act) <= col(*_K_V_THRESHOLD, r)
            vzero_t = (self.vzero_t[r] + dt) * stand
            self.vzero_t[r] = vzero_t
            speed_zero = stand & (vzero_t * 1000.0 >= col(*_K_V_THRESHOLD_TIME, r) - _THRESH_EPS)
            if pp.any():
                reached = reached | (pp & ((~self.pp_active[r] & pos_reached)
                                           | (halted & speed_zero)))
                bit12 = bit12 | (pp & self.pp_ack[r])
            if pv.any():
                v_goal = np.where(halted, 0.0, col(*_K_TARGET_VELOCITY, r))
                v_in = np.abs(v_act - v_goal) <= col(*_K_V_WINDOW, r)
                vwin_t = (self.vwin_t[r] + dt) * v_in
                self.vwin_t[r] = vwin_t
                v_reached = v_in & (vwin_t * 1000.0 >= col(*_K_V_WINDOW_TIME, r) - _THRESH_EPS)
                reached = reached | (pv & v_reached)
                bit12 = bit12 | (pv & speed_zero)
            if hm.any():
                phase = self.hm_phase[r]
                idle_hm = (phase < 0) | (phase >= _PH.DONE)
                reached = reached | (hm & idle_hm & speed_zero & steady)
                bit12 = bit12 | (hm & self.hm_attained[r])
                bit13 = bit13 | (hm & self.hm_error[r])
        if csx.any():
            bit12 = bit12 | (csx & (self.stop_opt[r] < 0))
        sw |= (op & reached) * 0x0400 | (op & bit12) * 0x1000 | (op & bit13) * 0x2000
        f(*_K_STATUSWORD)[r] = sw
