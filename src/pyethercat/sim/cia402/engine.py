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
   stop option codes 0x605B/0x605C/0x605E and halt 0x605D (``sim.cia402.power``);
5. the set-point of the next cycle by mode of operation (CSP/CSV/CST take
   the targets as they come; PP, PV, homing and every stop ramp generate
   it); software position limits 0x607D clamp position targets
   (``sim.cia402.setpoint``, homing in ``sim.cia402.homing``);
6. the statusword with the mode-dependent bits (``sim.cia402.statusword``)
   and the other inputs.

The engine runs the cycle over the per-axis state arrays of
``sim.cia402.arrays`` (:class:`DriveArrays`, its base); the parts above are
functions of those arrays in their own modules, so a reader finds each
concern by file name, and no part imports the engine.

Faults found here are returned to the caller (the device model), which
sends the emergencies: rare events, plain Python per instance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pyethercat.sim.cia402 import power, setpoint, statusword
from pyethercat.sim.cia402.arrays import DRIVE_FIELDS, DriveArrays
from pyethercat.sim.cia402.axis import CTRL_POSITION, Rows
from pyethercat.sim.cia402.keys import (
    DE,
    F64,
    I64,
    K_CW,
    K_ERROR,
    K_FE,
    K_FE_TIMEOUT,
    K_FE_WINDOW,
    K_HOME,
    K_INPUTS,
    K_MODE,
    K_MODE_DISPLAY,
    K_NEG_LIMIT,
    K_POS_LIMIT,
    K_POSITION,
    K_POSITION_DEMAND,
    K_RATED,
    K_TORQUE,
    K_TORQUE_DEMAND,
    K_VELOCITY,
    K_VELOCITY_DEMAND,
    PH,
    THRESH_EPS,
    B,
    S,
    all_of,
    any_of,
)
from pyethercat.sim.cia402.objects import DRIVE_MODES
from pyethercat.sim.cia402.power import COMMANDS, ENABLE, POWERED
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire.sii import SiiInfo

__all__ = ["DRIVE_FIELDS", "DriveEngine", "Faults"]

#: What a cycle found: (instances, error codes, detail values) of new faults, and the
#: instances whose fault was reset.
Faults = tuple[I64, I64, I64, I64]

# Supported modes by the int8 value of 0x6060 (+128).
_SUPPORTED = np.zeros(256, bool)
for _m in DRIVE_MODES:
    _SUPPORTED[int(_m) + 128] = True
_NONE = np.zeros(0, np.int64)
#: Actual values written when a PDO maps them, else when an SDO reads them.
_LAZY = frozenset({K_POSITION, K_VELOCITY, K_TORQUE, K_TORQUE_DEMAND, K_POSITION_DEMAND,
                   K_VELOCITY_DEMAND, K_FE, K_INPUTS})


class DriveEngine(DriveArrays):
    """CiA 402 behaviour of a drive kind over its axes (see the module docstring)."""

    def __init__(self, dictionary: Callable[[SiiInfo, MailboxDevice], SimObjectDictionary], *,
                 details: int, capacity_out: int = 128, capacity_in: int = 128) -> None:
        super().__init__(dictionary, details=details, capacity_out=capacity_out,
                         capacity_in=capacity_in)
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
        dt_ok = dt > 0
        all_dt = all_of(dt_ok)
        rest_in = (self.idle_fast_path and len(dt) > 0 and all_dt
                   and not np.count_nonzero(self.plan_mode[r])
                   and not np.count_nonzero(self.v[r]))
        self.integrate(r, dt)
        safe_dt = dt if all_dt else np.where(dt_ok, dt, 1.0)
        enc = self.encoder(r)
        v_act = (enc - self.enc_prev[r]) / safe_dt
        self.enc_prev[r] = enc
        p = self.p[r]
        state = self.state[r].astype(np.int64)
        cw = f(*K_CW)[r].astype(np.int64)
        al = self.al_op[r]
        if not all_of(al):
            cw = np.where(al, cw, 0)  # outputs count in OP only
        prev = self.prev_cw[r].copy()
        self.prev_cw[r] = cw
        # --- supervision ----------------------------------------------------------------
        enabled = state == S.OPERATION_ENABLED
        fe = (self.plan_to[r] - p) * (self.plan_mode[r] == CTRL_POSITION)
        over = (np.abs(fe) > col(*K_FE_WINDOW, r)) & enabled
        fe_t = (self.fe_t[r] + dt) * over
        self.fe_t[r] = fe_t
        fe_fault = over & (fe_t * 1000.0 > col(*K_FE_TIMEOUT, r) - THRESH_EPS)
        neg = p <= col(*K_NEG_LIMIT, r)
        posl = p >= col(*K_POS_LIMIT, r)
        home = p >= col(*K_HOME, r)
        faulted: B | None = None
        code = detail = None
        switch = neg | posl
        if any_of(fe_fault) or any_of(switch):
            homing = self.hm_phase[r] >= 0
            moving_neg = (self.g_v[r] < 0) | (self.v[r] < -1.0)
            moving_pos = (self.g_v[r] > 0) | (self.v[r] > 1.0)
            lim_fault = enabled & ~homing & ((neg & moving_neg) | (posl & moving_pos))
            faulted = fe_fault | lim_fault
            code = np.where(fe_fault, DE.FOLLOWING_ERROR, np.where(lim_fault, DE.REFERENCE_LIMIT, 0))
            detail = np.where(fe_fault, np.round(fe), np.where(neg, 1, 2)).astype(np.int64)
            if not any_of(faulted):
                faulted = None
        # --- power state machine ----------------------------------------------------------
        cmd = COMMANDS[cw & 0xFF]
        stopping = self.stop_opt[r] >= 0
        if faulted is None and all_of(enabled) and all_of(cmd == ENABLE) and not any_of(stopping):
            new, start_stop = state, None  # the usual cycle: enabled, stays enabled
        else:
            new, start_stop = power.transitions(self, r, state, cmd, cw, prev, stopping, faulted)
        reset = None if new is state else (state == S.FAULT) & (new == S.SWITCH_ON_DISABLED)
        # --- modes and the next set-point -------------------------------------------------
        shown = f(*K_MODE_DISPLAY)[r]
        rest_in = (rest_in and faulted is None and not any_of(POWERED[new])
                   and all_of(new == state) and not np.count_nonzero(v_act)
                   and all_of(f(*K_MODE)[r] == shown))
        mode = self._mode(r, inst)
        setpoint.plan(self, r, inst, new, mode, cw, prev, dt, safe_dt, start_stop, (neg, posl, home))
        if any_of(self.stop_opt[r] >= 0):
            new = power.stops_done(self, r, new, v_act)
        self.state[r] = new
        # --- inputs: the ones a PDO maps now; the others when an SDO reads them -------------
        self.v_act[r] = v_act
        self.fe_val[r] = fe
        self.inputs(r, self.tx_keys())
        statusword.statusword(self, r, new, mode, cw, fe, v_act, dt)
        clear = _NONE if reset is None else inst[reset]
        if len(clear):
            f(*K_ERROR)[clear] = 0
        elif rest_in and not np.count_nonzero(self.v[r]):
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
        if keys is None or K_POSITION in keys:
            f(*K_POSITION)[r] = self.enc_prev[r] - origin
        if keys is None or K_VELOCITY in keys:
            f(*K_VELOCITY)[r] = np.round(self.v_act[r])
        if keys is None or K_TORQUE in keys or K_TORQUE_DEMAND in keys:
            per_mille = np.round(self.torque[r] * (1e6 / np.maximum(col(*K_RATED, r), 1e-9)))
            f(*K_TORQUE)[r] = per_mille
            f(*K_TORQUE_DEMAND)[r] = per_mille
        if keys is None or K_POSITION_DEMAND in keys:
            f(*K_POSITION_DEMAND)[r] = np.round(self.plan_from[r] - origin)
        if keys is None or K_VELOCITY_DEMAND in keys:
            f(*K_VELOCITY_DEMAND)[r] = np.round(self.g_v[r])
        if keys is None or K_FE in keys:
            f(*K_FE)[r] = np.round(self.fe_val[r])
        if keys is None or K_INPUTS in keys:
            p = self.p[r]
            f(*K_INPUTS)[r] = ((p <= col(*K_NEG_LIMIT, r)) * 1 + (p >= col(*K_POS_LIMIT, r)) * 2
                                + (p >= col(*K_HOME, r)) * 4)

    def _read(self, instance: int, key: tuple[int, int]) -> bytes:
        if key in _LAZY and key not in self.tx_keys():
            self.inputs(np.array([instance], np.int64), None)
        return super()._read(instance, key)


    def _mode(self, r: Rows, inst: I64) -> I64:
        """Mode display after this cycle (0x6061 follows 0x6060 when the mode is supported)."""
        f = self.field
        want = f(*K_MODE)[r].astype(np.int64)
        shown = f(*K_MODE_DISPLAY)[r].astype(np.int64)
        take = (want != shown) & _SUPPORTED[want + 128]
        if not any_of(take):
            return shown
        mode: I64 = np.where(take, want, shown)
        f(*K_MODE_DISPLAY)[r] = mode
        # a new mode starts from where the axis stands, with its sub-states cleared
        changed = inst[take]
        self.pp_active[changed] = self.pp_buffered[changed] = self.pp_ack[changed] = False
        self.hm_phase[changed] = PH.IDLE
        self.g_p[changed] = self.plan_to[changed]
        return mode


    # --- helpers of the plan ---------------------------------------------------------------


    # --- statusword ------------------------------------------------------------------------

