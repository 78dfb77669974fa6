"""Datagram and frame codec: round trips, the facts-sheet example, malformed input."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
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


@given(st.lists(datagram_st, min_size=1, max_size=8))
def test_frame_and_udp_round_trip(dgrams: list[Datagram]) -> None:
    for raw, decode in ((encode_frame(dgrams), decode_frame),
                        (encode_udp_payload(dgrams), decode_udp_payload)):
        frame = decode(raw)
        assert [d.data for d in frame.datagrams] == [bytes(d.data) for d in dgrams]
        assert [d.address for d in frame.datagrams] == [d.address for d in dgrams]


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
    try:
        decode_frame(raw)
    except FrameError:
        pass


@given(st.lists(datagram_st, min_size=1, max_size=4), st.integers(0, 400), st.integers(0, 255))
def test_mutated_frames_only_raise_frame_error(dgrams: list[Datagram], pos: int, value: int) -> None:
    raw = bytearray(encode_frame(dgrams))
    raw[pos % len(raw)] = value
    for cut in (len(raw), pos % len(raw)):
        try:
            decode_frame(bytes(raw[:cut]))
        except FrameError:
            pass


def test_non_strict_decode_tolerates_trailing_byte_inside_length() -> None:
    # TwinCAT declares an EtherCAT length one byte longer than its datagrams.
    body = bytes([7, 0, 0, 0, 0, 0, 2, 0, 0, 0]) + bytes(4) + b"\x00"
    raw = b"\xff" * 12 + b"\x88\xa4" + struct.pack("<H", 0x1000 | len(body)) + body + bytes(40)
    with pytest.raises(FrameError, match="after the last datagram"):
        decode_frame(raw)
    assert len(decode_frame(raw, strict=False).datagrams) == 1
