"""The CiA 402 objects of a simulated servo drive (IEC 61800-7-201, ETG.6010) and their defaults.

:func:`add_cia402_objects` adds to a dictionary every object the drive model
reads or writes that the dictionary does not have yet, so a drive built from
an ESI (whose dictionary lists only some of them) gets the rest with these
defaults. Process-data objects are PDO-mappable (targets as RxPDO, actual
values as TxPDO); parameters are readable and writable in every state.

Units: positions in encoder increments (0x608F: 65536 per revolution),
velocities in increments/s, accelerations in increments/s², torques in
per mille of the rated torque 0x6076 (mNm), times in ms.

0x2100 "Simulated axis" holds what a real drive would measure on its motor:
inertia, friction, a constant load torque, the loop tuning, and where the
simulated limit switches and home switch sit (in raw encoder increments
from power-on; the index pulse comes once per revolution at multiples of the
encoder resolution).
"""

from __future__ import annotations

from enum import IntEnum

from pyethercat.sim.od import RO, RW, RW_PREOP, RXPDO, TXPDO, SimObjectDictionary, SimOdEntry
from pyethercat.sim.std_objects import add_sync_parameters
from pyethercat.wire.cia402 import OperationMode, supported_modes_word
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import (
    Cia402Object,
    StandardObject,
    SyncMode,
    SyncModeSupported,
)

__all__ = [
    "AXIS_OBJECT",
    "DRIVE_MODES",
    "ENCODER_INCREMENTS",
    "AxisSub",
    "add_cia402_objects",
]

_O = Cia402Object
I8, I16, I32 = DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32
U8, U16, U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
R32 = DataType.REAL32

#: Modes the simulated drive runs.
DRIVE_MODES = (OperationMode.PROFILE_POSITION, OperationMode.PROFILE_VELOCITY,
               OperationMode.HOMING, OperationMode.CYCLIC_SYNC_POSITION,
               OperationMode.CYCLIC_SYNC_VELOCITY, OperationMode.CYCLIC_SYNC_TORQUE)
#: Encoder increments per motor revolution (0x608F:01 default).
ENCODER_INCREMENTS = 65536
#: Index of the manufacturer-specific "simulated axis" record.
AXIS_OBJECT = 0x2100


class AxisSub(IntEnum):
    """Subindices of 0x2100 "Simulated axis"."""

    INERTIA = 1
    """REAL32, kg·m² (motor and load)."""
    VISCOUS_FRICTION = 2
    """REAL32, N·m per rad/s."""
    COULOMB_FRICTION = 3
    """REAL32, N·m."""
    LOAD_TORQUE = 4
    """REAL32, N·m, a constant external torque (gravity on a vertical axis)."""
    VELOCITY_BANDWIDTH = 5
    """REAL32, Hz: bandwidth of the velocity loop."""
    POSITION_GAIN = 6
    """REAL32, 1/s: gain of the position loop."""
    NEGATIVE_LIMIT_SWITCH = 7
    """INTEGER32, raw increments: the switch is active at and below this position."""
    POSITIVE_LIMIT_SWITCH = 8
    """INTEGER32, raw increments: active at and above."""
    HOME_SWITCH = 9
    """INTEGER32, raw increments: the home switch is active at and above."""


def _var(od: SimObjectDictionary, index: int, name: str, dtype: DataType, access: int,
         default: object, **kw: object) -> None:
    if index not in od:
        od.var(index, name, dtype, access, default, **kw)  # type: ignore[arg-type]


def _record(od: SimObjectDictionary, index: int, name: str, entries: list[SimOdEntry]) -> None:
    obj = od.find(index)
    if obj is None:
        od.record(index, name, entries)
        return
    for e in entries:  # an ESI record without some of the subindices the drive uses
        obj.entries.setdefault(e.subindex, e)
    top = max(obj.entries)
    if obj.entries[0].data_type.byte_size == 1 and obj.entries[0].raw and obj.entries[0].raw[0] < top:
        obj.entries[0].raw[:] = bytes([top])


def add_cia402_objects(od: SimObjectDictionary) -> None:
    """Add the drive objects ``od`` lacks (see the module docstring for units and defaults)."""
    std = StandardObject
    _var(od, std.ERROR_REGISTER, "Error register", U8, RO, 0)
    if std.ERROR_HISTORY not in od:
        hist = od.array(std.ERROR_HISTORY, "Pre-defined error field", U32, [], RO,
                        count_access=RW, length=8)
        hist.entries[0].allowed = frozenset({0})  # writing 0 clears the history
    _record(od, std.ERROR_SETTINGS, "Error settings", [
        SimOdEntry(1, "Local error reaction", U32, RW, 1, maximum=2),
        SimOdEntry(2, "Sync error counter limit", U16, RW, 4),
    ])
    if std.SM_OUTPUT_SYNC not in od:
        supported = int(SyncModeSupported.FREE_RUN | SyncModeSupported.SYNCHRONOUS
                        | SyncModeSupported.DC_SYNC0)
        add_sync_parameters(od, std.SM_OUTPUT_SYNC, mode=SyncMode.SM_EVENT, supported=supported,
                            min_cycle_ns=250_000)
        add_sync_parameters(od, std.SM_INPUT_SYNC, mode=SyncMode.SM2_EVENT, supported=supported,
                            min_cycle_ns=250_000)
    # --- device control -------------------------------------------------------------
    _var(od, _O.ERROR_CODE, "Error code", U16, RO | TXPDO, 0)
    _var(od, _O.CONTROLWORD, "Controlword", U16, RW | RXPDO, 0)
    _var(od, _O.STATUSWORD, "Statusword", U16, RO | TXPDO, 0x0250)
    _var(od, _O.QUICK_STOP_OPTION_CODE, "Quick stop option code", I16, RW, 2,
         minimum=0, maximum=8)
    _var(od, _O.SHUTDOWN_OPTION_CODE, "Shutdown option code", I16, RW, 0, minimum=0, maximum=1)
    _var(od, _O.DISABLE_OPERATION_OPTION_CODE, "Disable operation option code", I16, RW, 1,
         minimum=0, maximum=1)
    _var(od, _O.HALT_OPTION_CODE, "Halt option code", I16, RW, 1, minimum=1, maximum=4)
    _var(od, _O.FAULT_REACTION_OPTION_CODE, "Fault reaction option code", I16, RW, 2,
         minimum=0, maximum=4)
    _var(od, _O.MODES_OF_OPERATION, "Modes of operation", I8, RW | RXPDO, 0)
    _var(od, _O.MODES_OF_OPERATION_DISPLAY, "Modes of operation display", I8, RO | TXPDO, 0)
    _var(od, _O.SUPPORTED_DRIVE_MODES, "Supported drive modes", U32, RO,
         supported_modes_word(DRIVE_MODES))
    # --- position -------------------------------------------------------------------
    _var(od, _O.POSITION_DEMAND_VALUE, "Position demand value", I32, RO | TXPDO, 0)
    _var(od, _O.POSITION_ACTUAL_VALUE, "Position actual value", I32, RO | TXPDO, 0)
    _var(od, _O.FOLLOWING_ERROR_WINDOW, "Following error window", U32, RW | RXPDO, 10_000)
    _var(od, _O.FOLLOWING_ERROR_TIMEOUT, "Following error time out", U16, RW | RXPDO, 10)
    _var(od, _O.POSITION_WINDOW, "Position window", U32, RW, 100)
    _var(od, _O.POSITION_WINDOW_TIME, "Position window time", U16, RW, 10)
    _var(od, _O.FOLLOWING_ERROR_ACTUAL_VALUE, "Following error actual value", I32, RO | TXPDO, 0)
    _var(od, _O.TARGET_POSITION, "Target position", I32, RW | RXPDO, 0)
    _var(od, _O.POSITION_OFFSET, "Position offset", I32, RW | RXPDO, 0)
    _var(od, _O.HOME_OFFSET, "Home offset", I32, RW, 0)
    _record(od, _O.SOFTWARE_POSITION_LIMIT, "Software position limit", [
        SimOdEntry(1, "Min position limit", I32, RW, 0),
        SimOdEntry(2, "Max position limit", I32, RW, 0),
    ])
    _record(od, _O.POSITION_ENCODER_RESOLUTION, "Position encoder resolution", [
        SimOdEntry(1, "Encoder increments", U32, RO, ENCODER_INCREMENTS),
        SimOdEntry(2, "Motor revolutions", U32, RO, 1),
    ])
    # --- velocity -------------------------------------------------------------------
    _var(od, _O.VELOCITY_DEMAND_VALUE, "Velocity demand value", I32, RO | TXPDO, 0)
    _var(od, _O.VELOCITY_ACTUAL_VALUE, "Velocity actual value", I32, RO | TXPDO, 0)
    _var(od, _O.VELOCITY_WINDOW, "Velocity window", U16, RW, 1000)
    _var(od, _O.VELOCITY_WINDOW_TIME, "Velocity window time", U16, RW, 10)
    _var(od, _O.VELOCITY_THRESHOLD, "Velocity threshold", U16, RW, 200)
    _var(od, _O.VELOCITY_THRESHOLD_TIME, "Velocity threshold time", U16, RW, 10)
    _var(od, _O.TARGET_VELOCITY, "Target velocity", I32, RW | RXPDO, 0)
    _var(od, _O.VELOCITY_OFFSET, "Velocity offset", I32, RW | RXPDO, 0)
    _var(od, _O.MAX_PROFILE_VELOCITY, "Max profile velocity", U32, RW | RXPDO, 5_000_000)
    _var(od, _O.MAX_MOTOR_SPEED, "Max motor speed", U32, RW, 6000)  # rpm
    _var(od, _O.PROFILE_VELOCITY, "Profile velocity", U32, RW | RXPDO, 500_000)
    _var(od, _O.PROFILE_ACCELERATION, "Profile acceleration", U32, RW | RXPDO, 5_000_000)
    _var(od, _O.PROFILE_DECELERATION, "Profile deceleration", U32, RW | RXPDO, 5_000_000)
    _var(od, _O.QUICK_STOP_DECELERATION, "Quick stop deceleration", U32, RW, 20_000_000)
    _var(od, _O.MOTION_PROFILE_TYPE, "Motion profile type", I16, RW, 0, minimum=0, maximum=0)
    _var(od, _O.MAX_ACCELERATION, "Max acceleration", U32, RW, 100_000_000)
    _var(od, _O.MAX_DECELERATION, "Max deceleration", U32, RW, 100_000_000)
    # --- torque ---------------------------------------------------------------------
    _var(od, _O.TARGET_TORQUE, "Target torque", I16, RW | RXPDO, 0)
    _var(od, _O.TORQUE_OFFSET, "Torque offset", I16, RW | RXPDO, 0)
    _var(od, _O.MAX_TORQUE, "Max torque", U16, RW | RXPDO, 3000)
    _var(od, _O.TORQUE_DEMAND, "Torque demand", I16, RO | TXPDO, 0)
    _var(od, _O.MOTOR_RATED_TORQUE, "Motor rated torque", U32, RW, 1000)  # mNm
    _var(od, _O.TORQUE_ACTUAL_VALUE, "Torque actual value", I16, RO | TXPDO, 0)
    # --- homing ---------------------------------------------------------------------
    _var(od, _O.HOMING_METHOD, "Homing method", I8, RW | RXPDO, 37)
    _record(od, _O.HOMING_SPEEDS, "Homing speeds", [
        SimOdEntry(1, "Speed during search for switch", U32, RW, 200_000),
        SimOdEntry(2, "Speed during search for zero", U32, RW, 20_000),
    ])
    _var(od, _O.HOMING_ACCELERATION, "Homing acceleration", U32, RW, 2_000_000)
    # --- inputs, interpolation ------------------------------------------------------
    _var(od, _O.DIGITAL_INPUTS, "Digital inputs", U32, RO | TXPDO, 0)
    _record(od, _O.INTERPOLATION_TIME_PERIOD, "Interpolation time period", [
        SimOdEntry(1, "Interpolation time period value", U8, RW_PREOP, 1),
        SimOdEntry(2, "Interpolation time index", I8, RW_PREOP, -3),
    ])
    _record(od, AXIS_OBJECT, "Simulated axis", [
        SimOdEntry(AxisSub.INERTIA, "Inertia (kg m2)", R32, RW, 2e-4, minimum=1e-7, maximum=10.0),
        SimOdEntry(AxisSub.VISCOUS_FRICTION, "Viscous friction (N m s/rad)", R32, RW, 1e-4,
                minimum=0.0, maximum=10.0),
        SimOdEntry(AxisSub.COULOMB_FRICTION, "Coulomb friction (N m)", R32, RW, 0.02,
                minimum=0.0, maximum=100.0),
        SimOdEntry(AxisSub.LOAD_TORQUE, "Load torque (N m)", R32, RW, 0.0,
                minimum=-1000.0, maximum=1000.0),
        SimOdEntry(AxisSub.VELOCITY_BANDWIDTH, "Velocity loop bandwidth (Hz)", R32, RW, 120.0,
                minimum=1.0, maximum=400.0),
        SimOdEntry(AxisSub.POSITION_GAIN, "Position loop gain (1/s)", R32, RW, 150.0,
                minimum=0.0, maximum=2000.0),
        SimOdEntry(AxisSub.NEGATIVE_LIMIT_SWITCH, "Negative limit switch (inc)", I32, RW,
                -1_000_000_000),
        SimOdEntry(AxisSub.POSITIVE_LIMIT_SWITCH, "Positive limit switch (inc)", I32, RW,
                1_000_000_000),
        SimOdEntry(AxisSub.HOME_SWITCH, "Home switch (inc)", I32, RW, 50_000),
    ])
