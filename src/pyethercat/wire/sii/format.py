"""Human-readable multi-line dump of an ``SiiInfo`` (``pyethercat sii_read -v``)."""

from __future__ import annotations

from collections.abc import Callable
from enum import IntFlag

from pyethercat.errors import SiiError
from pyethercat.wire.sii.codec import category_body
from pyethercat.wire.sii.model import (
    SM_NOT_ASSIGNED,
    WORD_FIRST_CATEGORY,
    CategoryType,
    FmmuUsage,
    SiiCategory,
    SiiDc,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdoFlags,
    SiiPdos,
    SiiRawCategory,
    SiiStrings,
    SiiSyncManagers,
    SyncManagerEnable,
    SyncManagerType,
    category_name,
)

__all__ = ["format_sii"]

_MAX_SHOWN = 60  # characters of a string (an icon stored as a string is long)


def _show_bytes(raw: bytes) -> str:
    """Quote a string for display: printable latin-1, escapes otherwise, cut when long."""
    text = "".join(
        ch if (ch.isprintable() and ch != "\\") else f"\\x{ord(ch):02x}"
        for ch in raw[:_MAX_SHOWN].decode("latin-1")
    )
    more = f"... ({len(raw)} bytes)" if len(raw) > _MAX_SHOWN else ""
    return f'"{text}"{more}'


def _flag_names(value: int, flag_type: type[IntFlag]) -> str:
    names = [m.name for m in flag_type if m.value and (value & m.value) == m.value]
    return "|".join(n for n in names if n) or "-"


def _enum_name(value: int, enum_type: type) -> str:
    try:
        return str(enum_type(value).name)
    except ValueError:
        return f"0x{value:02X}"


def _hex_dump(data: bytes, indent: str) -> list[str]:
    return [f"{indent}{data[i : i + 16].hex(' ')}" for i in range(0, len(data), 16)]


def format_sii(info: SiiInfo) -> str:
    """Render ``info`` as text: fixed area, then each category with its contents."""
    s = info.string

    def named(index: int) -> str:
        name = s(index)
        return f"{index}" if name is None else f"{index} {_show_bytes(name.encode('latin-1'))}"

    lines = [
        "SII fixed area",
        f"  Vendor ID:          0x{info.vendor_id:08X}",
        f"  Product code:       0x{info.product_code:08X}",
        f"  Revision:           0x{info.revision:08X}",
        f"  Serial number:      0x{info.serial:08X}",
        f"  Station alias:      0x{info.station_alias:04X}",
        f"  PDI control:        0x{info.pdi_control:04X}",
        f"  PDI configuration:  0x{info.pdi_config:04X}  (config 2: 0x{info.pdi_config2:04X})",
        f"  SYNC impulse:       {info.sync_impulse_len} x 10 ns",
        f"  Checksum:           0x{info.checksum:04X} ({'ok' if info.checksum_ok else 'BAD'})",
        f"  Bootstrap mailbox:  rx 0x{info.boot_rx_mailbox_offset:04X}/{info.boot_rx_mailbox_size}"
        f"  tx 0x{info.boot_tx_mailbox_offset:04X}/{info.boot_tx_mailbox_size}",
        f"  Standard mailbox:   rx 0x{info.rx_mailbox_offset:04X}/{info.rx_mailbox_size}"
        f"  tx 0x{info.tx_mailbox_offset:04X}/{info.tx_mailbox_size}",
        f"  Mailbox protocols:  0x{int(info.mailbox_protocols):04X} "
        f"{_flag_names(int(info.mailbox_protocols), type(info.mailbox_protocols))}",
        f"  EEPROM size:        {info.eeprom_size_kbit} Kbit ({info.eeprom_size_bytes} bytes)",
        f"  Version:            {info.version}",
    ]
    word = WORD_FIRST_CATEGORY
    for cat in info.categories:
        try:
            size = len(category_body(cat)) // 2
        except SiiError:
            size = -1
        ctype = int(cat.type)
        lines.append(
            f"Category {category_name(ctype)} ({ctype}) at word 0x{word:04X}, {size} words"
        )
        word += 2 + max(size, 0)
        lines.extend(_format_category(cat, named))
    lines.append(f"End marker:           {'present' if info.end_marker else 'MISSING'}")
    for w in info.warnings:
        lines.append(f"Warning: {w}")
    return "\n".join(lines)


def _format_category(cat: SiiCategory, named: Callable[[int], str]) -> list[str]:
    out: list[str] = []
    if isinstance(cat, SiiStrings):
        for i, raw in enumerate(cat.strings, 1):
            out.append(f"  [{i}] {_show_bytes(raw)}")
    elif isinstance(cat, SiiGeneral):
        out += [
            f"  Group:              {named(cat.group_index)}",
            f"  Image:              {named(cat.image_index)}",
            f"  Order number:       {named(cat.order_index)}",
            f"  Name:               {named(cat.name_index)}",
            f"  CoE details:        0x{int(cat.coe_details):02X} "
            f"{_flag_names(int(cat.coe_details), type(cat.coe_details))}",
            f"  FoE details:        0x{cat.foe_details:02X}",
            f"  EoE details:        0x{cat.eoe_details:02X}",
            f"  SoE channels:       {cat.soe_channels}",
            f"  DS402 channels:     {cat.ds402_channels}",
            f"  SysmanClass:        {cat.sysman_class}",
            f"  Flags:              0x{int(cat.flags):02X} "
            f"{_flag_names(int(cat.flags), type(cat.flags))}",
            f"  Current on EBus:    {cat.ebus_current_ma} mA",
            "  Physical ports:     "
            + " ".join(
                f"{n}:{p.name if hasattr(p, 'name') else p}" for n, p in enumerate(cat.ports)
            ),
            f"  Phys. memory addr:  0x{cat.physical_memory_address:04X}",
        ]
    elif isinstance(cat, SiiFmmus):
        for i, u in enumerate(cat.usages):
            out.append(f"  FMMU{i}: {_enum_name(u, FmmuUsage)}")
    elif isinstance(cat, SiiSyncManagers):
        for i, sm in enumerate(cat.sync_managers):
            out.append(
                f"  SM{i}: start 0x{sm.start:04X} length {sm.length} control 0x{sm.control:02X}"
                f" status 0x{sm.status:02X} enable 0x{sm.enable:02X}"
                f" ({_flag_names(sm.enable, SyncManagerEnable)})"
                f" type {_enum_name(sm.sm_type, SyncManagerType)}"
            )
    elif isinstance(cat, SiiPdos):
        kind = "TxPDO" if cat.type == CategoryType.TXPDO else "RxPDO"
        for p in cat.pdos:
            sm_text = "none" if p.sync_manager == SM_NOT_ASSIGNED else str(p.sync_manager)
            out.append(
                f"  {kind} 0x{p.index:04X} {named(p.name_index)}: SM {sm_text}, DC sync {p.dc_sync},"
                f" flags 0x{p.flags:04X} ({_flag_names(p.flags, SiiPdoFlags)}),"
                f" {len(p.entries)} entries, {p.bit_length} bits"
            )
            for e in p.entries:
                out.append(
                    f"    0x{e.index:04X}:{e.subindex:02X} {e.bit_length:3d} bits"
                    f" type 0x{e.data_type:02X} {named(e.name_index)}"
                )
    elif isinstance(cat, SiiDc):
        for i, m in enumerate(cat.modes):
            out.append(
                f"  Mode {i} {named(m.name_index)}: AssignActivate 0x{m.assign_activate:04X}"
                f" cycle SYNC0 {m.cycle_time_sync0} shift SYNC0 {m.shift_time_sync0}"
                f" shift SYNC1 {m.shift_time_sync1} factor SYNC0 {m.sync0_cycle_factor}"
                f" SYNC1 {m.sync1_cycle_factor} description {named(m.description_index)}"
            )
    elif isinstance(cat, SiiRawCategory):
        vendor = " (vendor specific)" if cat.vendor_specific else ""
        out.append(f"  {len(cat.data)} bytes{vendor}")
        out += _hex_dump(cat.data, "    ")
    extra = getattr(cat, "extra", b"")
    if extra:
        out.append(f"  {len(extra)} extra bytes:")
        out += _hex_dump(extra, "    ")
    return out
