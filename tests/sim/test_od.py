"""Object dictionary: access rights per state, lengths, value ranges, complete access, lists."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.sim.od import RO, RW, RW_PREOP, RXPDO, TXPDO, WO, SimObjectDictionary, SimOdEntry
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import ObjectCode, SdoAbortCode
from pyethercat.wire.mailbox.datatypes import DataType

P, S, OP = AlState.PREOP, AlState.SAFEOP, AlState.OP


def make() -> SimObjectDictionary:
    od = SimObjectDictionary()
    od.var(0x1000, "Device type", DataType.UNSIGNED32, RO, 0x191)
    od.var(0x2000, "Blob", DataType.OCTET_STRING, RW, b"abc", max_length=16)
    od.var(0x2001, "Command", DataType.UNSIGNED32, WO, 0)
    od.var(0x2002, "Preop only", DataType.UNSIGNED16, RW_PREOP, 5, minimum=1, maximum=10)
    od.var(0x2003, "Mode", DataType.UNSIGNED8, RW, 0, allowed=frozenset({0, 2}))
    od.var(0x2004, "Flag", DataType.BOOLEAN, RW, False)
    od.var(0x2005, "Gain", DataType.REAL32, RW, 1.0, minimum=0.0, maximum=2.0)
    od.var(0x2006, "Signed", DataType.INTEGER16, RW, -5, minimum=-10, maximum=10)
    od.var(0x2007, "Name", DataType.VISIBLE_STRING, RW, "ab", max_length=8)
    od.var(0x2008, "Op only read", DataType.UNSIGNED8, 0x0004, 9)  # readable in OP only
    od.record(0x3000, "Rec", [
        SimOdEntry(1, "a", DataType.UNSIGNED8, RW | TXPDO, 1),
        SimOdEntry(2, "b", DataType.UNSIGNED16, RW | RXPDO, 0x0302),
        SimOdEntry(3, "bit", DataType.BOOLEAN, RW, True),
        SimOdEntry(4, "c", DataType.UNSIGNED32, RO, 0x07060504),
    ])
    od.array(0x3001, "Arr", DataType.UNSIGNED16, [10, 20, 30], RW, count_access=RW, length=4)
    return od


def code(fn: object, *args: object, **kw: object) -> int:
    with pytest.raises(SdoAbort) as info:
        fn(*args, **kw)  # type: ignore[operator]
    return info.value.code


def test_upload_values_and_missing() -> None:
    od = make()
    assert od.upload(0x1000, 0, P) == struct.pack("<I", 0x191)
    assert od.upload(0x2000, 0, OP) == b"abc"
    assert od.upload(0x3000, 0, P) == b"\x04"
    assert od.upload(0x3001, 0, P) == b"\x03"
    assert code(od.upload, 0x4000, 0, P) == SdoAbortCode.NO_OBJECT
    assert code(od.upload, 0x3000, 9, P) == SdoAbortCode.NO_SUBINDEX
    assert code(od.upload, 0x2001, 0, P) == SdoAbortCode.WRITE_ONLY
    assert code(od.upload, 0x2008, 0, P) == SdoAbortCode.DEVICE_STATE
    assert od.upload(0x2008, 0, OP) == b"\x09"


def test_download_access_rights_per_state() -> None:
    od = make()
    assert code(od.download, 0x1000, 0, b"\0\0\0\0", P) == SdoAbortCode.READ_ONLY
    od.download(0x2002, 0, b"\x07\x00", P)
    assert od.value(0x2002) == 7
    assert code(od.download, 0x2002, 0, b"\x08\x00", S) == SdoAbortCode.DEVICE_STATE
    assert code(od.download, 0x2002, 0, b"\x08\x00", OP) == SdoAbortCode.DEVICE_STATE
    od.download(0x2001, 0, b"\1\0\0\0", OP)  # write-only: writable everywhere
    assert od.entry(0x2001, 0).raw == b"\1\0\0\0"


def test_download_lengths() -> None:
    od = make()
    assert code(od.download, 0x2002, 0, b"\x01\x00\x00", P) == SdoAbortCode.LENGTH_TOO_HIGH
    assert code(od.download, 0x2002, 0, b"\x01", P) == SdoAbortCode.LENGTH_TOO_LOW
    assert code(od.download, 0x2002, 0, b"\x01", P, size_indicated=False) == (
        SdoAbortCode.LENGTH_MISMATCH)
    # expedited without size indication: 4 bytes, the low ones count
    od.download(0x2002, 0, b"\x03\x00\xee\xee", P, size_indicated=False, expedited=True)
    assert od.value(0x2002) == 3
    assert code(od.download, 0x2000, 0, bytes(17), P) == SdoAbortCode.LENGTH_TOO_HIGH
    od.download(0x2000, 0, b"", P)
    assert od.upload(0x2000, 0, P) == b""
    od.download(0x2007, 0, b"hello", P)
    assert od.value(0x2007) == "hello"
    with pytest.raises(SdoAbort):
        od.check_download(0x2000, 0, 17, P)
    with pytest.raises(SdoAbort):
        od.check_download(0x2002, 0, 4, P)
    od.check_download(0x2002, 0, 2, P)


def test_value_ranges() -> None:
    od = make()
    assert code(od.download, 0x2002, 0, b"\x0b\x00", P) == SdoAbortCode.VALUE_TOO_HIGH
    assert code(od.download, 0x2002, 0, b"\x00\x00", P) == SdoAbortCode.VALUE_TOO_LOW
    assert code(od.download, 0x2003, 0, b"\x01", P) == SdoAbortCode.VALUE_RANGE
    od.download(0x2003, 0, b"\x02", P)
    assert code(od.download, 0x2004, 0, b"\x02", P) == SdoAbortCode.VALUE_RANGE
    assert code(od.download, 0x2005, 0, struct.pack("<f", 2.5), P) == SdoAbortCode.VALUE_TOO_HIGH
    assert code(od.download, 0x2005, 0, struct.pack("<f", -1), P) == SdoAbortCode.VALUE_TOO_LOW
    assert code(od.download, 0x2006, 0, struct.pack("<h", -11), P) == SdoAbortCode.VALUE_TOO_LOW
    od.download(0x2006, 0, struct.pack("<h", -10), P)
    assert od.value(0x2006) == -10
    # nothing was stored by the refused writes
    assert od.value(0x2002) == 5


def test_complete_access_read_sub0_and_sub1() -> None:
    od = make()
    # sub0 as 16 bits, then a(8) b(16) bit(1) c(32), packed bit by bit
    acc = 1 | (0x0302 << 8) | (1 << 24) | (0x07060504 << 25)
    body = acc.to_bytes(8, "little")
    assert od.upload(0x3000, 0, P, complete_access=True) == b"\x04\x00" + body[:8]
    assert od.upload(0x3000, 1, P, complete_access=True) == body[:8]
    assert od.upload(0x3001, 0, P, True) == struct.pack("<BxHHH", 3, 10, 20, 30)
    assert od.upload(0x1000, 0, P, True) == struct.pack("<I", 0x191)  # a VAR: just the value
    assert code(od.upload, 0x3000, 2, P, True) == SdoAbortCode.UNSUPPORTED_ACCESS
    assert code(od.upload, 0x2000, 0, P, True) == SdoAbortCode.CA_VARIABLE_LENGTH


def test_complete_access_write() -> None:
    od = make()
    od.download(0x3001, 0, struct.pack("<BxHHHH", 4, 1, 2, 3, 4), P, complete_access=True)
    assert [od.value(0x3001, s) for s in range(5)] == [4, 1, 2, 3, 4]
    od.download(0x3001, 1, struct.pack("<HHHH", 5, 6, 7, 8), P, complete_access=True)
    assert [od.value(0x3001, s) for s in range(1, 5)] == [5, 6, 7, 8]
    assert code(od.download, 0x3001, 0, struct.pack("<BxHH", 4, 1, 2), P, True) == (
        SdoAbortCode.LENGTH_TOO_LOW)
    assert code(od.download, 0x3001, 0, struct.pack("<BxHHHHH", 4, 1, 2, 3, 4, 5), P, True) == (
        SdoAbortCode.LENGTH_TOO_HIGH)
    assert code(od.download, 0x3001, 0, struct.pack("<BxHHHHH", 5, 1, 2, 3, 4, 5), P, True) == (
        SdoAbortCode.VALUE_TOO_HIGH)
    # the record's read-only entry may ride along unchanged, not changed
    rec = od.upload(0x3000, 0, P, True)
    changed = bytearray(rec)
    changed[2] = 0x55
    od.download(0x3000, 0, bytes(changed), P, True)
    assert od.value(0x3000, 1) == 0x55
    bad = bytearray(rec)
    bad[-1] ^= 0x01
    assert code(od.download, 0x3000, 0, bytes(bad), P, True) == SdoAbortCode.READ_ONLY


def test_rx_mapped_entries_refuse_sdo_writes_in_safeop() -> None:
    od = make()
    od.rx_mapped = frozenset({(0x3000, 2)})
    od.download(0x3000, 2, b"\x01\x00", P)
    assert code(od.download, 0x3000, 2, b"\x02\x00", S) == SdoAbortCode.MAPPED_TO_RXPDO


def test_object_hooks_see_changes_and_can_refuse() -> None:
    od = make()
    seen: list[tuple[int, dict[int, bytes], bool]] = []
    obj = od.get(0x3001)

    def check(o: object, changes: dict[int, bytes], complete: bool) -> None:
        if changes.get(1) == b"\xff\xff":
            raise SdoAbort(SdoAbortCode.PARAMETER_INCOMPATIBLE, "no", 0x3001, 1)

    obj.check = check
    obj.after = lambda o, ch, c: seen.append((o.index, ch, c))
    od.download(0x3001, 1, b"\x01\x00", P)
    assert seen == [(0x3001, {1: b"\x01\x00"}, False)]
    assert code(od.download, 0x3001, 1, b"\xff\xff", P) == SdoAbortCode.PARAMETER_INCOMPATIBLE
    assert od.value(0x3001, 1) == 1


def test_lists_and_descriptions() -> None:
    od = make()
    assert od.indices(1) == tuple(sorted(o.index for o in od))
    assert od.indices(2) == (0x3000,)
    assert od.indices(3) == (0x3000,)
    assert od.indices(0) == (len(od), 1, 1, 0, 0)
    assert code(od.indices, 9) == SdoAbortCode.VALUE_RANGE
    rec = od.get(0x3000)
    assert rec.object_code == ObjectCode.RECORD and rec.max_subindex == 4
    assert od.get(0x1000).max_subindex == 0
    assert od.entry(0x2000, 0).bit_length == 128
    assert od.entry(0x3000, 3).bit_length == 1


def test_building_errors() -> None:
    od = SimObjectDictionary()
    with pytest.raises(MailboxError):
        od.var(0x2000, "x", DataType.OCTET_STRING, RW, bytes(5), max_length=4)
    with pytest.raises(MailboxError):
        SimOdEntry(300, "x", DataType.UNSIGNED8)
    with pytest.raises(MailboxError):
        od.record(0x2001, "r", [SimOdEntry(0, "no", DataType.UNSIGNED8)])


@given(st.integers(0, 0xFFFF))
def test_u16_round_trip_through_sdo_access(value: int) -> None:
    od = SimObjectDictionary()
    od.var(0x2000, "x", DataType.UNSIGNED16, RW, 0)
    od.download(0x2000, 0, struct.pack("<H", value), P)
    assert od.upload(0x2000, 0, OP) == struct.pack("<H", value)


@given(st.lists(st.integers(0, 0xFFFFFFFF), min_size=0, max_size=8))
def test_complete_access_round_trip(values: list[int]) -> None:
    od = SimObjectDictionary()
    od.array(0x1600, "map", DataType.UNSIGNED32, [], RW, count_access=RW, length=8)
    data = struct.pack(f"<Bx{len(values)}I", len(values), *values)
    od.download(0x1600, 0, data, P, complete_access=True)
    assert od.upload(0x1600, 0, P, complete_access=True) == data
