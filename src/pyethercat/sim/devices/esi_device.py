"""Simulated slaves made from ESI files: ``esi = "file.xml"`` in a topology file.

:func:`load_esi_device` picks the device (product code / revision) of an ESI
file and builds its SII image with :mod:`pyethercat.esi.sii_from_esi`;
:func:`esi_model` gives the device model of a device that speaks CoE
(:class:`EsiCoeModel`: every instance serves a copy of the ESI's object
dictionary; an ESI without ``Dictionary`` gets the objects its PDOs imply).
Devices without CoE run as ``sim.devices.behaviour`` decides (nothing for IO,
"protocol not supported" for other mailbox protocols).

The dictionary is the ESI's, made consistent with the SII: the identity object
carries the SII identity, every PDO the ESI declares has its mapping object
with the ESI's entries, 0x1C12/0x1C13 hold the default assignment, and an
object a PDO maps that the dictionary lacks is added as a plain variable. So
any master (ours, SOEM) that reads the PDO layout over CoE finds the layout
the ESI declares, and the SM lengths it computes match what the ESC checks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.esi.model import EsiDevice, EsiDictionary, EsiFile, EsiFlags, EsiOdEntry
from pyethercat.esi.parse import load_esi
from pyethercat.esi.sii_from_esi import SM_TYPES, esi_to_sii, pick_device
from pyethercat.sim.cia402.model import Cia402Model
from pyethercat.sim.cia402.objects import add_cia402_objects
from pyethercat.sim.coe_model import CoeModel
from pyethercat.sim.devices.eoe_web import device_status
from pyethercat.sim.eoe import attach_eoe
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import (
    RO,
    RW,
    RW_PREOP,
    RXPDO,
    TXPDO,
    WO,
    SimObjectDictionary,
    SimOdEntry,
    SimOdObject,
)
from pyethercat.sim.std_objects import (
    add_identity,
    add_pdo_assignment,
    add_pdo_mapping,
    add_sync_manager_objects,
)
from pyethercat.wire.mailbox.coe import ObjectCode
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import Cia402Object, IdentitySub, StandardObject
from pyethercat.wire.sii import CoeDetails, MailboxProtocol, SiiInfo, SyncManagerType

__all__ = ["EsiCoeModel", "EsiDriveModel", "EsiSlave", "esi_dictionary", "esi_model",
           "is_cia402_device", "load_esi_device"]

# Room for process data when the ESI gives no SM sizes (bytes per direction).
_PD_CAPACITY = 1024


@dataclass
class EsiSlave:
    """An ESI device chosen for a simulated slave, with its SII image."""

    path: Path
    vendor_id: int
    device: EsiDevice
    sii: bytes


def load_esi_device(
    path: Path, product: int | None, revision: int | None, serial: int = 0
) -> EsiSlave:
    """Read ``path``, choose the device and build its SII (errors: :class:`ConfigError`)."""
    try:
        esi = _load_cached(path)
        device = pick_device(esi, product, revision)
        image = esi_to_sii(device, vendor_id=esi.vendor.id, serial=serial).image
    except EtherCATError as exc:
        raise ConfigError(f"ESI {path}: {exc}") from exc
    return EsiSlave(path=path, vendor_id=esi.vendor.id, device=device, sii=image)


_CACHE: dict[tuple[str, int, int], EsiFile] = {}


def _load_cached(path: Path) -> EsiFile:
    """Parse each ESI file once per process (a topology may use one catalogue 100 times)."""
    try:
        st = path.stat()
    except OSError:
        return load_esi(path)  # raises EsiError naming the file
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    esi = _CACHE.get(key)
    if esi is None:
        esi = load_esi(path)
        if len(_CACHE) > 32:
            _CACHE.clear()
        _CACHE[key] = esi
    return esi


def _access(flags: EsiFlags) -> int:
    acc = (flags.access or "ro").lower()
    restr = (flags.write_restrictions or "").lower()
    if acc == "wo":
        value = WO
    elif acc == "rw":
        value = RW_PREOP if restr == "preop" else RW
    else:
        value = RO
    if flags.rx_mappable:
        value |= RXPDO
    if flags.tx_mappable:
        value |= TXPDO
    return value


def _entry(e: EsiOdEntry) -> SimOdEntry:
    code = e.code
    if code is None or code not in DataType.__members__.values():
        code = DataType.OCTET_STRING
    dt = DataType(code)
    size = dt.byte_size
    max_length = None if size is not None else max(0, e.bit_size // 8)
    if max_length is not None and e.default is not None:
        # A string declared STRING(0)/BitSize 0 with a DefaultString (SOES's ESI
        # generator writes 0x1009/0x100A so) holds its default.
        max_length = max(max_length, len(e.default))
    entry = SimOdEntry(e.subindex, e.name, dt, _access(e.flags), None, max_length=max_length)
    if e.default is not None:
        raw = e.default
        want = size if size is not None else max_length
        if want is not None:
            raw = (raw + bytes(want))[:want]
        entry.raw[:] = raw
    return entry


def esi_dictionary(device: EsiDevice, *, vendor_id: int, serial: int = 0) -> SimObjectDictionary:
    """The device's object dictionary, consistent with its SII (see the module text)."""
    od = SimObjectDictionary()
    esi_od: EsiDictionary | None = device.dictionary
    if esi_od is not None:
        for obj in esi_od.objects:
            flat = esi_od.entries(obj)
            if not flat:
                continue
            entries = {e.subindex: _entry(e) for e in flat}
            dt = esi_od.data_types.get(obj.type)
            if dt is None or not dt.sub_items:
                ocode = ObjectCode.VAR
            elif dt.array_elements is not None or len({s.type for s in dt.sub_items[1:]}) == 1:
                ocode = ObjectCode.ARRAY
            else:
                ocode = ObjectCode.RECORD
            if 0 not in entries:
                entries[0] = SimOdEntry(0, "SubIndex 000", DataType.UNSIGNED8, RO, max(entries))
            elif ocode != ObjectCode.VAR and flat[0].subindex == 0 and flat[0].default is None:
                # No default for "number of entries": all of them are in use.
                entries[0].raw[:] = bytes([max(entries) & 0xFF])
            first = entries.get(1, entries[0])
            od.add(SimOdObject(obj.index, str(obj.name), ocode, int(first.data_type), entries))
    # Identity as the SII says.
    if StandardObject.IDENTITY not in od:
        add_identity(od, vendor_id, device.product_code, device.revision, serial)
    else:
        ident = od.get(StandardObject.IDENTITY)
        for sub, value in ((IdentitySub.VENDOR_ID, vendor_id),
                           (IdentitySub.PRODUCT_CODE, device.product_code),
                           (IdentitySub.REVISION, device.revision),
                           (IdentitySub.SERIAL_NUMBER, serial)):  # fmt: skip
            slot = ident.entries.get(sub)
            if slot is not None and slot.data_type.byte_size == 4:
                slot.raw[:] = value.to_bytes(4, "little")
    # Mapped objects, mapping objects and the default assignment as the ESI declares.
    for pdo in device.pdos:
        for pe in pdo.entries:
            if pe.is_padding or (pe.index in od and pe.subindex in od.get(pe.index).entries):
                continue
            info = pe.type_info
            code: DataType | None = info.code if info is not None and info.code.byte_size else None
            if code is None:
                code = {8: DataType.UNSIGNED8, 16: DataType.UNSIGNED16, 32: DataType.UNSIGNED32,
                        64: DataType.UNSIGNED64}.get(pe.bit_len, DataType.UNSIGNED8)  # fmt: skip
            acc = RW | RXPDO if pdo.direction == "rx" else RO | TXPDO
            name = str(pe.name) or f"0x{pe.index:04X}"
            if pe.subindex == 0 and pe.index not in od:
                od.var(pe.index, name, code, acc)
            elif pe.index not in od:
                od.record(pe.index, f"0x{pe.index:04X}", [SimOdEntry(pe.subindex, name, code, acc)])
            else:
                od.get(pe.index).entries[pe.subindex] = SimOdEntry(pe.subindex, name, code, acc)
        words = [(e.index, e.subindex, e.bit_len) for e in pdo.entries]
        existing = od.find(pdo.index)
        size = max(8, len(words), existing.max_subindex if existing is not None else 0)
        add_pdo_mapping(od, pdo.index, pdo.name.pick() or f"PDO 0x{pdo.index:04X}", words,
                        max_entries=size)  # fmt: skip
    # SM communication types (0x1C00): SOEM reads them before the assignment.
    types = [int(SM_TYPES.get(s.kind or "", SyncManagerType.UNUSED)) for s in device.sms]
    if StandardObject.SM_COMM_TYPE not in od and device.sms:
        add_sync_manager_objects(od, types)
    elif device.sms:
        sm_types = od.get(StandardObject.SM_COMM_TYPE)
        if not any(any(e.raw) for n, e in sm_types.entries.items() if n):
            # The ESI lists 0x1C00 without values: take them from the SMs.
            for n, t in enumerate(types, start=1):
                if n in sm_types.entries:
                    sm_types.entries[n].raw[:] = t.to_bytes(len(sm_types.entries[n].raw) or 1,
                                                            "little")  # fmt: skip
    layout = device.pdo_layout()
    for assign, direction in ((StandardObject.RXPDO_ASSIGNMENT, "Outputs"),
                              (StandardObject.TXPDO_ASSIGNMENT, "Inputs")):
        pdos = [p.index for s in layout.sms if s.sm.kind == direction for p in s.pdos]
        existing = od.find(assign)
        if not pdos and existing is None:
            continue
        size = max(4, len(pdos), existing.max_subindex if existing is not None else 0)
        add_pdo_assignment(od, assign, pdos, max_entries=size)
    return od


def _capacity(device: EsiDevice, kind: str) -> int:
    sizes = [s.max_size or s.default_size or 0 for s in device.sms if s.kind == kind]
    return max([_PD_CAPACITY, *sizes])


class _EsiDictionaries:
    """One ESI device's dictionary for each instance: the ESI's objects built once (then
    completed by ``complete``, if given), copied per instance with its serial number."""

    def __init__(self, slave: EsiSlave,
                 complete: Callable[[SimObjectDictionary], None] | None = None) -> None:
        self.slave = slave
        self._complete = complete
        self._template: SimObjectDictionary | None = None
        #: The largest SM2/SM3 buffers the device takes (the models' capacities).
        self.capacity_out = _capacity(slave.device, "Outputs")
        self.capacity_in = _capacity(slave.device, "Inputs")

    def __call__(self, info: SiiInfo, app: MailboxDevice) -> SimObjectDictionary:
        if self._template is None:
            od = esi_dictionary(self.slave.device, vendor_id=self.slave.vendor_id)
            if self._complete is not None:
                self._complete(od)
            self._template = od
        return _instance_dictionary(self._template, info)


class EsiCoeModel(CoeModel):
    """The CoE slaves of one ESI device: a copy of its dictionary each; inputs keep their defaults.

    There is no behaviour on outputs: nothing runs per frame (an SDO read of
    an output object takes the value from the output buffer when asked).
    """

    def __init__(self, slave: EsiSlave, details: int) -> None:
        self.slave = slave
        dictionaries = _EsiDictionaries(slave)
        super().__init__(dictionaries, details=details, capacity_out=dictionaries.capacity_out,
                         capacity_in=dictionaries.capacity_in)

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        """An instance; it speaks EoE too (with a diagnostic page) when its ESI lists EoE."""
        instance, app = super().instance_app(info)
        _with_eoe(app, info)
        return instance, app


def _instance_dictionary(template: SimObjectDictionary, info: SiiInfo) -> SimObjectDictionary:
    """One instance's copy of a device's dictionary, with the instance's serial number."""
    od = template.copy()
    serial = od.get(StandardObject.IDENTITY).entries.get(IdentitySub.SERIAL_NUMBER)
    if serial is not None and serial.data_type.byte_size == 4:
        serial.raw[:] = info.serial.to_bytes(4, "little")
    return od


def _with_eoe(app: MailboxDevice, info: SiiInfo) -> None:
    """EoE with a diagnostic page for a device whose ESI lists EoE."""
    if info.mailbox_protocols & MailboxProtocol.EOE:
        started = time.monotonic()

        def status() -> dict[str, Any]:
            return device_status(app, info, started, kind="ESI-described device",
                                 temperatures=(("Device", 40.0, 2.0, 60.0),),
                                 live=lambda t: [("Uptime", f"{t:.3f} s")])

        attach_eoe(app, info.tx_mailbox_size or 128, info.serial, status)


class EsiDriveModel(Cia402Model):
    """The CiA 402 drives of one ESI device: the ESI's dictionary, completed with the objects
    the simulated drive uses (``sim.cia402.objects``), runs as ``sim.cia402``."""

    def __init__(self, slave: EsiSlave, details: int) -> None:
        self.slave = slave
        dictionaries = _EsiDictionaries(slave, add_cia402_objects)
        super().__init__(dictionaries, details=details, capacity_out=dictionaries.capacity_out,
                         capacity_in=dictionaries.capacity_in)

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        """An instance; it speaks EoE too when its ESI lists EoE."""
        instance, app = super().instance_app(info)
        _with_eoe(app, info)
        return instance, app


def is_cia402_device(device: EsiDevice) -> bool:
    """A CiA 402 drive: profile 402 (``<ProfileNo>``, ``DS402Channels``) with a controlword
    and a statusword in its PDOs or dictionary."""
    profile = any(402 in p.profile_no for p in device.profiles) or bool(
        device.mailbox is not None and device.mailbox.coe is not None
        and device.mailbox.coe.ds402_channels)
    indices = {e.index for pdo in device.pdos for e in pdo.entries}
    dictionary = device.dictionary
    if dictionary is not None:
        indices |= {o.index for o in dictionary.objects}
    return profile and {int(Cia402Object.CONTROLWORD), int(Cia402Object.STATUSWORD)} <= indices


def esi_model(slave: EsiSlave, info: SiiInfo) -> EsiCoeModel | EsiDriveModel | None:
    """The device model of an ESI device that speaks CoE (a drive model for a CiA 402
    drive); None for any other."""
    device = slave.device
    mbx = device.mailbox
    if mbx is None or mbx.coe is None:
        return None
    # The dictionary decides what the mapping objects allow; the server honours
    # SDO information / complete access only where the ESI announces them.
    gen = info.general
    details = int(gen.coe_details) if gen is not None else int(CoeDetails.SDO)
    if is_cia402_device(device):
        return EsiDriveModel(slave, details)
    return EsiCoeModel(slave, details)
