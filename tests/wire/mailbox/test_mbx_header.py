"""Mailbox header, error replies, counters, dispatch."""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import MailboxError, MailboxErrorReply
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.header import (
    MAILBOX_ERROR_NAMES,
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    decode_mailbox,
    decode_mailbox_error,
    encode_mailbox,
    encode_mailbox_error,
    is_repeated_counter,
    next_counter,
    pad_mailbox,
)

# Facts sheet 7.11: read 0x1018:01, counter 1.
REQUEST = bytes.fromhex("0A00 0000 00 13 0020 40 18 10 01 00000000")


def test_header_of_constructed_example() -> None:
    h = MailboxHeader.decode(REQUEST)
    assert h == MailboxHeader(length=10, type=MailboxType.COE, counter=1)
    assert h.encode() == REQUEST[:6]


def test_header_fields_bit_positions() -> None:
    h = MailboxHeader(
        length=0x1234, type=MailboxType.SOE, counter=7, address=0xBEEF, channel=0x3F, priority=3
    )
    assert h.encode() == bytes([0x34, 0x12, 0xEF, 0xBE, 0xFF, 0x75])


def test_mixed_case_aliases() -> None:
    assert MailboxType.CoE is MailboxType.COE
    assert MailboxType.VoE == 15


def test_unknown_type_decodes_as_int() -> None:
    h = MailboxHeader.decode(bytes([0, 0, 0, 0, 0, 0x19]))
    assert h.type == 9 and not isinstance(h.type, MailboxType)
    with pytest.raises(MailboxError):
        decode_message(h.encode())


def test_header_rejects_bad_fields() -> None:
    with pytest.raises(MailboxError):
        MailboxHeader(length=1, type=MailboxType.COE, counter=8)
    with pytest.raises(MailboxError):
        MailboxHeader.decode(b"\x00" * 5)


def test_encode_and_pad_to_sm_length() -> None:
    frame = encode_mailbox(MailboxType.COE, REQUEST[6:], counter=1, size=128)
    assert len(frame) == 128
    assert frame[:16] == REQUEST and frame[16:] == bytes(112)
    header, payload = decode_mailbox(frame)
    assert header.length == 10 and payload == REQUEST[6:]
    with pytest.raises(MailboxError):
        pad_mailbox(frame, 100)


def test_length_word_lies() -> None:
    with pytest.raises(MailboxError, match="exceeds"):
        decode_mailbox(bytes.fromhex("2000 0000 00 13") + bytes(10))


def test_error_reply() -> None:
    payload = encode_mailbox_error(MailboxErrorCode.UNSUPPORTED_PROTOCOL)
    assert payload == bytes([1, 0, 2, 0])
    frame = encode_mailbox(MailboxType.ERR, payload, counter=2)
    header, msg = decode_message(frame)
    assert header.type is MailboxType.ERR
    assert isinstance(msg, MailboxErrorReply)
    assert msg.code == 2 and "not supported" in msg.name
    err = decode_mailbox_error(bytes([1, 0, 0x42, 0]))
    assert "unknown" in err.name
    with pytest.raises(MailboxError):
        decode_mailbox_error(b"\x01\x00")


def test_error_table_complete() -> None:
    assert set(range(1, 9)) <= set(MAILBOX_ERROR_NAMES)


def test_counter() -> None:
    seq = [1]
    for _ in range(10):
        seq.append(next_counter(seq[-1]))
    assert seq == [1, 2, 3, 4, 5, 6, 7, 1, 2, 3, 4]
    assert next_counter(0) == 1
    assert 0 not in seq
    with pytest.raises(MailboxError):
        next_counter(8)
    assert is_repeated_counter(3, 3)
    assert not is_repeated_counter(0, 0)
    assert not is_repeated_counter(3, 4)


headers = st.builds(
    MailboxHeader,
    length=st.integers(0, 0xFFFF),
    type=st.sampled_from(list(MailboxType)) | st.integers(0, 15),
    counter=st.integers(0, 7),
    address=st.integers(0, 0xFFFF),
    channel=st.integers(0, 0x3F),
    priority=st.integers(0, 3),
    reserved=st.integers(0, 1),
)


@given(headers)
def test_header_round_trip(h: MailboxHeader) -> None:
    assert MailboxHeader.decode(h.encode()) == h


@given(st.binary(min_size=6, max_size=6))
def test_header_bytes_round_trip(raw: bytes) -> None:
    assert MailboxHeader.decode(raw).encode() == raw


@given(st.binary(max_size=64))
def test_random_mailbox_only_typed_errors(raw: bytes) -> None:
    with contextlib.suppress(MailboxError):
        decode_message(raw)
