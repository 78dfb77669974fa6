"""The power state machine of the simulated drive (IEC 61800-7-201 / CiA 402-2, device control).

From the controlword's command and the present state: the table of plain
transitions (:data:`TRANSITIONS`), then beside it the ones that depend on
option codes (quick stop 0x605A, shutdown 0x605B, disable operation 0x605C,
fault reaction 0x605E), on the fault-reset rising edge (bit 7) and on faults
found this cycle; and the end of stop ramps once the axis stands.
"""

from __future__ import annotations

import numpy as np

from pyethercat.sim.cia402.arrays import DriveArrays
from pyethercat.sim.cia402.axis import Rows
from pyethercat.sim.cia402.keys import (
    F64,
    I64,
    K_DISABLE_OPTION,
    K_FAULT_OPTION,
    K_QS_OPTION,
    K_SHUTDOWN_OPTION,
    NO_STOP,
    OBJ,
    SO,
    STAY,
    B,
    S,
)
from pyethercat.wire.cia402 import DriveCommand, DriveState, decode_command

__all__ = ["COMMANDS", "ENABLE", "POWERED", "TRANSITIONS", "quick_stop_code", "stops_done",
           "transitions"]

# Device-control commands by the controlword's low byte (COMMAND_MASKS: bit 7 must be 0).
_NONE_CMD, _SHUTDOWN, _SWITCH_ON, ENABLE, _DISABLE_VOLTAGE, _QUICK_STOP = range(6)
COMMANDS = np.zeros(256, np.int64)
for _cw in range(256):
    _c = decode_command(_cw)
    COMMANDS[_cw] = {None: _NONE_CMD, DriveCommand.SHUTDOWN: _SHUTDOWN,
                     DriveCommand.SWITCH_ON: _SWITCH_ON, DriveCommand.ENABLE_OPERATION: ENABLE,
                     DriveCommand.DISABLE_VOLTAGE: _DISABLE_VOLTAGE,
                     DriveCommand.QUICK_STOP: _QUICK_STOP}[_c]
# Transitions by (state, command); the ones that depend on option codes, stops, edges
# and faults are handled beside the table.
TRANSITIONS = np.repeat(np.arange(8, dtype=np.int64)[:, None], 6, axis=1)
TRANSITIONS[DriveState.SWITCH_ON_DISABLED, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
for _st in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCHED_ON):
    TRANSITIONS[_st, ENABLE] = DriveState.OPERATION_ENABLED          # 3 and 4 at once from ready
    TRANSITIONS[_st, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
    TRANSITIONS[_st, _DISABLE_VOLTAGE] = TRANSITIONS[_st, _QUICK_STOP] = DriveState.SWITCH_ON_DISABLED
TRANSITIONS[DriveState.READY_TO_SWITCH_ON, _SWITCH_ON] = DriveState.SWITCHED_ON
TRANSITIONS[DriveState.OPERATION_ENABLED, _SHUTDOWN] = DriveState.READY_TO_SWITCH_ON
TRANSITIONS[DriveState.OPERATION_ENABLED, _SWITCH_ON] = DriveState.SWITCHED_ON
TRANSITIONS[DriveState.OPERATION_ENABLED, _DISABLE_VOLTAGE] = DriveState.SWITCH_ON_DISABLED
TRANSITIONS[DriveState.OPERATION_ENABLED, _QUICK_STOP] = DriveState.QUICK_STOP_ACTIVE
TRANSITIONS[DriveState.QUICK_STOP_ACTIVE, _DISABLE_VOLTAGE] = DriveState.SWITCH_ON_DISABLED
# States with the power stage on (the loops run, a set-point generator may move).
POWERED = np.zeros(8, bool)
POWERED[[DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE,
         DriveState.FAULT_REACTION_ACTIVE]] = True


def transitions(eng: DriveArrays, r: Rows, state: I64, cmd: I64, cw: I64, prev: I64, stopping: B,
                faulted: B | None) -> tuple[I64, I64]:
    """New states and the stops they start (-1: none; else a stop option)."""
    col = eng.col
    new = TRANSITIONS[state, cmd]
    start = np.full(len(state), NO_STOP, np.int64)
    goal = eng.stop_goal[r].astype(np.int64)
    goal_new = goal.copy()
    sod, rdy, son = S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON
    op, qsa, fra, flt = (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE,
                         S.FAULT)
    m = state == op
    if m.any():
        qs_code = quick_stop_code(eng, r)
        go_qs = m & (cmd == _QUICK_STOP)
        new[go_qs & (qs_code == 0)] = sod         # option 0: torque off at once
        ramp_qs = go_qs & (qs_code != 0)
        start[ramp_qs] = np.where(qs_code > 4, qs_code - 4, qs_code)[ramp_qs]
        goal_new[ramp_qs] = np.where(qs_code > 4, STAY, sod)[ramp_qs]
        # shutdown / disable operation with a ramp (0x605B / 0x605C = 1) keep the state
        # until the axis stands; a stop already on its way is not started again
        for command, key, target in ((_SHUTDOWN, K_SHUTDOWN_OPTION, rdy),
                                     (_SWITCH_ON, K_DISABLE_OPTION, son)):
            asked = m & (cmd == command)
            if asked.any():
                ramp = col(*key, r) == 1
                keep = asked & (ramp | stopping)
                new[keep] = op
                sel = asked & ramp & ~stopping
                start[sel] = SO.SLOW_DOWN_RAMP
                goal_new[sel] = target
        # Enable operation takes back a stop towards Switched on / Ready
        back = m & stopping & (cmd == ENABLE) & ((goal == son) | (goal == rdy))
        if back.any():
            eng.stop_opt[r] = np.where(back, NO_STOP, eng.stop_opt[r])
    m = state == qsa
    if m.any():
        qs_code = quick_stop_code(eng, r)
        back = m & (cmd == ENABLE) & (qs_code >= 5) & ~stopping
        new[back] = op
    edge = ((cw & 0x80) != 0) & ((prev & 0x80) == 0)
    new[(state == flt) & edge] = sod
    if faulted is not None:
        react = col(*K_FAULT_OPTION, r).astype(np.int64)
        powered = (state == op) | (state == qsa)
        f_ramp = faulted & powered & (react != 0)
        new[faulted & (state != flt) & (state != fra)] = flt
        new[f_ramp] = fra
        start[f_ramp] = react[f_ramp]
        goal_new[f_ramp] = flt
    # power off ends any stop
    off = (new != op) & (new != qsa) & (new != fra)
    start[off] = NO_STOP
    eng.stop_opt[r] = np.where(start >= 0, start, np.where(off, NO_STOP, eng.stop_opt[r]))
    eng.stop_goal[r] = goal_new
    return new, start


def quick_stop_code(eng: DriveArrays, r: Rows) -> I64:
    """0x605A; negative (manufacturer-specific) values act as 2, the quick stop ramp."""
    code = eng.col(*K_QS_OPTION, r).astype(np.int64)
    out: I64 = np.where(code < 0, 2, code)
    return out


def stops_done(eng: DriveArrays, r: Rows, new: I64, v_act: F64) -> I64:
    """States after stops that finished this cycle (the axis stands)."""
    stop = eng.stop_opt[r]
    still = (eng.g_v[r] == 0) & (np.abs(v_act) <= eng.col(OBJ.VELOCITY_THRESHOLD, 0, r))
    done = (stop >= 0) & still
    if done.any():
        goal = eng.stop_goal[r].astype(np.int64)
        new = np.where(done & (goal >= 0), goal, new)
        eng.stop_opt[r] = np.where(done, NO_STOP, stop)
    return new
