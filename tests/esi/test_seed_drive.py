"""The seed 002 servo drive ESI shipped as package data: parses, and makes a valid SII."""

from __future__ import annotations

import pytest

from pyethercat.errors import EsiError
from pyethercat.esi import load_esi
from pyethercat.esi.bundled import SEED002_DRIVE, bundled_esi, bundled_esi_names
from pyethercat.esi.sii_from_esi import esi_to_sii
from pyethercat.wire.sii import CoeDetails, MailboxProtocol, parse_sii


def test_identity_pdos_init_cmds() -> None:
    esi = load_esi(bundled_esi())
    assert esi.vendor.id == 0xE4 and str(esi.vendor.name) == "Metronix"
    dev = esi.find_device(0x264860D2, 0x20000)
    rx = dev.pdo(0x1600)
    assert rx is not None and rx.sm == 2 and rx.fixed
    assert [(e.index, e.subindex, e.bit_len, e.data_type) for e in rx.entries] == [
        (0x6040, 0, 16, "UINT"),
        (0x6060, 0, 8, "USINT"),
    ]
    tx = dev.pdo(0x1A00)
    assert tx is not None and tx.sm == 3
    assert [e.index for e in tx.entries] == [0x6041, 0x6061, 0x6064]
    layout = dev.pdo_layout()
    assert (layout.output_bits, layout.input_bits) == (24, 56)
    assert dev.mailbox is not None and dev.mailbox.coe is not None
    assert dev.mailbox.coe.pdo_assign and dev.mailbox.coe.eds_file == "METRONIX.eds"
    assert dev.mailbox.coe.ds402_channels == 1  # <CoE DS402Channels="1" ...>
    cmds = {(c.index, c.subindex): (c.transitions, c.data) for c in dev.mailbox.coe.init_cmds}
    assert cmds[(0x6060, 0)] == (("PS",), b"\x03")
    assert cmds[(0x6040, 0)] == (("PS",), b"\x00\x00")
    assert dev.dc is not None and [m.assign_activate for m in dev.dc.op_modes] == [0, 0x300]


def test_dictionary_holds_the_seed_communication_objects() -> None:
    dev = load_esi(bundled_esi()).devices[0]
    od = dev.dictionary
    assert od is not None
    wanted = [0x1000, 0x1018, 0x1100, *range(0x1600, 0x1604), *range(0x1A00, 0x1A04)]
    wanted += [0x1C00, 0x1C10, 0x1C11, 0x1C12, 0x1C13]
    assert all(od.object(i) is not None for i in wanted)
    # Identity defaults agree with the device's identity.
    ident = {e.subindex: e.default for e in od.entries(od.object(0x1018))}  # type: ignore[arg-type]
    assert ident[1] == (0xE4).to_bytes(4, "little")
    assert ident[2] == (0x264860D2).to_bytes(4, "little")
    assert ident[3] == (0x20000).to_bytes(4, "little")
    # 0x1C12 assigns 0x1600 by default; 0x1600 maps 0x6040:00/16 and 0x6060:00/8.
    assign = {e.subindex: e.default for e in od.entries(od.object(0x1C12))}  # type: ignore[arg-type]
    assert assign[0] == b"\x01" and assign[1] == (0x1600).to_bytes(2, "little")
    mapping = {e.subindex: e.default for e in od.entries(od.object(0x1600))}  # type: ignore[arg-type]
    assert mapping[1] == (0x60400010).to_bytes(4, "little")
    assert mapping[2] == (0x60600008).to_bytes(4, "little")
    # Every PDO entry names an object of the dictionary.
    for pdo in dev.pdos:
        for e in pdo.entries:
            assert od.object(e.index) is not None, hex(e.index)


def test_valid_sii() -> None:
    esi = load_esi(bundled_esi())
    res = esi_to_sii(esi.devices[0], vendor_id=esi.vendor.id)
    info = parse_sii(res.image, strict=True)
    assert (info.vendor_id, info.product_code, info.revision) == (0xE4, 0x264860D2, 0x20000)
    assert info.mailbox_protocols == MailboxProtocol.COE
    assert info.general is not None and info.general.coe_details & CoeDetails.PDO_ASSIGN
    # General byte 9 (DS402 channels) from CoE@DS402Channels, read back from the raw bytes.
    assert info.general.ds402_channels == 1
    general = _category(res.image, 30)
    assert general[9] == 1 and general[8] == 0  # DS402 channels, SoE channels
    assert (info.output_bits, info.input_bits) == (24, 56)
    assert [p.index for p in info.rx_pdos] == [0x1600, 0x1601, 0x1602]
    assert not res.notes


def _category(image: bytes, wanted: int) -> bytes:
    """The data of the first category ``wanted`` of an SII image (walked by hand)."""
    at = 0x80
    while at + 4 <= len(image):
        ctype = int.from_bytes(image[at : at + 2], "little")
        words = int.from_bytes(image[at + 2 : at + 4], "little")
        if ctype == 0xFFFF:
            break
        if ctype == wanted:
            return image[at + 4 : at + 4 + 2 * words]
        at += 4 + 2 * words
    raise AssertionError(f"no category {wanted}")


def test_ds402_channels_round_trip_through_xml() -> None:
    """SII General DS402 byte -> ESI attribute (``pyethercat xml``) -> SII again."""
    from pyethercat.esi import parse_esi
    from pyethercat.esi.from_sii import esi_from_sii

    esi = load_esi(bundled_esi())
    info = esi_to_sii(esi.devices[0], vendor_id=esi.vendor.id).info
    assert info.general is not None
    info.general.ds402_channels = 2
    xml = esi_from_sii(info)
    assert b'DS402Channels="2"' in xml
    back = parse_esi(xml, "x.xml").devices[0]
    assert back.mailbox is not None and back.mailbox.coe is not None
    assert back.mailbox.coe.ds402_channels == 2
    again = esi_to_sii(back, vendor_id=0xE4).info.general
    assert again is not None and again.ds402_channels == 2


def test_ds402_channels_out_of_range() -> None:
    from pyethercat.esi import parse_esi

    doc = bundled_esi().read_bytes().replace(b'DS402Channels="1"', b'DS402Channels="256"')
    with pytest.raises(EsiError, match=r"drive\.xml:\d+: CoE@DS402Channels: 256 is out of range"):
        parse_esi(doc, "drive.xml")


def test_bundled_lookup() -> None:
    assert SEED002_DRIVE in bundled_esi_names()
    with pytest.raises(EsiError, match="no bundled ESI"):
        bundled_esi("nope.xml")
