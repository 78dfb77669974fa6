"""FoE, EoE and SoE codecs: byte vectors, round trips, fragmenters and reassemblers."""

from __future__ import annotations

from ipaddress import IPv4Address

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.eoe import (
    EoeFragment,
    EoeFrameType,
    EoeGetAddressFilterRequest,
    EoeGetAddressFilterResponse,
    EoeGetIpRequest,
    EoeGetIpResponse,
    EoeIpParameters,
    EoeReassembler,
    EoeResult,
    EoeSetAddressFilterRequest,
    EoeSetAddressFilterResponse,
    EoeSetIpRequest,
    EoeSetIpResponse,
    EoeTimestampResponse,
    decode_eoe,
    eoe_fragment,
)
from pyethercat.wire.mailbox.foe import (
    FoeAck,
    FoeBusy,
    FoeData,
    FoeError,
    FoeErrorCode,
    FoeReadRequest,
    FoeWriteRequest,
    decode_foe,
    foe_error_name,
    foe_packet_matches,
    foe_split,
)
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox
from pyethercat.wire.mailbox.soe import (
    SoeElement,
    SoeMessage,
    SoeOpCode,
    SoeReassembler,
    decode_soe,
    format_idn,
    parse_idn,
    soe_error_name,
    soe_write_fragments,
)

h = bytes.fromhex
text = st.text(max_size=30).filter(lambda s: "\ufffd" not in s)

# --- FoE ------------------------------------------------------------------------


def test_foe_vectors() -> None:
    assert FoeWriteRequest("fw.bin", 0x12345678).encode() == h("02 00 78563412") + b"fw.bin"
    assert FoeReadRequest("a").encode() == h("01 00 00000000 61")
    assert FoeData(1, b"xy").encode() == h("03 00 01000000 7879")
    assert FoeAck(0).encode() == h("04 00 00000000")
    assert FoeError(FoeErrorCode.NOT_FOUND, "nope").encode() == h("05 00 01800000") + b"nope"
    assert FoeBusy(3, 10).encode() == h("06 00 0300 0A00")
    frame = encode_mailbox(MailboxType.FOE, FoeAck(7).encode(), counter=3, size=32)
    assert decode_message(frame)[1] == FoeAck(7)
    assert foe_error_name(0x8005) == "packet number wrong"
    assert foe_packet_matches(0x10001, 1)


def test_foe_split() -> None:
    packets = foe_split(b"x" * 52, mailbox_size=32)  # 20 bytes per packet
    assert [len(p.data) for p in packets] == [20, 20, 12]
    assert [p.packet for p in packets] == [1, 2, 3]
    exact = foe_split(b"x" * 40, mailbox_size=32)
    assert [len(p.data) for p in exact] == [20, 20, 0]
    assert foe_split(b"", 32) == [FoeData(1, b"")]


foe_messages = st.one_of(
    st.builds(FoeReadRequest, text, st.integers(0, 0xFFFFFFFF)),
    st.builds(FoeWriteRequest, text, st.integers(0, 0xFFFFFFFF)),
    st.builds(FoeData, st.integers(0, 0xFFFFFFFF), st.binary(max_size=50)),
    st.builds(FoeAck, st.integers(0, 0xFFFFFFFF)),
    st.builds(FoeError, st.integers(0, 0xFFFFFFFF), text),
    st.builds(FoeBusy, st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), text),
)


@given(foe_messages)
def test_foe_round_trip(msg: object) -> None:
    assert decode_foe(msg.encode()) == msg  # type: ignore[attr-defined]


# --- EoE ------------------------------------------------------------------------

PARAMS = EoeIpParameters(
    mac=h("020000000001"),
    ip=IPv4Address("192.168.1.10"),
    subnet=IPv4Address("255.255.255.0"),
    gateway=IPv4Address("192.168.1.1"),
    dns_server=None,
    dns_name="drive1",
)


def test_set_ip_fixed_layout() -> None:
    raw = EoeSetIpRequest(PARAMS).encode()
    assert raw[:4] == h("0200 0000")
    body = raw[4:]
    assert len(body) == 58
    assert body[:4] == h("2F000000")  # MAC, IP, subnet, gateway, DNS name
    assert body[4:10] == h("020000000001")
    assert body[10:14] == h("0A01A8C0")  # a little-endian word, as IgH/SOEM/Wireshark
    assert body[14:18] == h("00FFFFFF") and body[18:22] == h("0101A8C0")
    assert body[22:26] == bytes(4)  # absent DNS server still reserved
    assert body[26:58] == b"drive1".ljust(32, b"\0")
    assert decode_eoe(raw) == EoeSetIpRequest(PARAMS)


def test_set_ip_packed_layout_soem() -> None:
    params = EoeIpParameters(ip=IPv4Address("10.0.0.2"))
    raw = EoeSetIpRequest(params, packed=True).encode()
    assert raw == h("0200 0000 02000000 0200000A")
    assert decode_eoe(raw) == EoeSetIpRequest(params, packed=True)
    with pytest.raises(MailboxError):
        decode_eoe(h("0200 0000 03000000 0200000A"))  # MAC flagged but missing


def test_eoe_responses() -> None:
    raw = EoeSetIpResponse(EoeResult.NO_IP_SUPPORT).encode()
    assert raw == h("0300 0102")
    msg = decode_eoe(raw)
    assert isinstance(msg, EoeSetIpResponse) and msg.result_name == "no IP support"


def test_fragment_header_bits() -> None:
    frag = EoeFragment(
        b"ab",
        fragment_number=2,
        offset=5,
        frame_number=9,
        last=True,
        port=1,
        timestamp=0x01020304,
        time_requested=True,
    )
    raw = frag.encode()
    word1 = 0x0000 | (1 << 4) | 0x0100 | 0x0200 | 0x0400
    word2 = 2 | (5 << 6) | (9 << 12)
    assert raw == word1.to_bytes(2, "little") + word2.to_bytes(2, "little") + b"ab" + h("04030201")
    assert decode_eoe(raw) == frag


def test_fragmenter_sizes_and_offsets() -> None:
    frame = bytes(i & 0xFF for i in range(1514))
    frags = eoe_fragment(frame, mailbox_size=128, frame_number=3)
    # (128 - 10) // 32 * 32 = 96 bytes per fragment except the last
    assert all(len(f.data) == 96 for f in frags[:-1])
    assert frags[0].offset == (1514 + 31) // 32 and frags[0].complete_size == 1536
    assert [f.byte_offset for f in frags[1:]] == [96 * i for i in range(1, len(frags))]
    assert [f.fragment_number for f in frags] == list(range(len(frags)))
    assert all(f.frame_number == 3 for f in frags) and frags[-1].last
    assert not any(f.last for f in frags[:-1])
    for f in frags:
        assert len(encode_mailbox(MailboxType.EOE, f.encode())) <= 128
    r = EoeReassembler()
    out = [r.feed(decode_eoe(f.encode())) for f in frags]  # type: ignore[arg-type]
    assert out[-1] == frame and out[:-1] == [None] * (len(frags) - 1)


def test_reassembler_errors() -> None:
    frame = bytes(300)
    frags = eoe_fragment(frame, 64, frame_number=1)
    r = EoeReassembler()
    with pytest.raises(MailboxError, match="without the first fragment"):
        r.feed(frags[1])
    r.feed(frags[0])
    with pytest.raises(MailboxError, match="expected"):
        r.feed(frags[2])
    assert not r.in_progress
    r.feed(frags[0])
    other = eoe_fragment(frame, 64, frame_number=2)
    with pytest.raises(MailboxError, match="frame number"):
        r.feed(other[1])
    r.feed(frags[0])
    r.feed(frags[0])  # restart drops the unfinished frame
    assert r.dropped == 1
    bad = EoeFragment(frags[1].data, 1, frags[1].offset + 1, 1, False)
    with pytest.raises(MailboxError, match="offset"):
        r.feed(bad)
    too_big = EoeFragment(bytes(40), 0, 1, 0, True)
    with pytest.raises(MailboxError, match="exceed"):
        r.feed(too_big)


def test_fragmenter_limits() -> None:
    with pytest.raises(MailboxError):
        eoe_fragment(bytes(100), mailbox_size=40)
    with pytest.raises(MailboxError):
        eoe_fragment(bytes(2100), mailbox_size=1024)


@given(
    st.binary(min_size=1, max_size=1514),
    st.integers(42, 600),
    st.integers(0, 15),
    st.none() | st.integers(0, 0xFFFFFFFF),
)
def test_fragment_reassemble_property(
    frame: bytes, mailbox_size: int, number: int, ts: int | None
) -> None:
    try:
        frags = eoe_fragment(frame, mailbox_size, number, timestamp=ts)
    except MailboxError:
        return  # too many fragments for a tiny mailbox
    r = EoeReassembler()
    result = None
    for f in frags:
        encoded = encode_mailbox(MailboxType.EOE, f.encode())
        assert len(encoded) <= mailbox_size
        msg = decode_message(encoded)[1]
        assert msg == f
        result = r.feed(f)
    assert result == frame and r.timestamp == ts


ip = st.none() | st.integers(0, 0xFFFFFFFF).map(IPv4Address)
params = st.builds(
    EoeIpParameters,
    st.none() | st.binary(min_size=6, max_size=6),
    ip,
    ip,
    ip,
    ip,
    st.none() | st.text(alphabet="abcdefghij.-0123", max_size=32),
)
eoe_messages = st.one_of(
    st.builds(
        EoeFragment,
        st.binary(max_size=60),
        st.integers(0, 63),
        st.integers(0, 63),
        st.integers(0, 15),
        st.just(False),
        st.integers(0, 15),
        st.none(),
        st.booleans(),
    ),
    st.builds(
        EoeFragment,
        st.binary(max_size=60),
        st.integers(0, 63),
        st.integers(0, 63),
        st.integers(0, 15),
        st.just(True),
        st.integers(0, 15),
        st.none() | st.integers(0, 0xFFFFFFFF),
        st.booleans(),
    ),
    st.builds(EoeSetIpRequest, params, st.integers(0, 15)),
    st.builds(EoeGetIpResponse, params, st.integers(0, 0xFFFF), st.integers(0, 15)),
    st.builds(EoeSetIpResponse, st.integers(0, 0xFFFF), st.integers(0, 15)),
    st.builds(EoeSetAddressFilterResponse, st.integers(0, 0xFFFF), st.integers(0, 15)),
    st.builds(EoeGetIpRequest, st.integers(0, 15)),
    st.builds(EoeGetAddressFilterRequest, st.integers(0, 15)),
    st.builds(
        EoeSetAddressFilterRequest,
        st.binary(max_size=40),
        st.integers(0, 15),
        st.integers(0, 0xFFFF),
    ),
    st.builds(
        EoeGetAddressFilterResponse,
        st.binary(max_size=40),
        st.integers(0, 15),
        st.integers(0, 0xFFFF),
    ),
    st.builds(
        EoeTimestampResponse, st.binary(max_size=8), st.integers(0, 15), st.integers(0, 0xFFFF)
    ),
)


@given(eoe_messages)
def test_eoe_round_trip(msg: object) -> None:
    assert decode_eoe(msg.encode()) == msg  # type: ignore[attr-defined]


def test_frame_type_aliases() -> None:
    assert EoeFrameType.INIT_REQUEST is EoeFrameType.SET_IP_REQUEST


# --- SoE ------------------------------------------------------------------------


def test_idn_encoding() -> None:
    assert parse_idn("S-0-0024") == 0x0018
    assert parse_idn("S-0-0016") == 0x0010
    assert parse_idn("P-0-0001") == 0x8001
    assert parse_idn("p-7-4095") == 0xFFFF
    assert parse_idn("0x0018") == 0x18
    assert format_idn(0x0018) == "S-0-0024"
    assert format_idn(0x8001) == "P-0-0001"
    with pytest.raises(MailboxError):
        parse_idn("S-8-0001")
    with pytest.raises(MailboxError):
        parse_idn("S-0-5000")


@given(st.integers(0, 0xFFFF))
def test_idn_round_trip(idn: int) -> None:
    assert parse_idn(format_idn(idn)) == idn


def test_soe_vectors() -> None:
    req = SoeMessage(SoeOpCode.READ_REQUEST, parse_idn("S-0-0024"), SoeElement.VALUE, drive=1)
    assert req.encode() == h("21 40 1800")
    err = SoeMessage(SoeOpCode.READ_RESPONSE, 0x18, SoeElement.VALUE, error_code=0x1001)
    assert err.encode() == h("12 40 1800 0110")
    msg = decode_soe(err.encode())
    assert msg == err and msg.error_name == "no IDN"
    assert soe_error_name(0x800C) == "no element addressed"
    with pytest.raises(MailboxError):
        decode_soe(h("12 40 1800"))  # error bit, no code


def test_soe_fragments() -> None:
    data = bytes(range(100))
    frags = soe_write_fragments(0x8001, data, mailbox_size=30)  # 20 bytes each
    assert len(frags) == 5
    assert [f.incomplete for f in frags] == [True] * 4 + [False]
    assert [f.idn for f in frags] == [4, 3, 2, 1, 0x8001]
    r = SoeReassembler()
    out = [r.feed(decode_soe(f.encode())) for f in frags]
    assert out[-1] == SoeMessage(SoeOpCode.WRITE_REQUEST, 0x8001, SoeElement.VALUE, data=data)
    r.feed(frags[0])
    with pytest.raises(MailboxError):
        r.feed(frags[0])


soe_messages = st.builds(
    SoeMessage,
    st.integers(1, 7),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFF),
    st.integers(0, 7),
    st.booleans(),
    st.none() | st.integers(0, 0xFFFF),
    st.binary(max_size=30),
)


@given(soe_messages)
def test_soe_round_trip(msg: SoeMessage) -> None:
    assert decode_soe(msg.encode()) == msg


def test_dns_name_any_bytes_decode() -> None:
    body = bytes.fromhex("20000000") + bytes(22) + bytes(range(0x80, 0xA0))
    msg = decode_eoe(bytes.fromhex("0200 0000") + body)
    assert isinstance(msg, EoeSetIpRequest)
    assert msg.encode()[4:] == body


def test_fragment_before_a_timestamp_that_does_not_fit_carries_whole_blocks() -> None:
    # 62 bytes fit a 74-byte mailbox (64 bytes of fragment data), but not with the 4-byte
    # timestamp: the first fragment is not the last, so it carries whole 32-byte blocks
    frags = eoe_fragment(bytes(range(62)), 74, 3, timestamp=7)
    assert [len(f.data) for f in frags] == [32, 30] and frags[-1].timestamp == 7
    r = EoeReassembler()
    assert [r.feed(f) for f in frags] == [None, bytes(range(62))] and r.timestamp == 7
    assert [len(f.data) for f in eoe_fragment(bytes(100), 74, timestamp=1)] == [64, 36]
    # 32-byte fragments (a 42-byte mailbox): a rest of 29 bytes never fits beside the time
    with pytest.raises(MailboxError, match="do not fit"):
        eoe_fragment(bytes(29), 42, timestamp=1)
    assert [len(f.data) for f in eoe_fragment(bytes(29), 42)] == [29]
