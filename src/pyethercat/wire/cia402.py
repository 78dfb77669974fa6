"""CiA 402 drive profile (IEC 61800-7-201, ETG.6010): one table shared by master and simulator.

- the power state machine: :class:`DriveState`, the statusword masks that
  decode it (:data:`STATE_MASKS`, :func:`decode_state`, :func:`decode_states`
  for many drives at once), the bit pattern a drive shows in each state
  (:data:`STATE_BITS`);
- :class:`Statusword` and :class:`Controlword` bits, the device-control
  commands (:class:`DriveCommand`) with the masks a drive decodes them by
  (:data:`COMMAND_MASKS`), and :func:`command_path`, the controlwords that
  walk a drive from one state to another;
- modes of operation 0x6060/0x6061 (:class:`OperationMode`, :func:`parse_mode`)
  and their bits in 0x6502 "supported drive modes";
- option codes of 0x605A-0x605E, the homing methods the project knows
  (:data:`HOMING_METHODS`), the emergency error codes drives use
  (:class:`DriveErrorCode`).

The masks are those of IEC 61800-7-201 (statusword 0x6041; also ETG.6010): a state is decoded
from bits 0-3, 5 and 6; bit 4 (voltage enabled), 7 (warning) and bits 8-15
do not take part.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError

__all__ = [
    "COMMAND_MASKS",
    "HOMING_METHODS",
    "MODE_NAMES",
    "STATE_BITS",
    "STATE_MASKS",
    "Controlword",
    "DriveCommand",
    "DriveErrorCode",
    "DriveState",
    "OperationMode",
    "QuickStopOption",
    "StopOption",
    "Statusword",
    "command_path",
    "decode_command",
    "decode_state",
    "decode_states",
    "parse_mode",
    "supported_modes",
    "supported_modes_word",
]


class DriveState(IntEnum):
    """States of the CiA 402 power state machine."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7

    @property
    def label(self) -> str:
        """The standard's name: "Operation enabled", "Switch on disabled" ..."""
        return self.name.replace("_", " ").capitalize()


#: (mask, value, state) in the order a statusword is matched (IEC 61800-7-201 table 30).
STATE_MASKS: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, DriveState.SWITCH_ON_DISABLED),
    (0x6F, 0x21, DriveState.READY_TO_SWITCH_ON),
    (0x6F, 0x23, DriveState.SWITCHED_ON),
    (0x6F, 0x27, DriveState.OPERATION_ENABLED),
    (0x6F, 0x07, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, DriveState.FAULT),
)

#: Statusword bits 0-6 a drive shows in each state (bit 5 "quick stop" is 1 = not active).
STATE_BITS: dict[DriveState, int] = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x00,
    DriveState.SWITCH_ON_DISABLED: 0x40,
    DriveState.READY_TO_SWITCH_ON: 0x21,
    DriveState.SWITCHED_ON: 0x23,
    DriveState.OPERATION_ENABLED: 0x27,
    DriveState.QUICK_STOP_ACTIVE: 0x07,
    DriveState.FAULT_REACTION_ACTIVE: 0x0F,
    DriveState.FAULT: 0x08,
}


def decode_state(statusword: int) -> DriveState | None:
    """The state a statusword shows; None for a pattern the standard does not define."""
    for mask, value, state in STATE_MASKS:
        if statusword & mask == value:
            return state
    return None


#: Lookup of the decoded state by the statusword's low 7 bits (-1: undefined pattern).
_STATE_LUT = np.array([int(s) if (s := decode_state(v)) is not None else -1 for v in range(128)],
                      np.int8)


def decode_states(statuswords: npt.ArrayLike) -> npt.NDArray[np.int8]:
    """:class:`DriveState` values of many statuswords at once (-1: undefined pattern)."""
    sw = np.asarray(statuswords, np.int64)
    out: npt.NDArray[np.int8] = _STATE_LUT[sw & 0x7F]
    return out


class Statusword(IntFlag):
    """Statusword 0x6041 bits. Bits 10, 12 and 13 depend on the mode of operation."""

    READY_TO_SWITCH_ON = 0x0001
    SWITCHED_ON = 0x0002
    OPERATION_ENABLED = 0x0004
    FAULT = 0x0008
    VOLTAGE_ENABLED = 0x0010
    QUICK_STOP = 0x0020
    """1 = quick stop *not* active."""
    SWITCH_ON_DISABLED = 0x0040
    WARNING = 0x0080
    MANUFACTURER_8 = 0x0100
    REMOTE = 0x0200
    """The drive takes its controlword from the fieldbus."""
    TARGET_REACHED = 0x0400
    INTERNAL_LIMIT_ACTIVE = 0x0800
    MODE_SPECIFIC_12 = 0x1000
    """PP: set-point acknowledge; PV: speed is zero; HM: homing attained;
    CSP/CSV/CST: the drive follows the command value."""
    MODE_SPECIFIC_13 = 0x2000
    """PP/CSP: following error; HM: homing error."""
    MANUFACTURER_14 = 0x4000
    MANUFACTURER_15 = 0x8000


class Controlword(IntFlag):
    """Controlword 0x6040 bits. Bits 4-6 and 9 depend on the mode of operation."""

    SWITCH_ON = 0x0001
    ENABLE_VOLTAGE = 0x0002
    QUICK_STOP = 0x0004
    """0 = quick stop."""
    ENABLE_OPERATION = 0x0008
    NEW_SET_POINT = 0x0010
    """PP: new set-point (rising edge); HM: homing operation start."""
    CHANGE_SET_IMMEDIATELY = 0x0020
    ABSOLUTE_RELATIVE = 0x0040
    """PP: 1 = the target is relative."""
    FAULT_RESET = 0x0080
    """Rising edge: fault -> switch on disabled."""
    HALT = 0x0100
    CHANGE_ON_SET_POINT = 0x0200


class DriveCommand(IntEnum):
    """Device-control commands as the controlword values a master sends."""

    DISABLE_VOLTAGE = 0x0000
    QUICK_STOP = 0x0002
    SHUTDOWN = 0x0006
    SWITCH_ON = 0x0007
    """Also "disable operation" from Operation enabled."""
    ENABLE_OPERATION = 0x000F
    FAULT_RESET = 0x0080


#: (mask, value) a drive decodes each command by; bit 7 (fault reset) must be 0 in all of them.
COMMAND_MASKS: dict[DriveCommand, tuple[int, int]] = {
    DriveCommand.SHUTDOWN: (0x0087, 0x0006),
    DriveCommand.SWITCH_ON: (0x008F, 0x0007),
    DriveCommand.ENABLE_OPERATION: (0x008F, 0x000F),
    DriveCommand.DISABLE_VOLTAGE: (0x0082, 0x0000),
    DriveCommand.QUICK_STOP: (0x0086, 0x0002),
}


def decode_command(controlword: int) -> DriveCommand | None:
    """The device-control command a controlword carries (the fault-reset bit aside)."""
    for command, (mask, value) in COMMAND_MASKS.items():
        if controlword & mask == value:
            return command
    return None


def command_path(current: DriveState, target: DriveState) -> list[DriveCommand]:
    """Controlwords that take a drive from ``current`` to ``target`` one transition at a time.

    ``target`` is one of Switch on disabled, Ready to switch on, Switched on or
    Operation enabled. From Fault the path starts with a fault reset (a rising
    edge of bit 7: the master sends 0 before it); from Quick stop active it goes
    through Switch on disabled. :class:`ConfigError` for other targets.
    """
    ladder = (DriveState.SWITCH_ON_DISABLED, DriveState.READY_TO_SWITCH_ON,
              DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED)
    if target not in ladder:
        raise ConfigError(f"cannot walk a drive to {target.label!r}")
    steps: list[DriveCommand] = []
    if current in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
        steps.append(DriveCommand.FAULT_RESET)
        current = DriveState.SWITCH_ON_DISABLED
    elif current in (DriveState.QUICK_STOP_ACTIVE, DriveState.NOT_READY_TO_SWITCH_ON):
        steps.append(DriveCommand.DISABLE_VOLTAGE)
        current = DriveState.SWITCH_ON_DISABLED
    i, j = ladder.index(current), ladder.index(target)
    if j > i:
        up = (DriveCommand.SHUTDOWN, DriveCommand.SWITCH_ON, DriveCommand.ENABLE_OPERATION)
        steps.extend(up[i:j])
    elif j < i:
        down = {DriveState.SWITCH_ON_DISABLED: DriveCommand.DISABLE_VOLTAGE,
                DriveState.READY_TO_SWITCH_ON: DriveCommand.SHUTDOWN,
                DriveState.SWITCHED_ON: DriveCommand.SWITCH_ON}
        steps.append(down[target])
    return steps


class OperationMode(IntEnum):
    """Modes of operation (0x6060 written, 0x6061 displayed)."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    VELOCITY = 2
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10

    @property
    def short(self) -> str:
        """The usual abbreviation: PP, PV, HM, CSP ..."""
        return _SHORT.get(self, self.name.lower())


_SHORT = {
    OperationMode.NO_MODE: "none", OperationMode.PROFILE_POSITION: "PP",
    OperationMode.VELOCITY: "VL", OperationMode.PROFILE_VELOCITY: "PV",
    OperationMode.PROFILE_TORQUE: "PT", OperationMode.HOMING: "HM",
    OperationMode.INTERPOLATED_POSITION: "IP", OperationMode.CYCLIC_SYNC_POSITION: "CSP",
    OperationMode.CYCLIC_SYNC_VELOCITY: "CSV", OperationMode.CYCLIC_SYNC_TORQUE: "CST",
}
#: Mode by lower-case abbreviation or name ("csp", "cyclic_sync_position", ...).
MODE_NAMES: dict[str, OperationMode] = {
    **{m.short.lower(): m for m in OperationMode},
    **{m.name.lower(): m for m in OperationMode},
}
# Bit of each mode in 0x6502 "supported drive modes".
_MODE_BIT = {
    OperationMode.PROFILE_POSITION: 0, OperationMode.VELOCITY: 1,
    OperationMode.PROFILE_VELOCITY: 2, OperationMode.PROFILE_TORQUE: 3,
    OperationMode.HOMING: 5, OperationMode.INTERPOLATED_POSITION: 6,
    OperationMode.CYCLIC_SYNC_POSITION: 7, OperationMode.CYCLIC_SYNC_VELOCITY: 8,
    OperationMode.CYCLIC_SYNC_TORQUE: 9,
}


def parse_mode(text: str | int) -> OperationMode:
    """A mode from its number, abbreviation or name; :class:`ConfigError` naming the choices."""
    if isinstance(text, int) or text.strip().lstrip("-").isdigit():
        try:
            return OperationMode(int(text))
        except ValueError:
            pass
    else:
        mode = MODE_NAMES.get(text.strip().lower())
        if mode is not None:
            return mode
    choices = ", ".join(m.short for m in OperationMode if m is not OperationMode.NO_MODE)
    raise ConfigError(f"unknown mode of operation {text!r}: choose one of {choices} (or 1-10)")


def supported_modes_word(modes: tuple[OperationMode, ...] | list[OperationMode]) -> int:
    """0x6502 value announcing ``modes``."""
    word = 0
    for m in modes:
        if m in _MODE_BIT:
            word |= 1 << _MODE_BIT[m]
    return word


def supported_modes(word: int) -> list[OperationMode]:
    """Modes a 0x6502 value announces."""
    return [m for m, bit in _MODE_BIT.items() if word >> bit & 1]


class QuickStopOption(IntEnum):
    """0x605A quick stop option code: how to stop, and whether to stay in Quick stop active."""

    DISABLE_DRIVE = 0
    SLOW_DOWN_RAMP = 1
    QUICK_STOP_RAMP = 2
    CURRENT_LIMIT = 3
    VOLTAGE_LIMIT = 4
    SLOW_DOWN_RAMP_STAY = 5
    QUICK_STOP_RAMP_STAY = 6
    CURRENT_LIMIT_STAY = 7
    VOLTAGE_LIMIT_STAY = 8


class StopOption(IntEnum):
    """How a stop decelerates (0x605B-0x605E; 0x605A values 1-4 and 5-8 map onto 1-4)."""

    DISABLE_DRIVE = 0
    """Torque off: the axis coasts."""
    SLOW_DOWN_RAMP = 1
    """Profile deceleration 0x6084."""
    QUICK_STOP_RAMP = 2
    """Quick stop deceleration 0x6085."""
    CURRENT_LIMIT = 3
    """Maximum torque 0x6072."""
    VOLTAGE_LIMIT = 4
    """Treated as current limit by the simulator (no DC-link model)."""


class DriveErrorCode(IntEnum):
    """Emergency error codes (0x603F) of drive errors (see ``EMERGENCY_ERROR_CLASSES``)."""

    COMMUNICATION = 0x7500
    """The drive lost its cyclic commands (EtherCAT left OP while enabled)."""
    FOLLOWING_ERROR = 0x8611
    REFERENCE_LIMIT = 0x8612
    """A limit switch was hit outside homing."""
    SYNC_CONTROLLER = 0x8700
    """Synchronisation lost (SYNC0 missing, SM events missed) or not available."""
    TRANSITION_PREOP_SAFEOP = 0xA000
    """EtherCAT PRE-OP -> SAFE-OP refused (sync manager lengths)."""
    TRANSITION_SAFEOP_OP = 0xA001
    """EtherCAT SAFE-OP -> OP refused."""


#: Homing methods the simulated drive runs (IEC 61800-7-201 numbering), with their meaning.
HOMING_METHODS: dict[int, str] = {
    1: "negative limit switch, then the index pulse",
    2: "positive limit switch, then the index pulse",
    17: "negative limit switch (its falling edge)",
    18: "positive limit switch (its falling edge)",
    19: "positive home switch, falling edge (approached from the positive side)",
    20: "positive home switch, rising edge (approached from the negative side)",
    33: "index pulse in negative direction",
    34: "index pulse in positive direction",
    35: "current position (old numbering)",
    37: "current position",
}
