"""Built-in CoE devices: ``builtin:coe-io`` and a servo controller's communication objects.

``coe-io`` is a test device with everything CoE has: IO in dynamically
mappable PDOs whose inputs echo the outputs (so loopback tests can check
them), a writable configuration area with value ranges, a 4 KiB octet string
for segmented transfers, write-only and PREOP-only parameters, the mapping
objects, 0x1C32/0x1C33, and SII CoE details announcing SDO, SDO information,
PDO assignment, PDO configuration and complete access. Its objects are
listed in ``docs/coe.md``.

``seed002-drive`` carries the communication objects of the item Industrie-
technik "Servo Positioning Controller C Series" as its EtherCAT manual lists
them (chapter 6.1.2, "Communication objects": 0x1000, 0x1018, 0x1100,
0x1600-0x1603, 0x1A00-0x1A03, 0x1C00, 0x1C10-0x1C13 with the values of its
tables), identity vendor 0xE4, product 0x264860d2, revision 0x20000, and
is a CiA 402 servo drive (``sim.cia402``: power state machine, modes of
operation, motor and load, the manual's EtherCAT errors) that also speaks
EoE with a diagnostic web page. :func:`add_seed002_objects` is the reusable
builder of its communication objects.

Both kinds are device models (``sim.coe_model.CoeModel``): their behaviour
is numpy over the object values of all instances at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cia402.model import Cia402Model
from pyethercat.sim.cia402.objects import add_cia402_objects
from pyethercat.sim.coe_model import CoeModel
from pyethercat.sim.devices.builtin import BuiltinDevice, BuiltinPdo, BuiltinPdoEntry, BuiltinSm
from pyethercat.sim.devices.eoe_web import device_status
from pyethercat.sim.eoe import attach_eoe
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import RO, RW, RW_PREOP, RXPDO, TXPDO, WO, SimObjectDictionary, SimOdEntry
from pyethercat.sim.std_objects import (
    add_device_info,
    add_identity,
    add_pdo_assignment,
    add_pdo_mapping,
    add_sync_manager_objects,
    add_sync_parameters,
)
from pyethercat.wire import registers as R
from pyethercat.wire.cia402 import decode_state
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import (
    Cia402Object,
    StandardObject,
    SyncMode,
    sm_pdo_assignment,
)
from pyethercat.wire.sii import (
    CoeDetails,
    FmmuUsage,
    MailboxProtocol,
    SiiInfo,
    SiiPortType,
    SyncManagerType,
)

__all__ = [
    "COE_IO",
    "SEED002_DRIVE",
    "CoeIoModel",
    "Seed002Model",
    "add_seed002_objects",
    "coe_devices",
    "coe_io_dictionary",
]

_COE_ALL = int(CoeDetails.SDO | CoeDetails.SDO_INFO | CoeDetails.PDO_ASSIGN
               | CoeDetails.PDO_CONFIG | CoeDetails.SDO_COMPLETE_ACCESS)
_MBX = (0x1000, 128, 0x1080, 128)  # standard mailbox: SM0 0x1000, SM1 0x1080, 128 bytes each
_SMS_STANDARD = (
    BuiltinSm(0x1000, 128, R.SM_CONTROL_MAILBOX_OUT, SyncManagerType.MAILBOX_OUT),
    BuiltinSm(0x1080, 128, R.SM_CONTROL_MAILBOX_IN, SyncManagerType.MAILBOX_IN),
)
_PD_CAPACITY = 128  # SM2 at 0x1100 and SM3 at 0x1180: room for 128 bytes each
_STD = StandardObject
_402 = Cia402Object
_SM_TYPES = (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN, SyncManagerType.OUTPUTS,
             SyncManagerType.INPUTS)  # 0x1C00 of both devices: SM0-SM3 in the usual roles
_EBUS2 = (SiiPortType.EBUS, SiiPortType.EBUS, SiiPortType.NOT_USED, SiiPortType.NOT_USED)
_MII2 = (SiiPortType.MII, SiiPortType.MII, SiiPortType.NOT_USED, SiiPortType.NOT_USED)

#: Size of the octet-string object 0x2000 (segmented transfers).
DATA_BLOCK_SIZE = 4096
#: Size of the octet-string object 0x2003 (segmented-transfer throughput benchmarks).
LARGE_BLOCK_SIZE = 65536
# Default contents of 0x2000/0x2003, made once (every instance copies them).
_DATA_BLOCK = bytes(i & 0xFF for i in range(DATA_BLOCK_SIZE))
_LARGE_BLOCK = bytes(i * 7 & 0xFF for i in range(LARGE_BLOCK_SIZE))
I64 = npt.NDArray[np.int64]


# --- coe-io ---------------------------------------------------------------------------


def coe_io_dictionary(vendor: int, product: int, revision: int, serial: int = 0) -> SimObjectDictionary:
    """The object dictionary of ``builtin:coe-io`` with its default mapping."""
    od = SimObjectDictionary()
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    add_device_info(od, 0x00000191, "PEC-COEIO CoE test IO", "1.0", "pyethercat sim 1.0")
    add_identity(od, vendor, product, revision, serial)
    od.record(_STD.ERROR_SETTINGS, "Error settings", [
        SimOdEntry(1, "Local error reaction", u32, RW, 1, maximum=2),
        SimOdEntry(2, "Sync error counter limit", u16, RW, 4),
    ])
    add_pdo_mapping(od, 0x1600, "DO outputs", [(0x7000, 1, 8)])
    add_pdo_mapping(od, 0x1601, "Value outputs", [(0x7000, 2, 16), (0x7000, 3, 32)])
    add_pdo_mapping(od, 0x1602, "Spare RxPDO", [])
    add_pdo_mapping(od, 0x1603, "Spare RxPDO 2", [])
    add_pdo_mapping(od, 0x1A00, "DI inputs", [(0x6000, 1, 8)])
    add_pdo_mapping(od, 0x1A01, "Value inputs", [(0x6000, 2, 16), (0x6000, 3, 32)])
    add_pdo_mapping(od, 0x1A02, "Status", [(0x6000, 4, 16)])
    add_pdo_mapping(od, 0x1A03, "Spare TxPDO", [])
    add_sync_manager_objects(od, _SM_TYPES)
    add_pdo_assignment(od, _STD.RXPDO_ASSIGNMENT, [0x1600, 0x1601])
    add_pdo_assignment(od, _STD.TXPDO_ASSIGNMENT, [0x1A00, 0x1A01])
    add_sync_parameters(od, _STD.SM_OUTPUT_SYNC, mode=SyncMode.SM_EVENT)
    # Inputs are latched when the outputs arrive.
    add_sync_parameters(od, _STD.SM_INPUT_SYNC, mode=SyncMode.SM2_EVENT)
    od.var(0x2000, "Data block", DataType.OCTET_STRING, RW,
           _DATA_BLOCK, max_length=DATA_BLOCK_SIZE)
    od.var(0x2001, "Command", u32, WO, 0)
    od.var(0x2003, "Large data block", DataType.OCTET_STRING, RW,
           _LARGE_BLOCK, max_length=LARGE_BLOCK_SIZE)
    od.var(0x2002, "PREOP parameter", u16, RW_PREOP, 100, minimum=1, maximum=1000)
    od.record(0x6000, "Inputs", [
        SimOdEntry(1, "Digital inputs", u8, RO | TXPDO, 0),
        SimOdEntry(2, "Value 16", u16, RO | TXPDO, 0),
        SimOdEntry(3, "Value 32", u32, RO | TXPDO, 0),
        SimOdEntry(4, "Cycle counter", u16, RO | TXPDO, 0),
        SimOdEntry(5, "Bit input", DataType.BOOLEAN, RO | TXPDO, False),
    ])
    od.record(0x7000, "Outputs", [
        SimOdEntry(1, "Digital outputs", u8, RW | RXPDO, 0),
        SimOdEntry(2, "Value 16", u16, RW | RXPDO, 0),
        SimOdEntry(3, "Value 32", u32, RW | RXPDO, 0),
        SimOdEntry(4, "Bit output", DataType.BOOLEAN, RW | RXPDO, False),
    ])
    od.record(0x8000, "Settings", [
        SimOdEntry(1, "Filter time", u16, RW, 10, maximum=10000),
        SimOdEntry(2, "Offset", DataType.INTEGER32, RW, 0, minimum=-1_000_000, maximum=1_000_000),
        SimOdEntry(3, "Invert digital", DataType.BOOLEAN, RW, False),
        SimOdEntry(4, "Mode", u8, RW, 0, allowed=frozenset({0, 1, 2})),
        SimOdEntry(5, "Gain", DataType.REAL32, RW, 1.0, minimum=0.0, maximum=100.0),
        SimOdEntry(6, "Channel name", DataType.VISIBLE_STRING, RW, "channel 1", max_length=32),
    ])
    od.record(0x8001, "Limits", [
        SimOdEntry(1, "Low", DataType.INTEGER16, RW, -100),
        SimOdEntry(2, "High", DataType.INTEGER16, RW, 100),
    ])
    return od


#: XOR mask of the digital inputs by the value of 0x8000:03 (any non-zero value inverts).
_INVERT_MASK = np.full(256, 0xFF, np.uint8)
_INVERT_MASK[0] = 0
#: (An array operand: a Python int scalar costs the ufunc a type promotion per call.)
_ONE_U16 = np.ones(1, np.uint16)
#: The entries CoeIoModel.compute reads and writes, in its order.
_IO_COLUMNS = ((0x6000, 1), (0x6000, 2), (0x6000, 3), (0x6000, 4), (0x6000, 5),
               (0x7000, 1), (0x7000, 2), (0x7000, 3), (0x7000, 4), (0x8000, 2), (0x8000, 3))


class CoeIoModel(CoeModel):
    """``builtin:coe-io``: inputs echo outputs through the current PDO mapping.

    Digital inputs = digital outputs (inverted when 0x8000:03 is set), value 16
    = value 16, value 32 = value 32 + offset 0x8000:02 (mod 2^32), bit input =
    bit output, cycle counter +1 per output buffer; for all instances at once.
    """

    output_events = True

    def __init__(self) -> None:
        super().__init__(self._dictionary, details=_COE_ALL, capacity_out=_PD_CAPACITY,
                         capacity_in=_PD_CAPACITY, fields=((0x8000, 2), (0x8000, 3)))
        # One dictionary built per identity, copied per instance (a segment of
        # thousands of coe-io slaves would spend seconds building each anew).
        self._templates: dict[tuple[int, int, int], SimObjectDictionary] = {}

    def _dictionary(self, info: SiiInfo, app: MailboxDevice) -> SimObjectDictionary:
        key = (info.vendor_id, info.product_code, info.revision)
        template = self._templates.get(key)
        if template is None:
            template = self._templates[key] = coe_io_dictionary(*key)
        od = template.copy()
        od.set_value(_STD.IDENTITY, 4, info.serial)
        return od

    def compute(self, instances: I64) -> None:
        if len(instances) == self.count:
            # Every instance (the usual frame): the columns cut to the instances there are,
            # no index; each numpy call costs about a microsecond whatever the instance
            # count. (Assignments, not ufuncs with out=: out= into a view of the same image
            # as the operands makes numpy check them for overlap, which costs more.)
            di, v16i, v32i, count, bit_in, do, v16o, v32o, bit_out, offset, invert = (
                self.live_fields(_IO_COLUMNS))
            di[...] = do ^ _INVERT_MASK[invert]
            v16i[...] = v16o
            v32i[...] = v32o + offset.view(np.uint32)
            bit_in[...] = bit_out
            count += _ONE_U16
            return
        di, v16i, v32i, count, bit_in, do, v16o, v32o, bit_out, offset, invert = self.fields_of(_IO_COLUMNS)
        r = instances  # some of them: gathered, computed, scattered
        # Inverted where 0x8000:03 is set: XOR with a mask looked up from it, not a select.
        di[r] = do[r] ^ _INVERT_MASK[invert[r]]
        v16i[r] = v16o[r]
        v32i[r] = v32o[r] + offset[r].view(np.uint32)
        bit_in[r] = bit_out[r]
        count[r] += _ONE_U16


COE_IO = BuiltinDevice(
    key="coe-io",
    product_code=0x00050001,
    order="PEC-COEIO",
    name="PEC-COEIO CoE test IO (dynamic PDOs)",
    group="CoE",
    profile="ET1100",
    ports=_EBUS2,
    sync_managers=_SMS_STANDARD + (
        BuiltinSm(0x1100, 7, R.SM_CONTROL_OUTPUTS, SyncManagerType.OUTPUTS),
        BuiltinSm(0x1180, 7, R.SM_CONTROL_INPUTS, SyncManagerType.INPUTS),
    ),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.INPUTS, FmmuUsage.MAILBOX_STATE),
    rx_pdos=(
        BuiltinPdo(0x1600, 2, "DO outputs", (BuiltinPdoEntry(0x7000, 1, 8, "Digital outputs", 0x0005),)),
        BuiltinPdo(0x1601, 2, "Value outputs", (BuiltinPdoEntry(0x7000, 2, 16, "Value 16", 0x0006),
                                          BuiltinPdoEntry(0x7000, 3, 32, "Value 32", 0x0007))),
    ),
    tx_pdos=(
        BuiltinPdo(0x1A00, 3, "DI inputs", (BuiltinPdoEntry(0x6000, 1, 8, "Digital inputs", 0x0005),)),
        BuiltinPdo(0x1A01, 3, "Value inputs", (BuiltinPdoEntry(0x6000, 2, 16, "Value 16", 0x0006),
                                         BuiltinPdoEntry(0x6000, 3, 32, "Value 32", 0x0007))),
    ),
    mailbox=_MBX,
    ebus_current_ma=120,
    pdi_control=0x0C05,  # PDI: SPI (a microcontroller runs the CoE stack)
    description="CoE IO: 8 DI/8 DO, 16/32-bit values each way (inputs echo outputs), "
                "dynamic PDOs, 4 KiB octet string 0x2000, settings 0x8000",
    coe_details=_COE_ALL,
    mailbox_protocols=int(MailboxProtocol.COE),
    model=CoeIoModel,
    dc_modes=True,  # 0x1C32 offers DC SYNC0
)


# --- the item C series servo controller --------------------------------------------------

SEED002_VENDOR = 0x000000E4
SEED002_PRODUCT = 0x264860D2
SEED002_REVISION = 0x00020000


def add_seed002_objects(od: SimObjectDictionary, *, serial: int = 0,
                        station_address: Callable[[], int] | None = None,
                        assigned_rx: int = 0, assigned_tx: int = 0,
                        profile_objects: bool = True) -> None:
    """The servo controller's CoE communication objects (its EtherCAT manual, chapter 6.1.2).

    0x1000 device type (CiA 402 servo drive), 0x1018 identity, 0x1100 fixed
    station address (read-only, the live register 0x0010 when
    ``station_address`` is given), four RxPDO and four TxPDO mapping objects
    (0x1600 = controlword 0x6040 + modes of operation 0x6060 as in the manual's
    ESI example; 0x1A00 = statusword 0x6041 + modes display 0x6061),
    0x1C00 = 4 channels of types 1, 2, 3, 4 (read-only), 0x1C10/0x1C11 with no
    PDO, 0x1C12/0x1C13 with 0x1600-0x1603 / 0x1A00-0x1A03 in subindices 1-4
    and subindex 0 = ``assigned_rx``/``assigned_tx`` (the manual's default is 0:
    the master assigns). 0x1008-0x100A are absent, as the manual says.
    ``profile_objects`` adds 0x6040/0x6041/0x6060/0x6061 when missing, so
    the default mapping validates.
    """
    od.var(_STD.DEVICE_TYPE, "Device type", DataType.UNSIGNED32, RO, 0x00020192)  # profile 402
    od.var(_STD.ERROR_REGISTER, "Error register", DataType.UNSIGNED8, RO, 0)
    add_identity(od, SEED002_VENDOR, SEED002_PRODUCT, SEED002_REVISION, serial)
    hook = None
    if station_address is not None:
        def hook() -> bytes:
            return (station_address() & 0xFFFF).to_bytes(2, "little")
    od.var(_STD.STATION_ADDRESS, "EtherCAT fixed station address", DataType.UNSIGNED16, RO, 0,
           on_read=hook)
    if profile_objects:
        for index, name, dtype, access in (
                (_402.CONTROLWORD, "Controlword", DataType.UNSIGNED16, RW | RXPDO),
                (_402.STATUSWORD, "Statusword", DataType.UNSIGNED16, RO | TXPDO),
                (_402.MODES_OF_OPERATION, "Modes of operation", DataType.INTEGER8, RW | RXPDO),
                (_402.MODES_OF_OPERATION_DISPLAY, "Modes of operation display",
                 DataType.INTEGER8, RO | TXPDO)):
            if index not in od:
                od.var(index, name, dtype, access, 0)
    rx_pdos = [_STD.RXPDO_MAPPING_FIRST + n for n in range(4)]  # 0x1600-0x1603
    tx_pdos = [_STD.TXPDO_MAPPING_FIRST + n for n in range(4)]  # 0x1A00-0x1A03
    add_pdo_mapping(od, rx_pdos[0], "1. RxPDO mapping",
                    [(_402.CONTROLWORD, 0, 16), (_402.MODES_OF_OPERATION, 0, 8)])
    for n in range(1, 4):
        add_pdo_mapping(od, rx_pdos[n], f"{n + 1}. RxPDO mapping", [])
    add_pdo_mapping(od, tx_pdos[0], "1. TxPDO mapping",
                    [(_402.STATUSWORD, 0, 16), (_402.MODES_OF_OPERATION_DISPLAY, 0, 8)])
    for n in range(1, 4):
        add_pdo_mapping(od, tx_pdos[n], f"{n + 1}. TxPDO mapping", [])
    add_sync_manager_objects(od, _SM_TYPES)
    od.get(_STD.SM_COMM_TYPE).name = "Sync manager communication type"
    od.get(sm_pdo_assignment(0)).name = "Sync manager channel 0 (mailbox receive)"
    od.get(sm_pdo_assignment(1)).name = "Sync manager channel 1 (mailbox send)"
    rx = add_pdo_assignment(od, _STD.RXPDO_ASSIGNMENT, rx_pdos, assigned=assigned_rx)
    rx.name = "Sync manager channel 2 (process data output)"
    tx = add_pdo_assignment(od, _STD.TXPDO_ASSIGNMENT, tx_pdos, assigned=assigned_tx)
    tx.name = "Sync manager channel 3 (process data input)"
    # Entry names as the manual's tables give them (entry descriptions, `sdos`).
    types = od.get(_STD.SM_COMM_TYPE)
    types.entries[0].name = "Number of used Sync Manager Channels"
    for n in range(1, 5):
        types.entries[n].name = f"Communication Type Sync Channel {n - 1}"
    for sm in range(4):
        od.get(sm_pdo_assignment(sm)).entries[0].name = "Number of assigned PDOs"
    for n in range(1, 5):
        rx.entries[n].name = "PDO Mapping object Number of assigned RxPDO"
        tx.entries[n].name = "PDO Mapping object number of assigned TxPDO"


class Seed002Model(Cia402Model):
    """``builtin:seed002-drive``: the controller's communication objects and a CiA 402 drive.

    The drive itself (power state machine, modes, motor and load, its
    EtherCAT errors) is ``sim.cia402``; this kind adds the controller's
    communication objects (:func:`add_seed002_objects`) and the EoE diagnostic page.
    """

    def __init__(self) -> None:
        super().__init__(self._dictionary, details=_COE_ALL & ~int(CoeDetails.SDO_COMPLETE_ACCESS),
                         capacity_out=_PD_CAPACITY, capacity_in=_PD_CAPACITY)

    @staticmethod
    def _dictionary(info: SiiInfo, app: MailboxDevice) -> SimObjectDictionary:
        def station() -> int:
            if app.pdi is None:
                return 0
            return int.from_bytes(app.pdi.read(R.STATION_ADDRESS, 2), "little")

        od = SimObjectDictionary()
        add_seed002_objects(od, serial=info.serial, station_address=station)
        add_cia402_objects(od)
        return od

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        """An instance that also speaks EoE and serves a diagnostic web page.

        As the intelligent drive of the 2003 EtherCAT article ("ein
        HTTP-Server ... der seine eigene Diagnoseschnittstelle in Form von
        Web-Seiten mitbringt").
        """
        instance, app = super().instance_app(info)
        started = time.monotonic()

        def status() -> dict[str, Any]:
            def value(index: int, signed: bool = False) -> int:
                # as an SDO upload reads it: actual values no PDO maps are made when read
                return int.from_bytes(self._read(instance, (index, 0)), "little", signed=signed)

            statusword, control = value(_402.STATUSWORD), value(_402.CONTROLWORD)
            # The drive model's own values (its encoder and speed): the large live value is
            # what the axis does, so a page drawn by a stopped device model shows it stopped.
            position = value(_402.POSITION_ACTUAL_VALUE, signed=True)
            velocity = value(_402.VELOCITY_ACTUAL_VALUE, signed=True)
            state = decode_state(statusword)

            def live(t: float) -> list[tuple[str, Any]]:
                return [("Position actual value", f"{position} inc"),
                        ("Velocity 0x606C", f"{velocity} inc/s"),
                        ("Statusword 0x6041", f"0x{statusword:04X}"),
                        ("Drive state", state.label if state is not None else "?"),
                        ("Controlword 0x6040", f"0x{control:04X}"),
                        ("DC link voltage", "560.0 V"),
                        ("Uptime", f"{t:.1f} s")]

            return device_status(app, info, started, kind="Servo positioning controller",
                                 temperatures=(("Power stage", 46.0, 4.0, 45.0),
                                               ("Motor", 39.0, 3.0, 90.0),
                                               ("Controller board", 41.0, 1.5, 30.0)),
                                 live=live)

        attach_eoe(app, info.tx_mailbox_size or 128, info.serial, status)
        return instance, app


SEED002_DRIVE = BuiltinDevice(
    key="seed002-drive",
    product_code=SEED002_PRODUCT,
    order="item C-Serie EtherCAT",
    name="item Servo Positioning Controller C Series",
    group="Drive",
    profile="IPCORE",
    ports=_MII2,
    sync_managers=_SMS_STANDARD + (
        BuiltinSm(0x1100, 3, R.SM_CONTROL_OUTPUTS, SyncManagerType.OUTPUTS),
        BuiltinSm(0x1180, 3, R.SM_CONTROL_INPUTS, SyncManagerType.INPUTS),
    ),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.INPUTS, FmmuUsage.MAILBOX_STATE),
    rx_pdos=(BuiltinPdo(0x1600, 2, "Outputs", (
        BuiltinPdoEntry(_402.CONTROLWORD, 0, 16, "Controlword", 0x0006),
        BuiltinPdoEntry(_402.MODES_OF_OPERATION, 0, 8, "Mode_Of_Operation", 0x0002))),),
    tx_pdos=(BuiltinPdo(0x1A00, 3, "Inputs", (
        BuiltinPdoEntry(_402.STATUSWORD, 0, 16, "Statusword", 0x0006),
        BuiltinPdoEntry(_402.MODES_OF_OPERATION_DISPLAY, 0, 8, "Mode_Of_Operation_Display",
                 0x0002))),),
    mailbox=_MBX,
    pdi_control=0x0C05,
    description="item C series servo controller: CiA 402 drive (CSP/CSV/CST, PP, PV, homing) "
                "with a simulated motor; CoE objects 0x1000-0x1C13 (0x1C12/0x1C13 "
                "subindex 0 = 0 until the master assigns PDOs); EoE with a diagnostic page",
    coe_details=_COE_ALL & ~int(CoeDetails.SDO_COMPLETE_ACCESS),
    mailbox_protocols=int(MailboxProtocol.COE | MailboxProtocol.EOE),
    vendor_id=SEED002_VENDOR,
    revision=SEED002_REVISION,
    model=Seed002Model,
    dc_modes=True,  # "SM-Synchron" and "DC-Synchron" (SYNC0), as the ESI's <Dc>
)


def coe_devices() -> tuple[BuiltinDevice, ...]:
    """The CoE kinds of this module (a provider of ``sim.devices.registry``)."""
    return (COE_IO, SEED002_DRIVE)
