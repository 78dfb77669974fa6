"""SII image codec: CRC, parse, build, and the master's read plan.

Pure functions, no I/O. ``parse_sii`` is tolerant by default, because real
dumps are often cut short, lack the end marker or carry a stale checksum: what
can be read is kept and each problem is written to ``SiiInfo.warnings``. With
``strict=True`` the first problem raises ``SiiError`` instead. Only
``SiiError`` ever leaves this module.
"""

from __future__ import annotations

import struct

from pyethercat.errors import SiiError
from pyethercat.wire.sii.model import (
    CRC_COVERED_BYTES,
    DC_MODE_SIZE,
    END_MARKER,
    FIXED_AREA_BYTES,
    GENERAL_SIZE,
    PDO_ENTRY_SIZE,
    PDO_HEADER_SIZE,
    SYNC_MANAGER_SIZE,
    WORD_CHECKSUM,
    WORD_FIRST_CATEGORY,
    CategoryType,
    CoeDetails,
    FmmuUsage,
    GeneralFlags,
    MailboxProtocol,
    SiiCategory,
    SiiDc,
    SiiDcMode,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdos,
    SiiRawCategory,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerType,
    _enum_or_int,
    category_name,
)

__all__ = [
    "SII_DEFAULT_MAX_BYTES",
    "build_sii",
    "category_body",
    "parse_sii",
    "sii_bytes_needed",
    "sii_crc",
    "sii_fix_checksum",
]

# Fixed area, bytes 0x00-0x7F: words 0-4, reserved 5-6, checksum 7, identity
# 8-0xF, reserved 0x10-0x13, mailboxes 0x14-0x1B, protocols 0x1C, reserved
# 0x1D-0x3D, size 0x3E, version 0x3F.
_FIXED = struct.Struct("<5H4sH4I8s9H66s2H")
assert _FIXED.size == FIXED_AREA_BYTES
_GENERAL = struct.Struct("<12BhHHH12s")
assert _GENERAL.size == GENERAL_SIZE
_SM = struct.Struct("<HH4B")
_PDO_HEADER = struct.Struct("<HBBBBH")
_PDO_ENTRY = struct.Struct("<HBBBBH")
_DC_MODE = struct.Struct("<IiihHhBB4s")
assert _DC_MODE.size == DC_MODE_SIZE

# Cap for sii_bytes_needed: a category chain that has not ended after this many
# bytes is not followed further (IgH stops at 4096 words for the same reason).
SII_DEFAULT_MAX_BYTES = 0x4000


# --- CRC -------------------------------------------------------------------------


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def sii_crc(data: bytes | bytearray | memoryview) -> int:
    """CRC-8 of the SII header: poly 0x07, init 0xFF, MSB first, no final XOR.

    ``data`` is normally bytes 0-13 of the image (words 0-6); longer input is
    cut to 14 bytes, so the whole image may be passed.
    """
    crc = 0xFF
    for b in data[:CRC_COVERED_BYTES]:
        crc = _CRC_TABLE[crc ^ b]
    return crc


def sii_fix_checksum(image: bytes) -> bytes:
    """Return ``image`` with word 7 set to the CRC of bytes 0-13 (high byte 0)."""
    if len(image) < 2 * WORD_CHECKSUM + 2:
        raise SiiError(f"SII image of {len(image)} bytes has no checksum word (needs 16 bytes)")
    out = bytearray(image)
    out[2 * WORD_CHECKSUM] = sii_crc(image)
    out[2 * WORD_CHECKSUM + 1] = 0
    return bytes(out)


# --- parse ---------------------------------------------------------------------------


class _Ctx:
    """Collects warnings; in strict mode the first one raises."""

    def __init__(self, strict: bool) -> None:
        self.strict = strict
        self.warnings: list[str] = []

    def warn(self, message: str) -> None:
        if self.strict:
            raise SiiError(message)
        self.warnings.append(message)


def _where(ctype: int, word: int) -> str:
    return f"category {category_name(ctype)} at word 0x{word:04X}"


def _split_pad(body: bytes, used: int) -> bytes:
    """Bytes of ``body`` after ``used``, minus a lone zero byte that pads to a word."""
    rest = body[used:]
    if len(rest) == 1 and rest == b"\x00":
        return b""
    return rest


def _parse_strings(body: bytes, where: str, ctx: _Ctx) -> SiiStrings:
    if not body:
        ctx.warn(f"{where}: empty body, no string count")
        return SiiStrings()
    count = body[0]
    pos = 1
    strings: list[bytes] = []
    for i in range(1, count + 1):
        if pos >= len(body):
            ctx.warn(f"{where}: string {i} of {count} missing (body is {len(body)} bytes)")
            break
        length = body[pos]
        end = pos + 1 + length
        if end > len(body):
            ctx.warn(
                f"{where}: string {i} of {count} ({length} bytes at body byte {pos}) "
                f"runs past the body ({len(body)} bytes)"
            )
            strings.append(body[pos + 1 :])
            pos = len(body)
            break
        strings.append(body[pos + 1 : end])
        pos = end
    return SiiStrings(strings=strings, extra=_split_pad(body, pos))


def _parse_general(body: bytes, where: str, ctx: _Ctx) -> SiiGeneral:
    if len(body) < GENERAL_SIZE:
        ctx.warn(f"{where}: {len(body)} bytes, expected {GENERAL_SIZE}; rest taken as zero")
    v = _GENERAL.unpack(body[:GENERAL_SIZE].ljust(GENERAL_SIZE, b"\x00"))
    return SiiGeneral(
        group_index=v[0],
        image_index=v[1],
        order_index=v[2],
        name_index=v[3],
        reserved_04=v[4],
        coe_details=CoeDetails(v[5]),
        foe_details=v[6],
        eoe_details=v[7],
        soe_channels=v[8],
        ds402_channels=v[9],
        sysman_class=v[10],
        flags=GeneralFlags(v[11]),
        ebus_current_ma=v[12],
        reserved_0e=v[13],
        physical_ports=v[14],
        physical_memory_address=v[15],
        reserved_14=v[16],
        extra=body[GENERAL_SIZE:],
    )


def _parse_fmmus(body: bytes) -> SiiFmmus:
    return SiiFmmus(usages=[_enum_or_int(FmmuUsage, b) for b in body])


def _parse_syncms(body: bytes, where: str, ctx: _Ctx) -> SiiSyncManagers:
    n, rest = divmod(len(body), SYNC_MANAGER_SIZE)
    if rest:
        ctx.warn(f"{where}: {len(body)} bytes is not a whole number of 8-byte SyncManagers")
    sms = []
    for i in range(n):
        start, length, control, status, enable, sm_type = _SM.unpack_from(
            body, i * SYNC_MANAGER_SIZE
        )
        sms.append(
            SiiSyncManager(
                start, length, control, status, enable, _enum_or_int(SyncManagerType, sm_type)
            )
        )
    return SiiSyncManagers(sync_managers=sms, extra=body[n * SYNC_MANAGER_SIZE :])


def _parse_pdos(ctype: int, body: bytes, where: str, ctx: _Ctx) -> SiiPdos:
    pdos: list[SiiPdo] = []
    pos = 0
    while pos + PDO_HEADER_SIZE <= len(body):
        index, count, sm, dc, name, flags = _PDO_HEADER.unpack_from(body, pos)
        pos += PDO_HEADER_SIZE
        available = (len(body) - pos) // PDO_ENTRY_SIZE
        if count > available:
            ctx.warn(
                f"{where}: PDO 0x{index:04X} declares {count} entries, "
                f"only {available} fit in the category"
            )
            count = available
        entries = [
            SiiPdoEntry(*_PDO_ENTRY.unpack_from(body, pos + k * PDO_ENTRY_SIZE))
            for k in range(count)
        ]
        pos += count * PDO_ENTRY_SIZE
        pdos.append(
            SiiPdo(
                index=index,
                sync_manager=sm,
                dc_sync=dc,
                name_index=name,
                flags=flags,
                entries=entries,
            )
        )
    extra = body[pos:]
    if extra:
        ctx.warn(f"{where}: {len(extra)} trailing bytes are not a whole PDO header")
    return SiiPdos(type=CategoryType(ctype), pdos=pdos, extra=extra)


def _parse_dc(body: bytes, where: str, ctx: _Ctx) -> SiiDc:
    n, rest = divmod(len(body), DC_MODE_SIZE)
    if rest:
        ctx.warn(f"{where}: {len(body)} bytes is not a whole number of 24-byte DC modes")
    modes = [SiiDcMode(*_DC_MODE.unpack_from(body, i * DC_MODE_SIZE)) for i in range(n)]
    return SiiDc(modes=modes, extra=body[n * DC_MODE_SIZE :])


def _parse_category(ctype: int, body: bytes, word: int, ctx: _Ctx) -> SiiCategory:
    where = _where(ctype, word)
    if ctype == CategoryType.STRINGS:
        return _parse_strings(body, where, ctx)
    if ctype == CategoryType.GENERAL:
        return _parse_general(body, where, ctx)
    if ctype == CategoryType.FMMU:
        return _parse_fmmus(body)
    if ctype == CategoryType.SYNCM:
        return _parse_syncms(body, where, ctx)
    if ctype in (CategoryType.TXPDO, CategoryType.RXPDO):
        return _parse_pdos(ctype, body, where, ctx)
    if ctype == CategoryType.DC:
        return _parse_dc(body, where, ctx)
    return SiiRawCategory(type=_enum_or_int(CategoryType, ctype), data=body)


def parse_sii(data: bytes, *, strict: bool = False) -> SiiInfo:
    """Parse an SII image (from word 0) into an ``SiiInfo``.

    Tolerant by default: a bad checksum sets ``checksum_ok=False``; a missing
    end marker, a category running past the end of ``data`` or a malformed
    category body are recorded in ``warnings`` and whatever could be read is
    kept. ``strict=True`` raises ``SiiError`` (naming the category and word
    offset) on the first such problem. ``data`` shorter than 32 bytes (no
    identity) always raises ``SiiError``.

    The chain ends at a 0xFFFF type word (the size word after it need not be
    present), at the end of ``data``, or at a zero header (type 0, size 0),
    which is what a blank (zeroed) EEPROM reads; ``sii_bytes_needed`` stops
    at the same places.
    """
    data = bytes(data)
    ctx = _Ctx(strict)
    if len(data) < 32:
        raise SiiError(f"SII image of {len(data)} bytes is too short for the identity (32 bytes)")
    if len(data) % 2:
        ctx.warn(f"SII image has an odd length ({len(data)} bytes); last byte ignored")
        data = data[:-1]
    fixed = data[:FIXED_AREA_BYTES]
    if len(fixed) < FIXED_AREA_BYTES:
        ctx.warn(
            f"SII image of {len(data)} bytes ends inside the fixed area "
            f"(words 0x00-0x3F, {FIXED_AREA_BYTES} bytes); missing words taken as 0xFFFF"
        )
        fixed = fixed.ljust(FIXED_AREA_BYTES, b"\xff")
    v = _FIXED.unpack(fixed)
    crc = sii_crc(fixed)
    checksum = v[6]
    checksum_ok = (checksum & 0xFF) == crc
    if not checksum_ok:
        ctx.warn(
            f"SII checksum (word 0x07) is 0x{checksum & 0xFF:02X}, CRC of bytes 0-13 is 0x{crc:02X}"
        )
    info = SiiInfo(
        pdi_control=v[0],
        pdi_config=v[1],
        sync_impulse_len=v[2],
        pdi_config2=v[3],
        station_alias=v[4],
        reserved_05=v[5],
        checksum=checksum,
        vendor_id=v[7],
        product_code=v[8],
        revision=v[9],
        serial=v[10],
        reserved_10=v[11],
        boot_rx_mailbox_offset=v[12],
        boot_rx_mailbox_size=v[13],
        boot_tx_mailbox_offset=v[14],
        boot_tx_mailbox_size=v[15],
        rx_mailbox_offset=v[16],
        rx_mailbox_size=v[17],
        tx_mailbox_offset=v[18],
        tx_mailbox_size=v[19],
        mailbox_protocols=MailboxProtocol(v[20]),
        reserved_1d=v[21],
        eeprom_size_code=v[22],
        version=v[23],
        checksum_ok=checksum_ok,
    )
    info.end_marker = _parse_chain(data, info.categories, ctx)
    info.warnings = ctx.warnings
    return info


def _parse_chain(data: bytes, out: list[SiiCategory], ctx: _Ctx) -> bool:
    """Append the categories of ``data`` to ``out``; True if the end marker was found."""
    nwords = len(data) // 2
    word = WORD_FIRST_CATEGORY
    while True:
        if word >= nwords:
            if nwords > WORD_FIRST_CATEGORY:
                ctx.warn(f"no end marker: the image ends at word 0x{nwords:04X}")
            else:
                ctx.warn("no categories: the image ends with the fixed area")
            return False
        (ctype,) = struct.unpack_from("<H", data, 2 * word)
        if ctype == END_MARKER:
            return True
        if word + 1 >= nwords:
            ctx.warn(f"{_where(ctype, word)}: header cut off by the end of the image")
            return False
        (size,) = struct.unpack_from("<H", data, 2 * word + 2)
        if ctype == 0 and size == 0:
            # A zero-length NOP carries nothing; an all-zero header is what a
            # blank (zeroed) EEPROM reads, so the chain ends here.
            ctx.warn(f"no end marker: zero header (blank EEPROM) at word 0x{word:04X}")
            return False
        start = word + 2
        end = start + size
        if end > nwords:
            ctx.warn(
                f"{_where(ctype, word)}: {size} words run past the end of the image "
                f"(word 0x{nwords:04X}); kept {nwords - start} words"
            )
            out.append(_parse_category(ctype, data[2 * start :], word, ctx))
            return False
        out.append(_parse_category(ctype, data[2 * start : 2 * end], word, ctx))
        word = end


# --- read plan ---------------------------------------------------------------------------


def sii_bytes_needed(data: bytes, *, max_bytes: int = SII_DEFAULT_MAX_BYTES) -> int | None:
    """How much of the SII the master must read before it can parse it.

    ``data`` is what has been read so far, contiguous from word 0. Returns the
    total number of bytes (from word 0) needed to make progress, or None when
    ``data`` already holds the whole category chain (end marker reached, a
    zero header (blank EEPROM) reached, or ``max_bytes`` exceeded). The master
    loops: read up to the returned size (rounded up to its 4/8-byte reads),
    ask again, stop at None, then ``parse_sii`` what it has. Pure function.
    """
    have = len(data) - len(data) % 2
    word = WORD_FIRST_CATEGORY
    while True:
        pos = 2 * word
        # Ask for the whole 2-word header at once; the type word alone is
        # enough when it is the end marker.
        if pos + 2 > have:
            return pos + 4 if pos + 4 <= max_bytes else None
        (ctype,) = struct.unpack_from("<H", data, pos)
        if ctype == END_MARKER:
            return None
        if pos + 4 > have:
            return pos + 4 if pos + 4 <= max_bytes else None
        (size,) = struct.unpack_from("<H", data, pos + 2)
        if ctype == 0 and size == 0:
            return None
        word += 2 + size


# --- build -------------------------------------------------------------------------------


def _pad_word(body: bytes) -> bytes:
    return body + b"\x00" if len(body) % 2 else body


def _build_strings(cat: SiiStrings) -> bytes:
    if len(cat.strings) > 255:
        raise SiiError(f"Strings category holds {len(cat.strings)} strings, at most 255 fit")
    out = bytearray([len(cat.strings)])
    for i, s in enumerate(cat.strings, 1):
        if len(s) > 255:
            raise SiiError(f"string {i} is {len(s)} bytes long, at most 255 fit")
        out.append(len(s))
        out += s
    return bytes(out) + cat.extra


def _build_general(g: SiiGeneral) -> bytes:
    return (
        _GENERAL.pack(
            g.group_index,
            g.image_index,
            g.order_index,
            g.name_index,
            g.reserved_04,
            int(g.coe_details),
            g.foe_details,
            g.eoe_details,
            g.soe_channels,
            g.ds402_channels,
            g.sysman_class,
            int(g.flags),
            g.ebus_current_ma,
            g.reserved_0e,
            g.physical_ports,
            g.physical_memory_address,
            _exact(g.reserved_14, 12, "General reserved_14"),
        )
        + g.extra
    )


def _build_pdos(cat: SiiPdos) -> bytes:
    out = bytearray()
    for p in cat.pdos:
        out += _PDO_HEADER.pack(
            p.index, len(p.entries), p.sync_manager, p.dc_sync, p.name_index, p.flags
        )
        for e in p.entries:
            out += _PDO_ENTRY.pack(
                e.index, e.subindex, e.name_index, e.data_type, e.bit_length, e.flags
            )
    return bytes(out) + cat.extra


def _build_dc(cat: SiiDc) -> bytes:
    out = bytearray()
    for m in cat.modes:
        out += _DC_MODE.pack(
            m.cycle_time_sync0,
            m.shift_time_sync0,
            m.shift_time_sync1,
            m.sync1_cycle_factor,
            m.assign_activate,
            m.sync0_cycle_factor,
            m.name_index,
            m.description_index,
            _exact(m.reserved, 4, "DC mode reserved"),
        )
    return bytes(out) + cat.extra


def _exact(value: bytes, size: int, what: str) -> bytes:
    if len(value) != size:
        raise SiiError(f"{what} must be {size} bytes, got {len(value)}")
    return bytes(value)


def _category_body(cat: SiiCategory) -> tuple[int, bytes]:
    if isinstance(cat, SiiStrings):
        return CategoryType.STRINGS, _build_strings(cat)
    if isinstance(cat, SiiGeneral):
        return CategoryType.GENERAL, _build_general(cat)
    if isinstance(cat, SiiFmmus):
        return CategoryType.FMMU, bytes(int(u) for u in cat.usages)
    if isinstance(cat, SiiSyncManagers):
        body = b"".join(
            _SM.pack(s.start, s.length, s.control, s.status, s.enable, int(s.sm_type))
            for s in cat.sync_managers
        )
        return CategoryType.SYNCM, body + cat.extra
    if isinstance(cat, SiiPdos):
        if cat.type not in (CategoryType.TXPDO, CategoryType.RXPDO):
            raise SiiError(f"SiiPdos.type must be TXPDO (50) or RXPDO (51), got {cat.type}")
        return cat.type, _build_pdos(cat)
    if isinstance(cat, SiiDc):
        return CategoryType.DC, _build_dc(cat)
    if cat.type == END_MARKER:
        raise SiiError("a raw category cannot have the end-marker type 0xFFFF")
    if cat.type == CategoryType.NOP and not cat.data:
        # A zero header reads back as a blank EEPROM (end of the chain).
        raise SiiError("an empty NOP category would read back as a blank EEPROM")
    return cat.type, bytes(cat.data)


def category_body(cat: SiiCategory) -> bytes:
    """Encoded body of one category (without its 2-word header), padded to whole words."""
    try:
        return _pad_word(_category_body(cat)[1])
    except struct.error as exc:
        raise SiiError(f"{category_name(int(cat.type))} field out of range: {exc}") from exc


def build_sii(info: SiiInfo, *, pad: bool = True, fix_checksum: bool = True) -> bytes:
    """Build the image bytes of ``info``.

    Fixed area (checksum recomputed unless ``fix_checksum=False``, which writes
    ``info.checksum`` as is, e.g. to simulate a corrupt EEPROM), the categories
    in list order, each padded to whole words, and the end marker 0xFFFF. With
    ``pad`` the image is filled with 0xFF (erased EEPROM) up to
    ``info.eeprom_size_bytes``; content larger than that raises ``SiiError``.
    Out-of-range field values raise ``SiiError`` too.
    """
    try:
        fixed = bytearray(
            _FIXED.pack(
                info.pdi_control,
                info.pdi_config,
                info.sync_impulse_len,
                info.pdi_config2,
                info.station_alias,
                _exact(info.reserved_05, 4, "reserved_05"),
                info.checksum,
                info.vendor_id,
                info.product_code,
                info.revision,
                info.serial,
                _exact(info.reserved_10, 8, "reserved_10"),
                info.boot_rx_mailbox_offset,
                info.boot_rx_mailbox_size,
                info.boot_tx_mailbox_offset,
                info.boot_tx_mailbox_size,
                info.rx_mailbox_offset,
                info.rx_mailbox_size,
                info.tx_mailbox_offset,
                info.tx_mailbox_size,
                int(info.mailbox_protocols),
                _exact(info.reserved_1d, 66, "reserved_1d"),
                info.eeprom_size_code,
                info.version,
            )
        )
        if fix_checksum:
            fixed[2 * WORD_CHECKSUM : 2 * WORD_CHECKSUM + 2] = bytes((sii_crc(fixed), 0))
        out = bytearray(fixed)
        for i, cat in enumerate(info.categories):
            ctype, body = _category_body(cat)
            body = _pad_word(body)
            if len(body) // 2 > 0xFFFF:
                raise SiiError(f"category {i} ({category_name(ctype)}) is too large")
            out += struct.pack("<HH", ctype, len(body) // 2) + body
    except struct.error as exc:
        raise SiiError(f"SII field out of range: {exc}") from exc
    out += struct.pack("<H", END_MARKER)
    if pad:
        size = info.eeprom_size_bytes
        if len(out) > size:
            raise SiiError(
                f"SII content needs {len(out)} bytes, the EEPROM size word (0x3E = "
                f"{info.eeprom_size_code}) gives {size} bytes"
            )
        out += b"\xff" * (size - len(out))
    return bytes(out)
