"""The per-axis state of the simulated CiA 402 drives, as arrays indexed by instance.

:class:`DriveArrays` holds what the parts of a drive cycle read and write:
the power state machine (``sim.cia402.power``), the set-point generators
(``sim.cia402.setpoint``), homing (``sim.cia402.homing``) and the statusword
(``sim.cia402.statusword``) take it as their first argument;
:class:`~pyethercat.sim.cia402.engine.DriveEngine` derives from it and runs
the cycle. The parts therefore depend on this module, not on the engine
that calls them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pyethercat.sim.cia402.axis import AxisModel
from pyethercat.sim.cia402.keys import F64, NO_STOP, OBJ, PH, STAY, S
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire.mailbox.objects import StandardObject
from pyethercat.wire.sii import SiiInfo

__all__ = ["DRIVE_FIELDS", "DriveArrays"]

#: Parameter entries the cycle reads (beyond the PDO-mappable ones and the axis').
DRIVE_FIELDS: tuple[tuple[int, int], ...] = (
    (OBJ.ERROR_CODE, 0), (OBJ.QUICK_STOP_OPTION_CODE, 0), (OBJ.SHUTDOWN_OPTION_CODE, 0),
    (OBJ.DISABLE_OPERATION_OPTION_CODE, 0), (OBJ.HALT_OPTION_CODE, 0),
    (OBJ.FAULT_REACTION_OPTION_CODE, 0), (OBJ.FOLLOWING_ERROR_WINDOW, 0),
    (OBJ.FOLLOWING_ERROR_TIMEOUT, 0), (OBJ.POSITION_WINDOW, 0), (OBJ.POSITION_WINDOW_TIME, 0),
    (OBJ.VELOCITY_WINDOW, 0), (OBJ.VELOCITY_WINDOW_TIME, 0), (OBJ.VELOCITY_THRESHOLD, 0),
    (OBJ.VELOCITY_THRESHOLD_TIME, 0), (OBJ.HOME_OFFSET, 0), (OBJ.SOFTWARE_POSITION_LIMIT, 1),
    (OBJ.SOFTWARE_POSITION_LIMIT, 2), (OBJ.MAX_PROFILE_VELOCITY, 0), (OBJ.PROFILE_VELOCITY, 0),
    (OBJ.PROFILE_ACCELERATION, 0), (OBJ.PROFILE_DECELERATION, 0), (OBJ.QUICK_STOP_DECELERATION, 0),
    (OBJ.MAX_ACCELERATION, 0), (OBJ.MAX_DECELERATION, 0), (OBJ.HOMING_METHOD, 0),
    (OBJ.HOMING_SPEEDS, 1), (OBJ.HOMING_SPEEDS, 2), (OBJ.HOMING_ACCELERATION, 0),
    (OBJ.TARGET_POSITION, 0), (OBJ.TARGET_VELOCITY, 0), (OBJ.TARGET_TORQUE, 0),
    (OBJ.POSITION_OFFSET, 0), (OBJ.VELOCITY_OFFSET, 0), (OBJ.TORQUE_OFFSET, 0),
    (OBJ.CONTROLWORD, 0), (OBJ.MODES_OF_OPERATION, 0), (OBJ.STATUSWORD, 0),
    (OBJ.MODES_OF_OPERATION_DISPLAY, 0), (OBJ.POSITION_ACTUAL_VALUE, 0),
    (OBJ.VELOCITY_ACTUAL_VALUE, 0), (OBJ.TORQUE_ACTUAL_VALUE, 0), (OBJ.POSITION_DEMAND_VALUE, 0),
    (OBJ.VELOCITY_DEMAND_VALUE, 0), (OBJ.TORQUE_DEMAND, 0), (OBJ.FOLLOWING_ERROR_ACTUAL_VALUE, 0),
    (OBJ.DIGITAL_INPUTS, 0), (StandardObject.ERROR_SETTINGS, 2),
)


class DriveArrays(AxisModel):
    """The drive state of every axis of a kind (the mechanics' arrays are :class:`AxisModel`'s)."""

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
        self.stop_opt = arr("stop_opt", np.int8, NO_STOP)
        self.stop_goal = arr("stop_goal", np.int8, STAY)
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
        self.hm_phase = arr("hm_phase", np.int8, int(PH.IDLE))
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
