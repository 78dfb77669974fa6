"""Builders of the standard CoE objects of a simulated slave (IEC 61158-6-12 5.6.7; CiA 301).

0x1000-0x100A device information, 0x1018 identity, PDO mapping objects
0x16xx/0x1Axx, PDO assignment 0x1C12/0x1C13, SM communication types 0x1C00
and the synchronisation parameters 0x1C32/0x1C33 (SOES
``applications/rtl_xmc4_dynpdo/slave_objectlist.c`` ``SDO1C32``; IEC
61158-6-12 5.6.7.4.11), with the names and access rights real devices give them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from pyethercat.sim.od import RO, RW, RW_PREOP, SimObjectDictionary, SimOdEntry, SimOdObject
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import (
    IdentitySub,
    StandardObject,
    SyncMode,
    SyncModeSupported,
    SyncSub,
    assignment_sm,
    mapping_word,
    sm_pdo_assignment,
)
from pyethercat.wire.sii import SyncManagerType

__all__ = [
    "add_device_info",
    "add_identity",
    "add_pdo_assignment",
    "add_pdo_mapping",
    "add_sync_manager_objects",
    "add_sync_parameters",
    "mapping_word",
]

_RX_ASSIGN = int(StandardObject.RXPDO_ASSIGNMENT)
_TX_ASSIGN = int(StandardObject.TXPDO_ASSIGNMENT)
_SM_OUTPUT_SYNC = int(StandardObject.SM_OUTPUT_SYNC)


def add_device_info(od: SimObjectDictionary, device_type: int, name: str, hardware: str = "",
                    software: str = "") -> None:
    """0x1000 device type, 0x1001 error register and the 0x1008/0x1009/0x100A strings."""
    std = StandardObject
    od.var(std.DEVICE_TYPE, "Device type", DataType.UNSIGNED32, RO, device_type)
    od.var(std.ERROR_REGISTER, "Error register", DataType.UNSIGNED8, RO, 0)
    od.var(std.DEVICE_NAME, "Manufacturer device name", DataType.VISIBLE_STRING, RO, name)
    if hardware:
        od.var(std.HARDWARE_VERSION, "Manufacturer hardware version", DataType.VISIBLE_STRING,
               RO, hardware)
    if software:
        od.var(std.SOFTWARE_VERSION, "Manufacturer software version", DataType.VISIBLE_STRING,
               RO, software)


def add_identity(od: SimObjectDictionary, vendor: int, product: int, revision: int,
                 serial: int = 0) -> None:
    """0x1018 identity (vendor id, product code, revision, serial number)."""
    od.record(StandardObject.IDENTITY, "Identity", [
        SimOdEntry(IdentitySub.VENDOR_ID, "Vendor ID", DataType.UNSIGNED32, RO, vendor),
        SimOdEntry(IdentitySub.PRODUCT_CODE, "Product code", DataType.UNSIGNED32, RO, product),
        SimOdEntry(IdentitySub.REVISION, "Revision", DataType.UNSIGNED32, RO, revision),
        SimOdEntry(IdentitySub.SERIAL_NUMBER, "Serial number", DataType.UNSIGNED32, RO, serial),
    ], data_type=int(DataType.IDENTITY))


def add_pdo_mapping(od: SimObjectDictionary, index: int, name: str,
                    entries: Iterable[tuple[int, int, int]], *, max_entries: int = 8,
                    access: int = RW_PREOP) -> SimOdObject:
    """A PDO mapping object 0x16xx/0x1Axx with ``(index, subindex, bits)`` entries."""
    words = [mapping_word(*e) for e in entries]
    obj = od.array(index, name, DataType.UNSIGNED32, words, access, count_access=access,
                   length=max_entries,
                   names=[f"SubIndex {n:03d}" for n in range(1, max_entries + 1)])
    return obj


def add_pdo_assignment(od: SimObjectDictionary, index: int, pdos: Sequence[int], *,
                       max_entries: int = 4, access: int = RW_PREOP,
                       assigned: int | None = None) -> SimOdObject:
    """0x1C12/0x1C13: subindex n = PDO index; subindex 0 = ``assigned`` (default: all)."""
    name = ("RxPDO assign" if index == _RX_ASSIGN else "TxPDO assign" if index == _TX_ASSIGN
            else f"SM{assignment_sm(index)} PDO assign")
    obj = od.array(index, name, DataType.UNSIGNED16, list(pdos), access, count_access=access,
                   length=max_entries)
    if assigned is not None:
        obj.entries[0].raw[:] = bytes([assigned])
    return obj


#: SM communication types (0x1C00) of the usual SM0-SM3 layout.
_STANDARD_SM_TYPES = (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN,
                      SyncManagerType.OUTPUTS, SyncManagerType.INPUTS)


def add_sync_manager_objects(od: SimObjectDictionary,
                             types: Sequence[int] = _STANDARD_SM_TYPES) -> None:
    """0x1C00 SM communication types and the (empty) 0x1C10/0x1C11 mailbox assignments.

    ``types`` are SII SyncM type codes (:class:`~pyethercat.wire.sii.SyncManagerType`),
    the numbering 0x1C00 uses too.
    """
    od.array(StandardObject.SM_COMM_TYPE, "Sync manager type", DataType.UNSIGNED8,
             [int(t) for t in types], RO)
    for n, t in enumerate(types[:2]):
        if t in (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN):
            od.array(sm_pdo_assignment(n), f"SM{n} PDO assign", DataType.UNSIGNED16, [], RO)


_DEFAULT_SYNC_SUPPORT = int(SyncModeSupported.FREE_RUN | SyncModeSupported.SYNCHRONOUS
                            | SyncModeSupported.DC_SYNC0)


def add_sync_parameters(od: SimObjectDictionary, index: int, *, mode: int,
                        supported: int = _DEFAULT_SYNC_SUPPORT,
                        min_cycle_ns: int = 100_000) -> None:
    """0x1C32 (outputs) or 0x1C33 (inputs) synchronisation parameters (SOES ``SDO1C32``)."""
    name = "SM output parameter" if index == _SM_OUTPUT_SYNC else "SM input parameter"
    u16, u32 = DataType.UNSIGNED16, DataType.UNSIGNED32
    modes = frozenset(int(m) for m in SyncMode)
    S = SyncSub
    od.record(index, name, [
        SimOdEntry(S.SYNC_MODE, "Sync mode", u16, RW_PREOP, mode, allowed=modes),
        SimOdEntry(S.CYCLE_TIME, "Cycle time", u32, RO, 0),
        SimOdEntry(S.SHIFT_TIME, "Shift time", u32, RO, 0),
        SimOdEntry(S.SYNC_MODES_SUPPORTED, "Sync modes supported", u16, RO, supported),
        SimOdEntry(S.MIN_CYCLE_TIME, "Minimum cycle time", u32, RO, min_cycle_ns),
        SimOdEntry(S.CALC_AND_COPY_TIME, "Calc and copy time", u32, RO, 0),
        SimOdEntry(S.MIN_DELAY_TIME, "Minimum delay time", u32, RO, 0),
        SimOdEntry(S.GET_CYCLE_TIME, "Get cycle time", u16, RW, 0, maximum=3),
        SimOdEntry(S.DELAY_TIME, "Delay time", u32, RO, 0),
        SimOdEntry(S.SYNC0_CYCLE_TIME, "Sync0 cycle time", u32, RW_PREOP, 0),
        SimOdEntry(S.SM_EVENT_MISSED, "SM event missed", u16, RO, 0),
        SimOdEntry(S.CYCLE_TIME_TOO_SMALL, "Cycle time too small", u16, RO, 0),
        SimOdEntry(S.SYNC_ERROR, "Sync error", DataType.BOOLEAN, RO, False),
    ], data_type=int(DataType.SYNC_PAR))
