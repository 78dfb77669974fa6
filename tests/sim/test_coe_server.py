"""CoE server of builtin:coe-io over a segment: real mailbox frames in SM0, replies from SM1."""

from __future__ import annotations

import struct

import pytest
from coehelp import MBX_SIZE, CoeSlave, coe_of

from pyethercat.errors import MailboxErrorReply
from pyethercat.sim.coe import coe_server
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import (
    CoeHeader,
    CoePdo,
    CoeService,
    Emergency,
    ObjectAccess,
    ObjectCode,
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
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
    ValueInfo,
)
from pyethercat.wire.mailbox.header import (
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
)


@pytest.fixture
def slave() -> CoeSlave:
    return CoeSlave()


def abort_of(slave: CoeSlave, msg: object) -> int:
    reply = slave.exchange(msg)  # type: ignore[arg-type]
    assert isinstance(reply, SdoAbortTransfer), reply
    return reply.code


def mailbox_error(slave: CoeSlave) -> int:
    header, msg = slave.fetch_message()
    assert header.type == MailboxType.ERR
    assert isinstance(msg, MailboxErrorReply)
    return msg.code


# --- expedited, normal, segmented ----------------------------------------------------


def test_expedited_upload_matches_facts_example(slave: CoeSlave) -> None:
    # facts 7.11: read 0x1018:01 expedited
    assert slave.send(bytes.fromhex("0020 4018100100000000")) == 1
    raw = slave.fetch()
    assert raw is not None
    assert raw[:2] == b"\x0a\x00" and raw[5] & 0x0F == MailboxType.COE
    assert raw[6:12] == bytes.fromhex("0030 43181001")
    assert raw[12:16] == struct.pack("<I", 0x00504543)


def test_identity_from_sii_and_strings(slave: CoeSlave) -> None:
    assert [struct.unpack("<I", slave.upload(0x1018, s))[0] for s in (1, 2, 3, 4)] == [
        0x00504543, 0x00050001, 0x00010000, 7]
    assert slave.upload(0x1008, 0) == b"PEC-COEIO CoE test IO"  # normal, one frame
    assert slave.upload(0x1C00, 0) == b"\x04"


def test_expedited_download_all_sizes(slave: CoeSlave) -> None:
    slave.download(0x8000, 4, b"\x02")
    slave.download(0x8000, 1, struct.pack("<H", 300))
    slave.download(0x8000, 2, struct.pack("<i", -7))
    assert slave.upload(0x8000, 4) == b"\x02"
    assert slave.upload(0x8000, 1) == struct.pack("<H", 300)
    assert slave.upload(0x8000, 2) == struct.pack("<i", -7)
    # a normal (non-expedited) transfer of a small value works too
    slave.download(0x8000, 1, struct.pack("<H", 301), expedited=False)
    assert slave.upload(0x8000, 1) == struct.pack("<H", 301)


def test_segmented_upload_of_4k_object(slave: CoeSlave) -> None:
    data = slave.upload(0x2000, 0)
    assert data == bytes(i & 0xFF for i in range(4096))


def test_segmented_download_of_4k_object_and_back(slave: CoeSlave) -> None:
    blob = bytes((i * 7 + 3) & 0xFF for i in range(4096))
    slave.download(0x2000, 0, blob)
    assert slave.upload(0x2000, 0) == blob
    # shorter content is allowed (variable length), longer than the capacity is not
    slave.download(0x2000, 0, b"short")
    assert slave.upload(0x2000, 0) == b"short"
    assert slave.abort_code(slave.download, 0x2000, 0, bytes(4097)) == SdoAbortCode.LENGTH_TOO_HIGH


def test_string_write_and_read(slave: CoeSlave) -> None:
    slave.download(0x8000, 6, b"axis X")
    assert slave.upload(0x8000, 6) == b"axis X"


def test_upload_segment_toggle_error_aborts(slave: CoeSlave) -> None:
    first = slave.exchange(SdoInitiateUploadRequest(0x2000, 0))
    assert isinstance(first, SdoInitiateUploadResponse) and first.total_size == 4096
    seg = slave.exchange(SdoUploadSegmentRequest(False))
    assert isinstance(seg, SdoUploadSegmentResponse) and not seg.last
    assert len(seg.data) == MBX_SIZE - 9
    assert abort_of(slave, SdoUploadSegmentRequest(False)) == SdoAbortCode.TOGGLE_BIT
    # the transfer is gone: another segment request is a protocol error
    assert abort_of(slave, SdoUploadSegmentRequest(True)) == SdoAbortCode.INVALID_COMMAND


def test_download_segment_toggle_error_aborts(slave: CoeSlave) -> None:
    first = SdoInitiateDownloadRequest(0x2000, 0, bytes(100), expedited=False, complete_size=300)
    assert isinstance(slave.exchange(first), SdoInitiateDownloadResponse)
    r = slave.exchange(SdoDownloadSegmentRequest(False, False, bytes(100)))
    assert isinstance(r, SdoDownloadSegmentResponse) and r.toggle is False
    assert abort_of(slave, SdoDownloadSegmentRequest(False, True, bytes(100))) == (
        SdoAbortCode.TOGGLE_BIT)
    assert slave.upload(0x2000, 0)[:4] == b"\x00\x01\x02\x03"  # nothing stored


def test_download_segment_too_much_data_aborts(slave: CoeSlave) -> None:
    first = SdoInitiateDownloadRequest(0x2000, 0, bytes(10), expedited=False, complete_size=20)
    assert isinstance(slave.exchange(first), SdoInitiateDownloadResponse)
    assert abort_of(slave, SdoDownloadSegmentRequest(False, True, bytes(20))) == (
        SdoAbortCode.LENGTH_TOO_HIGH)


def test_segment_without_transfer_and_unknown_command(slave: CoeSlave) -> None:
    assert abort_of(slave, SdoDownloadSegmentRequest(False, True, b"x")) == (
        SdoAbortCode.INVALID_COMMAND)
    # command specifier 6 (block download) is not supported
    slave.send(CoeHeader(CoeService.SDO_REQUEST).encode() + bytes([0xC0]) + struct.pack(
        "<HBI", 0x2000, 0, 0))
    reply = coe_of(slave.fetch() or b"")
    assert isinstance(reply, SdoAbortTransfer)
    assert (reply.code, reply.index) == (SdoAbortCode.INVALID_COMMAND, 0x2000)


def test_master_abort_ends_transfer_without_reply(slave: CoeSlave) -> None:
    assert isinstance(slave.exchange(SdoInitiateUploadRequest(0x2000, 0)),
                      SdoInitiateUploadResponse)
    slave.send(SdoAbortTransfer(0x2000, 0, SdoAbortCode.GENERAL_ERROR).encode())
    assert slave.fetch() is None
    assert abort_of(slave, SdoUploadSegmentRequest(False)) == SdoAbortCode.INVALID_COMMAND


# --- abort paths -----------------------------------------------------------------------


def test_abort_codes_of_access_rules(slave: CoeSlave) -> None:
    a = slave.abort_code
    assert a(slave.upload, 0x5555, 0) == SdoAbortCode.NO_OBJECT
    assert a(slave.upload, 0x1018, 9) == SdoAbortCode.NO_SUBINDEX
    assert a(slave.download, 0x1018, 9, b"\0") == SdoAbortCode.NO_SUBINDEX
    assert a(slave.upload, 0x2001, 0) == SdoAbortCode.WRITE_ONLY
    assert a(slave.download, 0x1018, 1, b"\0\0\0\0") == SdoAbortCode.READ_ONLY
    assert a(slave.download, 0x8000, 1, b"\1\0\0\0") == SdoAbortCode.LENGTH_TOO_HIGH
    assert a(slave.download, 0x8000, 2, b"\1\0") == SdoAbortCode.LENGTH_TOO_LOW
    assert a(slave.download, 0x8000, 1, struct.pack("<H", 10001)) == SdoAbortCode.VALUE_TOO_HIGH
    assert a(slave.download, 0x8000, 2, struct.pack("<i", -1_000_001)) == (
        SdoAbortCode.VALUE_TOO_LOW)
    assert a(slave.download, 0x8000, 4, b"\x03") == SdoAbortCode.VALUE_RANGE
    assert a(slave.download, 0x8000, 5, struct.pack("<f", 100.5)) == SdoAbortCode.VALUE_TOO_HIGH
    assert a(slave.download, 0x8000, 6, bytes(33)) == SdoAbortCode.LENGTH_TOO_HIGH
    assert a(slave.upload, 0x8000, 0, ca=True) == SdoAbortCode.CA_VARIABLE_LENGTH
    assert a(slave.upload, 0x8001, 2, ca=True) == SdoAbortCode.UNSUPPORTED_ACCESS


def test_length_mismatch_without_size_indication(slave: CoeSlave) -> None:
    # a normal download without size indication whose length does not fit the type
    msg = SdoInitiateDownloadRequest(0x8000, 1, b"\1\2\3", expedited=False, size_indicated=False)
    assert abort_of(slave, msg) == SdoAbortCode.LENGTH_MISMATCH
    # expedited without size indication: 4 bytes, the low ones count for a UINT16
    ok = SdoInitiateDownloadRequest(0x8000, 1, b"\x2a\x00\xff\xff", size_indicated=False)
    assert isinstance(slave.exchange(ok), SdoInitiateDownloadResponse)
    assert slave.upload(0x8000, 1) == b"\x2a\x00"


def test_state_dependent_access(slave: CoeSlave) -> None:
    slave.download(0x2002, 0, struct.pack("<H", 200))
    slave.configure_process_data(7, 7)
    assert slave.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)
    assert slave.abort_code(slave.download, 0x2002, 0, struct.pack("<H", 201)) == (
        SdoAbortCode.DEVICE_STATE)
    assert slave.upload(0x2002, 0) == struct.pack("<H", 200)
    # an output mapped in the active RxPDOs is blocked for SDO writes
    assert slave.abort_code(slave.download, 0x7000, 2, b"\1\0") == SdoAbortCode.MAPPED_TO_RXPDO
    slave.download(0x7000, 4, b"\x01")  # not mapped: fine
    assert slave.request_state(AlState.PREOP) == (int(AlState.PREOP), 0)
    slave.download(0x2002, 0, struct.pack("<H", 201))


# --- complete access -------------------------------------------------------------------


def test_complete_access_upload_and_download(slave: CoeSlave) -> None:
    assert slave.upload(0x1C12, 0, ca=True) == struct.pack("<BxHH", 2, 0x1600, 0x1601)
    assert slave.upload(0x1C12, 1, ca=True) == struct.pack("<HH", 0x1600, 0x1601)
    ident = slave.upload(0x1018, 0, ca=True)
    assert ident == struct.pack("<BxIIII", 4, 0x00504543, 0x00050001, 0x00010000, 7)
    assert slave.upload(0x1C00, 0, ca=True) == bytes([4, 0, 1, 2, 3, 4])
    slave.download(0x8001, 0, struct.pack("<Bxhh", 2, -50, 50), ca=True)
    assert slave.upload(0x8001, 1) == struct.pack("<h", -50)
    slave.download(0x8001, 1, struct.pack("<hh", -60, 60), ca=True)
    assert slave.upload(0x8001, 0, ca=True) == struct.pack("<Bxhh", 2, -60, 60)
    assert slave.abort_code(slave.download, 0x8001, 1, struct.pack("<h", 1), ca=True) == (
        SdoAbortCode.LENGTH_TOO_LOW)


def test_complete_access_refused_without_the_sii_flag() -> None:
    drive = CoeSlave("seed002-drive")
    assert drive.abort_code(drive.upload, 0x1018, 0, ca=True) == SdoAbortCode.UNSUPPORTED_ACCESS


# --- SDO information -------------------------------------------------------------------


def test_od_list_all_types(slave: CoeSlave) -> None:
    od = coe_server(slave.app).od
    everything = slave.info(SdoInfoGetOdListRequest(1))
    assert isinstance(everything, SdoInfoGetOdListResponse)
    assert everything.indices == tuple(o.index for o in od)
    assert {0x1000, 0x1018, 0x1600, 0x1A00, 0x1C12, 0x1C13, 0x1C32, 0x2000, 0x6000, 0x7000,
            0x8000} <= set(everything.indices)
    rx = slave.info(SdoInfoGetOdListRequest(2))
    tx = slave.info(SdoInfoGetOdListRequest(3))
    assert isinstance(rx, SdoInfoGetOdListResponse) and rx.indices == (0x7000,)
    assert isinstance(tx, SdoInfoGetOdListResponse) and tx.indices == (0x6000,)
    counts = slave.info(SdoInfoGetOdListRequest(0))
    assert isinstance(counts, SdoInfoGetOdListResponse)
    assert counts.indices == (len(everything.indices), 1, 1, 0, 0)
    bad = slave.info(SdoInfoGetOdListRequest(7))
    assert isinstance(bad, SdoInfoError) and bad.code == SdoAbortCode.VALUE_RANGE


def test_object_descriptions(slave: CoeSlave) -> None:
    d = slave.info(SdoInfoGetObjectDescriptionRequest(0x1018))
    assert d == SdoInfoGetObjectDescriptionResponse(0x1018, 0x0023, 4, ObjectCode.RECORD,
                                                    "Identity")
    d = slave.info(SdoInfoGetObjectDescriptionRequest(0x1600))
    assert isinstance(d, SdoInfoGetObjectDescriptionResponse)
    assert (d.object_code, d.max_subindex, d.data_type) == (ObjectCode.ARRAY, 8, 0x0007)
    d = slave.info(SdoInfoGetObjectDescriptionRequest(0x2000))
    assert isinstance(d, SdoInfoGetObjectDescriptionResponse)
    assert (d.object_code, d.data_type, d.name) == (ObjectCode.VAR, 0x000A, "Data block")
    err = slave.info(SdoInfoGetObjectDescriptionRequest(0x5555))
    assert err == SdoInfoError(SdoAbortCode.NO_OBJECT)


def test_entry_descriptions_with_value_info(slave: CoeSlave) -> None:
    full = ValueInfo.UNIT_TYPE | ValueInfo.DEFAULT_VALUE | ValueInfo.MINIMUM_VALUE | (
        ValueInfo.MAXIMUM_VALUE)
    e = slave.info(SdoInfoGetEntryDescriptionRequest(0x8000, 1, int(full)))
    assert isinstance(e, SdoInfoGetEntryDescriptionResponse)
    assert (e.data_type, e.bit_length, e.object_access) == (0x0006, 16, ObjectAccess.READ_WRITE)
    assert (e.unit_type, e.default_value, e.minimum_value, e.maximum_value) == (
        0, b"\x0a\x00", b"\x00\x00", struct.pack("<H", 10000))
    assert e.description == "Filter time"
    e = slave.info(SdoInfoGetEntryDescriptionRequest(0x7000, 2, 0x07))  # what SOEM asks
    assert isinstance(e, SdoInfoGetEntryDescriptionResponse)
    assert e.value_info == 0x07 and e.default_value is None
    assert e.object_access == int(ObjectAccess.READ_WRITE | ObjectAccess.RXPDO_MAPPABLE)
    e = slave.info(SdoInfoGetEntryDescriptionRequest(0x6000, 5, 0))
    assert isinstance(e, SdoInfoGetEntryDescriptionResponse)
    assert (e.data_type, e.bit_length) == (0x0001, 1)
    err = slave.info(SdoInfoGetEntryDescriptionRequest(0x6000, 9, 0))
    assert err == SdoInfoError(SdoAbortCode.NO_SUBINDEX)


def test_long_entry_description_is_fragmented(slave: CoeSlave) -> None:
    # the default of the 4 KiB octet string does not fit one mailbox
    slave.send(SdoInfoGetEntryDescriptionRequest(0x2000, 0, int(ValueInfo.DEFAULT_VALUE)).encode())
    frames = []
    while True:
        raw = slave.fetch()
        assert raw is not None
        header = MailboxHeader.decode(raw)
        frag = SdoInfoFragment.from_payload(raw[6: 6 + header.length])
        frames.append(frag)
        if not frag.incomplete:
            break
    assert len(frames) > 30
    assert [f.fragments_left for f in frames] == list(range(len(frames) - 1, -1, -1))
    body = b"".join(f.data for f in frames)
    e = SdoInfoGetEntryDescriptionResponse.from_body(body)
    assert e.bit_length == 4096 * 8 and e.default_value == bytes(i & 0xFF for i in range(4096))


# --- emergency -------------------------------------------------------------------------


def test_emergency_goes_out_through_sm1(slave: CoeSlave) -> None:
    assert coe_server(slave.app).emergency(0x8210, 0x11, b"\x01\x02\x03")
    header, msg = slave.fetch_message()
    assert header.type == MailboxType.COE and header.counter != 0
    assert msg == Emergency(0x8210, 0x11, b"\x01\x02\x03\x00\x00")
    assert slave.upload(0x1001, 0) == b"\x11"


def test_emergency_waits_while_sm1_is_full(slave: CoeSlave) -> None:
    app = slave.app
    coe_server(app).emergency(0x1000, 1)
    coe_server(app).emergency(0x2000, 2)
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode())
    codes = []
    for _ in range(3):
        _h, msg = slave.fetch_message()
        codes.append(msg.error_code if isinstance(msg, Emergency) else msg)  # type: ignore[attr-defined]
    assert codes[:2] == [0x1000, 0x2000]
    assert isinstance(codes[2], SdoInitiateUploadResponse)
    assert slave.fetch() is None


def test_no_emergency_in_init(slave: CoeSlave) -> None:
    assert slave.request_state(AlState.INIT)[0] == int(AlState.INIT)
    assert not coe_server(slave.app).emergency(0x1000)


# --- mailbox layer ---------------------------------------------------------------------


def test_repeated_counter_is_not_executed_twice(slave: CoeSlave) -> None:
    req = SdoInitiateDownloadRequest(0x8000, 1, struct.pack("<H", 5))
    assert slave.send(req.encode(), counter=3) == 1
    first = slave.fetch()
    assert first is not None
    # the same counter again: dropped, no second reply
    assert slave.send(SdoInitiateUploadRequest(0x8000, 1).encode(), counter=3) == 1
    assert slave.fetch() is None
    assert slave.app.mailbox.duplicates == 1  # type: ignore[attr-defined]
    # the next counter is served; counter 0 ("not used") is never a duplicate
    assert slave.send(SdoInitiateUploadRequest(0x8000, 1).encode(), counter=4) == 1
    assert slave.fetch() is not None
    for _ in range(2):
        slave.send(SdoInitiateUploadRequest(0x8000, 1).encode(), counter=0)
        assert slave.fetch() is not None


def test_reply_counters_run_1_to_7_and_wrap(slave: CoeSlave) -> None:
    seen = []
    for _ in range(9):
        slave.send(SdoInitiateUploadRequest(0x1000, 0).encode())
        seen.append(slave.fetch_message()[0].counter)
    assert seen == [1, 2, 3, 4, 5, 6, 7, 1, 2]


def test_lost_reply_recovered_by_repeat_request(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1018, 2).encode())
    lost = slave.fetch()  # the master "loses" this frame
    assert lost is not None and slave.fetch() is None
    base = R.sm_address(1)
    status_act = bytearray(slave.fprd(base + R.SM_STATUS, 2).data)
    status_act[1] ^= R.SM_ACTIVATE_REPEAT  # facts 6.6 step 1 (SOEM: XOR 0x0200 on 0x080D)
    slave.fpwr(base + R.SM_STATUS, bytes(status_act))
    pdi_ctl = slave.fprd(base + R.SM_PDI_CONTROL, 1).data[0]
    assert bool(pdi_ctl & R.SM_PDI_REPEAT_ACK) == bool(status_act[1] & R.SM_ACTIVATE_REPEAT)
    again = slave.fetch()
    assert again == lost
    assert lost.startswith(slave.app.mailbox.last_reply)  # type: ignore[attr-defined]


def test_sm0_write_refused_while_full_is_not_a_second_request(slave: CoeSlave) -> None:
    # the app reads SM0 at once, so a second write is accepted and served once
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode())
    slave.send(SdoInitiateUploadRequest(0x1008, 0).encode())
    assert isinstance(coe_of(slave.fetch() or b""), SdoInitiateUploadResponse)
    second = coe_of(slave.fetch() or b"")
    assert isinstance(second, SdoInitiateUploadResponse) and second.index == 0x1008


@pytest.mark.parametrize("mtype", [MailboxType.AOE, MailboxType.EOE, MailboxType.FOE,
                                   MailboxType.SOE, MailboxType.VOE, 0x7])
def test_unsupported_protocol(slave: CoeSlave, mtype: int) -> None:
    slave.send(b"\x00" * 8, mtype=mtype)
    assert mailbox_error(slave) == MailboxErrorCode.UNSUPPORTED_PROTOCOL


def test_mailbox_header_errors(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode(), channel=1)
    assert mailbox_error(slave) == MailboxErrorCode.INVALID_CHANNEL
    slave.send(b"\x01\x00\x02\x00", mtype=MailboxType.ERR)
    assert mailbox_error(slave) == MailboxErrorCode.INVALID_HEADER
    slave.send(b"")
    assert mailbox_error(slave) == MailboxErrorCode.SIZE_TOO_SHORT
    bad_len = bytearray(encode_mailbox(MailboxType.COE, b"\x00\x20", counter=5))
    bad_len[0:2] = struct.pack("<H", MBX_SIZE)  # longer than SM0 minus the header
    slave.send_raw(bytes(bad_len))
    assert mailbox_error(slave) == MailboxErrorCode.INVALID_SIZE


def test_coe_service_errors(slave: CoeSlave) -> None:
    slave.send(b"\x00")  # CoE header cut short
    assert mailbox_error(slave) == MailboxErrorCode.SIZE_TOO_SHORT
    slave.send(CoeHeader(CoeService.SDO_REQUEST).encode() + b"\x40\x00")  # SDO cut short
    assert mailbox_error(slave) == MailboxErrorCode.SIZE_TOO_SHORT
    slave.send(CoePdo(CoeService.RXPDO, 1, b"\x01").encode())
    assert mailbox_error(slave) == MailboxErrorCode.SERVICE_NOT_SUPPORTED
    slave.send(CoeHeader(0xE).encode() + bytes(8))
    assert mailbox_error(slave) == MailboxErrorCode.SERVICE_NOT_SUPPORTED
    slave.send(SdoInitiateDownloadResponse(0x1000, 0).encode())  # a response is no request
    assert mailbox_error(slave) == MailboxErrorCode.SERVICE_NOT_SUPPORTED
    slave.send(Emergency(0x1000).encode())
    assert mailbox_error(slave) == MailboxErrorCode.SERVICE_NOT_SUPPORTED


def test_no_sdo_info_without_the_sii_flag() -> None:
    drive = CoeSlave("seed002-drive")
    coe_server(drive.app).details &= ~0x02
    drive.send(SdoInfoGetOdListRequest(1).encode())
    assert mailbox_error(drive) == MailboxErrorCode.SERVICE_NOT_SUPPORTED


def test_mailbox_restarts_after_init(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode(), counter=1)
    assert slave.fetch() is not None
    assert slave.request_state(AlState.INIT)[0] == int(AlState.INIT)
    assert slave.request_state(AlState.PREOP)[0] == int(AlState.PREOP)
    # a new master starts its counter at 1 again: not a duplicate after INIT
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode(), counter=1)
    header, _ = slave.fetch_message()
    assert header.counter == 1
