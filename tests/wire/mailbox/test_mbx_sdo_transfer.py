"""SDO transfer state machines: clients against servers, over encoded bytes."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import (
    CoeMessage,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoDownloadClient,
    SdoDownloadEvent,
    SdoDownloadSegmentRequest,
    SdoDownloadSegmentResponse,
    SdoDownloadServer,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoTransferDone,
    SdoUploadClient,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
    SdoUploadServer,
)
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox, next_counter


def wire(msg: CoeMessage, mailbox_size: int, counter: int) -> CoeMessage:
    """Send a message through a padded SM buffer and decode it on the other side."""
    frame = encode_mailbox(MailboxType.COE, msg.encode(), counter=counter, size=mailbox_size)
    _, out = decode_message(frame)
    assert out == msg
    assert isinstance(out, type(msg))
    return out  # type: ignore[return-value]


def run_upload(data: bytes, mailbox_size: int, ca: bool = False) -> tuple[bytes, int]:
    client = SdoUploadClient(0x2000, 1, complete_access=ca)
    req = wire(client.start(), mailbox_size, 1)
    assert isinstance(req, SdoInitiateUploadRequest)
    server = SdoUploadServer(
        req.index,
        req.subindex,
        data,
        mailbox_size=mailbox_size,
        complete_access=req.complete_access,
    )
    reply: CoeMessage = server.start()
    frames, counter = 1, 1
    while True:
        counter = next_counter(counter)
        step = client.receive(wire(reply, mailbox_size, counter))
        if isinstance(step, SdoTransferDone):
            assert client.done and server.done
            return step.data, frames
        frames += 1
        reply = server.receive(wire(step, mailbox_size, counter))


def run_download(data: bytes, mailbox_size: int, ca: bool = False) -> tuple[bytes, int]:
    client = SdoDownloadClient(0x2000, 1, data, mailbox_size=mailbox_size, complete_access=ca)
    req = wire(client.start(), mailbox_size, 1)
    assert isinstance(req, SdoInitiateDownloadRequest)
    server = SdoDownloadServer(req)
    event = server.start()
    stored = event.data
    frames = 1
    while True:
        step = client.receive(wire(event.reply, mailbox_size, 2))
        if isinstance(step, SdoTransferDone):
            assert server.done
            assert stored is not None
            return stored, frames
        frames += 1
        event = server.receive(wire(step, mailbox_size, 3))
        if event.data is not None:
            stored = event.data


def test_expedited_upload() -> None:
    assert run_upload(b"\x9a\x02\x00\x00", 128) == (b"\x9a\x02\x00\x00", 1)
    assert run_upload(b"\x07", 128) == (b"\x07", 1)


def test_normal_upload_fits_one_frame() -> None:
    assert run_upload(b"A" * 100, 128) == (b"A" * 100, 1)
    assert run_upload(b"", 128) == (b"", 1)


def test_segmented_upload() -> None:
    data = bytes(range(256)) * 3
    out, frames = run_upload(data, 48)
    assert out == data
    # initiate carries 32 bytes, each segment 39
    assert frames == 1 + -(-(len(data) - 32) // 39)


def test_downloads() -> None:
    assert run_download(b"\x01\x02", 128) == (b"\x01\x02", 1)
    assert run_download(b"x" * 100, 128) == (b"x" * 100, 1)
    data = bytes(range(200))
    out, frames = run_download(data, 32)
    assert out == data and frames > 2
    # complete access never goes expedited
    out, _ = run_download(b"\x01\x00\x00\x16", 64, ca=True)
    assert out == b"\x01\x00\x00\x16"


@settings(max_examples=60)
@given(st.binary(max_size=600), st.integers(17, 300), st.booleans())
def test_transfers_property(data: bytes, mailbox_size: int, ca: bool) -> None:
    assert run_upload(data, mailbox_size, ca)[0] == data
    assert run_download(data, mailbox_size, ca)[0] == data


def test_slave_abort_raises() -> None:
    client = SdoUploadClient(0x6000, 9)
    client.start()
    with pytest.raises(SdoAbort) as exc:
        client.receive(SdoAbortTransfer(0x6000, 9, SdoAbortCode.NO_SUBINDEX))
    assert exc.value.code == 0x06090011 and exc.value.subindex == 9
    assert client.done and client.abort_request is None


def test_client_detects_toggle_error() -> None:
    client = SdoUploadClient(0x1008, 0)
    client.start()
    nxt = client.receive(
        SdoInitiateUploadResponse(0x1008, 0, b"", expedited=False, complete_size=20)
    )
    assert nxt == SdoUploadSegmentRequest(False)
    with pytest.raises(SdoAbort) as exc:
        client.receive(SdoUploadSegmentResponse(True, False, b"x" * 7))
    assert exc.value.code == SdoAbortCode.TOGGLE_BIT
    assert client.abort_request == SdoAbortTransfer(0x1008, 0, 0x05030000)


def test_client_detects_size_mismatch_and_wrong_object() -> None:
    client = SdoUploadClient(0x1008, 0)
    client.start()
    client.receive(SdoInitiateUploadResponse(0x1008, 0, b"", expedited=False, complete_size=3))
    with pytest.raises(SdoAbort):
        client.receive(SdoUploadSegmentResponse(False, True, b"12"))
    other = SdoUploadClient(0x1008, 0)
    other.start()
    with pytest.raises(SdoAbort):
        other.receive(SdoInitiateUploadResponse(0x1009, 0, b"1"))
    dl = SdoDownloadClient(0x1, 0, b"1", mailbox_size=64)
    dl.start()
    with pytest.raises(SdoAbort):
        dl.receive(SdoDownloadSegmentResponse(False))
    with pytest.raises(MailboxError):
        dl.receive(SdoInitiateDownloadResponse(0x1, 0))  # already finished


def test_server_answers_toggle_error_with_abort() -> None:
    server = SdoUploadServer(0x1008, 0, b"y" * 100, mailbox_size=32)
    assert isinstance(server.start(), SdoInitiateUploadResponse)
    assert isinstance(server.receive(SdoUploadSegmentRequest(False)), SdoUploadSegmentResponse)
    reply = server.receive(SdoUploadSegmentRequest(False))
    assert reply == SdoAbortTransfer(0x1008, 0, SdoAbortCode.TOGGLE_BIT)
    assert server.done


def test_download_server_errors() -> None:
    req = SdoInitiateDownloadRequest(0x2000, 0, b"ab", expedited=False, complete_size=10)
    server = SdoDownloadServer(req)
    assert server.start() == SdoDownloadEvent(SdoInitiateDownloadResponse(0x2000, 0))
    ev = server.receive(SdoDownloadSegmentRequest(True, False, b"cd"))
    assert ev.reply == SdoAbortTransfer(0x2000, 0, SdoAbortCode.TOGGLE_BIT)
    server = SdoDownloadServer(req)
    server.start()
    ev = server.receive(SdoDownloadSegmentRequest(False, True, b"cd"))
    assert ev.reply == SdoAbortTransfer(0x2000, 0, SdoAbortCode.LENGTH_TOO_LOW)
    server = SdoDownloadServer(req)
    server.start()
    ev = server.receive(SdoDownloadSegmentRequest(False, False, b"c" * 20))
    assert ev.reply == SdoAbortTransfer(0x2000, 0, SdoAbortCode.LENGTH_TOO_HIGH)
