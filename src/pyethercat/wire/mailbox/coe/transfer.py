"""SDO transfer state machines: upload and download, client (master) and server (slave).

In the h11 manner: messages in, the next message (or a completion event) out;
no I/O, no clock. Expedited, normal and segmented transfers of any size, with
complete access (CiA 301 SDO protocol; the sequences SOEM ``src/ec_coe.c``
``ecx_SDOread``/``ecx_SDOwrite`` and SOES ``soes/esc_coe.c`` run).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox.coe.decode import CoeMessage
from pyethercat.wire.mailbox.coe.header import (
    COE_HEADER_SIZE,
    SDO_HEADER_SIZE,
    CoeService,
    SdoAbortCode,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.coe.sdo import (
    SdoAbortTransfer,
    SdoDownloadSegmentRequest,
    SdoDownloadSegmentResponse,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
    check_address,
)
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    "sdo_initiate_max_data",
    "sdo_segment_max_data",
    "SdoTransferDone",
    "SdoUploadClient",
    "SdoDownloadClient",
    "SdoUploadServer",
    "SdoDownloadServer",
    "SdoDownloadEvent",
]


def sdo_initiate_max_data(mailbox_size: int) -> int:
    """Data bytes an initiate frame (normal transfer) can carry in a mailbox of this size."""
    return mailbox_size - MAILBOX_HEADER_SIZE - COE_HEADER_SIZE - SDO_HEADER_SIZE


def sdo_segment_max_data(mailbox_size: int) -> int:
    """Data bytes a segment frame can carry in a mailbox of this size."""
    return mailbox_size - MAILBOX_HEADER_SIZE - COE_HEADER_SIZE - 1


def _check_mailbox_size(mailbox_size: int) -> None:
    # a mailbox must at least hold a 10-byte CoE/SDO frame plus one data byte
    if mailbox_size < MAILBOX_HEADER_SIZE + COE_HEADER_SIZE + SDO_HEADER_SIZE + 1:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for SDO transfers")


def _split_segments(data: bytes, size: int) -> list[bytes]:
    return [data[i : i + size] for i in range(0, len(data), size)]


_Initiate = TypeVar("_Initiate", SdoInitiateDownloadRequest, SdoInitiateUploadResponse)


def _initiate_and_segments(kind: type[_Initiate], index: int, subindex: int, data: bytes,
                           expedited: bool, complete_access: bool, mailbox_size: int,
                           ) -> tuple[_Initiate, list[bytes]]:
    """The initiate frame of the side that sends ``data`` and the segments that follow it:
    expedited (1..4 bytes in the frame), or the first part with the complete size."""
    if expedited:
        return kind(index, subindex, data, True, True, None, complete_access), []
    first = sdo_initiate_max_data(mailbox_size)
    return (kind(index, subindex, data[:first], False, True, len(data), complete_access),
            _split_segments(data[first:], sdo_segment_max_data(mailbox_size)))


@dataclass(frozen=True, slots=True)
class SdoTransferDone:
    """A transfer finished. ``data`` is the uploaded object (empty for downloads)."""

    data: bytes = b""


class _ClientBase:
    def __init__(self, index: int, subindex: int, complete_access: bool) -> None:
        check_address(index, subindex)
        self.index = index
        self.subindex = subindex
        self.complete_access = complete_access
        self.done = False
        self.abort_request: SdoAbortTransfer | None = None

    def _fail(self, code: int, why: str) -> SdoAbort:
        """Record the abort we must send and build the error to raise."""
        self.abort_request = SdoAbortTransfer(self.index, self.subindex, code)
        self.done = True
        return SdoAbort(code, f"{sdo_abort_name(code)} ({why})", self.index, self.subindex)

    def _check_common(self, msg: object) -> None:
        if self.done:
            raise MailboxError("SDO transfer already finished")
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            raise msg.to_error()

    def _check_address(self, index: int, subindex: int) -> None:
        """An initiate response names the object asked for (any subindex with complete access)."""
        if index != self.index or (subindex != self.subindex and not self.complete_access):
            raise self._fail(SdoAbortCode.INVALID_COMMAND,
                             f"response for 0x{index:04X}:{subindex:02X}")


class _SdoClient:
    """What both SDO clients show: whether the transfer ended, the abort to send."""

    _c: _ClientBase
    _started: bool

    @property
    def done(self) -> bool:
        """True once finished (successfully or not)."""
        return self._c.done

    @property
    def abort_request(self) -> SdoAbortTransfer | None:
        """The abort the master should send after a local protocol failure."""
        return self._c.abort_request

    def _response(self, msg: CoeMessage) -> _ClientBase:
        """The checks every response passes first (finished, an abort, before start())."""
        c = self._c
        c._check_common(msg)
        if not self._started:
            raise MailboxError(f"{type(self).__name__}.receive() before start()")
        return c


class SdoUploadClient(_SdoClient):
    """Master side of one SDO upload (read), expedited, normal or segmented.

    ``start()`` gives the initiate request; ``receive(response)`` gives the
    next request or :class:`SdoTransferDone`. A slave abort raises
    :class:`SdoAbort`; a protocol violation raises :class:`SdoAbort` too and
    leaves the abort to send in ``abort_request``.
    """

    def __init__(self, index: int, subindex: int, *, complete_access: bool = False) -> None:
        self._c = _ClientBase(index, subindex, complete_access)
        self._buffer = bytearray()
        self._total: int | None = None
        self._toggle = False
        self._started = False

    def start(self) -> SdoInitiateUploadRequest:
        """The initiate upload request."""
        self._started = True
        return SdoInitiateUploadRequest(self._c.index, self._c.subindex, self._c.complete_access)

    def receive(self, msg: CoeMessage) -> SdoUploadSegmentRequest | SdoTransferDone:
        """Process one response from the slave."""
        c = self._response(msg)
        if isinstance(msg, SdoInitiateUploadResponse) and self._total is None and not self._buffer:
            c._check_address(msg.index, msg.subindex)
            if msg.expedited:
                c.done = True
                return SdoTransferDone(msg.data)
            self._buffer += msg.data
            if msg.size_indicated:
                self._total = msg.total_size
                if len(self._buffer) >= self._total:
                    c.done = True
                    return SdoTransferDone(bytes(self._buffer[: self._total]))
            else:
                self._total = -1  # unknown: segments until the last one
            return SdoUploadSegmentRequest(self._toggle)
        if isinstance(msg, SdoUploadSegmentResponse) and self._total is not None:
            if msg.toggle != self._toggle:
                raise c._fail(SdoAbortCode.TOGGLE_BIT, "upload segment toggle not alternated")
            self._buffer += msg.data
            if self._total >= 0 and len(self._buffer) > self._total:
                raise c._fail(
                    SdoAbortCode.LENGTH_TOO_HIGH,
                    f"{len(self._buffer)} bytes received, complete size {self._total}",
                )
            if msg.last:
                if self._total >= 0 and len(self._buffer) != self._total:
                    raise c._fail(
                        SdoAbortCode.LENGTH_MISMATCH,
                        f"{len(self._buffer)} bytes received, complete size {self._total}",
                    )
                c.done = True
                return SdoTransferDone(bytes(self._buffer))
            self._toggle = not self._toggle
            return SdoUploadSegmentRequest(self._toggle)
        raise c._fail(SdoAbortCode.INVALID_COMMAND, f"unexpected {type(msg).__name__}")


class SdoDownloadClient(_SdoClient):
    """Master side of one SDO download (write).

    Expedited when the data has 1..4 bytes and complete access is off (as
    SOEM does); otherwise a normal transfer whose first part rides in the
    initiate frame and the rest in segments sized for ``mailbox_size``.
    """

    def __init__(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        mailbox_size: int,
        complete_access: bool = False,
        expedited: bool | None = None,
    ) -> None:
        _check_mailbox_size(mailbox_size)
        self._c = _ClientBase(index, subindex, complete_access)
        data = bytes(data)
        if expedited is None:
            expedited = 1 <= len(data) <= 4 and not complete_access
        if expedited and not 1 <= len(data) <= 4:
            raise MailboxError(f"expedited download carries 1..4 bytes, got {len(data)}")
        self._expedited = expedited
        self._initiate, self._segments = _initiate_and_segments(
            SdoInitiateDownloadRequest, index, subindex, data, expedited, complete_access,
            mailbox_size)
        self._next = 0
        self._toggle = False
        self._started = False

    def start(self) -> SdoInitiateDownloadRequest:
        """The initiate download request."""
        self._started = True
        return self._initiate

    def _next_segment(self) -> SdoDownloadSegmentRequest:
        chunk = self._segments[self._next]
        self._next += 1
        return SdoDownloadSegmentRequest(self._toggle, self._next == len(self._segments), chunk)

    def receive(self, msg: CoeMessage) -> SdoDownloadSegmentRequest | SdoTransferDone:
        """Process one response from the slave."""
        c = self._response(msg)
        if isinstance(msg, SdoInitiateDownloadResponse) and self._next == 0:
            c._check_address(msg.index, msg.subindex)
            if not self._segments:
                c.done = True
                return SdoTransferDone()
            return self._next_segment()
        if isinstance(msg, SdoDownloadSegmentResponse) and self._next > 0:
            if msg.toggle != self._toggle:
                raise c._fail(SdoAbortCode.TOGGLE_BIT, "download segment toggle not echoed")
            if self._next == len(self._segments):
                c.done = True
                return SdoTransferDone()
            self._toggle = not self._toggle
            return self._next_segment()
        raise c._fail(SdoAbortCode.INVALID_COMMAND, f"unexpected {type(msg).__name__}")


class SdoUploadServer:
    """Slave side of one upload: answers the initiate, then each segment request.

    Build it when an :class:`SdoInitiateUploadRequest` arrived and the object
    was read; ``start()`` is the initiate response; ``receive(request)``
    answers segment requests (a toggle error or a stray request yields an
    :class:`SdoAbortTransfer` and ends the transfer).
    """

    def __init__(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        mailbox_size: int,
        complete_access: bool = False,
    ) -> None:
        _check_mailbox_size(mailbox_size)
        check_address(index, subindex)
        data = bytes(data)
        self.index = index
        self.subindex = subindex
        self.done = False
        self._initiate, self._segments = _initiate_and_segments(
            SdoInitiateUploadResponse, index, subindex, data,
            1 <= len(data) <= 4 and not complete_access, complete_access, mailbox_size)
        self._next = 0
        self._toggle = False

    def start(self) -> SdoInitiateUploadResponse:
        """The initiate upload response."""
        if not self._segments:
            self.done = True
        return self._initiate

    def receive(self, msg: CoeMessage) -> SdoUploadSegmentResponse | SdoAbortTransfer:
        """Answer one request of the master."""
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            return msg
        if self.done or not isinstance(msg, SdoUploadSegmentRequest):
            self.done = True
            return SdoAbortTransfer(
                self.index, self.subindex, SdoAbortCode.INVALID_COMMAND, CoeService.SDO_REQUEST
            )
        if msg.toggle != self._toggle:
            self.done = True
            return SdoAbortTransfer(self.index, self.subindex, SdoAbortCode.TOGGLE_BIT)
        chunk = self._segments[self._next]
        self._next += 1
        last = self._next == len(self._segments)
        reply = SdoUploadSegmentResponse(self._toggle, last, chunk)
        self._toggle = not self._toggle
        self.done = last
        return reply


@dataclass(frozen=True, slots=True)
class SdoDownloadEvent:
    """What :class:`SdoDownloadServer` says about one request.

    ``reply`` is the message to send; when ``data`` is not None the transfer is
    complete: store ``data`` and send ``reply`` (or an abort instead, if the
    object refuses the value).
    """

    reply: SdoInitiateDownloadResponse | SdoDownloadSegmentResponse | SdoAbortTransfer
    data: bytes | None = None


class SdoDownloadServer:
    """Slave side of one download: collects the initiate frame and the segments."""

    def __init__(self, request: SdoInitiateDownloadRequest) -> None:
        self.index = request.index
        self.subindex = request.subindex
        self.complete_access = request.complete_access
        self._request = request
        self._buffer = bytearray(request.data)
        self._total = request.total_size
        self._toggle = False
        self.done = False

    def start(self) -> SdoDownloadEvent:
        """Handle the initiate request this server was built with."""
        reply = SdoInitiateDownloadResponse(self.index, self.subindex, self.complete_access)
        req = self._request
        if req.expedited or len(self._buffer) >= self._total:
            self.done = True
            return SdoDownloadEvent(reply, bytes(self._buffer))
        return SdoDownloadEvent(reply)

    def _abort(self, code: int) -> SdoDownloadEvent:
        self.done = True
        return SdoDownloadEvent(SdoAbortTransfer(self.index, self.subindex, code))

    def receive(self, msg: CoeMessage) -> SdoDownloadEvent:
        """Handle one download segment request."""
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            return SdoDownloadEvent(msg)
        if self.done or not isinstance(msg, SdoDownloadSegmentRequest):
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        if msg.toggle != self._toggle:
            return self._abort(SdoAbortCode.TOGGLE_BIT)
        self._buffer += msg.data
        if len(self._buffer) > self._total:
            return self._abort(SdoAbortCode.LENGTH_TOO_HIGH)
        reply = SdoDownloadSegmentResponse(self._toggle)
        self._toggle = not self._toggle
        if msg.last:
            self.done = True
            if len(self._buffer) != self._total:
                return self._abort(SdoAbortCode.LENGTH_TOO_LOW)
            return SdoDownloadEvent(reply, bytes(self._buffer))
        return SdoDownloadEvent(reply)
