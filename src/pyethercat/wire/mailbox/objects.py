"""The standard CoE object indices and subindices (ETG.1000.6 / CiA 301 communication area): one table.

Master and simulator name the communication objects of a CANopen-over-EtherCAT
slave from here instead of writing their numbers again:

- :class:`StandardObject`: 0x1000 device type ... 0x1C33 SM input
  synchronisation, including the first and last indices of the PDO mapping
  ranges (0x1600-0x17FF RxPDO, 0x1A00-0x1BFF TxPDO) and of the SM PDO
  assignment range (0x1C10-0x1C2F, one object per sync manager).
- helpers: :func:`sm_pdo_assignment` (0x1C10 + SM), :func:`assignment_sm`,
  :func:`is_rxpdo_mapping`, :func:`is_txpdo_mapping`, :func:`is_pdo_mapping`,
  :func:`is_pdo_assignment`; :func:`mapping_word` / :func:`split_mapping_word`
  for the u32 PDO mapping entries.
- subindices: :class:`IdentitySub` (0x1018), :class:`SyncSub` (0x1C32/0x1C33),
  with :class:`SyncMode` and :class:`SyncModeSupported` for their values.
- :class:`Cia402Object`: the CiA 402 drive-profile objects the project uses.

The values of 0x1C00 (SM communication type n) are the SII SyncM type codes,
:class:`pyethercat.wire.sii.SyncManagerType` (0 unused, 1 mailbox out,
2 mailbox in, 3 outputs, 4 inputs): the same numbers, kept in one place there.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

from pyethercat.errors import ConfigError

__all__ = [
    "SM_PDO_ASSIGNMENT_COUNT",
    "SYNC_MODE_SM_EVENT_BASE",
    "Cia402Object",
    "IdentitySub",
    "StandardObject",
    "SyncMode",
    "SyncModeSupported",
    "SyncSub",
    "assignment_sm",
    "is_pdo_assignment",
    "is_pdo_mapping",
    "is_rxpdo_mapping",
    "is_txpdo_mapping",
    "mapping_word",
    "sm_pdo_assignment",
    "sm_sync_mode",
    "split_mapping_word",
]


class StandardObject(IntEnum):
    """Indices of the standard communication objects (0x1000-0x1FFF, CiA 301 and ETG.1000.6)."""

    DEVICE_TYPE = 0x1000
    """u32: bits 15:0 device profile (402, 5001, ...), bits 31:16 additional info."""
    ERROR_REGISTER = 0x1001
    """u8, bits as :class:`pyethercat.wire.mailbox.coe.ErrorRegister`."""
    ERROR_HISTORY = 0x1003
    """Pre-defined error field: sub 0 = count (writing 0 clears), sub 1 = newest (u32: error
    code in bits 15:0, manufacturer information in bits 31:16), CiA 301 section 7.5.2.5."""
    DEVICE_NAME = 0x1008
    """Manufacturer device name (string)."""
    HARDWARE_VERSION = 0x1009
    """Manufacturer hardware version (string)."""
    SOFTWARE_VERSION = 0x100A
    """Manufacturer software version (string)."""
    IDENTITY = 0x1018
    """Vendor ID, product code, revision, serial number (:class:`IdentitySub`)."""
    ERROR_SETTINGS = 0x10F1
    """Error settings (local error reaction, sync error counter limit)."""
    STATION_ADDRESS = 0x1100
    """EtherCAT fixed station address (u16)."""
    RXPDO_MAPPING_FIRST = 0x1600
    """First RxPDO (output) mapping object."""
    RXPDO_MAPPING_LAST = 0x17FF
    """Last RxPDO (output) mapping object."""
    TXPDO_MAPPING_FIRST = 0x1A00
    """First TxPDO (input) mapping object."""
    TXPDO_MAPPING_LAST = 0x1BFF
    """Last TxPDO (input) mapping object."""
    SM_COMM_TYPE = 0x1C00
    """Sub n + 1 = communication type of SM n (SII SyncM type codes)."""
    SM_PDO_ASSIGNMENT_FIRST = 0x1C10
    """PDO assignment of SM0; SM n has 0x1C10 + n (:func:`sm_pdo_assignment`)."""
    RXPDO_ASSIGNMENT = 0x1C12
    """SM2 PDO assignment: the outputs (RxPDOs)."""
    TXPDO_ASSIGNMENT = 0x1C13
    """SM3 PDO assignment: the inputs (TxPDOs)."""
    SM_PDO_ASSIGNMENT_LAST = 0x1C2F
    """PDO assignment of SM31, the last of the range."""
    SM_OUTPUT_SYNC = 0x1C32
    """SM2 (output) synchronisation parameters (:class:`SyncSub`)."""
    SM_INPUT_SYNC = 0x1C33
    """SM3 (input) synchronisation parameters (:class:`SyncSub`)."""


#: Sync managers the assignment range 0x1C10-0x1C2F has room for.
SM_PDO_ASSIGNMENT_COUNT = (
    StandardObject.SM_PDO_ASSIGNMENT_LAST - StandardObject.SM_PDO_ASSIGNMENT_FIRST + 1
)


def sm_pdo_assignment(sm: int) -> int:
    """Index of the PDO assignment object of sync manager ``sm`` (0x1C10 + sm).

    :class:`ConfigError` when ``sm`` is outside 0-31 (the range has 32 objects).
    """
    if not 0 <= sm < SM_PDO_ASSIGNMENT_COUNT:
        raise ConfigError(f"SM{sm} has no PDO assignment object (SM 0-"
                          f"{SM_PDO_ASSIGNMENT_COUNT - 1} only)")
    return StandardObject.SM_PDO_ASSIGNMENT_FIRST + sm


def is_pdo_assignment(index: int) -> bool:
    """Whether ``index`` is an SM PDO assignment object (0x1C10-0x1C2F)."""
    return (StandardObject.SM_PDO_ASSIGNMENT_FIRST <= index
            <= StandardObject.SM_PDO_ASSIGNMENT_LAST)


def assignment_sm(index: int) -> int:
    """The sync manager a PDO assignment object belongs to (0x1C12 -> 2).

    :class:`ConfigError` when ``index`` is no assignment object.
    """
    if not is_pdo_assignment(index):
        raise ConfigError(f"0x{index:04X} is no SM PDO assignment object (0x1C10-0x1C2F)")
    return index - StandardObject.SM_PDO_ASSIGNMENT_FIRST


def is_rxpdo_mapping(index: int) -> bool:
    """Whether ``index`` is an RxPDO (output) mapping object (0x1600-0x17FF)."""
    return StandardObject.RXPDO_MAPPING_FIRST <= index <= StandardObject.RXPDO_MAPPING_LAST


def is_txpdo_mapping(index: int) -> bool:
    """Whether ``index`` is a TxPDO (input) mapping object (0x1A00-0x1BFF)."""
    return StandardObject.TXPDO_MAPPING_FIRST <= index <= StandardObject.TXPDO_MAPPING_LAST


def is_pdo_mapping(index: int) -> bool:
    """Whether ``index`` is a PDO mapping object of either direction."""
    return is_rxpdo_mapping(index) or is_txpdo_mapping(index)


def mapping_word(index: int, subindex: int, bit_length: int) -> int:
    """PDO mapping entry (u32): ``index << 16 | subindex << 8 | bit_length`` (CiA 301).

    Index 0 is a gap of ``bit_length`` bits. :class:`ConfigError` when a part
    does not fit its field (index 16 bits, subindex and length 8 bits each).
    """
    if not (0 <= index <= 0xFFFF and 0 <= subindex <= 0xFF and 0 <= bit_length <= 0xFF):
        raise ConfigError(f"PDO mapping entry 0x{index:X}:{subindex:X} {bit_length} bit "
                          "out of range")
    return (index << 16) | (subindex << 8) | bit_length


def split_mapping_word(word: int) -> tuple[int, int, int]:
    """(index, subindex, bit length) of a PDO mapping entry (u32)."""
    return (word >> 16) & 0xFFFF, (word >> 8) & 0xFF, word & 0xFF


class IdentitySub(IntEnum):
    """Subindices of 0x1018 identity (u32 each)."""

    VENDOR_ID = 1
    PRODUCT_CODE = 2
    REVISION = 3
    SERIAL_NUMBER = 4


class SyncSub(IntEnum):
    """Subindices of 0x1C32 / 0x1C33, SM output / input synchronisation (ETG.1020; SOES
    ``applications/rtl_xmc4_dynpdo/slave_objectlist.c`` ``SDO1C32``)."""

    SYNC_MODE = 0x01
    """u16, a :class:`SyncMode`."""
    CYCLE_TIME = 0x02
    """u32, ns."""
    SHIFT_TIME = 0x03
    """u32, ns."""
    SYNC_MODES_SUPPORTED = 0x04
    """u16, :class:`SyncModeSupported` bits."""
    MIN_CYCLE_TIME = 0x05
    """u32, ns."""
    CALC_AND_COPY_TIME = 0x06
    """u32, ns."""
    MIN_DELAY_TIME = 0x07
    """u32."""
    GET_CYCLE_TIME = 0x08
    """u16 command."""
    DELAY_TIME = 0x09
    """u32."""
    SYNC0_CYCLE_TIME = 0x0A
    """u32."""
    SM_EVENT_MISSED = 0x0B
    """u16 counter."""
    CYCLE_TIME_TOO_SMALL = 0x0C
    """u16 counter."""
    SHIFT_TIME_TOO_SHORT = 0x0D
    """u16 counter."""
    RXPDO_TOGGLE_FAILED = 0x0E
    """u16 counter."""
    MIN_CYCLE_DISTANCE = 0x0F
    """u32."""
    MAX_CYCLE_DISTANCE = 0x10
    """u32."""
    MIN_SM_SYNC_DISTANCE = 0x11
    """u32."""
    MAX_SM_SYNC_DISTANCE = 0x12
    """u32."""
    SYNC_ERROR = 0x20
    """bool."""


class SyncMode(IntEnum):
    """Values of 0x1C32/0x1C33 sub 1; 32 + n is "with the event of SM n" (:func:`sm_sync_mode`)."""

    FREE_RUN = 0
    SM_EVENT = 1
    """Synchronous with the event of the object's own SM."""
    DC_SYNC0 = 2
    DC_SYNC1 = 3
    SM2_EVENT = 0x22
    """Synchronous with the SM2 event (inputs latched when the outputs arrive)."""


#: Sync mode 32 + n: synchronous with the event of SM n.
SYNC_MODE_SM_EVENT_BASE = 0x20


def sm_sync_mode(sm: int) -> int:
    """Sync mode value "synchronous with the event of SM ``sm``" (0x20 + sm)."""
    if not 0 <= sm < SM_PDO_ASSIGNMENT_COUNT:
        raise ConfigError(f"no sync mode for SM{sm} (SM 0-{SM_PDO_ASSIGNMENT_COUNT - 1} only)")
    return SYNC_MODE_SM_EVENT_BASE + sm


class SyncModeSupported(IntFlag):
    """Bits of 0x1C32/0x1C33 sub 4, as SOES defines them (other bits unverified)."""

    FREE_RUN = 0x0001
    SYNCHRONOUS = 0x0002
    DC_SYNC0 = 0x0004
    DC_SYNC1 = 0x0008
    SUBORDINATED_CYCLES = 0x0010


class Cia402Object(IntEnum):
    """CiA 402 (IEC 61800-7-201 drive profile) objects the project's devices and tools use."""

    ERROR_CODE = 0x603F
    CONTROLWORD = 0x6040
    STATUSWORD = 0x6041
    QUICK_STOP_OPTION_CODE = 0x605A
    SHUTDOWN_OPTION_CODE = 0x605B
    DISABLE_OPERATION_OPTION_CODE = 0x605C
    HALT_OPTION_CODE = 0x605D
    FAULT_REACTION_OPTION_CODE = 0x605E
    MODES_OF_OPERATION = 0x6060
    MODES_OF_OPERATION_DISPLAY = 0x6061
    POSITION_DEMAND_VALUE = 0x6062
    POSITION_ACTUAL_VALUE = 0x6064
    FOLLOWING_ERROR_WINDOW = 0x6065
    FOLLOWING_ERROR_TIMEOUT = 0x6066
    POSITION_WINDOW = 0x6067
    POSITION_WINDOW_TIME = 0x6068
    VELOCITY_DEMAND_VALUE = 0x606B
    VELOCITY_ACTUAL_VALUE = 0x606C
    VELOCITY_WINDOW = 0x606D
    VELOCITY_WINDOW_TIME = 0x606E
    VELOCITY_THRESHOLD = 0x606F
    VELOCITY_THRESHOLD_TIME = 0x6070
    TARGET_TORQUE = 0x6071
    MAX_TORQUE = 0x6072
    TORQUE_DEMAND = 0x6074
    MOTOR_RATED_TORQUE = 0x6076
    TORQUE_ACTUAL_VALUE = 0x6077
    TARGET_POSITION = 0x607A
    HOME_OFFSET = 0x607C
    SOFTWARE_POSITION_LIMIT = 0x607D
    MAX_PROFILE_VELOCITY = 0x607F
    MAX_MOTOR_SPEED = 0x6080
    PROFILE_VELOCITY = 0x6081
    PROFILE_ACCELERATION = 0x6083
    PROFILE_DECELERATION = 0x6084
    QUICK_STOP_DECELERATION = 0x6085
    MOTION_PROFILE_TYPE = 0x6086
    POSITION_ENCODER_RESOLUTION = 0x608F
    HOMING_METHOD = 0x6098
    HOMING_SPEEDS = 0x6099
    HOMING_ACCELERATION = 0x609A
    POSITION_OFFSET = 0x60B0
    VELOCITY_OFFSET = 0x60B1
    TORQUE_OFFSET = 0x60B2
    INTERPOLATION_TIME_PERIOD = 0x60C2
    MAX_ACCELERATION = 0x60C5
    MAX_DECELERATION = 0x60C6
    FOLLOWING_ERROR_ACTUAL_VALUE = 0x60F4
    DIGITAL_INPUTS = 0x60FD
    TARGET_VELOCITY = 0x60FF
    SUPPORTED_DRIVE_MODES = 0x6502
