"""The next cycle's set-point of the simulated drive, by mode of operation.

:func:`plan` sets the plan the inner loops follow over the next cycle
(``sim.cia402.axis``): CSP, CSV and CST take the master's targets as they
come; profile position, profile velocity and homing generate the demand
(``sim.cia402.profile``, ``sim.cia402.homing``); stop ramps (quick stop,
fault reaction, disable with a ramp) and halt brake from where the axis is.
Software position limits 0x607D clamp position targets. :func:`plan_csp` is
the usual cycle of a CSP group, the general case without the other modes.
"""

from __future__ import annotations

import numpy as np

from pyethercat.sim.cia402 import homing
from pyethercat.sim.cia402.arrays import DriveArrays
from pyethercat.sim.cia402.axis import CTRL_OFF, CTRL_POSITION, CTRL_TORQUE, CTRL_VELOCITY, Rows
from pyethercat.sim.cia402.keys import (
    F64,
    I64,
    K_LIMIT_MAX,
    K_LIMIT_MIN,
    K_POSITION_OFFSET,
    K_RATED,
    K_TARGET_POSITION,
    K_TORQUE_OFFSET,
    K_VELOCITY_OFFSET,
    OBJ,
    OM,
    SO,
    B,
    S,
    all_of,
    any_of,
)
from pyethercat.sim.cia402.profile import profile_move, ramp_velocity

__all__ = ["acc_dec", "max_velocity", "plan", "plan_csp", "profile_position", "stop_deceleration",
           "torque"]


def plan(eng: DriveArrays, r: Rows, inst: I64, state: I64, mode: I64, cw: I64, prev: I64, dt: F64,
         safe_dt: F64, start_stop: I64 | None, switches: tuple[B, B, B]) -> None:
    """The next cycle's plan of every axis (see :class:`~pyethercat.sim.cia402.axis.AxisModel`)."""
    if (start_stop is None and all_of(state == S.OPERATION_ENABLED)
            and all_of(mode == OM.CYCLIC_SYNC_POSITION)
            and all_of(eng.plan_mode[r] == CTRL_POSITION)
            and not any_of(eng.stop_opt[r] >= 0)):
        plan_csp(eng, r, safe_dt)  # the usual cycle of a CSP group: its own short path
        return
    col = eng.col
    p, v = eng.p[r], eng.v[r]
    powered = (state == S.OPERATION_ENABLED) | (state == S.QUICK_STOP_ACTIVE) | (
        state == S.FAULT_REACTION_ACTIVE)
    stop = eng.stop_opt[r].astype(np.int64)
    stopping = powered & (stop >= 0)
    just_on = powered & (eng.plan_mode[r] == CTRL_OFF)
    # a stop brakes from where the axis is and how fast it moves (after a following
    # error the demand may be far away)
    fresh = just_on if start_stop is None else just_on | (start_stop >= 0)
    if all_of(powered) and not any_of(fresh):
        g_p, g_v = eng.g_p[r].copy(), eng.g_v[r].copy()
    else:
        g_p = np.where(powered & ~fresh, eng.g_p[r], p)
        g_v = np.where(powered & ~fresh, eng.g_v[r], np.where(powered & ~just_on, v, 0.0))
    origin = eng.origin[r]
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
    if any_of(ramp_to_zero):
        opt = np.where(stopping, stop, col(OBJ.HALT_OPTION_CODE, 0, r).astype(np.int64))
        dec = stop_deceleration(eng, r, opt)
        rv = ramp_velocity(g_v, np.zeros_like(g_v), dec, dec, dt)
        new_v = np.where(ramp_to_zero, rv, new_v)
        new_p = np.where(ramp_to_zero, g_p + (g_v + rv) * 0.5 * dt, new_p)
    active = running & ~halt
    lo, hi = col(OBJ.SOFTWARE_POSITION_LIMIT, 1, r), col(OBJ.SOFTWARE_POSITION_LIMIT, 2, r)
    limits = lo < hi
    limited = np.zeros(len(p), bool)
    m = active & (mode == OM.CYCLIC_SYNC_POSITION)
    if any_of(m):
        tgt = col(OBJ.TARGET_POSITION, 0, r) + col(OBJ.POSITION_OFFSET, 0, r)
        clamped = np.where(limits, np.clip(tgt, lo, hi), tgt)
        limited |= m & (clamped != tgt)
        raw = clamped + origin
        new_v = np.where(m, (raw - g_p) / safe_dt, new_v)
        new_p = np.where(m, raw, new_p)
        vff_extra = np.where(m, col(OBJ.VELOCITY_OFFSET, 0, r), vff_extra)
        tff = np.where(m, torque(eng, r, col(OBJ.TORQUE_OFFSET, 0, r)), tff)
    m = active & (mode == OM.CYCLIC_SYNC_VELOCITY)
    if any_of(m):
        vel = col(OBJ.TARGET_VELOCITY, 0, r) + col(OBJ.VELOCITY_OFFSET, 0, r)
        ctrl = np.where(m, CTRL_VELOCITY, ctrl)
        vcmd = np.where(m, vel, vcmd)
        new_v = np.where(m, vel, new_v)
        new_p = np.where(m, p, new_p)
    m = active & (mode == OM.CYCLIC_SYNC_TORQUE)
    if any_of(m):
        ctrl = np.where(m, CTRL_TORQUE, ctrl)
        tcmd = np.where(m, torque(eng, r, col(OBJ.TARGET_TORQUE, 0, r)
                                       + col(OBJ.TORQUE_OFFSET, 0, r)), tcmd)
        new_v = np.where(m, v, new_v)
        new_p = np.where(m, p, new_p)
    m = running & (mode == OM.PROFILE_POSITION)
    if any_of(m):
        new_p, new_v, lim = profile_position(eng, r, inst, m, halt, cw, prev, g_p, g_v,
                                                    new_p, new_v, dt, lo, hi, limits)
        limited |= lim
    m = active & (mode == OM.PROFILE_VELOCITY)
    if any_of(m):
        goal = np.clip(col(OBJ.TARGET_VELOCITY, 0, r), -max_velocity(eng, r), max_velocity(eng, r))
        acc, dec = acc_dec(eng, r)
        rv = ramp_velocity(g_v, goal, acc, dec, dt)
        ctrl = np.where(m, CTRL_VELOCITY, ctrl)
        vcmd = np.where(m, rv, vcmd)
        new_v = np.where(m, rv, new_v)
        new_p = np.where(m, p, new_p)
    m = running & (mode == OM.HOMING)
    if any_of(m):
        g_p, g_v, new_p, new_v = homing.run_homing(eng, r, inst, m, halt, cw, prev, p, g_p, g_v, new_p,
                                              new_v, dt, switches)
    # commit the plan
    position = ctrl == CTRL_POSITION
    was_position = eng.plan_mode[r] == CTRL_POSITION
    eng.plan_mode[r] = ctrl
    eng.plan_from[r] = np.where(powered, g_p, p)
    eng.plan_to[r] = np.where(powered, new_p, p)
    vff = ((new_p - g_p) / safe_dt + vff_extra) * position
    # acceleration feed-forward: the torque the demanded change of velocity needs
    # (inertia), as servo drives add it to the velocity loop's output. A generated
    # demand (profile position, homing, stop ramps) goes from g_v to new_v over the
    # cycle; in CSP new_v is the cycle's mean velocity and g_v the last cycle's.
    accel = (new_v - g_v) / safe_dt * (position & was_position)
    consts = eng.constants(r)
    inertia = consts.inertia / consts.counts_per_rad
    eng.plan_vff[r] = vff
    eng.plan_tff[r] = tff + inertia * accel
    eng.plan_acc[r] = accel
    eng.plan_v[r] = vcmd
    eng.plan_t[r] = tcmd
    eng.g_p[r] = np.where(powered, new_p, p)
    eng.g_v[r] = np.where(powered, new_v, v)
    eng.limited[r] = limited


def plan_csp(eng: DriveArrays, r: Rows, safe_dt: F64) -> None:
    """Every axis enabled in CSP and running: the target is the next demand."""
    col = eng.col
    g_p = eng.g_p[r].copy()
    tgt = col(*K_TARGET_POSITION, r) + col(*K_POSITION_OFFSET, r)
    lo, hi = col(*K_LIMIT_MIN, r), col(*K_LIMIT_MAX, r)
    limits = lo < hi
    limited = np.zeros(len(g_p), bool)
    if any_of(limits):
        clamped = np.where(limits, np.minimum(np.maximum(tgt, lo), hi), tgt)
        limited = clamped != tgt
        tgt = clamped
    raw = tgt + eng.origin[r]
    vff = (raw - g_p) / safe_dt + col(*K_VELOCITY_OFFSET, r)
    consts = eng.constants(r)
    accel = (vff - eng.plan_vff[r]) / safe_dt
    eng.plan_from[r] = g_p
    eng.plan_to[r] = raw
    eng.plan_vff[r] = vff
    eng.plan_tff[r] = (col(*K_TORQUE_OFFSET, r) * col(*K_RATED, r) * 1e-6
                        + consts.inertia / consts.counts_per_rad * accel)
    eng.plan_acc[r] = accel
    eng.g_p[r] = raw
    eng.g_v[r] = (raw - g_p) / safe_dt
    eng.limited[r] = limited


def torque(eng: DriveArrays, r: Rows, per_mille: F64) -> F64:
    out: F64 = per_mille * eng.col(OBJ.MOTOR_RATED_TORQUE, 0, r) * 1e-6
    return out


def max_velocity(eng: DriveArrays, r: Rows) -> F64:
    cap = eng.col(OBJ.MAX_PROFILE_VELOCITY, 0, r)
    out: F64 = np.where(cap > 0, cap, np.inf)
    return out


def acc_dec(eng: DriveArrays, r: Rows) -> tuple[F64, F64]:
    col = eng.col
    acc = col(OBJ.PROFILE_ACCELERATION, 0, r)
    dec = col(OBJ.PROFILE_DECELERATION, 0, r)
    amax, dmax = col(OBJ.MAX_ACCELERATION, 0, r), col(OBJ.MAX_DECELERATION, 0, r)
    acc = np.where(amax > 0, np.minimum(acc, amax), acc)
    dec = np.where(dmax > 0, np.minimum(dec, dmax), dec)
    return np.maximum(acc, 1.0), np.maximum(dec, 1.0)


def stop_deceleration(eng: DriveArrays, r: Rows, option: I64) -> F64:
    """Deceleration of a stop by :class:`StopOption` (inc/s²)."""
    col = eng.col
    _acc, slow = acc_dec(eng, r)
    quick = np.maximum(col(OBJ.QUICK_STOP_DECELERATION, 0, r), 1.0)
    limit = np.maximum(eng.max_acceleration(r), 1.0)
    out: F64 = np.select([option == SO.SLOW_DOWN_RAMP,
                          option == SO.QUICK_STOP_RAMP], [slow, quick], limit)
    return out


def profile_position(eng: DriveArrays, r: Rows, inst: I64, m: B, halt: B, cw: I64, prev: I64,
                     g_p: F64, g_v: F64, new_p: F64, new_v: F64, dt: F64, lo: F64, hi: F64,
                     limits: B) -> tuple[F64, F64, B]:
    """Profile position: set-point handshake (bits 4, 5, 6, 9 / status bit 12) and the move."""
    col = eng.col
    origin = eng.origin[r]
    edge = m & ((cw & 0x10) != 0) & ((prev & 0x10) == 0)
    ack, active = eng.pp_ack[r], eng.pp_active[r]
    buffered = eng.pp_buffered[r]
    goal, buf = eng.pp_goal[r], eng.pp_buf[r]
    tgt = col(OBJ.TARGET_POSITION, 0, r)
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
    vmax = np.minimum(col(OBJ.PROFILE_VELOCITY, 0, r), max_velocity(eng, r))
    acc, dec = acc_dec(eng, r)
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
    eng.pp_ack[sel], eng.pp_active[sel] = ack[m], active[m]
    eng.pp_buffered[sel], eng.pp_goal[sel], eng.pp_buf[sel] = buffered[m], goal[m], buf[m]
    return new_p, new_v, m & (clamped != user) & take
