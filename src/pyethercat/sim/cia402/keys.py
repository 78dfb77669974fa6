"""What the parts of the drive cycle share: entry keys, enums as plain ints, array types.

The cycle (``engine``), the power state machine (``power``), the set-point
generators (``setpoint``), homing (``homing``) and the statusword
(``statusword``) read the same object dictionary entries, as ``(index,
subindex)`` keys of the kind's image columns.
"""

from __future__ import annotations

from enum import IntEnum
from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cia402.objects import AXIS_OBJECT, AxisSub
from pyethercat.wire.cia402 import DriveErrorCode, DriveState, OperationMode, StopOption
from pyethercat.wire.mailbox.objects import Cia402Object

__all__ = [
    "AX", "B", "DE", "F64", "I64", "K_CW", "K_DISABLE_OPTION", "K_ERROR",
    "K_FAULT_OPTION", "K_FE", "K_FE_TIMEOUT", "K_FE_WINDOW", "K_HOME", "K_INPUTS",
    "K_LIMIT_MAX", "K_LIMIT_MIN", "K_MODE", "K_MODE_DISPLAY", "K_NEG_LIMIT",
    "K_POSITION", "K_POSITION_DEMAND", "K_POSITION_OFFSET", "K_POS_LIMIT",
    "K_POS_WINDOW", "K_POS_WINDOW_TIME", "K_QS_OPTION", "K_RATED", "K_SHUTDOWN_OPTION",
    "K_STATUSWORD", "K_TARGET_POSITION", "K_TARGET_VELOCITY", "K_TORQUE",
    "K_TORQUE_DEMAND", "K_TORQUE_OFFSET", "K_VELOCITY", "K_VELOCITY_DEMAND",
    "K_VELOCITY_OFFSET", "K_V_THRESHOLD", "K_V_THRESHOLD_TIME", "K_V_WINDOW",
    "K_V_WINDOW_TIME", "NO_STOP", "OBJ", "OM", "PH", "Phase", "S", "SO", "STAY", "THRESH_EPS",
    "all_of", "any_of", "ints",
]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]


def any_of(mask: B) -> bool:
    """``mask.any()`` of a bool array as a byte search (a bool is the byte 0 or 1).

    The cycle asks a dozen such questions of arrays of a few elements; numpy's
    reduction costs several microseconds each there, the search a tenth of one.
    """
    return 1 in mask.tobytes()


def all_of(mask: B) -> bool:
    """``mask.all()`` of a bool array as a byte search (see :func:`any_of`)."""
    return 0 not in mask.tobytes()


def ints(enum: type[IntEnum]) -> Any:
    """An enum's members as plain ints: IntEnum attribute lookups cost microseconds each,
    and the drive cycle makes hundreds of them."""
    return SimpleNamespace(**{m.name: int(m) for m in enum})


class Phase(IntEnum):
    """Homing phases beyond the search steps (0 .. steps-1); ``sim.cia402.homing`` runs them."""

    IDLE = -1
    APPROACH = 10
    """Moving on at zero-search speed until the index pulse is passed."""
    STOP = 11
    """Decelerating with the homing acceleration 0x609A."""
    DONE = 12
    ERROR = 13


OBJ = ints(Cia402Object)
S = ints(DriveState)
OM = ints(OperationMode)
AX = ints(AxisSub)
SO = ints(StopOption)
DE = ints(DriveErrorCode)
PH = ints(Phase)

# The entries the cycle reads and writes, as (index, subindex).
K_CW, K_MODE, K_MODE_DISPLAY = (0x6040, 0), (0x6060, 0), (0x6061, 0)
K_ERROR, K_STATUSWORD = (0x603F, 0), (0x6041, 0)
K_FE_WINDOW, K_FE_TIMEOUT = (0x6065, 0), (0x6066, 0)
K_NEG_LIMIT, K_POS_LIMIT, K_HOME = ((AXIS_OBJECT, int(AxisSub.NEGATIVE_LIMIT_SWITCH)),
                                    (AXIS_OBJECT, int(AxisSub.POSITIVE_LIMIT_SWITCH)),
                                    (AXIS_OBJECT, int(AxisSub.HOME_SWITCH)))
K_POSITION, K_VELOCITY, K_TORQUE = (0x6064, 0), (0x606C, 0), (0x6077, 0)
K_TORQUE_DEMAND, K_POSITION_DEMAND, K_VELOCITY_DEMAND = (0x6074, 0), (0x6062, 0), (0x606B, 0)
K_FE, K_INPUTS, K_RATED = (0x60F4, 0), (0x60FD, 0), (0x6076, 0)
K_QS_OPTION, K_SHUTDOWN_OPTION, K_DISABLE_OPTION = (0x605A, 0), (0x605B, 0), (0x605C, 0)
K_FAULT_OPTION = (0x605E, 0)
K_POS_WINDOW, K_POS_WINDOW_TIME = (0x6067, 0), (0x6068, 0)
K_V_WINDOW, K_V_WINDOW_TIME = (0x606D, 0), (0x606E, 0)
K_V_THRESHOLD, K_V_THRESHOLD_TIME = (0x606F, 0), (0x6070, 0)
K_TARGET_VELOCITY = (0x60FF, 0)
K_TARGET_POSITION, K_POSITION_OFFSET = (0x607A, 0), (0x60B0, 0)
K_VELOCITY_OFFSET, K_TORQUE_OFFSET = (0x60B1, 0), (0x60B2, 0)
K_LIMIT_MIN, K_LIMIT_MAX = (0x607D, 1), (0x607D, 2)

#: No stop in progress (``stop_opt``); a stop that ends in the state it is in (``stop_goal``).
NO_STOP = -1
STAY = -1
#: Slack of the window timers' comparisons (float sums of cycle times).
THRESH_EPS = 1e-9
