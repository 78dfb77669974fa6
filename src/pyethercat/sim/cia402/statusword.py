"""The statusword of the simulated drive: state bits, and the bits each mode of operation defines.

Bits 0-6 by state, voltage enabled and remote (bits 4, 9), warning (7),
internal limit active (11), then by mode (CiA 402-2, the modes' statusword
tables): target reached (10), set-point acknowledge / speed zero / homing
attained / drive follows the command value (12), following error / homing
error (13). The window timers of 0x6067/0x6068 (position), 0x606D/0x606E
(velocity) and 0x606F/0x6070 (speed zero) run here.
"""

from __future__ import annotations

import numpy as np

from pyethercat.sim.cia402.arrays import DriveArrays
from pyethercat.sim.cia402.axis import Rows
from pyethercat.sim.cia402.keys import (
    F64,
    I64,
    K_FE_WINDOW,
    K_POS_WINDOW,
    K_POS_WINDOW_TIME,
    K_STATUSWORD,
    K_TARGET_VELOCITY,
    K_V_THRESHOLD,
    K_V_THRESHOLD_TIME,
    K_V_WINDOW,
    K_V_WINDOW_TIME,
    OM,
    PH,
    THRESH_EPS,
    S,
    all_of,
    any_of,
)

__all__ = ["statusword"]

# Statusword bits 0-6 by state.
_STATE_BITS = np.array([0x00, 0x40, 0x21, 0x23, 0x27, 0x07, 0x0F, 0x08], np.int64)
_VOLTAGE_REMOTE = 0x0010 | 0x0200
_FALSE = np.zeros(1 << 16, bool)


def statusword(eng: DriveArrays, r: Rows, state: I64, mode: I64, cw: I64, fe: F64, v_act: F64,
               dt: F64) -> None:
    col, f = eng.col, eng.field
    sw = _STATE_BITS[state] | _VOLTAGE_REMOTE
    warn, limited = eng.warn[r], eng.limited[r]
    if any_of(warn):
        sw |= warn * 0x0080
    if any_of(limited):
        sw |= limited * 0x0800
    op = state == S.OPERATION_ENABLED
    if not any_of(op):
        f(*K_STATUSWORD)[r] = sw
        return
    if all_of(op) and all_of(mode == OM.CYCLIC_SYNC_POSITION):
        # the usual cycle of a CSP group, the general case below without the other modes
        in_win = (eng.g_v[r] == 0) & (np.abs((eng.plan_to[r] - eng.origin[r])
                                              - (eng.enc_prev[r] - eng.origin[r]))
                                       <= col(*K_POS_WINDOW, r))
        win_t = (eng.win_t[r] + dt) * in_win
        eng.win_t[r] = win_t
        reached = in_win & (win_t * 1000.0 >= col(*K_POS_WINDOW_TIME, r) - THRESH_EPS)
        sw |= (reached * 0x0400 | (eng.stop_opt[r] < 0) * 0x1000
               | (np.abs(fe) > col(*K_FE_WINDOW, r)) * 0x2000)
        f(*K_STATUSWORD)[r] = sw
        return
    halted = op & ((cw & 0x100) != 0)
    steady = eng.g_v[r] == 0
    pp, pv, hm = mode == OM.PROFILE_POSITION, mode == OM.PROFILE_VELOCITY, mode == OM.HOMING
    csp = mode == OM.CYCLIC_SYNC_POSITION
    csx = csp | (mode == OM.CYCLIC_SYNC_VELOCITY) | (mode == OM.CYCLIC_SYNC_TORQUE)
    zero = _FALSE[: len(sw)] if isinstance(r, slice) else np.zeros(len(sw), bool)
    reached, bit12, bit13 = zero, zero, zero
    if any_of(pp | csp):
        user_act = eng.enc_prev[r] - eng.origin[r]
        tgt_user = eng.plan_to[r] - eng.origin[r]
        in_win = steady & (np.abs(tgt_user - user_act) <= col(*K_POS_WINDOW, r))
        win_t = (eng.win_t[r] + dt) * in_win
        eng.win_t[r] = win_t
        pos_reached = in_win & (win_t * 1000.0 >= col(*K_POS_WINDOW_TIME, r) - THRESH_EPS)
        fe_bit = np.abs(fe) > col(*K_FE_WINDOW, r)
        reached = reached | (csp & pos_reached)
        bit13 = bit13 | ((pp | csp) & fe_bit)
    if any_of(pp | pv | hm):
        stand = np.abs(v_act) <= col(*K_V_THRESHOLD, r)
        vzero_t = (eng.vzero_t[r] + dt) * stand
        eng.vzero_t[r] = vzero_t
        speed_zero = stand & (vzero_t * 1000.0 >= col(*K_V_THRESHOLD_TIME, r) - THRESH_EPS)
        if any_of(pp):
            reached = reached | (pp & ((~eng.pp_active[r] & pos_reached)
                                       | (halted & speed_zero)))
            bit12 = bit12 | (pp & eng.pp_ack[r])
        if any_of(pv):
            v_goal = np.where(halted, 0.0, col(*K_TARGET_VELOCITY, r))
            v_in = np.abs(v_act - v_goal) <= col(*K_V_WINDOW, r)
            vwin_t = (eng.vwin_t[r] + dt) * v_in
            eng.vwin_t[r] = vwin_t
            v_reached = v_in & (vwin_t * 1000.0 >= col(*K_V_WINDOW_TIME, r) - THRESH_EPS)
            reached = reached | (pv & v_reached)
            bit12 = bit12 | (pv & speed_zero)
        if any_of(hm):
            phase = eng.hm_phase[r]
            idle_hm = (phase < 0) | (phase >= PH.DONE)
            reached = reached | (hm & idle_hm & speed_zero & steady)
            bit12 = bit12 | (hm & eng.hm_attained[r])
            bit13 = bit13 | (hm & eng.hm_error[r])
    if any_of(csx):
        bit12 = bit12 | (csx & (eng.stop_opt[r] < 0))
    sw |= (op & reached) * 0x0400 | (op & bit12) * 0x1000 | (op & bit13) * 0x2000
    f(*K_STATUSWORD)[r] = sw
