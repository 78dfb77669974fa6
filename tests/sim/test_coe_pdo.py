"""PDO mapping objects define the process data: dynamic remap in PREOP, P->S checks, exchange."""

from __future__ import annotations

import struct

import pytest
from coehelp import SM2, SM3, CoeSlave

from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.mailbox.coe import SdoAbortCode
from pyethercat.wire.mailbox.objects import mapping_word


@pytest.fixture
def slave() -> CoeSlave:
    return CoeSlave()


def u8(v: int) -> bytes:
    return bytes([v])


def u16(v: int) -> bytes:
    return struct.pack("<H", v)


def u32(v: int) -> bytes:
    return struct.pack("<I", v)


def to_op(slave: CoeSlave, out_len: int, in_len: int) -> None:
    slave.configure_process_data(out_len, in_len)
    assert slave.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)
    if out_len:
        assert slave.fpwr(SM2, bytes(out_len)) == 1
    assert slave.request_state(AlState.OP) == (int(AlState.OP), 0)


def cycle(slave: CoeSlave, outputs: bytes, in_len: int) -> bytes:
    assert slave.fpwr(SM2, outputs) == 1
    d = slave.fprd(SM3, in_len)
    assert d.wkc == 1
    return bytes(d.data)


def remap(slave: CoeSlave, assign: int, pdo: int, entries: list[int], pdos: list[int]) -> None:
    """The standard sequence: assignment off, mapping 0, entries, mapping n, assignment n."""
    slave.download(assign, 0, u8(0))
    slave.download(pdo, 0, u8(0))
    for n, word in enumerate(entries, 1):
        slave.download(pdo, n, u32(word))
    slave.download(pdo, 0, u8(len(entries)))
    for n, p in enumerate(pdos, 1):
        slave.download(assign, n, u16(p))
    slave.download(assign, 0, u8(len(pdos)))


def test_default_mapping_and_echo(slave: CoeSlave) -> None:
    assert slave.app.process_data_sizes() == (7, 7)  # type: ignore[attr-defined]
    to_op(slave, 7, 7)
    outputs = struct.pack("<BHI", 0xA5, 0x1234, 0xDEADBEEF)
    assert cycle(slave, outputs, 7) == outputs
    slave.download(0x8000, 3, b"\x01")  # invert digital inputs (settings are writable in OP)
    slave.download(0x8000, 2, struct.pack("<i", 10))  # offset on value 32
    assert cycle(slave, outputs, 7) == struct.pack("<BHI", 0x5A, 0x1234, 0xDEADBEEF + 10)


def test_wrong_sm_lengths_refused_on_preop_to_safeop(slave: CoeSlave) -> None:
    slave.configure_process_data(6, 7)
    status, code = slave.request_state(AlState.SAFEOP)
    assert status == int(AlState.PREOP) | R.AL_ERROR_FLAG
    assert code == AlStatusCode.INVALID_OUTPUT_CONFIG
    slave.ack(AlState.PREOP)
    slave.configure_process_data(7, 8)
    status, code = slave.request_state(AlState.SAFEOP)
    assert (status & 0x0F, code) == (int(AlState.PREOP), AlStatusCode.INVALID_INPUT_CONFIG)


def test_dynamic_remap_changes_sizes_checks_and_image(slave: CoeSlave) -> None:
    # outputs: bit output + 7 bits gap + value 32 in the spare RxPDO 0x1602
    remap(slave, 0x1C12, 0x1602, [mapping_word(0x7000, 4, 1), mapping_word(0, 0, 7),
                                  mapping_word(0x7000, 3, 32)], [0x1602])
    # inputs: counter PDO + value 32 + bit input, the bit at the end
    remap(slave, 0x1C13, 0x1A03, [mapping_word(0x6000, 3, 32), mapping_word(0x6000, 5, 1)],
          [0x1A02, 0x1A03])
    assert slave.app.process_data_sizes() == (5, 7)  # type: ignore[attr-defined]
    assert slave.upload(0x1C12, 0, ca=True) == struct.pack("<BxH", 1, 0x1602)
    # the old lengths no longer pass the PREOP -> SAFEOP check
    slave.configure_process_data(7, 7)
    assert slave.request_state(AlState.SAFEOP)[1] == AlStatusCode.INVALID_OUTPUT_CONFIG
    slave.ack(AlState.PREOP)
    to_op(slave, 5, 7)
    out = bytes([0x01]) + u32(0x01020304)
    first = cycle(slave, out, 7)
    counter = struct.unpack_from("<H", first)[0]
    assert first[2:6] == u32(0x01020304) and first[6] == 0x01
    second = cycle(slave, bytes([0x00]) + u32(7), 7)
    assert struct.unpack_from("<H", second)[0] == counter + 1
    assert second[2:] == u32(7) + b"\x00"


def test_complete_access_remap(slave: CoeSlave) -> None:
    slave.download(0x1C13, 0, u8(0))
    slave.download(0x1A03, 0, struct.pack("<BxII", 2, mapping_word(0x6000, 2, 16),
                                          mapping_word(0x6000, 1, 8)), ca=True)
    slave.download(0x1C13, 0, struct.pack("<BxH", 1, 0x1A03), ca=True)
    assert slave.app.process_data_sizes() == (7, 3)  # type: ignore[attr-defined]
    to_op(slave, 7, 3)
    assert cycle(slave, struct.pack("<BHI", 0x33, 0xBEEF, 0), 3) == struct.pack("<HB", 0xBEEF, 0x33)


def test_mapping_abort_paths(slave: CoeSlave) -> None:
    a = slave.abort_code
    # entries only while subindex 0 is 0
    assert a(slave.download, 0x1600, 1, u32(mapping_word(0x7000, 1, 8))) == (
        SdoAbortCode.SUBINDEX_WRITE)
    assert a(slave.download, 0x1C12, 1, u16(0x1602)) == SdoAbortCode.SUBINDEX_WRITE
    slave.download(0x1C12, 0, u8(0))
    slave.download(0x1602, 0, u8(0))
    assert a(slave.download, 0x1602, 1, u32(mapping_word(0x5555, 1, 8))) == SdoAbortCode.NO_OBJECT
    assert a(slave.download, 0x1602, 1, u32(mapping_word(0x7000, 9, 8))) == (
        SdoAbortCode.NO_SUBINDEX)
    assert a(slave.download, 0x1602, 1, u32(mapping_word(0x6000, 1, 8))) == (
        SdoAbortCode.NOT_MAPPABLE)  # an input in an RxPDO
    assert a(slave.download, 0x1602, 1, u32(mapping_word(0x8000, 1, 16))) == (
        SdoAbortCode.NOT_MAPPABLE)  # a setting
    assert a(slave.download, 0x1602, 1, u32(mapping_word(0x7000, 2, 8))) == (
        SdoAbortCode.PARAMETER_INCOMPATIBLE)  # wrong bit length
    assert a(slave.download, 0x1602, 0, u8(9)) == SdoAbortCode.VALUE_TOO_HIGH
    # 8 x 32 bits = 32 bytes per PDO; four such PDOs exceed the 128-byte SM buffer
    for pdo in (0x1600, 0x1601, 0x1602, 0x1603):
        slave.download(pdo, 0, u8(0))
        for n in range(1, 9):
            slave.download(pdo, n, u32(mapping_word(0, 0, 32 if pdo != 0x1603 else 40)))
        slave.download(pdo, 0, u8(8))
    for n, pdo in enumerate((0x1600, 0x1601, 0x1602, 0x1603), 1):
        slave.download(0x1C12, n, u16(pdo))
    assert a(slave.download, 0x1C12, 0, u8(4)) == SdoAbortCode.PDO_LENGTH_EXCEEDED
    slave.download(0x1C12, 0, u8(3))
    assert slave.app.process_data_sizes()[0] == 96  # type: ignore[attr-defined]
    # assignment values must be PDOs of the right direction, each once
    slave.download(0x1C12, 0, u8(0))
    assert a(slave.download, 0x1C12, 1, u16(0x1A00)) == SdoAbortCode.VALUE_RANGE
    assert a(slave.download, 0x1C12, 1, u16(0x1604)) == SdoAbortCode.VALUE_RANGE
    slave.download(0x1C12, 2, u16(0x1600))
    assert a(slave.download, 0x1C12, 0, u8(2)) == SdoAbortCode.PARAMETER_INCOMPATIBLE
    assert a(slave.download, 0x1C12, 0, u8(5)) == SdoAbortCode.VALUE_TOO_HIGH


def test_mapping_objects_are_preop_only(slave: CoeSlave) -> None:
    to_op(slave, 7, 7)
    for index in (0x1C12, 0x1C13, 0x1600, 0x1A00):
        assert slave.abort_code(slave.download, index, 0, u8(0)) == SdoAbortCode.DEVICE_STATE
    assert slave.upload(0x1600, 1) == u32(mapping_word(0x7000, 1, 8))


def test_remap_after_going_back_to_preop(slave: CoeSlave) -> None:
    to_op(slave, 7, 7)
    assert slave.app.process_data_sizes() == (7, 7)  # type: ignore[attr-defined]
    assert slave.request_state(AlState.PREOP) == (int(AlState.PREOP), 0)
    slave.download(0x1C13, 0, u8(0))
    assert slave.app.process_data_sizes() == (7, 0)  # type: ignore[attr-defined]
    slave.configure_process_data(7, 0)
    assert slave.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)


def test_sync_objects(slave: CoeSlave) -> None:
    assert slave.upload(0x1C32, 1) == u16(1)
    assert slave.upload(0x1C33, 1) == u16(0x22)
    assert slave.upload(0x1C32, 4) == u16(0x0007)
    slave.download(0x1C32, 1, u16(2))
    assert slave.upload(0x1C32, 1) == u16(2)
    # (DC SYNC0 mode without a running SYNC0 would refuse SAFEOP: back to SM event)
    slave.download(0x1C32, 1, u16(1))
    assert slave.abort_code(slave.download, 0x1C32, 1, u16(5)) == SdoAbortCode.VALUE_RANGE
    assert slave.abort_code(slave.download, 0x1C32, 2, u32(1000)) == SdoAbortCode.READ_ONLY
    to_op(slave, 7, 7)
    slave.clock.advance(1_000_000)  # type: ignore[attr-defined]
    cycle(slave, bytes(7), 7)
    assert struct.unpack("<I", slave.upload(0x1C32, 2))[0] > 0  # measured cycle time


def test_seed002_drive_objects() -> None:
    drive = CoeSlave("seed002-drive", serial=0x42)
    up = drive.upload
    assert struct.unpack("<I", up(0x1000, 0))[0] == 0x00020192
    assert [struct.unpack("<I", up(0x1018, s))[0] for s in range(1, 5)] == [
        0xE4, 0x264860D2, 0x00020000, 0x42]
    assert up(0x1100, 0) == u16(0x1001)  # the configured station address, live
    assert [up(0x1C00, s)[0] for s in range(5)] == [4, 1, 2, 3, 4]
    assert up(0x1C10, 0) == b"\x00" and up(0x1C11, 0) == b"\x00"
    assert up(0x1C12, 0) == b"\x00" and up(0x1C13, 0) == b"\x00"  # the seed's default
    assert [up(0x1C12, s) for s in range(1, 5)] == [u16(0x1600 + n) for n in range(4)]
    assert [up(0x1C13, s) for s in range(1, 5)] == [u16(0x1A00 + n) for n in range(4)]
    assert up(0x1600, 0) == b"\x02"
    assert up(0x1600, 1) == u32(0x60400010) and up(0x1600, 2) == u32(0x60600008)
    assert up(0x1A00, 1) == u32(0x60410010) and up(0x1A00, 2) == u32(0x60610008)
    for index in (0x1008, 0x1009, 0x100A):  # "Objekt ist nicht vorhanden"
        assert drive.abort_code(up, index, 0) == SdoAbortCode.NO_OBJECT
    assert drive.abort_code(drive.download, 0x1C00, 1, b"\x00") == SdoAbortCode.READ_ONLY
    assert drive.abort_code(drive.download, 0x1100, 0, u16(1)) == SdoAbortCode.READ_ONLY
    assert drive.app.process_data_sizes() == (0, 0)  # type: ignore[attr-defined]
    # the master assigns the PDOs (as an ESI's PdoAssign does), then runs
    drive.download(0x1C12, 0, u8(1))
    drive.download(0x1C13, 0, u8(1))
    assert drive.app.process_data_sizes() == (3, 3)  # type: ignore[attr-defined]
    to_op(drive, 3, 3)
    # 0x0F is no transition out of Switch on disabled; bit 7 warns that there is no SYNC0
    # (the manual's warning 63-3: the drive synchronises on the frames)
    assert cycle(drive, struct.pack("<Hb", 0x000F, 3), 3) == struct.pack("<Hb", 0x02D0, 3)
    assert cycle(drive, struct.pack("<Hb", 0x0006, 3), 3) == struct.pack("<Hb", 0x02B1, 3)
