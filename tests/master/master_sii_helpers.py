"""Small SII images for master tests, built with the shared SII model."""

from __future__ import annotations

from collections.abc import Sequence

from pyethercat.wire.sii import (
    FmmuUsage,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdos,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerType,
    build_sii,
    parse_sii,
)
from pyethercat.wire.sii.model import CategoryType

#: (entry name, bit length, CoE data type code)
Entry = tuple[str, int, int]

BOOL, UINT8, UINT16, INT16, REAL32 = 0x0001, 0x0005, 0x0006, 0x0003, 0x0008


def io_sii(name: str, outputs: Sequence[Entry] = (), inputs: Sequence[Entry] = (),
           product: int = 0x1234, mailbox: bool = False, out_pdo: str = "Outputs",
           in_pdo: str = "Inputs") -> SiiInfo:
    """An IO terminal: one RxPDO on the output SM and one TxPDO on the input SM."""
    strings: list[bytes] = []

    def s(text: str) -> int:
        strings.append(text.encode())
        return len(strings)

    sms: list[SiiSyncManager] = []
    if mailbox:
        sms += [SiiSyncManager(0x1000, 128, 0x26, 0, 1, SyncManagerType.MAILBOX_OUT),
                SiiSyncManager(0x1080, 128, 0x22, 0, 1, SyncManagerType.MAILBOX_IN)]
    out_sm = len(sms)
    sms.append(SiiSyncManager(0x1100, 0, 0x64, 0, 1, SyncManagerType.OUTPUTS))
    in_sm = len(sms)
    sms.append(SiiSyncManager(0x1180, 0, 0x20, 0, 1, SyncManagerType.INPUTS))
    name_idx = s(name)
    cats: list = [
        SiiGeneral(name_index=name_idx, group_index=name_idx),
        SiiFmmus([FmmuUsage.OUTPUTS, FmmuUsage.INPUTS, FmmuUsage.MAILBOX_STATE]),
        SiiSyncManagers(sms),
    ]
    if outputs:
        entries = [SiiPdoEntry(0x7000 + 0x10 * i, 1, s(n), t, b) for i, (n, b, t) in enumerate(outputs)]
        cats.append(SiiPdos(CategoryType.RXPDO, [SiiPdo(0x1600, out_sm, 0, s(out_pdo), 0, entries)]))
    if inputs:
        entries = [SiiPdoEntry(0x6000 + 0x10 * i, 1, s(n), t, b) for i, (n, b, t) in enumerate(inputs)]
        cats.append(SiiPdos(CategoryType.TXPDO, [SiiPdo(0x1A00, in_sm, 0, s(in_pdo), 0, entries)]))
    cats.insert(0, SiiStrings(strings))
    info = SiiInfo(vendor_id=0x0BEEF, product_code=product, revision=1, categories=cats,
                   eeprom_size_code=31)
    if mailbox:
        info.rx_mailbox_offset, info.rx_mailbox_size = 0x1000, 128
        info.tx_mailbox_offset, info.tx_mailbox_size = 0x1080, 128
    # Round trip through bytes so tests see exactly what a master would parse.
    return parse_sii(build_sii(info))


def di(n: int, name: str = "di") -> SiiInfo:
    return io_sii(f"{name}{n}", inputs=[(f"Input {i + 1}", 1, BOOL) for i in range(n)],
                  product=0x100 + n)


def do(n: int, name: str = "do") -> SiiInfo:
    return io_sii(f"{name}{n}", outputs=[(f"Output {i + 1}", 1, BOOL) for i in range(n)],
                  product=0x200 + n)


def coupler() -> SiiInfo:
    info = SiiInfo(vendor_id=0x0BEEF, product_code=1, revision=1,
                   categories=[SiiStrings([b"coupler"]), SiiGeneral(name_index=1)],
                   eeprom_size_code=31)
    return parse_sii(build_sii(info))
