"""Unit and property tests of the SII codec (pyethercat.wire.sii) with hand-made bytes."""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pyethercat.errors import SiiError
from pyethercat.wire.sii import (
    CategoryType,
    CoeDetails,
    FmmuUsage,
    GeneralFlags,
    MailboxProtocol,
    SiiDc,
    SiiDcMode,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdos,
    SiiPortType,
    SiiRawCategory,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerType,
    build_sii,
    category_body,
    format_sii,
    parse_sii,
    sii_bytes_needed,
    sii_crc,
    sii_fix_checksum,
)

# --- CRC (facts 5.2 test vectors) ------------------------------------------------------


@pytest.mark.parametrize(
    ("header", "crc"),
    [
        ("08 0E 02 88 00 00 00 00 00 00 00 00 00 00", 0x2F),  # siitool example
        ("80 02 00 00 00 00 00 00 00 00 00 00 00 00", 0xC6),  # SOES lan9252 demo
        ("05 0E 03 06 10 27 00 00 00 00 00 00 00 00", 0xD7),  # SOES xmc4300
        ("80 03 00 6E FF 00 FF 00 00 00 00 00 00 00", 0x22),  # KickCAT sim slave
    ],
)
def test_crc_vectors(header: str, crc: int) -> None:
    data = bytes.fromhex(header)
    assert sii_crc(data) == crc
    # Longer input (a whole image) is cut to the 14 covered bytes.
    assert sii_crc(data + b"\x12\x34" * 10) == crc


def test_fix_checksum() -> None:
    image = bytes.fromhex("05 0E 03 06 10 27 00 00 00 00 00 00 00 00 AA BB") + b"\xff" * 16
    fixed = sii_fix_checksum(image)
    assert fixed[14:16] == b"\xd7\x00"
    assert fixed[:14] == image[:14] and fixed[16:] == image[16:]
    with pytest.raises(SiiError):
        sii_fix_checksum(b"\x00" * 10)


# --- a hand-made image ---------------------------------------------------------------------


def _hand_content() -> bytes:
    """An image written byte by byte from facts section 5 (not with build_sii)."""
    fixed = bytearray(128)
    fixed[0:14] = bytes.fromhex("05 0E 03 06 10 27 00 00 00 00 00 00 00 00")
    fixed[14] = 0xD7
    struct.pack_into("<IIII", fixed, 0x10, 0x1337, 0x12783456, 1, 0xDEADBEEF)
    struct.pack_into("<8H", fixed, 0x28, 0x1000, 128, 0x1080, 128, 0x1000, 128, 0x1080, 128)
    struct.pack_into("<H", fixed, 0x38, 0x000C)  # CoE + FoE
    struct.pack_into("<HH", fixed, 0x7C, 0x001E, 1)  # 31 Kbit = 3968 bytes, version 1
    cats = bytearray()
    strings = b"\x02\x03abc\x04\xb5dev"  # 10 bytes: latin-1 micro sign in string 2
    cats += struct.pack("<HH", 10, 5) + strings
    general = bytearray(32)
    general[0:4] = bytes([1, 0, 1, 2])
    general[5] = 0x23  # SDO, SDO info, complete access
    general[6] = 1
    general[0x0B] = 0x03  # SafeOp, not LRW
    struct.pack_into("<hHHH", general, 0x0C, -2000, 0, 0x0031, 0x1234)
    cats += struct.pack("<HH", 30, 16) + general
    cats += struct.pack("<HH", 40, 2) + bytes([1, 2, 3, 0xFF])
    # The SOES SM0 example from the facts sheet, then SM2 outputs.
    sm = bytes.fromhex("00 10 80 00 26 00 01 01") + bytes.fromhex("00 11 02 00 64 00 01 03")
    cats += struct.pack("<HH", 41, 8) + sm
    rxpdo = struct.pack("<HBBBBH", 0x1600, 2, 2, 0, 2, 0)
    rxpdo += struct.pack("<HBBBBH", 0x7000, 1, 1, 0x01, 1, 0)
    rxpdo += struct.pack("<HBBBBH", 0x0000, 0, 0, 0x00, 7, 0)
    cats += struct.pack("<HH", 51, len(rxpdo) // 2) + rxpdo
    dc = struct.pack("<IiihHhBB4s", 1000000, -500, 0, -1, 0x0300, 1, 2, 0, bytes(4))
    cats += struct.pack("<HH", 60, 12) + dc
    cats += struct.pack("<HH", 0x8001, 2) + b"\x01\x02\x03\x04"  # vendor flag (bit 15)
    cats += struct.pack("<H", 0xFFFF)
    return bytes(fixed + cats)


def _hand_image() -> bytes:
    content = _hand_content()
    return content + b"\xff" * (3968 - len(content))


def test_parse_hand_image() -> None:
    info = parse_sii(_hand_image(), strict=True)
    assert info.checksum_ok and info.end_marker and info.warnings == []
    assert (info.pdi_control, info.pdi_config, info.sync_impulse_len) == (0x0E05, 0x0603, 0x2710)
    assert (info.vendor_id, info.product_code, info.revision, info.serial) == (
        0x1337,
        0x12783456,
        1,
        0xDEADBEEF,
    )
    assert (info.rx_mailbox_offset, info.rx_mailbox_size) == (0x1000, 128)
    assert (info.tx_mailbox_offset, info.tx_mailbox_size) == (0x1080, 128)
    assert info.mailbox_protocols == MailboxProtocol.COE | MailboxProtocol.FOE
    assert (info.eeprom_size_kbit, info.eeprom_size_bytes, info.version) == (31, 3968, 1)
    assert info.strings == [b"abc", b"\xb5dev"]
    assert info.string(0) is None and info.string(3) is None
    assert info.device_name == "\u00b5dev" and info.order_number == "abc"
    assert info.group_name == "abc" and info.image_name is None
    g = info.general
    assert g is not None
    assert g.coe_details == CoeDetails.SDO | CoeDetails.SDO_INFO | CoeDetails.SDO_COMPLETE_ACCESS
    assert g.flags == GeneralFlags.ENABLE_SAFEOP | GeneralFlags.NOT_LRW
    assert g.foe_details == 1
    assert g.ebus_current_ma == -2000
    assert g.ports == (SiiPortType.MII, SiiPortType.EBUS, SiiPortType.NOT_USED, SiiPortType.NOT_USED)
    assert g.physical_memory_address == 0x1234
    assert info.fmmus == [
        FmmuUsage.OUTPUTS,
        FmmuUsage.INPUTS,
        FmmuUsage.MAILBOX_STATE,
        FmmuUsage.NOT_USED,
    ]
    sm0, sm1 = info.sync_managers
    assert (sm0.start, sm0.length, sm0.control, sm0.enable, sm0.sm_type) == (
        0x1000,
        128,
        0x26,
        1,
        SyncManagerType.MAILBOX_OUT,
    )
    assert sm0.enabled and sm1.sm_type == SyncManagerType.OUTPUTS
    (pdo,) = info.rx_pdos
    assert (pdo.index, pdo.sync_manager, len(pdo.entries), pdo.bit_length) == (0x1600, 2, 2, 8)
    assert info.pdo_name(pdo) == "\u00b5dev" and info.pdo_name(pdo.entries[0]) == "abc"
    assert info.output_bits == 8 and info.input_bits == 0 and info.tx_pdos == []
    (mode,) = info.dc_modes
    assert (mode.cycle_time_sync0, mode.shift_time_sync0, mode.sync1_cycle_factor) == (
        1000000,
        -500,
        -1,
    )
    assert (mode.assign_activate, mode.sync0_cycle_factor, mode.name_index) == (0x0300, 1, 2)
    (raw,) = info.raw_categories
    assert raw.type == 0x8001 and raw.vendor_specific and raw.data == b"\x01\x02\x03\x04"


def test_build_reproduces_hand_image() -> None:
    image = _hand_image()
    info = parse_sii(image)
    assert build_sii(info) == image
    assert category_body(info.categories[0]) == b"\x02\x03abc\x04\xb5dev"


def test_build_from_scratch() -> None:
    info = SiiInfo(
        vendor_id=2,
        product_code=0x07D43052,
        eeprom_size_code=1,
        categories=[
            SiiStrings([b"EL2004"]),
            SiiGeneral(name_index=1, ebus_current_ma=100),
            SiiFmmus([FmmuUsage.OUTPUTS]),  # odd: padded with an UNUSED entry
        ],
    )
    image = build_sii(info)
    assert len(image) == 256
    assert image[14] == sii_crc(image) and image[15] == 0
    assert struct.unpack_from("<HH", image, 0x80) == (10, 4)  # strings: 1+1+6 = 8 bytes
    assert image[0x84:0x8C] == b"\x01\x06EL2004"
    end = 0x80 + 4 + 8 + 4 + 32 + 4 + 2
    assert image[end : end + 2] == b"\xff\xff"
    assert set(image[end:]) == {0xFF}
    back = parse_sii(image, strict=True)
    assert back.device_name == "EL2004"
    assert back.fmmus == [FmmuUsage.OUTPUTS, FmmuUsage.UNUSED]
    assert "EL2004" in format_sii(back)


def test_build_errors() -> None:
    with pytest.raises(SiiError, match="EEPROM size"):
        build_sii(SiiInfo(eeprom_size_code=0, categories=[SiiRawCategory(0x800, bytes(200))]))
    with pytest.raises(SiiError, match="out of range"):
        build_sii(SiiInfo(vendor_id=1 << 32))
    with pytest.raises(SiiError, match="out of range"):
        build_sii(SiiInfo(categories=[SiiGeneral(ebus_current_ma=40000)]))
    with pytest.raises(SiiError, match="reserved_10"):
        build_sii(SiiInfo(reserved_10=b"\x00"))
    with pytest.raises(SiiError, match="at most 255"):
        build_sii(SiiInfo(categories=[SiiStrings([b"x" * 256])]))
    with pytest.raises(SiiError, match="0xFFFF"):
        build_sii(SiiInfo(categories=[SiiRawCategory(0xFFFF)]))
    with pytest.raises(SiiError, match="blank"):
        build_sii(SiiInfo(categories=[SiiRawCategory(CategoryType.NOP)]))
    with pytest.raises(SiiError, match="TXPDO"):
        build_sii(SiiInfo(categories=[SiiPdos(type=CategoryType.DC)]))


def test_keep_bad_checksum_on_request() -> None:
    image = build_sii(SiiInfo(checksum=0x55, eeprom_size_code=1), fix_checksum=False)
    info = parse_sii(image)
    assert not info.checksum_ok and info.checksum == 0x55
    assert "checksum" in info.warnings[0]
    with pytest.raises(SiiError, match="checksum"):
        parse_sii(image, strict=True)


# --- tolerance -----------------------------------------------------------------------------


def test_truncated_category_keeps_what_parsed() -> None:
    image = _hand_image()
    cut = image[: 0x80 + 4 + 10 + 4 + 12]  # inside the General category (at word 0x47)
    info = parse_sii(cut)
    assert info.strings == [b"abc", b"\xb5dev"]
    g = info.general
    assert g is not None and g.group_index == 1 and g.ebus_current_ma == 0
    assert not info.end_marker
    assert any("GENERAL at word 0x0047" in w and "past the end" in w for w in info.warnings)
    with pytest.raises(SiiError, match="GENERAL at word 0x0047"):
        parse_sii(cut, strict=True)


def test_missing_end_marker_and_short_images() -> None:
    image = _hand_image()
    end = len(_hand_content()) - 2  # the end-marker word
    info = parse_sii(image[:end])
    assert not info.end_marker and "no end marker" in info.warnings[-1]
    assert info == parse_sii(image)  # same content
    with pytest.raises(SiiError, match="end marker"):
        parse_sii(image[:end], strict=True)
    # Only the fixed area, odd length, a cut fixed area, too short for the identity.
    assert parse_sii(image[:128]).categories == []
    assert any("odd length" in w for w in parse_sii(image[:129]).warnings)
    short = parse_sii(image[:40])
    assert short.vendor_id == 0x1337 and any("fixed area" in w for w in short.warnings)
    with pytest.raises(SiiError, match="too short"):
        parse_sii(image[:31])
    with pytest.raises(SiiError):
        parse_sii(b"")


def test_malformed_bodies_warn() -> None:
    def image_with(ctype: int, body: bytes) -> bytes:
        return build_sii(SiiInfo(eeprom_size_code=3, categories=[SiiRawCategory(ctype, body)]))

    info = parse_sii(image_with(CategoryType.STRINGS, b"\x03\x02ab\x09xy"))
    assert info.strings == [b"ab", b"xy\x00"]  # cut string keeps the pad byte
    assert any("string 2 of 3" in w for w in info.warnings)
    info = parse_sii(image_with(CategoryType.RXPDO, struct.pack("<HBBBBH", 0x1600, 5, 0, 0, 0, 0)))
    assert info.rx_pdos[0].entries == [] and "declares 5 entries" in info.warnings[0]
    info = parse_sii(image_with(CategoryType.SYNCM, bytes(10)))
    assert len(info.sync_managers) == 1 and "8-byte" in info.warnings[0]
    info = parse_sii(image_with(CategoryType.DC, bytes(26)))
    assert len(info.dc_modes) == 1 and "24-byte" in info.warnings[0]
    info = parse_sii(image_with(CategoryType.GENERAL, bytes(8)))
    assert info.general == SiiGeneral() and "expected 32" in info.warnings[0]
    for ctype in (CategoryType.STRINGS, CategoryType.RXPDO, CategoryType.GENERAL):
        with pytest.raises(SiiError, match=f"{CategoryType(ctype).name} at word 0x0040"):
            parse_sii(image_with(ctype, b"\x07\x00\x01\x02"), strict=True)


def test_blank_and_zero_headers() -> None:
    fixed = build_sii(SiiInfo(eeprom_size_code=1), pad=False)[:128]
    info = parse_sii(fixed + bytes(128))
    assert info.categories == [] and not info.end_marker and "blank" in info.warnings[0]
    assert sii_bytes_needed(fixed + bytes(128)) is None


# --- read plan -----------------------------------------------------------------------------


def test_read_plan_steps() -> None:
    image = _hand_image()
    assert sii_bytes_needed(b"") == 132  # fixed area + first header
    assert sii_bytes_needed(image[:100]) == 132
    # After the first header (strings, 5 words) the next header is at byte 0x80+4+10.
    assert sii_bytes_needed(image[:132]) == 0x80 + 4 + 10 + 4
    end = len(_hand_content()) - 2  # the end-marker word
    assert sii_bytes_needed(image[:end]) == end + 4
    assert sii_bytes_needed(image[: end + 2]) is None  # the end-marker word is enough
    assert sii_bytes_needed(image) is None
    # A chain that never ends stops at max_bytes.
    endless = image[:128] + struct.pack("<HH", 0x800, 0x7000) + bytes(0xE000)
    assert sii_bytes_needed(endless[:132], max_bytes=4096) is None
    assert sii_bytes_needed(endless[:132]) is None  # default cap 16 KiB
    assert sii_bytes_needed(endless[:132], max_bytes=0x10000) == 0x80 + 4 + 0xE000 + 4


# --- properties ----------------------------------------------------------------------------

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
i16 = st.integers(-0x8000, 0x7FFF)
i32 = st.integers(-0x80000000, 0x7FFFFFFF)


def _even_bytes(max_size: int) -> st.SearchStrategy[bytes]:
    return st.binary(max_size=max_size).map(lambda b: b[: len(b) - len(b) % 2])


entries = st.builds(
    SiiPdoEntry, index=u16, subindex=u8, name_index=u8, data_type=u8, bit_length=u8, flags=u16
)
pdos = st.builds(
    SiiPdo,
    index=u16,
    sync_manager=u8,
    dc_sync=u8,
    name_index=u8,
    flags=u16,
    entries=st.lists(entries, max_size=4),
)
categories = st.one_of(
    st.builds(SiiStrings, strings=st.lists(st.binary(max_size=12), max_size=6)),
    st.builds(
        SiiGeneral,
        group_index=u8,
        image_index=u8,
        order_index=u8,
        name_index=u8,
        reserved_04=u8,
        coe_details=u8.map(CoeDetails),
        foe_details=u8,
        eoe_details=u8,
        soe_channels=u8,
        ds402_channels=u8,
        sysman_class=u8,
        flags=u8.map(GeneralFlags),
        ebus_current_ma=i16,
        reserved_0e=u16,
        physical_ports=u16,
        physical_memory_address=u16,
        reserved_14=st.binary(min_size=12, max_size=12),
        extra=_even_bytes(6),
    ),
    st.builds(SiiFmmus, usages=st.lists(u8, max_size=6).map(lambda x: x[: len(x) - len(x) % 2])),
    st.builds(
        SiiSyncManagers,
        sync_managers=st.lists(
            st.builds(
                SiiSyncManager,
                start=u16,
                length=u16,
                control=u8,
                status=u8,
                enable=u8,
                sm_type=u8,
            ),
            max_size=4,
        ),
    ),
    st.builds(
        SiiPdos,
        type=st.sampled_from([CategoryType.TXPDO, CategoryType.RXPDO]),
        pdos=st.lists(pdos, max_size=3),
    ),
    st.builds(
        SiiDc,
        modes=st.lists(
            st.builds(
                SiiDcMode,
                cycle_time_sync0=u32,
                shift_time_sync0=i32,
                shift_time_sync1=i32,
                sync1_cycle_factor=i16,
                assign_activate=u16,
                sync0_cycle_factor=i16,
                name_index=u8,
                description_index=u8,
                reserved=st.binary(min_size=4, max_size=4),
            ),
            max_size=3,
        ),
    ),
    st.builds(
        SiiRawCategory,
        type=st.integers(0, 0xFFFE).filter(lambda t: t not in {10, 30, 40, 41, 50, 51, 60}),
        data=_even_bytes(20).filter(bool),
    ),
)
infos = st.builds(
    SiiInfo,
    pdi_control=u16,
    pdi_config=u16,
    sync_impulse_len=u16,
    pdi_config2=u16,
    station_alias=u16,
    reserved_05=st.binary(min_size=4, max_size=4),
    vendor_id=u32,
    product_code=u32,
    revision=u32,
    serial=u32,
    reserved_10=st.binary(min_size=8, max_size=8),
    boot_rx_mailbox_offset=u16,
    boot_rx_mailbox_size=u16,
    boot_tx_mailbox_offset=u16,
    boot_tx_mailbox_size=u16,
    rx_mailbox_offset=u16,
    rx_mailbox_size=u16,
    tx_mailbox_offset=u16,
    tx_mailbox_size=u16,
    mailbox_protocols=u16.map(MailboxProtocol),
    reserved_1d=st.binary(min_size=66, max_size=66),
    eeprom_size_code=st.integers(0x3F, 0x7F),
    version=u16,
    categories=st.lists(categories, max_size=8),
)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(infos)
def test_round_trip(info: SiiInfo) -> None:
    image = build_sii(info)
    assert len(image) == info.eeprom_size_bytes
    back = parse_sii(image, strict=True)
    assert back == info
    assert back.checksum_ok and back.end_marker and back.warnings == []
    assert build_sii(back) == image
    # The unpadded image carries the same content, and the read plan ends exactly on it.
    short = build_sii(info, pad=False)
    assert parse_sii(short, strict=True) == info
    assert sii_bytes_needed(short) is None
    assert sii_bytes_needed(short[:-2]) == len(short) + 2
    format_sii(back)


@settings(max_examples=300)
@given(st.binary(max_size=400))
def test_random_bytes_raise_only_sii_error(data: bytes) -> None:
    for strict in (False, True):
        try:
            info = parse_sii(data, strict=strict)
        except SiiError:
            continue
        format_sii(info)
    need = sii_bytes_needed(data)
    assert need is None or len(data) < need <= 0x4000


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(
    infos,
    st.lists(st.tuples(st.integers(0, 1 << 16), u8), min_size=1, max_size=8),
    st.integers(0, 1 << 16),
)
def test_mutated_images_raise_only_sii_error(
    info: SiiInfo, flips: list[tuple[int, int]], cut: int
) -> None:
    image = bytearray(build_sii(info, pad=False))
    for pos, value in flips:
        image[pos % len(image)] = value
    data = bytes(image[: max(cut % (len(image) + 1), 0)])
    for strict in (False, True):
        try:
            parsed = parse_sii(data, strict=strict)
        except SiiError:
            continue
        format_sii(parsed)
        # Whatever parsed tolerantly can be rebuilt or is refused with SiiError.
        with contextlib.suppress(SiiError):
            build_sii(parsed, pad=False)
    need = sii_bytes_needed(data)
    assert need is None or need > len(data)
