"""An ESI file for a device known only by its SII (and, optionally, its object dictionary).

``pyethercat xml -p POS`` uses :func:`esi_from_sii` to describe a live slave:
identity, names and group from the SII strings, FMMUs, SMs, PDOs, mailbox
protocols and CoE details, DC op modes, the EEPROM header (ConfigData,
BootStrap, ByteSize), and, when the master could browse it over CoE (SDO
information), the object dictionary. Feeding the result back through
:func:`~pyethercat.esi.sii_from_esi.esi_to_sii` gives an image with the same
identity, mailbox, SM, FMMU and PDO content (tested).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from lxml import etree

from pyethercat.esi.eni import _sub
from pyethercat.esi.model import ESI_TYPE_NAMES
from pyethercat.esi.sii_from_esi import FMMU_USAGES, MAILBOX_PROTOCOLS, PORT_LETTERS, SM_TYPES
from pyethercat.wire.mailbox.coe import ObjectAccess, ObjectCode
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.sii import (
    SM_NOT_ASSIGNED,
    CoeDetails,
    GeneralFlags,
    SiiInfo,
    SiiPdo,
    SiiPdoFlags,
    SyncManagerEnable,
)

__all__ = ["DictEntry", "DictObject", "esi_from_sii"]

# Strings take their length in the name: STRING(n).
_TYPE_NAMES: dict[int, str] = {
    **ESI_TYPE_NAMES, DataType.VISIBLE_STRING: "STRING", DataType.OCTET_STRING: "OCTET_STRING"
}
_SM_NAMES = {v: k for k, v in SM_TYPES.items()}
_FMMU_NAMES = {v: k for k, v in FMMU_USAGES.items()}

@dataclass
class DictEntry:
    """One subindex as the SDO information service describes it."""

    subindex: int
    name: str
    data_type: int
    bit_length: int
    access: int
    default: bytes | None = None


@dataclass
class DictObject:
    """One object (VAR, ARRAY or RECORD) with its entries."""

    index: int
    name: str
    object_code: int  # ObjectCode: VAR, ARRAY or RECORD
    entries: list[DictEntry] = field(default_factory=list)


def _type_name(code: int, bits: int) -> str:
    name = _TYPE_NAMES.get(code)
    if name in ("STRING", "OCTET_STRING"):
        return f"{name}({max(1, bits // 8)})"
    if name is not None:
        return name
    return {1: "BOOL", 8: "USINT", 16: "UINT", 32: "UDINT", 64: "ULINT"}.get(bits, "USINT")


def _access(a: int) -> str:
    if a & ObjectAccess.WRITE and a & ObjectAccess.READ:
        return "rw"
    return "wo" if a & ObjectAccess.WRITE else "ro"


def _dictionary(parent: etree._Element, objects: Sequence[DictObject]) -> None:
    dic = _sub(parent, "Dictionary")
    types = _sub(dic, "DataTypes")
    objs = _sub(dic, "Objects")
    base: dict[str, int] = {}
    for o in objects:
        for e in o.entries:
            t = _type_name(e.data_type, e.bit_length)
            base.setdefault(t, e.bit_length)
    for t, bits in base.items():
        dt = _sub(types, "DataType")
        _sub(dt, "Name", t)
        _sub(dt, "BitSize", bits)
    for o in objects:
        ob = _sub(objs, "Object")
        _sub(ob, "Index", f"#x{o.index:04X}")
        _sub(ob, "Name", o.name)
        if o.object_code == ObjectCode.VAR or len(o.entries) == 1:
            e = o.entries[0]
            _sub(ob, "Type", _type_name(e.data_type, e.bit_length))
            _sub(ob, "BitSize", e.bit_length)
            if e.default is not None:
                _sub(_sub(ob, "Info"), "DefaultData", e.default.hex().upper())
            flags = _sub(ob, "Flags")
            _sub(flags, "Access", _access(e.access))
            pm = (("R" if e.access & ObjectAccess.RXPDO_MAPPABLE else "")
                  + ("T" if e.access & ObjectAccess.TXPDO_MAPPABLE else ""))
            if pm:
                _sub(flags, "PdoMapping", pm)
            continue
        # Record/array: a data type of its own, with one sub item per entry.
        dt = _sub(types, "DataType")
        tname = f"DT{o.index:04X}"
        _sub(dt, "Name", tname)
        offs = 0
        subs = []
        for e in o.entries:
            si = _sub(dt, "SubItem")
            _sub(si, "SubIdx", e.subindex)
            _sub(si, "Name", e.name)
            _sub(si, "Type", _type_name(e.data_type, e.bit_length))
            _sub(si, "BitSize", e.bit_length)
            _sub(si, "BitOffs", offs)
            _sub(_sub(si, "Flags"), "Access", _access(e.access))
            offs += e.bit_length if e.subindex else 16  # subindex 0 padded to 16 bits
            subs.append(e)
        _sub(dt, "BitSize", offs)
        _sub(ob, "Type", tname)
        _sub(ob, "BitSize", offs)
        info = _sub(ob, "Info")
        for e in subs:
            si = _sub(info, "SubItem")
            _sub(si, "Name", e.name)
            if e.default is not None:
                _sub(_sub(si, "Info"), "DefaultData", e.default.hex().upper())


def _pdo(parent: etree._Element, info: SiiInfo, p: SiiPdo, tag: str) -> None:
    attrs: dict[str, str] = {}
    if p.flags & SiiPdoFlags.FIXED_CONTENT:
        attrs["Fixed"] = "1"
    if p.flags & SiiPdoFlags.MANDATORY:
        attrs["Mandatory"] = "1"
    if p.sync_manager != SM_NOT_ASSIGNED:
        attrs["Sm"] = str(p.sync_manager)
    el = _sub(parent, tag, **attrs)
    _sub(el, "Index", f"#x{p.index:04X}")
    _sub(el, "Name", info.pdo_name(p) or "")
    for e in p.entries:
        en = _sub(el, "Entry")
        _sub(en, "Index", f"#x{e.index:04X}")
        if e.index:
            _sub(en, "SubIndex", e.subindex)
        _sub(en, "BitLen", e.bit_length)
        if e.index:
            _sub(en, "Name", info.pdo_name(e) or "")
            _sub(en, "DataType", _type_name(e.data_type, e.bit_length))


def esi_from_sii(
    info: SiiInfo,
    objects: Sequence[DictObject] | None = None,
    *,
    vendor_name: str = "",
    comment: str = "generated by pyethercat from the slave's SII",
) -> bytes:
    """ESI XML describing the device of ``info`` (and its dictionary ``objects``)."""
    root = etree.Element("EtherCATInfo", {"Version": "1.6"})
    root.append(etree.Comment(f" {comment} "))
    vendor = _sub(root, "Vendor")
    _sub(vendor, "Id", f"#x{info.vendor_id:08X}")
    _sub(vendor, "Name", vendor_name or f"Vendor 0x{info.vendor_id:X}")
    desc = _sub(root, "Descriptions")
    group = info.group_name or "Devices"
    g = _sub(_sub(desc, "Groups"), "Group")
    _sub(g, "Type", group)
    _sub(g, "Name", group, LcId="1033")
    ports = info.general.ports if info.general is not None else (0, 0, 0, 0)
    physics = "".join(PORT_LETTERS.get(p, " ") for p in ports)
    dev = _sub(_sub(desc, "Devices"), "Device", Physics=physics.rstrip() or "YY")
    type_name = info.order_number or info.device_name or f"0x{info.product_code:08X}"
    _sub(dev, "Type", type_name, ProductCode=f"#x{info.product_code:08X}",
         RevisionNo=f"#x{info.revision:08X}")  # fmt: skip
    _sub(dev, "Name", info.device_name or type_name, LcId="1033")
    _sub(dev, "GroupType", group)
    if objects:
        _dictionary(_sub(dev, "Profile"), objects)
    for u in info.fmmus:
        if u in _FMMU_NAMES:
            _sub(dev, "Fmmu", _FMMU_NAMES[u])  # type: ignore[index]
    for s in info.sync_managers:
        attrs = {"StartAddress": f"#x{s.start:04X}", "ControlByte": f"#x{s.control:02X}",
                 "Enable": "1" if s.enabled else "0"}  # fmt: skip
        if s.length:
            attrs["DefaultSize"] = str(s.length)
        if s.enable & SyncManagerEnable.VIRTUAL:
            attrs["Virtual"] = "1"
        if s.enable & SyncManagerEnable.OP_ONLY:
            attrs["OpOnly"] = "1"
        _sub(dev, "Sm", _SM_NAMES.get(s.sm_type, ""), **attrs)  # type: ignore[call-overload]
    for p in info.rx_pdos:
        _pdo(dev, info, p, "RxPdo")
    for p in info.tx_pdos:
        _pdo(dev, info, p, "TxPdo")
    if info.mailbox_protocols:
        gen = info.general
        mb = _sub(dev, "Mailbox", DataLinkLayer="true" if gen and gen.flags & GeneralFlags.MBOX_DATA_LINK_LAYER else "false")
        for name, bit in MAILBOX_PROTOCOLS.items():
            if not info.mailbox_protocols & bit:
                continue
            if name == "CoE":
                d = gen.coe_details if gen is not None else CoeDetails.NONE
                coe = _sub(mb, "CoE", SdoInfo=_b(d & CoeDetails.SDO_INFO),
                           PdoAssign=_b(d & CoeDetails.PDO_ASSIGN),
                           PdoConfig=_b(d & CoeDetails.PDO_CONFIG),
                           PdoUpload=_b(d & CoeDetails.UPLOAD_AT_STARTUP),
                           CompleteAccess=_b(d & CoeDetails.SDO_COMPLETE_ACCESS))  # fmt: skip
                if gen is not None and gen.ds402_channels:
                    coe.set("DS402Channels", str(gen.ds402_channels))
            else:
                _sub(mb, name)
    if info.dc_modes:
        dc = _sub(dev, "Dc")
        for m in info.dc_modes:
            om = _sub(dc, "OpMode")
            _sub(om, "Name", info.string(m.name_index) or "DC")
            if m.description_index:
                _sub(om, "Desc", info.string(m.description_index))
            _sub(om, "AssignActivate", f"#x{m.assign_activate:04X}")
            cyc = _sub(om, "CycleTimeSync0", m.cycle_time_sync0)
            if m.sync0_cycle_factor:
                cyc.set("Factor", str(m.sync0_cycle_factor))
            _sub(om, "ShiftTimeSync0", m.shift_time_sync0)
            if m.shift_time_sync1:
                _sub(om, "ShiftTimeSync1", m.shift_time_sync1)
    ee = _sub(dev, "Eeprom")
    _sub(ee, "ByteSize", info.eeprom_size_bytes)
    words = (info.pdi_control, info.pdi_config, info.sync_impulse_len, info.pdi_config2,
             info.station_alias)  # fmt: skip
    config = b"".join(w.to_bytes(2, "little") for w in words) + info.reserved_05
    _sub(ee, "ConfigData", config.hex().upper())
    boot = (info.boot_rx_mailbox_offset, info.boot_rx_mailbox_size,
            info.boot_tx_mailbox_offset, info.boot_tx_mailbox_size)  # fmt: skip
    if any(boot):
        _sub(ee, "BootStrap", b"".join(w.to_bytes(2, "little") for w in boot).hex().upper())
    etree.indent(root, space="  ")
    out: bytes = etree.tostring(root, xml_declaration=True, encoding="UTF-8")
    return out + b"\n"


def _b(flag: object) -> str:
    return "true" if flag else "false"
