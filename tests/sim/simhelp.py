"""Helpers for the simulator core tests: SII images, segments, frames."""

from __future__ import annotations

import struct

from pyethercat.clock import VirtualClock
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.profiles import PROFILES, EscProfile
from pyethercat.sim.segment import Segment, SimSlaveSpec
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame
from pyethercat.wire.sii import (
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdos,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    build_sii,
)
from pyethercat.wire.sii.model import CategoryType

MBX_OUT, MBX_IN, OUT_SM, IN_SM = 0x1000, 0x1080, 0x1100, 0x1180


def make_sii(name: str = "dev", product: int = 0x1234, out_bits: int = 0, in_bits: int = 0,
             mailbox: bool = False, alias: int = 0, boot: bool = False,
             esc_config: int = 0) -> bytes:
    """A small SII image: identity, optional mailbox, SM2/SM3 with PDOs of the given sizes."""
    sms = [
        SiiSyncManager(MBX_OUT, 128 if mailbox else 0, 0x26, 0, 1 if mailbox else 0, 1),
        SiiSyncManager(MBX_IN, 128 if mailbox else 0, 0x22, 0, 1 if mailbox else 0, 2),
        SiiSyncManager(OUT_SM, (out_bits + 7) // 8, 0x64, 0, 1 if out_bits else 0, 3),
        SiiSyncManager(IN_SM, (in_bits + 7) // 8, 0x20, 0, 1 if in_bits else 0, 4),
    ]
    cats: list = [SiiStrings([name.encode()]), SiiGeneral(name_index=1), SiiSyncManagers(sms)]
    if out_bits:
        cats.append(SiiPdos(CategoryType.RXPDO, [SiiPdo(0x1600, 2, entries=[
            SiiPdoEntry(0x7000, 1, 0, 1, out_bits)])]))
    if in_bits:
        cats.append(SiiPdos(CategoryType.TXPDO, [SiiPdo(0x1A00, 3, entries=[
            SiiPdoEntry(0x6000, 1, 0, 1, in_bits)])]))
    info = SiiInfo(vendor_id=2, product_code=product, revision=1, station_alias=alias,
                   pdi_control=esc_config << 8,
                   rx_mailbox_offset=MBX_OUT if mailbox else 0, rx_mailbox_size=128 if mailbox else 0,
                   tx_mailbox_offset=MBX_IN if mailbox else 0, tx_mailbox_size=128 if mailbox else 0,
                   boot_rx_mailbox_offset=MBX_OUT if boot else 0, boot_rx_mailbox_size=128 if boot else 0,
                   boot_tx_mailbox_offset=MBX_IN if boot else 0, boot_tx_mailbox_size=128 if boot else 0,
                   eeprom_size_code=7, categories=cats)
    return build_sii(info)


def spec(name: str = "dev", profile: str | EscProfile = "ET1100", app: DeviceApp | None = None,
         **kw: object) -> SimSlaveSpec:
    prof = PROFILES[profile] if isinstance(profile, str) else profile
    sii_kw = {k: kw.pop(k) for k in list(kw) if k in (
        "product", "out_bits", "in_bits", "mailbox", "alias_sii", "boot", "esc_config")}
    if "alias_sii" in sii_kw:
        sii_kw["alias"] = sii_kw.pop("alias_sii")
    return SimSlaveSpec(name, make_sii(name, **sii_kw), prof, app, **kw)  # type: ignore[arg-type]


def line(n: int, profile: str = "ET1100", **kw: object) -> Segment:
    seg = Segment(VirtualClock(1_000_000))
    for i in range(n):
        seg.add_slave(spec(f"s{i}", profile, **kw))
    return seg


def xfer(seg: Segment, *dgrams: Datagram) -> list[Datagram]:
    """Send datagrams in one frame; return the reply's datagrams (raises if lost)."""
    reply = seg.process(encode_frame(list(dgrams)))
    assert reply is not None, "frame lost"
    return decode_frame(reply).datagrams


def one(seg: Segment, d: Datagram) -> Datagram:
    return xfer(seg, d)[0]


def fprd(seg: Segment, station: int, ado: int, n: int) -> Datagram:
    return one(seg, Datagram.device(Command.FPRD, station, ado, n))


def fpwr(seg: Segment, station: int, ado: int, data: bytes) -> Datagram:
    return one(seg, Datagram.device(Command.FPWR, station, ado, data))


def u16(d: Datagram) -> int:
    return int(struct.unpack_from("<H", d.data)[0])


def address_all(seg: Segment, base: int = 0x1000) -> None:
    for i in range(len(seg.slaves)):
        d = one(seg, Datagram.positional(Command.APWR, i, R.STATION_ADDRESS,
                                         struct.pack("<H", base + i)))
        assert d.wkc == 1


def sm_bytes(start: int, length: int, control: int, enable: int = 1) -> bytes:
    return struct.pack("<HHBBBB", start, length, control, 0, enable, 0)


def fmmu_bytes(logical: int, length: int, sbit: int, ebit: int, phys: int, pbit: int,
               ftype: int, enable: int = 1) -> bytes:
    return struct.pack("<IHBBHBBB3x", logical, length, sbit, ebit, phys, pbit, ftype, enable)
