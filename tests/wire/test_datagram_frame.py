"""Datagram and frame codec: round trips, the facts-sheet example, malformed input."""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import FrameError, FrameTooLargeError
from pyethercat.wire.datagram import MAX_DATA, Command, Datagram, decode_datagrams, encode_datagrams
from pyethercat.wire.frame import (
    MIN_FRAME_SIZE,
    FrameBuilder,
    NotEtherCATError,
    decode_frame,
    decode_udp_payload,
    encode_frame,
    encode_mailbox_frame,
    encode_udp_payload,
    returned_source_mac,
)

datagram_st = st.builds(
    Datagram,
    command=st.sampled_from(list(Command)),
    index=st.integers(0, 255),
    address=st.integers(0, 0xFFFFFFFF),
    data=st.binary(max_size=64),
    irq=st.integers(0, 0xFFFF),
    wkc=st.integers(0, 0xFFFF),
    circulating=st.booleans(),
)


def test_brd_slave_count_example_matches_facts_sheet() -> None:
    frame = encode_frame([Datagram.device(Command.BRD, 0, 0x0000, 2)], src=b"\x01" * 6)
    expected = bytes.fromhex(
        "ffffffffffff" "010101010101" "88a4" "0e10" "07000000000002000000" "0000" "0000"
    )
    assert frame[: len(expected)] == expected
    assert len(frame) == MIN_FRAME_SIZE and frame[len(expected):] == bytes(30)


@given(st.lists(datagram_st, min_size=1, max_size=12))
def test_datagrams_round_trip(dgrams: list[Datagram]) -> None:
    decoded = decode_datagrams(encode_datagrams(dgrams))
    assert len(decoded) == len(dgrams)
    for i, (a, b) in enumerate(zip(dgrams, decoded, strict=True)):
        assert (a.command, a.index, a.address, bytes(a.data), a.irq, a.wkc, a.circulating) == (
            b.command, b.index, b.address, b.data, b.irq, b.wkc, b.circulating)
        assert b.more == (i != len(dgrams) - 1)


def _fields(d: Datagram) -> tuple[int, int, int, bytes, int, int, bool]:
    return (int(d.command), d.index, d.address, bytes(d.data), d.irq, d.wkc, d.circulating)


# Every code a datagram header can carry, not only the 15 standard commands.
any_command_datagram_st = st.builds(
    Datagram,
    command=st.one_of(st.sampled_from(list(Command)), st.integers(0, 255)),
    index=st.integers(0, 255),
    address=st.integers(0, 0xFFFFFFFF),
    data=st.binary(max_size=64),
    irq=st.integers(0, 0xFFFF),
    wkc=st.integers(0, 0xFFFF),
    circulating=st.booleans(),
)


@given(st.lists(any_command_datagram_st, min_size=1, max_size=8),
       st.binary(min_size=6, max_size=6), st.binary(min_size=6, max_size=6))
def test_frame_and_udp_round_trip(dgrams: list[Datagram], src: bytes, dst: bytes) -> None:
    raw_frame = encode_frame(dgrams, src, dst)
    assert len(raw_frame) == max(60, 16 + sum(d.size for d in dgrams))
    for raw, decode in ((raw_frame, decode_frame), (encode_udp_payload(dgrams), decode_udp_payload)):
        frame = decode(raw)
        assert frame.frame_type == 1
        assert [_fields(d) for d in frame.datagrams] == [_fields(d) for d in dgrams]
        assert [d.more for d in frame.datagrams] == [True] * (len(dgrams) - 1) + [False]
        # Standard codes come back as Command, the others as plain int.
        assert [isinstance(d.command, Command) for d in frame.datagrams] == [
            int(d.command) < 15 for d in dgrams]
    decoded = decode_frame(raw_frame)
    assert (decoded.src, decoded.dst) == (src, dst)
    assert decoded.padding == len(raw_frame) - 16 - sum(d.size for d in dgrams)


def test_largest_single_datagram_makes_a_1514_byte_frame() -> None:
    raw = encode_frame([Datagram.logical(Command.LRW, 0x10000, bytes(range(256)) * 5 + bytes(206))])
    assert len(raw) == 1514 and MAX_DATA == 1486
    assert raw[14:16] == struct.pack("<H", 0x1000 | 1498)
    frame = decode_frame(raw)
    assert len(frame.datagrams[0].data) == MAX_DATA and frame.padding == 0
    with pytest.raises(FrameTooLargeError, match="1499 bytes, a frame holds 1498"):
        encode_frame([Datagram.logical(Command.LRW, 0, MAX_DATA + 1)])


def test_many_datagrams_filling_the_frame_exactly() -> None:
    # 123 empty datagrams (12 bytes each) + one with 10 data bytes = 1498 bytes.
    dgrams = [Datagram.device(Command.NOP, 0, 0, b"", i) for i in range(123)]
    dgrams.append(Datagram.device(Command.BRD, 0, 0, 10, 123))
    builder = FrameBuilder()
    for d in dgrams:
        builder.add(d)
    assert builder.free == 0
    assert not builder.fits(Datagram.device(Command.NOP, 0, 0, b""))
    with pytest.raises(FrameTooLargeError, match="0 bytes free"):
        builder.add(Datagram.device(Command.NOP, 0, 0, b""))
    raw = builder.build()
    assert len(raw) == 1514
    decoded = decode_frame(raw).datagrams
    assert [d.index for d in decoded] == list(range(124))
    assert [len(d.data) for d in decoded] == [0] * 123 + [10]
    with pytest.raises(FrameTooLargeError):
        encode_frame(dgrams + [Datagram.device(Command.NOP, 0, 0, b"")])


def test_zero_length_datagram_and_padding() -> None:
    raw = encode_frame([Datagram.device(Command.FPRD, 0x1001, 0x0130, b"", 7)])
    assert len(raw) == 60 and raw[16 + 12:] == bytes(60 - 28)
    (d,) = decode_frame(raw).datagrams
    assert (d.command, d.index, d.adp, d.ado, d.data) == (Command.FPRD, 7, 0x1001, 0x0130, b"")
    # Any amount of padding, odd or even, is ignored and counted.
    for extra in (0, 1, 3, 33):
        assert decode_frame(raw + bytes(extra)).padding == 60 - 28 + extra


def test_vlan_tagged_frame_decodes() -> None:
    raw = encode_frame([Datagram.device(Command.BRD, 0, 0x0000, 2, 9)])
    tagged = raw[:12] + b"\x81\x00\x20\x05" + raw[12:]
    frame = decode_frame(tagged)
    assert frame.datagrams[0].index == 9 and frame.padding == 30
    with pytest.raises(FrameError, match="VLAN-tagged frame truncated"):
        decode_frame(tagged[:16])
    with pytest.raises(NotEtherCATError, match="0x0800"):
        decode_frame(raw[:12] + b"\x81\x00\x00\x05\x08\x00" + raw[14:])


def test_length_fields_and_reserved_bits() -> None:
    raw = bytearray(encode_frame([Datagram.device(Command.BRD, 0, 0, 2)]))
    # Reserved bits 11-13 of the datagram length word do not change its 11-bit length.
    raw[22:24] = struct.pack("<H", 0x3800 | 2)
    assert len(decode_frame(bytes(raw)).datagrams[0].data) == 2
    # Bit 11 of the EtherCAT header is not part of the length: a frame with it set is refused.
    raw[14:16] = struct.pack("<H", 0x1000 | 0x0800 | 14)
    with pytest.raises(FrameError, match="reserved bit 11"):
        decode_frame(bytes(raw))
    with pytest.raises(FrameTooLargeError, match="11-bit"):
        encode_datagrams([Datagram.device(Command.BRD, 0, 0, 2048)])


@pytest.mark.parametrize(
    "field, value",
    [("command", 256), ("command", -1), ("index", 256), ("address", 1 << 32), ("irq", 0x10000),
     ("wkc", 0x10000), ("wkc", -1)],
)
def test_fields_out_of_range_are_refused_not_cut(field: str, value: int) -> None:
    d = Datagram.device(Command.BRD, 0, 0, 2)
    setattr(d, field, value)
    with pytest.raises(FrameError, match="does not fit its width"):
        encode_frame([d])


def test_address_views() -> None:
    d = Datagram.positional(Command.APRD, 2, 0x0130, 2)
    assert d.adp == 0xFFFE and d.ado == 0x0130
    lrw = Datagram.logical(Command.LRW, 0x00014711, 2)
    assert lrw.logical_address == 0x00014711 and lrw.adp == 0x4711 and lrw.ado == 0x0001


def test_frame_builder_refuses_overflow() -> None:
    builder = FrameBuilder()
    builder.add(Datagram.logical(Command.LRW, 0, MAX_DATA))
    with pytest.raises(FrameTooLargeError):
        builder.add(Datagram.device(Command.BRD, 0, 0, 1))
    with pytest.raises(FrameTooLargeError):
        encode_frame([Datagram.logical(Command.LRW, 0, MAX_DATA + 1)])


def test_mailbox_frame_type() -> None:
    frame = decode_frame(encode_mailbox_frame(b"\x0a\x00" + bytes(10)))
    assert frame.frame_type == 5 and frame.mailbox is not None and len(frame.mailbox) == 12


def test_returned_mac_sets_locally_administered_bit() -> None:
    assert returned_source_mac(b"\x10\x10\x10\x10\x10\x10")[0] == 0x12


@pytest.mark.parametrize(
    "raw, fragment",
    [
        (b"\xff" * 10, "shorter than its 14-byte header"),
        (b"\xff" * 12 + b"\x08\x00" + bytes(46), "not EtherCAT"),
        (b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1000 | 100) + bytes(20), "says 100 bytes"),
        (b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1800 | 14) + bytes(14), "reserved bit"),
        (b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1000 | 14)
         + bytes([7, 0, 0, 0, 0, 0, 40, 0, 0, 0]) + bytes(4), "claims 40 data bytes"),
        (b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1000 | 14)
         + bytes([7, 0, 0, 0, 0, 0, 2, 0x80, 0, 0]) + bytes(4), "another follows"),
        (b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0xE000 | 4) + bytes(4), "unknown EtherCAT frame type"),
    ],
)
def test_malformed_frames_raise_typed_errors(raw: bytes, fragment: str) -> None:
    with pytest.raises(FrameError, match=fragment):
        decode_frame(raw)


def test_not_ethercat_is_a_frame_error_subclass() -> None:
    with pytest.raises(NotEtherCATError):
        decode_frame(b"\xff" * 12 + b"\x08\x00" + bytes(46))


@given(st.binary(max_size=200))
def test_random_bytes_only_raise_frame_error(raw: bytes) -> None:
    with contextlib.suppress(FrameError):
        decode_frame(raw)


@settings(max_examples=500)
@given(st.sampled_from([b"\xff" * 12 + b"\x88\xa4", b"\xff" * 12 + b"\x81\x00\x00\x01\x88\xa4"]),
       # Mostly type-1 headers with small lengths, so the datagram parser is reached.
       st.one_of(st.integers(0, 0xFFFF), st.integers(0, 130).map(lambda n: 0x1000 | n)),
       st.binary(max_size=120), st.booleans())
def test_random_ethercat_bodies_only_raise_frame_error(
        prefix: bytes, header: int, body: bytes, strict: bool) -> None:
    # Past the EtherType, so the EtherCAT header and datagram parsers really get the bytes.
    raw = prefix + struct.pack("<H", header) + body
    try:
        frame = decode_frame(raw, strict=strict)
    except FrameError:
        return
    length = header & 0x07FF
    assert not header & 0x0800 and 2 + length <= len(raw) - len(prefix)
    if frame.frame_type == 1:
        assert sum(d.size for d in frame.datagrams) <= length
        assert not strict or sum(d.size for d in frame.datagrams) == length


@given(st.lists(datagram_st, min_size=1, max_size=4), st.integers(0, 400), st.integers(0, 255))
def test_mutated_frames_only_raise_frame_error(dgrams: list[Datagram], pos: int, value: int) -> None:
    raw = bytearray(encode_frame(dgrams))
    raw[pos % len(raw)] = value
    for cut in (len(raw), pos % len(raw)):
        with contextlib.suppress(FrameError):
            decode_frame(bytes(raw[:cut]))


def test_non_strict_decode_tolerates_trailing_byte_inside_length() -> None:
    # TwinCAT declares an EtherCAT length one byte longer than its datagrams.
    body = bytes([7, 0, 0, 0, 0, 0, 2, 0, 0, 0]) + bytes(4) + b"\x00"
    raw = b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1000 | len(body)) + body + bytes(40)
    with pytest.raises(FrameError, match="after the last datagram"):
        decode_frame(raw)
    assert len(decode_frame(raw, strict=False).datagrams) == 1
    assert decode_frame(raw, strict=False).trailing == 1
    assert decode_frame(encode_frame([Datagram.device(Command.BRD, 0, 0, 2)]),
                        strict=False).trailing == 0
