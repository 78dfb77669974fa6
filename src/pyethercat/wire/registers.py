"""The ESC register map (Beckhoff ESC datasheet section II), shared by master and simulator.

Every register address, size and bit used anywhere in pyethercat is defined
here once. ``REGISTERS`` describes each register (name, size, who writes it)
for tools such as ``pyethercat decode`` and the simulator's access rules.
"""

from __future__ import annotations

import bisect
import enum
import struct
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "ADDRESS_SPACE",
    "AL_CONTROL",
    "AL_ERROR_FLAG",
    "AL_EVENT_MASK",
    "AL_EVENT_REQUEST",
    "AL_ID_FLAG",
    "AL_STATE_MASK",
    "AL_STATUS",
    "AL_STATUS_CODE",
    "BUILD",
    "DC_ACTIVATION",
    "DC_ACTIVATION_STATUS",
    "DC_CYCLIC_UNIT_CONTROL",
    "DC_ECAT_BUFFER_CHANGE",
    "DC_LATCH0_CONTROL",
    "DC_LATCH0_NEGATIVE",
    "DC_LATCH0_POSITIVE",
    "DC_LATCH0_STATUS",
    "DC_LATCH1_CONTROL",
    "DC_LATCH1_NEGATIVE",
    "DC_LATCH1_POSITIVE",
    "DC_LATCH1_STATUS",
    "DC_LATCH_CONTROL_NEGATIVE_SINGLE",
    "DC_LATCH_CONTROL_POSITIVE_SINGLE",
    "DC_PDI_BUFFER_CHANGE",
    "DC_PDI_BUFFER_START",
    "DC_RECEIVE_TIME_ECAT",
    "DC_RECEIVE_TIME_PORT0",
    "DC_SPEED_COUNTER_DIFF",
    "DC_SPEED_COUNTER_START",
    "DC_SPEED_COUNTER_START_DEFAULT",
    "DC_SPEED_FILTER_DEPTH",
    "DC_SPEED_FILTER_DEPTH_DEFAULT",
    "DC_START_TIME",
    "DC_START_TIME1",
    "DC_SYNC0_CYCLE",
    "DC_SYNC0_STATUS",
    "DC_SYNC1_CYCLE",
    "DC_SYNC1_STATUS",
    "DC_SYNC_PULSE_LENGTH",
    "DC_SYNC_STATUS_PULSE",
    "DC_SYSTEM_TIME",
    "DC_SYSTEM_TIME_DELAY",
    "DC_SYSTEM_TIME_DIFFERENCE",
    "DC_SYSTEM_TIME_OFFSET",
    "DC_TIME_FILTER_DEPTH",
    "DC_TIME_FILTER_DEPTH_DEFAULT",
    "DIGITAL_OUTPUT",
    "DL_CONTROL",
    "DL_CONTROL_ALIAS",
    "DL_CONTROL_ALIAS_ENABLE",
    "DL_CONTROL_EBUS_LOW_JITTER",
    "DL_CONTROL_FIFO_SIZE_MASK",
    "DL_CONTROL_FIFO_SIZE_SHIFT",
    "DL_CONTROL_FORWARDING_RULE",
    "DL_CONTROL_LOOP",
    "DL_CONTROL_TEMPORARY_LOOP",
    "DL_STATUS",
    "ECAT_EVENT_MASK",
    "ECAT_EVENT_REQUEST",
    "ECAT_PROCESSING_ERROR_COUNTER",
    "ERR_LED_OVERRIDE",
    "ESC_CONFIG",
    "ESC_RESET_ECAT",
    "ESC_RESET_PDI",
    "ESC_RESET_SEQUENCE",
    "ESC_WRITE_ENABLE",
    "ESC_WRITE_PROTECTION",
    "FEATURES",
    "FMMU_ACTIVATE",
    "FMMU_BASE",
    "FMMU_COUNT",
    "FMMU_LENGTH",
    "FMMU_LOGICAL_START",
    "FMMU_LOGICAL_START_BIT",
    "FMMU_LOGICAL_STOP_BIT",
    "FMMU_PHYSICAL_START",
    "FMMU_PHYSICAL_START_BIT",
    "FMMU_SIZE",
    "FMMU_TYPE",
    "FORWARDED_RX_ERROR_COUNTER",
    "LOST_LINK_COUNTER",
    "MII_CONTROL",
    "MII_ECAT_ACCESS",
    "MII_PDI_ACCESS",
    "MII_PHY_ADDRESS",
    "MII_PHY_DATA",
    "MII_PHY_REGISTER",
    "MII_PORT_STATUS",
    "PDI_CONFIG",
    "PDI_CONTROL",
    "PDI_ERROR_CODE",
    "PDI_ERROR_COUNTER",
    "PDI_INFORMATION",
    "PHYSICAL_RW_OFFSET",
    "PORT_DESCRIPTOR",
    "RAM_SIZE",
    "RAM_START",
    "REGISTERS",
    "REVISION",
    "RUN_LED_OVERRIDE",
    "RX_ERROR_COUNTER",
    "SII_ADDRESS",
    "SII_COMMAND_MASK",
    "SII_CONFIG",
    "SII_CONFIG_FORCE_ECAT",
    "SII_CONFIG_PDI_OWNS",
    "SII_CONTROL",
    "SII_DATA",
    "SII_ERROR_MASK",
    "SII_PDI_ACCESS",
    "SM_ACTIVATE",
    "SM_ACTIVATE_ENABLE",
    "SM_ACTIVATE_LATCH_ECAT",
    "SM_ACTIVATE_LATCH_PDI",
    "SM_ACTIVATE_REPEAT",
    "SM_BASE",
    "SM_CONTROL",
    "SM_CONTROL_AL_EVENT",
    "SM_CONTROL_DIRECTION_MASK",
    "SM_CONTROL_DIRECTION_SHIFT",
    "SM_CONTROL_ECAT_EVENT",
    "SM_CONTROL_INPUTS",
    "SM_CONTROL_MAILBOX_IN",
    "SM_CONTROL_MAILBOX_OUT",
    "SM_CONTROL_MODE_MASK",
    "SM_CONTROL_OUTPUTS",
    "SM_CONTROL_WATCHDOG",
    "SM_COUNT",
    "SM_LENGTH",
    "SM_PDI_CONTROL",
    "SM_PDI_DEACTIVATE",
    "SM_PDI_REPEAT_ACK",
    "SM_SIZE",
    "SM_STRUCT",
    "FMMU_STRUCT",
    "SM_START",
    "SM_STATUS",
    "SM_STATUS_BUFFER_MASK",
    "SM_STATUS_BUFFER_SHIFT",
    "SM_STATUS_MAILBOX_FULL",
    "SM_STATUS_READ_EVENT",
    "SM_STATUS_READ_OPEN",
    "SM_STATUS_WRITE_EVENT",
    "SM_STATUS_WRITE_OPEN",
    "STATION_ADDRESS",
    "STATION_ALIAS",
    "TYPE",
    "USER_RAM",
    "WATCHDOG_COUNTER_PDI",
    "WATCHDOG_COUNTER_PROCESS_DATA",
    "WATCHDOG_DIVIDER",
    "WATCHDOG_DIVIDER_DEFAULT",
    "WATCHDOG_STATUS_OK",
    "WATCHDOG_STATUS_PROCESS_DATA",
    "WATCHDOG_TICK_NS",
    "WATCHDOG_TIME_DEFAULT",
    "WATCHDOG_TIME_PDI",
    "WATCHDOG_TIME_PROCESS_DATA",
    "WRITE_REGISTER_ENABLE",
    "WRITE_REGISTER_PROTECTION",
    "RegisterAccess",
    "AlEvent",
    "DcActivation",
    "DcActivationStatus",
    "DcCyclicUnitControl",
    "DcLatchStatus",
    "DlStatus",
    "EcatEvent",
    "EscConfig",
    "EscFeaturesMixin",
    "Feature",
    "FmmuType",
    "LoopControl",
    "PdiType",
    "PortType",
    "Register",
    "SiiControl",
    "SmDirection",
    "SmMode",
    "al_event_sm",
    "dl_status_com",
    "dl_status_link",
    "dl_status_loop",
    "ecat_event_sm",
    "fmmu_address",
    "port_descriptor",
    "port_types",
    "register_at",
    "register_containing",
    "register_name",
    "sm_address",
    "sm_control",
    "watchdog_unit_ns",
]


class RegisterAccess(enum.Flag):
    """What the EtherCAT side (the master) may do with a register.

    Every register is readable; ``W`` marks those a master writes. Registers
    only the ESC or the PDI (the slave's own controller) writes are ``R``.
    """

    R = enum.auto()  # read by ECAT
    W = enum.auto()  # written by ECAT
    RW = R | W


@dataclass(frozen=True, slots=True)
class Register:
    """One entry of the register map: start address, size in bytes, name, ECAT access."""

    address: int
    size: int
    name: str
    access: RegisterAccess = RegisterAccess.R


# --- addresses -------------------------------------------------------------------
TYPE = 0x0000
REVISION = 0x0001
BUILD = 0x0002
FMMU_COUNT = 0x0004
SM_COUNT = 0x0005
RAM_SIZE = 0x0006
PORT_DESCRIPTOR = 0x0007
FEATURES = 0x0008
STATION_ADDRESS = 0x0010
STATION_ALIAS = 0x0012
WRITE_REGISTER_ENABLE = 0x0020
WRITE_REGISTER_PROTECTION = 0x0021
ESC_WRITE_ENABLE = 0x0030
ESC_WRITE_PROTECTION = 0x0031
ESC_RESET_ECAT = 0x0040
ESC_RESET_PDI = 0x0041
DL_CONTROL = 0x0100
DL_CONTROL_LOOP = 0x0101  # loop control byte, 2 bits per port
DL_CONTROL_ALIAS = 0x0103  # bit 0: station alias addressing enable
PHYSICAL_RW_OFFSET = 0x0108
DL_STATUS = 0x0110
AL_CONTROL = 0x0120
AL_STATUS = 0x0130
AL_STATUS_CODE = 0x0134
RUN_LED_OVERRIDE = 0x0138
ERR_LED_OVERRIDE = 0x0139
PDI_CONTROL = 0x0140
ESC_CONFIG = 0x0141
PDI_INFORMATION = 0x014E
PDI_CONFIG = 0x0150
ECAT_EVENT_MASK = 0x0200
AL_EVENT_MASK = 0x0204
ECAT_EVENT_REQUEST = 0x0210
AL_EVENT_REQUEST = 0x0220
RX_ERROR_COUNTER = 0x0300  # 0x0300 + 2n invalid frame, 0x0301 + 2n RX error, n = port
FORWARDED_RX_ERROR_COUNTER = 0x0308  # + port
ECAT_PROCESSING_ERROR_COUNTER = 0x030C
PDI_ERROR_COUNTER = 0x030D
PDI_ERROR_CODE = 0x030E
LOST_LINK_COUNTER = 0x0310  # + port
WATCHDOG_DIVIDER = 0x0400
WATCHDOG_TIME_PDI = 0x0410
WATCHDOG_TIME_PROCESS_DATA = 0x0420
WATCHDOG_STATUS_PROCESS_DATA = 0x0440
WATCHDOG_COUNTER_PROCESS_DATA = 0x0442
WATCHDOG_COUNTER_PDI = 0x0443
SII_CONFIG = 0x0500
SII_PDI_ACCESS = 0x0501
SII_CONTROL = 0x0502
SII_ADDRESS = 0x0504
SII_DATA = 0x0508
MII_CONTROL = 0x0510
MII_PHY_ADDRESS = 0x0512
MII_PHY_REGISTER = 0x0513
MII_PHY_DATA = 0x0514
MII_ECAT_ACCESS = 0x0516
MII_PDI_ACCESS = 0x0517
MII_PORT_STATUS = 0x0518
FMMU_BASE = 0x0600
FMMU_SIZE = 16
SM_BASE = 0x0800
SM_SIZE = 8
DC_RECEIVE_TIME_PORT0 = 0x0900  # + 4 * port; a write latches receive times
DC_SYSTEM_TIME = 0x0910
DC_RECEIVE_TIME_ECAT = 0x0918
DC_SYSTEM_TIME_OFFSET = 0x0920
DC_SYSTEM_TIME_DELAY = 0x0928
DC_SYSTEM_TIME_DIFFERENCE = 0x092C
DC_SPEED_COUNTER_START = 0x0930
DC_SPEED_COUNTER_DIFF = 0x0932
DC_TIME_FILTER_DEPTH = 0x0934
DC_SPEED_FILTER_DEPTH = 0x0935
DC_CYCLIC_UNIT_CONTROL = 0x0980
DC_ACTIVATION = 0x0981
DC_SYNC_PULSE_LENGTH = 0x0982
DC_ACTIVATION_STATUS = 0x0984
DC_SYNC0_STATUS = 0x098E
DC_SYNC1_STATUS = 0x098F
DC_START_TIME = 0x0990
#: Wireshark (packet-ethercat-datagram.c) calls it "StartTime1"; no public source we
#: know says whether it reads back the next SYNC1 pulse.
DC_START_TIME1 = 0x0998
DC_SYNC0_CYCLE = 0x09A0
DC_SYNC1_CYCLE = 0x09A4
DC_LATCH0_CONTROL = 0x09A8
DC_LATCH1_CONTROL = 0x09A9
DC_LATCH0_STATUS = 0x09AE
DC_LATCH1_STATUS = 0x09AF
DC_LATCH0_POSITIVE = 0x09B0
DC_LATCH0_NEGATIVE = 0x09B8
DC_LATCH1_POSITIVE = 0x09C0
DC_LATCH1_NEGATIVE = 0x09C8
DC_ECAT_BUFFER_CHANGE = 0x09F0
DC_PDI_BUFFER_START = 0x09F8
DC_PDI_BUFFER_CHANGE = 0x09FC
DIGITAL_OUTPUT = 0x0F00
USER_RAM = 0x0F80
#: Process-data RAM starts here.
RAM_START = 0x1000
#: Size of an ESC's address space.
ADDRESS_SPACE = 0x10000


def fmmu_address(n: int) -> int:
    """Base address of FMMU ``n``."""
    return FMMU_BASE + FMMU_SIZE * n


def sm_address(n: int) -> int:
    """Base address of sync manager ``n``."""
    return SM_BASE + SM_SIZE * n


# FMMU register offsets
FMMU_LOGICAL_START = 0x0
FMMU_LENGTH = 0x4
FMMU_LOGICAL_START_BIT = 0x6
FMMU_LOGICAL_STOP_BIT = 0x7
FMMU_PHYSICAL_START = 0x8
FMMU_PHYSICAL_START_BIT = 0xA
FMMU_TYPE = 0xB
FMMU_ACTIVATE = 0xC

# SM register offsets
SM_START = 0
SM_LENGTH = 2
SM_CONTROL = 4
SM_STATUS = 5
SM_ACTIVATE = 6
SM_PDI_CONTROL = 7

#: The 8 bytes of one sync manager: start, length, control, status, activate, PDI control.
SM_STRUCT = struct.Struct("<HHBBBB")
#: The 16 bytes of one FMMU: logical start, length, logical start bit, logical stop bit,
#: physical start, physical start bit, type, activate (3 reserved bytes).
FMMU_STRUCT = struct.Struct("<IHBBHBBB3x")


# --- bit fields --------------------------------------------------------------------


class Feature(enum.IntFlag):
    """ESC features register 0x0008."""

    FMMU_BYTE_ORIENTED = 1 << 0
    UNUSED_REGISTER_ACCESS = 1 << 1
    DC_SUPPORTED = 1 << 2
    DC_64BIT = 1 << 3
    LOW_JITTER_EBUS = 1 << 4
    ENHANCED_LINK_EBUS = 1 << 5
    ENHANCED_LINK_MII = 1 << 6
    SEPARATE_FCS_ERRORS = 1 << 7
    ENHANCED_DC_SYNC = 1 << 8
    LRW_NOT_SUPPORTED = 1 << 9
    RW_NOT_SUPPORTED = 1 << 10
    FIXED_FMMU_SM = 1 << 11


class EscFeaturesMixin:
    """What the ESC features register 0x0008 says, decoded once for master and simulator.

    Mixed into the classes that hold the register value as ``features``
    (the master's ``EscInfo``, the simulator's ``EscProfile``).
    """

    __slots__ = ()
    #: Value of register 0x0008 (see :class:`Feature`).
    features: int

    @property
    def dc_supported(self) -> bool:
        """Distributed clocks are available (bit 2)."""
        return bool(self.features & Feature.DC_SUPPORTED)

    @property
    def dc_64bit(self) -> bool:
        """The DC system time is 64 bits wide (bit 3; else 32)."""
        return bool(self.features & Feature.DC_64BIT)

    @property
    def lrw_supported(self) -> bool:
        """The ESC executes LRW (bit 9 clear)."""
        return not self.features & Feature.LRW_NOT_SUPPORTED

    @property
    def rw_supported(self) -> bool:
        """The ESC executes the read/write commands APRW/FPRW/BRW (bit 10 clear)."""
        return not self.features & Feature.RW_NOT_SUPPORTED

    @property
    def bitwise_fmmu(self) -> bool:
        """The FMMUs map bit by bit (bit 0 clear; set: byte-oriented only)."""
        return not self.features & Feature.FMMU_BYTE_ORIENTED

    @property
    def fixed_fmmu_sm(self) -> bool:
        """FMMU and sync manager use is fixed by the chip (bit 11)."""
        return bool(self.features & Feature.FIXED_FMMU_SM)


class PortType(enum.IntEnum):
    """Port descriptor 0x0007, two bits per port."""

    NOT_IMPLEMENTED = 0
    NOT_CONFIGURED = 1
    EBUS = 2
    MII = 3

    @property
    def implemented(self) -> bool:
        """The chip has this port as an E-Bus or MII port."""
        return self in (PortType.EBUS, PortType.MII)


def port_types(descriptor: int) -> list[PortType]:
    """Decode the port descriptor byte into the four ports' types."""
    return [PortType((descriptor >> (2 * n)) & 3) for n in range(4)]


def port_descriptor(types: Sequence[PortType]) -> int:
    """Encode up to four ports' types as the port descriptor byte (inverse of :func:`port_types`)."""
    value = 0
    for n, ptype in enumerate(types):
        value |= (int(ptype) & 3) << (2 * n)
    return value


class LoopControl(enum.IntEnum):
    """DL control loop setting per port (0x0101, two bits per port)."""

    AUTO = 0
    AUTO_CLOSE = 1
    OPEN = 2
    CLOSED = 3


DL_CONTROL_FORWARDING_RULE = 1 << 0
DL_CONTROL_TEMPORARY_LOOP = 1 << 1
DL_CONTROL_FIFO_SIZE_SHIFT = 16  # bits 18:16, RX FIFO size
DL_CONTROL_FIFO_SIZE_MASK = 0x7 << 16
DL_CONTROL_EBUS_LOW_JITTER = 1 << 19
DL_CONTROL_ALIAS_ENABLE = 1 << 24  # as a bit of the 32-bit DL control


class DlStatus(enum.IntFlag):
    """DL status 0x0110."""

    PDI_OPERATIONAL = 1 << 0
    PDI_WATCHDOG_OK = 1 << 1
    ENHANCED_LINK_DETECTION = 1 << 2
    LINK_PORT0 = 1 << 4
    LINK_PORT1 = 1 << 5
    LINK_PORT2 = 1 << 6
    LINK_PORT3 = 1 << 7
    LOOP_PORT0 = 1 << 8
    COM_PORT0 = 1 << 9
    LOOP_PORT1 = 1 << 10
    COM_PORT1 = 1 << 11
    LOOP_PORT2 = 1 << 12
    COM_PORT2 = 1 << 13
    LOOP_PORT3 = 1 << 14
    COM_PORT3 = 1 << 15


def dl_status_link(port: int) -> int:
    """Physical-link bit of ``port`` in DL status."""
    return 1 << (4 + port)


def dl_status_loop(port: int) -> int:
    """Loop-closed bit of ``port`` in DL status."""
    return 1 << (8 + 2 * port)


def dl_status_com(port: int) -> int:
    """Communication-established bit of ``port`` in DL status."""
    return 1 << (9 + 2 * port)


AL_STATE_MASK = 0x0F
AL_ERROR_FLAG = 0x10  # AL status: error indication; AL control: error acknowledge
AL_ID_FLAG = 0x20  # AL control: device ID request; AL status: ID loaded


class EscConfig(enum.IntFlag):
    """ESC configuration 0x0141."""

    DEVICE_EMULATION = 1 << 0
    ENHANCED_LINK_ALL = 1 << 1
    DC_SYNC_OUT = 1 << 2
    DC_LATCH_IN = 1 << 3
    ENHANCED_LINK_PORT0 = 1 << 4
    ENHANCED_LINK_PORT1 = 1 << 5
    ENHANCED_LINK_PORT2 = 1 << 6
    ENHANCED_LINK_PORT3 = 1 << 7


class PdiType(enum.IntEnum):
    """PDI control 0x0140: the kind of process data interface (Wireshark ``vals_esc_reg_140``)."""

    NONE = 0
    DIGITAL_IN_4BIT = 1
    DIGITAL_OUT_4BIT = 2
    DIGITAL_IN_OUT_2BIT = 3
    DIGITAL_IO = 4
    SPI_SLAVE = 5
    ETHERCAT_BRIDGE = 7
    UC_ASYNC_16BIT = 8
    UC_ASYNC_8BIT = 9
    UC_SYNC_16BIT = 10
    UC_SYNC_8BIT = 11
    DIGITAL_IO_32_0 = 16
    DIGITAL_IO_24_8 = 17
    DIGITAL_IO_16_16 = 18
    DIGITAL_IO_8_24 = 19
    DIGITAL_IO_0_32 = 20
    ON_CHIP_BUS = 128


class EcatEvent(enum.IntFlag):
    """ECAT event request/mask 0x0210/0x0200 (SM n status mirror at bit 4 + n)."""

    DC_LATCH = 1 << 0
    DL_STATUS = 1 << 2
    AL_STATUS = 1 << 3


def ecat_event_sm(n: int) -> int:
    """ECAT event bit of sync manager ``n`` (n = 0..7)."""
    return 1 << (4 + n)


class AlEvent(enum.IntFlag):
    """AL (PDI) event request/mask 0x0220/0x0204 (SM n interrupt at bit 8 + n)."""

    AL_CONTROL = 1 << 0
    DC_LATCH = 1 << 1
    SYNC0 = 1 << 2
    SYNC1 = 1 << 3
    SM_ACTIVATION = 1 << 4
    EEPROM_EMULATION = 1 << 5
    WATCHDOG = 1 << 6


def al_event_sm(n: int) -> int:
    """AL event bit of sync manager ``n`` (n = 0..15)."""
    return 1 << (8 + n)


class SiiControl(enum.IntFlag):
    """SII control/status 0x0502."""

    WRITE_ENABLE = 1 << 0
    EMULATION = 1 << 5
    READ_8_BYTES = 1 << 6
    TWO_ADDRESS_BYTES = 1 << 7
    CMD_READ = 0x0100
    CMD_WRITE = 0x0200
    CMD_RELOAD = 0x0400
    CHECKSUM_ERROR = 1 << 11
    LOAD_ERROR = 1 << 12
    ACK_ERROR = 1 << 13
    WRITE_ENABLE_ERROR = 1 << 14
    BUSY = 1 << 15


SII_COMMAND_MASK = 0x0700
SII_ERROR_MASK = 0x7800
SII_CONFIG_PDI_OWNS = 1 << 0
SII_CONFIG_FORCE_ECAT = 1 << 1


class FmmuType(enum.IntFlag):
    """FMMU type register (+0xB)."""

    READ = 1 << 0  # physical -> logical (inputs)
    WRITE = 1 << 1  # logical -> physical (outputs)


class SmMode(enum.IntEnum):
    """Sync manager operation mode, control bits 1:0."""

    BUFFERED = 0
    MAILBOX = 2


class SmDirection(enum.IntEnum):
    """Sync manager direction, control bits 3:2."""

    READ = 0  # ECAT reads, PDI writes (inputs, SM1/SM3)
    WRITE = 1  # ECAT writes, PDI reads (outputs, SM0/SM2)


SM_CONTROL_MODE_MASK = 0x03
SM_CONTROL_DIRECTION_SHIFT = 2
SM_CONTROL_DIRECTION_MASK = 0x0C
SM_CONTROL_ECAT_EVENT = 1 << 4
SM_CONTROL_AL_EVENT = 1 << 5
SM_CONTROL_WATCHDOG = 1 << 6
SM_STATUS_WRITE_EVENT = 1 << 0
SM_STATUS_READ_EVENT = 1 << 1
SM_STATUS_MAILBOX_FULL = 1 << 3
SM_STATUS_BUFFER_SHIFT = 4
SM_STATUS_BUFFER_MASK = 0x30
SM_STATUS_READ_OPEN = 1 << 6
SM_STATUS_WRITE_OPEN = 1 << 7
SM_ACTIVATE_ENABLE = 1 << 0
SM_ACTIVATE_REPEAT = 1 << 1
SM_ACTIVATE_LATCH_ECAT = 1 << 6  # latch DC event time on an ECAT buffer change (0x09F0)
SM_ACTIVATE_LATCH_PDI = 1 << 7  # latch DC event time on a PDI buffer change (0x09F8)
SM_PDI_DEACTIVATE = 1 << 0
SM_PDI_REPEAT_ACK = 1 << 1

#: Typical sync manager control bytes (SOEM src/ec_config.c EC_DEFAULTMBXSM0/1 and
#: EC_DEFAULTDOSM0; KickCAT protocol.h SM_CONTROL_*).
SM_CONTROL_MAILBOX_OUT = 0x26  # SM0: mailbox, ECAT writes, AL event
SM_CONTROL_MAILBOX_IN = 0x22  # SM1: mailbox, ECAT reads, AL event
SM_CONTROL_OUTPUTS = 0x64  # SM2: buffered, ECAT writes, AL event, watchdog
SM_CONTROL_INPUTS = 0x20  # SM3: buffered, ECAT reads, AL event


def sm_control(mode: SmMode, direction: SmDirection, ecat_event: bool = False,
               al_event: bool = True, watchdog: bool = False) -> int:
    """Compose a sync manager control byte."""
    return (int(mode) | (int(direction) << SM_CONTROL_DIRECTION_SHIFT)
            | (SM_CONTROL_ECAT_EVENT if ecat_event else 0)
            | (SM_CONTROL_AL_EVENT if al_event else 0)
            | (SM_CONTROL_WATCHDOG if watchdog else 0))


class DcCyclicUnitControl(enum.IntFlag):
    """DC cyclic unit control 0x0980: which side controls a unit (1 = PDI, 0 = ECAT)."""

    SYNC_UNIT_PDI = 1 << 0
    LATCH0_PDI = 1 << 4
    LATCH1_PDI = 1 << 5


class DcActivationStatus(enum.IntFlag):
    """DC activation status 0x0984."""

    SYNC0_PENDING = 1 << 0
    SYNC1_PENDING = 1 << 1
    START_TIME_OUT_OF_RANGE = 1 << 2


class DcLatchStatus(enum.IntFlag):
    """DC latch status 0x09AE / 0x09AF."""

    POSITIVE_EDGE = 1 << 0
    NEGATIVE_EDGE = 1 << 1
    PIN_STATE = 1 << 2


#: DC latch control 0x09A8 / 0x09A9: 1 = single event, 0 = continuous, per edge.
DC_LATCH_CONTROL_POSITIVE_SINGLE = 1 << 0
DC_LATCH_CONTROL_NEGATIVE_SINGLE = 1 << 1
#: DC SYNC0/SYNC1 status 0x098E / 0x098F bit 0: a pulse was generated.
DC_SYNC_STATUS_PULSE = 1 << 0
#: Process-data watchdog status 0x0440 bit 0: 1 = running or disabled, 0 = expired.
WATCHDOG_STATUS_OK = 1 << 0


class DcActivation(enum.IntFlag):
    """DC activation 0x0981."""

    CYCLIC = 1 << 0
    SYNC0 = 1 << 1
    SYNC1 = 1 << 2
    AUTO_ACTIVATE = 1 << 3
    START_TIME_64BIT = 1 << 4
    PLAUSIBILITY_CHECK = 1 << 5
    NEAR_FUTURE = 1 << 6
    DEBUG_PULSE = 1 << 7


#: Watchdog defaults (divider 2498 -> 100 us per unit; 1000 units -> 100 ms).
WATCHDOG_DIVIDER_DEFAULT = 2498
WATCHDOG_TIME_DEFAULT = 1000
WATCHDOG_TICK_NS = 40


#: DC loop reset values (ESC datasheet section II, 0x0930-0x0935; KickCAT
#: lib/slave/src/ESC/EmulatedESC.cc constructor).
DC_SPEED_COUNTER_START_DEFAULT = 0x1000
DC_TIME_FILTER_DEPTH_DEFAULT = 4
DC_SPEED_FILTER_DEPTH_DEFAULT = 12
#: Bytes to write to ESC_RESET_ECAT, one per frame, to reset an ESC ("RES"; IgH
#: master/fsm_reboot.c).
ESC_RESET_SEQUENCE = (0x52, 0x45, 0x53)


def watchdog_unit_ns(divider: int) -> int:
    """Duration of one watchdog time unit for a divider value."""
    return (divider + 2) * WATCHDOG_TICK_NS


# --- descriptive table ------------------------------------------------------------

_R, _W, _RW = RegisterAccess.R, RegisterAccess.W, RegisterAccess.RW


def _table() -> list[Register]:
    regs = [
        Register(TYPE, 1, "Type"), Register(REVISION, 1, "Revision"), Register(BUILD, 2, "Build"),
        Register(FMMU_COUNT, 1, "FMMUs supported"), Register(SM_COUNT, 1, "SyncManagers supported"),
        Register(RAM_SIZE, 1, "RAM size"), Register(PORT_DESCRIPTOR, 1, "Port descriptor"),
        Register(FEATURES, 2, "ESC features"),
        Register(STATION_ADDRESS, 2, "Configured station address", _RW),
        Register(STATION_ALIAS, 2, "Configured station alias"),
        Register(WRITE_REGISTER_ENABLE, 1, "Write register enable", _RW),
        Register(WRITE_REGISTER_PROTECTION, 1, "Write register protection", _RW),
        Register(ESC_WRITE_ENABLE, 1, "ESC write enable", _RW),
        Register(ESC_WRITE_PROTECTION, 1, "ESC write protection", _RW),
        Register(ESC_RESET_ECAT, 1, "ESC reset ECAT", _RW),
        Register(ESC_RESET_PDI, 1, "ESC reset PDI"),
        Register(DL_CONTROL, 4, "DL control", _RW),
        Register(PHYSICAL_RW_OFFSET, 2, "Physical read/write offset", _RW),
        Register(DL_STATUS, 2, "DL status"),
        Register(AL_CONTROL, 2, "AL control", _RW), Register(AL_STATUS, 2, "AL status"),
        Register(AL_STATUS_CODE, 2, "AL status code"),
        Register(RUN_LED_OVERRIDE, 1, "RUN LED override", _RW),
        Register(ERR_LED_OVERRIDE, 1, "ERR LED override", _RW),
        Register(PDI_CONTROL, 1, "PDI control"), Register(ESC_CONFIG, 1, "ESC configuration"),
        Register(PDI_INFORMATION, 2, "PDI information"),
        Register(PDI_CONFIG, 4, "PDI configuration"),
        Register(ECAT_EVENT_MASK, 2, "ECAT event mask", _RW),
        Register(AL_EVENT_MASK, 4, "AL event mask"),
        Register(ECAT_EVENT_REQUEST, 2, "ECAT event request"),
        Register(AL_EVENT_REQUEST, 4, "AL event request"),
    ]
    for port in range(4):
        regs.append(Register(RX_ERROR_COUNTER + 2 * port, 1, f"Invalid frame counter port {port}", _RW))
        regs.append(Register(RX_ERROR_COUNTER + 2 * port + 1, 1, f"RX error counter port {port}", _RW))
        regs.append(Register(FORWARDED_RX_ERROR_COUNTER + port, 1,
                             f"Forwarded RX error counter port {port}", _RW))
        regs.append(Register(LOST_LINK_COUNTER + port, 1, f"Lost link counter port {port}", _RW))
        # Any ECAT write to port 0's receive time latches all ports; the others are read-only.
        regs.append(Register(DC_RECEIVE_TIME_PORT0 + 4 * port, 4, f"DC receive time port {port}",
                             _RW if port == 0 else _R))
        regs.append(Register(MII_PORT_STATUS + port, 1, f"PHY port status {port}"))
    regs += [
        Register(ECAT_PROCESSING_ERROR_COUNTER, 1, "ECAT processing unit error counter", _RW),
        Register(PDI_ERROR_COUNTER, 1, "PDI error counter", _RW),
        Register(PDI_ERROR_CODE, 2, "PDI error code"),
        Register(WATCHDOG_DIVIDER, 2, "Watchdog divider", _RW),
        Register(WATCHDOG_TIME_PDI, 2, "Watchdog time PDI", _RW),
        Register(WATCHDOG_TIME_PROCESS_DATA, 2, "Watchdog time process data", _RW),
        Register(WATCHDOG_STATUS_PROCESS_DATA, 2, "Watchdog status process data"),
        Register(WATCHDOG_COUNTER_PROCESS_DATA, 1, "Watchdog counter process data", _RW),
        Register(WATCHDOG_COUNTER_PDI, 1, "Watchdog counter PDI", _RW),
        Register(SII_CONFIG, 1, "SII configuration", _RW),
        Register(SII_PDI_ACCESS, 1, "SII PDI access state"),
        Register(SII_CONTROL, 2, "SII control/status", _RW),
        Register(SII_ADDRESS, 4, "SII address", _RW),
        Register(SII_DATA, 8, "SII data", _RW),
        Register(MII_CONTROL, 2, "MII control/status", _RW),
        Register(MII_PHY_ADDRESS, 1, "MII PHY address", _RW),
        Register(MII_PHY_REGISTER, 1, "MII PHY register address", _RW),
        Register(MII_PHY_DATA, 2, "MII PHY data", _RW),
        Register(MII_ECAT_ACCESS, 1, "MII ECAT access state", _RW),
        Register(MII_PDI_ACCESS, 1, "MII PDI access state"),
        Register(DC_SYSTEM_TIME, 8, "DC system time", _RW),
        Register(DC_RECEIVE_TIME_ECAT, 8, "DC receive time ECAT processing unit"),
        Register(DC_SYSTEM_TIME_OFFSET, 8, "DC system time offset", _RW),
        Register(DC_SYSTEM_TIME_DELAY, 4, "DC system time delay", _RW),
        Register(DC_SYSTEM_TIME_DIFFERENCE, 4, "DC system time difference"),
        Register(DC_SPEED_COUNTER_START, 2, "DC speed counter start", _RW),
        Register(DC_SPEED_COUNTER_DIFF, 2, "DC speed counter difference"),
        Register(DC_TIME_FILTER_DEPTH, 1, "DC system time difference filter depth", _RW),
        Register(DC_SPEED_FILTER_DEPTH, 1, "DC speed counter filter depth", _RW),
        Register(DC_CYCLIC_UNIT_CONTROL, 1, "DC cyclic unit control", _RW),
        Register(DC_ACTIVATION, 1, "DC activation", _RW),
        Register(DC_SYNC_PULSE_LENGTH, 2, "DC SYNC pulse length"),
        Register(DC_ACTIVATION_STATUS, 1, "DC activation status"),
        Register(DC_SYNC0_STATUS, 1, "DC SYNC0 status"),
        Register(DC_SYNC1_STATUS, 1, "DC SYNC1 status"),
        Register(DC_START_TIME, 8, "DC start time cyclic operation", _RW),
        Register(DC_START_TIME1, 8, "DC start time 1"),
        Register(DC_SYNC0_CYCLE, 4, "DC SYNC0 cycle time", _RW),
        Register(DC_SYNC1_CYCLE, 4, "DC SYNC1 cycle time", _RW),
        Register(DC_LATCH0_CONTROL, 1, "DC latch0 control", _RW),
        Register(DC_LATCH1_CONTROL, 1, "DC latch1 control", _RW),
        Register(DC_LATCH0_STATUS, 1, "DC latch0 status"),
        Register(DC_LATCH1_STATUS, 1, "DC latch1 status"),
        Register(DC_LATCH0_POSITIVE, 8, "DC latch0 time positive edge"),
        Register(DC_LATCH0_NEGATIVE, 8, "DC latch0 time negative edge"),
        Register(DC_LATCH1_POSITIVE, 8, "DC latch1 time positive edge"),
        Register(DC_LATCH1_NEGATIVE, 8, "DC latch1 time negative edge"),
        Register(DC_ECAT_BUFFER_CHANGE, 4, "DC EtherCAT buffer change event time"),
        Register(DC_PDI_BUFFER_START, 4, "DC PDI buffer start event time"),
        Register(DC_PDI_BUFFER_CHANGE, 4, "DC PDI buffer change event time"),
        Register(DIGITAL_OUTPUT, 4, "Digital I/O output data", _RW),
        Register(USER_RAM, 128, "User RAM", _RW),
    ]
    fmmu_fields = [(FMMU_LOGICAL_START, 4, "logical start address"), (FMMU_LENGTH, 2, "length"),
                   (FMMU_LOGICAL_START_BIT, 1, "logical start bit"),
                   (FMMU_LOGICAL_STOP_BIT, 1, "logical stop bit"),
                   (FMMU_PHYSICAL_START, 2, "physical start address"),
                   (FMMU_PHYSICAL_START_BIT, 1, "physical start bit"),
                   (FMMU_TYPE, 1, "type"), (FMMU_ACTIVATE, 1, "activate")]
    for n in range(16):
        for off, size, label in fmmu_fields:
            regs.append(Register(fmmu_address(n) + off, size, f"FMMU{n} {label}", _RW))
    sm_fields = [(SM_START, 2, "physical start address", _RW), (SM_LENGTH, 2, "length", _RW),
                 (SM_CONTROL, 1, "control", _RW), (SM_STATUS, 1, "status", _R),
                 (SM_ACTIVATE, 1, "activate", _RW), (SM_PDI_CONTROL, 1, "PDI control", _R)]
    for n in range(16):
        for off, size, label, acc in sm_fields:
            regs.append(Register(sm_address(n) + off, size, f"SM{n} {label}", acc))
    regs.sort(key=lambda r: r.address)
    return regs


REGISTERS: tuple[Register, ...] = tuple(_table())
_BY_ADDRESS = {r.address: r for r in REGISTERS}
_STARTS = [r.address for r in REGISTERS]


def register_at(address: int) -> Register | None:
    """The register starting exactly at ``address``."""
    return _BY_ADDRESS.get(address)


def register_containing(address: int) -> Register | None:
    """The register whose bytes include ``address``."""
    i = bisect.bisect_right(_STARTS, address) - 1
    if i < 0:
        return None
    reg = REGISTERS[i]
    return reg if address < reg.address + reg.size else None


def register_name(address: int) -> str | None:
    """Name of the register at ``address`` (with ``+n`` inside a register)."""
    reg = register_containing(address)
    if reg is None:
        return None
    if reg.address == address:
        return reg.name
    return f"{reg.name}+{address - reg.address}"
