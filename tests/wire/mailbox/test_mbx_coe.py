"""CoE codecs: SDO frames, aborts, SDO information, emergency (byte vectors + round trips)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import (
    SDO_ABORT_CODES,
    CoeHeader,
    CoePdo,
    CoeService,
    Emergency,
    ObjectAccess,
    ObjectCode,
    OdListType,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoDownloadSegmentRequest,
    SdoDownloadSegmentResponse,
    SdoInfoError,
    SdoInfoFragment,
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoGetObjectDescriptionRequest,
    SdoInfoGetObjectDescriptionResponse,
    SdoInfoGetOdListRequest,
    SdoInfoGetOdListResponse,
    SdoInfoReassembler,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
    ValueInfo,
    decode_coe,
    emergency_error_name,
    encode_sdo_info_fragments,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# --- facts sheet 7.11 constructed example ---------------------------------------


def test_constructed_example_request() -> None:
    req = SdoInitiateUploadRequest(0x1018, 1)
    frame = encode_mailbox(MailboxType.COE, req.encode(), counter=1)
    assert frame == h("0A00 0000 00 13 0020 40 18 10 01 00000000")
    header, msg = decode_message(frame)
    assert header.counter == 1 and msg == req


def test_constructed_example_response() -> None:
    frame = h("0A00 0000 00 13 0030 43 18 10 01 9A 02 00 00")
    _, msg = decode_message(frame)
    assert msg == SdoInitiateUploadResponse(0x1018, 1, h("9A020000"))
    assert isinstance(msg, SdoInitiateUploadResponse)
    assert msg.expedited and msg.total_size == 4
    assert msg.encode() == frame[6:]


# --- command specifier byte values (facts 7.3) ----------------------------------


@pytest.mark.parametrize(("size", "cs"), [(4, 0x23), (3, 0x27), (2, 0x2B), (1, 0x2F)])
def test_expedited_download_command_bytes(size: int, cs: int) -> None:
    data = bytes(range(1, size + 1))
    raw = SdoInitiateDownloadRequest(0x6040, 0, data).encode()
    assert raw == h("0020") + bytes([cs]) + h("4060 00") + data.ljust(4, b"\0")
    assert decode_coe(raw) == SdoInitiateDownloadRequest(0x6040, 0, data)


@pytest.mark.parametrize(("size", "cs"), [(4, 0x43), (3, 0x47), (2, 0x4B), (1, 0x4F)])
def test_expedited_upload_response_command_bytes(size: int, cs: int) -> None:
    data = b"\xaa" * size
    raw = SdoInitiateUploadResponse(0x1000, 0, data).encode()
    assert raw[2] == cs and raw[:2] == h("0030")
    assert decode_coe(raw) == SdoInitiateUploadResponse(0x1000, 0, data)


def test_normal_download_and_complete_access() -> None:
    req = SdoInitiateDownloadRequest(
        0x1C12, 0, b"\x01\x00\x00\x16", expedited=False, complete_access=True
    )
    raw = req.encode()
    assert raw == h("0020 31 121C 00 04000000 01000016")
    assert decode_coe(raw) == req
    normal = SdoInitiateDownloadRequest(0x2000, 1, b"abc", expedited=False, complete_size=100)
    assert normal.encode()[2] == 0x21
    assert decode_coe(normal.encode()) == normal


def test_other_command_bytes() -> None:
    assert SdoInitiateUploadRequest(0x1018, 0, True).encode()[2] == 0x50
    assert SdoUploadSegmentRequest(False).encode() == h("0020 60 00000000000000")
    assert SdoUploadSegmentRequest(True).encode()[2] == 0x70
    assert SdoInitiateDownloadResponse(0x1, 0).encode()[2] == 0x60
    assert SdoInitiateDownloadResponse(0x1, 0, True).encode()[2] == 0x70
    assert SdoDownloadSegmentResponse(False).encode() == h("0030 20 00000000000000")
    assert SdoDownloadSegmentResponse(True).encode()[2] == 0x30
    assert SdoInitiateUploadResponse(0x1008, 0, b"x" * 20, expedited=False).encode()[2] == 0x41


def test_segment_encoding_rules() -> None:
    # fewer than 7 bytes: padded to 7, n = unused count, mailbox length 10
    seg = SdoDownloadSegmentRequest(toggle=True, last=True, data=b"ab")
    raw = seg.encode()
    assert len(raw) == 10
    assert raw[2] == 0x10 | (5 << 1) | 1
    assert decode_coe(raw) == seg
    # 7 or more bytes: n = 0, mailbox length 3 + bytes
    long = SdoUploadSegmentResponse(toggle=False, last=False, data=bytes(range(20)))
    raw = long.encode()
    assert len(raw) == 3 + 20 and raw[2] == 0x00
    assert decode_coe(raw) == long
    seven = SdoUploadSegmentResponse(False, True, b"1234567")
    assert len(seven.encode()) == 10 and seven.encode()[2] == 0x01
    assert decode_coe(seven.encode()) == seven


def test_abort() -> None:
    abort = SdoAbortTransfer(0x6000, 2, SdoAbortCode.NO_OBJECT)
    raw = abort.encode()
    assert raw == h("0020 80 0060 02 00000206")
    msg = decode_coe(raw)
    assert msg == abort
    err = abort.to_error()
    assert isinstance(err, SdoAbort) and err.code == 0x06020000
    assert "does not exist" in str(err) and "0x6000:02" in str(err)
    # an abort in service 3 also decodes (SOEM accepts aborts on any SDO service)
    resp = decode_coe(h("0030 80 0060 02 11000906"))
    assert isinstance(resp, SdoAbortTransfer)
    assert resp.service is CoeService.SDO_RESPONSE and resp.name == "subindex does not exist"


def test_abort_table() -> None:
    for code in (
        0x05030000,
        0x05040000,
        0x05040001,
        0x05040002,
        0x05040003,
        0x05040004,
        0x05040005,
        0x06010000,
        0x06010001,
        0x06010002,
        0x06010003,
        0x06010004,
        0x06010005,
        0x06010006,
        0x06020000,
        0x06040041,
        0x06040042,
        0x06040043,
        0x06040047,
        0x06060000,
        0x06070010,
        0x06070012,
        0x06070013,
        0x06090011,
        0x06090030,
        0x06090031,
        0x06090032,
        0x06090033,
        0x06090036,
        0x060A0023,
        0x08000000,
        0x08000020,
        0x08000021,
        0x08000022,
        0x08000023,
        0x08000024,
    ):
        assert code in SDO_ABORT_CODES
    assert {int(c) for c in SdoAbortCode} == set(SDO_ABORT_CODES)
    assert sdo_abort_name(0x12345678) == "unknown SDO abort code 0x12345678"


def test_block_transfer_commands_rejected() -> None:
    with pytest.raises(MailboxError, match="command specifier"):
        decode_coe(h("0020 C0 0010 00 00000000"))
    with pytest.raises(MailboxError, match="too short|needs"):
        decode_coe(h("0020 40 0010"))
    with pytest.raises(MailboxError, match="service"):
        decode_coe(h("00F0 00000000 00000000"))


def test_coe_header() -> None:
    assert CoeHeader(CoeService.TXPDO, 0x1FF).encode() == h("FF41")
    assert CoeHeader.decode(h("FF41")) == CoeHeader(CoeService.TXPDO, 0x1FF)
    pdo = CoePdo(CoeService.RXPDO, 3, b"\x01\x02")
    assert decode_coe(pdo.encode()) == pdo


def test_emergency() -> None:
    emcy = Emergency(0x8130, 0x11, b"\x01\x02\x03\x04\x05")
    raw = emcy.encode()
    assert raw == h("0010 3081 11 0102030405")
    assert decode_coe(raw) == emcy
    assert emcy.name == "life guard or heartbeat error"
    assert emergency_error_name(0x2311) == "current, device output side"
    assert emergency_error_name(0x5432) == "device hardware"
    assert emergency_error_name(0xFF12) == "device specific"
    with pytest.raises(MailboxError):
        decode_coe(h("0010 3081 11 01"))


# --- SDO information ---------------------------------------------------------------


def test_od_list_request_bytes() -> None:
    raw = SdoInfoGetOdListRequest(OdListType.ALL).encode()
    assert raw == h("0080 01 00 0000 0100")
    assert decode_coe(raw) == SdoInfoGetOdListRequest(1)


def test_object_description_bytes() -> None:
    resp = SdoInfoGetObjectDescriptionResponse(0x1018, 0x0023, 4, ObjectCode.RECORD, "Identity")
    raw = resp.encode()
    assert raw == h("0080 04 00 0000 1810 2300 04 09") + b"Identity"
    assert decode_coe(raw) == resp
    assert decode_coe(
        SdoInfoGetObjectDescriptionRequest(0x1018).encode()
    ) == SdoInfoGetObjectDescriptionRequest(0x1018)


def test_entry_description_optional_fields() -> None:
    vi = ValueInfo.UNIT_TYPE | ValueInfo.DEFAULT_VALUE | ValueInfo.MAXIMUM_VALUE
    resp = SdoInfoGetEntryDescriptionResponse(
        0x6040,
        0,
        int(vi),
        0x0006,
        16,
        int(ObjectAccess.READ_WRITE | ObjectAccess.RXPDO_MAPPABLE),
        "Controlword",
        unit_type=0,
        default_value=b"\x00\x00",
        maximum_value=b"\xff\xff",
    )
    raw = resp.encode()
    assert raw[6:16] == h("4060 00 58 0600 1000 7F00")
    assert raw[16:18] == h("0000") and raw[18:22] == h("0000 FFFF")
    assert raw[22:] == b"Controlword"
    assert decode_coe(raw) == resp
    with pytest.raises(MailboxError):
        SdoInfoGetEntryDescriptionResponse(1, 0, 0x10, 7, 32, 7)  # default missing
    req = SdoInfoGetEntryDescriptionRequest(0x6040, 0, 0x78)
    assert decode_coe(req.encode()) == req


def test_info_error() -> None:
    raw = SdoInfoError(0x06020000).encode()
    assert raw == h("0080 07 00 0000 00000206")
    msg = decode_coe(raw)
    assert isinstance(msg, SdoInfoError)
    assert msg.to_error(0x1234).code == 0x06020000


def test_od_list_fragmentation_and_reassembly() -> None:
    indices = tuple(range(0x1000, 0x1000 + 100))
    resp = SdoInfoGetOdListResponse(OdListType.ALL, indices)
    frames = encode_sdo_info_fragments(resp, mailbox_size=48)
    assert len(frames) > 1
    for i, frame in enumerate(frames):
        assert len(frame) <= 48 - 6
        frag = SdoInfoFragment.from_payload(frame)
        assert frag.incomplete == (i < len(frames) - 1)
        assert frag.fragments_left == len(frames) - 1 - i
    first = decode_coe(frames[0])
    assert isinstance(first, SdoInfoFragment) and first.incomplete
    r = SdoInfoReassembler()
    out = [r.feed(f) for f in frames]
    assert out[:-1] == [None] * (len(frames) - 1)
    assert out[-1] == resp
    assert not r.in_progress


def test_reassembler_rejects_gap_and_accepts_error() -> None:
    resp = SdoInfoGetOdListResponse(1, tuple(range(200)))
    frames = encode_sdo_info_fragments(resp, mailbox_size=64)
    r = SdoInfoReassembler()
    assert r.feed(frames[0]) is None
    with pytest.raises(MailboxError, match="fragments-left"):
        r.feed(frames[2])
    assert not r.in_progress
    assert r.feed(frames[0]) is None
    assert r.feed(SdoInfoError(0x08000000).encode()) == SdoInfoError(0x08000000)


def test_single_frame_info_reassembles() -> None:
    msg = SdoInfoGetObjectDescriptionResponse(0x6000, 7, 0, 7, "x" * 10)
    assert SdoInfoReassembler().feed(msg.encode()) == msg


# --- properties -----------------------------------------------------------------------

u16 = st.integers(0, 0xFFFF)
u8 = st.integers(0, 0xFF)
text = st.text(max_size=40).filter(lambda s: "\ufffd" not in s)


@st.composite
def initiate_with_data(draw: st.DrawFn, cls: type) -> object:
    index, sub, ca = draw(u16), draw(u8), draw(st.booleans())
    kind = draw(st.sampled_from(["exp", "exp_nosize", "normal", "normal_nosize"]))
    if kind == "exp":
        return cls(index, sub, draw(st.binary(min_size=1, max_size=4)), True, True, None, ca)
    if kind == "exp_nosize":
        return cls(index, sub, draw(st.binary(min_size=4, max_size=4)), True, False, None, ca)
    data = draw(st.binary(max_size=64))
    if kind == "normal_nosize":
        return cls(index, sub, data, False, False, None, ca)
    extra = draw(st.integers(0, 0xFFFFFFFF - len(data)))
    return cls(index, sub, data, False, True, len(data) + extra, ca)


def _value_info_entry(draw: st.DrawFn) -> SdoInfoGetEntryDescriptionResponse:
    vi = draw(u8)
    bitlen = draw(st.integers(0, 80))
    size = (bitlen + 7) // 8

    def opt(bit: int) -> bytes | None:
        return draw(st.binary(min_size=size, max_size=size)) if vi & bit else None

    return SdoInfoGetEntryDescriptionResponse(
        draw(u16),
        draw(u8),
        vi,
        draw(u16),
        bitlen,
        draw(u16),
        draw(text),
        draw(u16) if vi & ValueInfo.UNIT_TYPE else None,
        opt(ValueInfo.DEFAULT_VALUE),
        opt(ValueInfo.MINIMUM_VALUE),
        opt(ValueInfo.MAXIMUM_VALUE),
    )


coe_messages = st.one_of(
    initiate_with_data(SdoInitiateDownloadRequest),
    initiate_with_data(SdoInitiateUploadResponse),
    st.builds(SdoInitiateUploadRequest, u16, u8, st.booleans()),
    st.builds(SdoInitiateDownloadResponse, u16, u8, st.booleans()),
    st.builds(SdoDownloadSegmentRequest, st.booleans(), st.booleans(), st.binary(max_size=50)),
    st.builds(SdoUploadSegmentResponse, st.booleans(), st.booleans(), st.binary(max_size=50)),
    st.builds(SdoUploadSegmentRequest, st.booleans()),
    st.builds(SdoDownloadSegmentResponse, st.booleans()),
    st.builds(
        SdoAbortTransfer,
        u16,
        u8,
        st.integers(0, 0xFFFFFFFF),
        st.sampled_from([CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE]),
    ),
    st.builds(Emergency, u16, u8, st.binary(min_size=5, max_size=5)),
    st.builds(
        CoePdo,
        st.sampled_from([CoeService(s) for s in (4, 5, 6, 7)]),
        st.integers(0, 0x1FF),
        st.binary(max_size=20),
    ),
    st.builds(SdoInfoGetOdListRequest, u16),
    st.builds(SdoInfoGetOdListResponse, u16, st.lists(u16, max_size=40).map(tuple)),
    st.builds(SdoInfoGetObjectDescriptionRequest, u16),
    st.builds(SdoInfoGetObjectDescriptionResponse, u16, u16, u8, u8, text),
    st.builds(SdoInfoGetEntryDescriptionRequest, u16, u8, u8),
    st.composite(lambda draw: _value_info_entry(draw))(),
    st.builds(SdoInfoError, st.integers(0, 0xFFFFFFFF)),
)


@given(coe_messages)
def test_coe_round_trip(msg: object) -> None:
    raw = msg.encode()  # type: ignore[attr-defined]
    assert decode_coe(raw) == msg


@given(
    st.one_of(
        st.builds(SdoInfoGetOdListResponse, u16, st.lists(u16, max_size=300).map(tuple)),
        st.builds(SdoInfoGetObjectDescriptionResponse, u16, u16, u8, u8, text),
        st.composite(lambda draw: _value_info_entry(draw))(),
    ),
    st.integers(20, 200),
)
def test_info_fragments_round_trip(msg: object, mailbox_size: int) -> None:
    r = SdoInfoReassembler()
    frames = encode_sdo_info_fragments(msg, mailbox_size)  # type: ignore[arg-type]
    results = [r.feed(f) for f in frames]
    assert results[-1] == msg
    assert all(x is None for x in results[:-1])


@given(st.binary(max_size=40))
def test_random_coe_only_typed_errors(raw: bytes) -> None:
    try:
        msg = decode_coe(raw)
    except MailboxError:
        return
    msg.encode()  # whatever decodes must encode again
