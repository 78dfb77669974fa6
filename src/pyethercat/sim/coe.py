"""CoE server of a simulated slave: SDO, SDO information and emergencies.

:class:`CoeServer` is the mailbox protocol server (``sim.mailbox.ProtocolServer``)
of CoE, answering requests against a slave's
:class:`~pyethercat.sim.od.SimObjectDictionary`: SDO upload and download
(expedited, normal, segmented with toggle checks, complete access with the
subindex 0 and 1 variants), SDO information (OD lists of every list type,
object and entry descriptions with value info, fragmented to the mailbox
size) and aborts with the codes SOES ``soes/esc.h`` (``ABORT_*``) and SOEM
``src/ec_print.c`` (``ec_sdoerrorlist``) list. It uses the sans-IO codecs and
transfer state machines of :mod:`pyethercat.wire.mailbox.coe`.
:meth:`CoeServer.emergency` sends a CoE emergency (CoE service 1: code,
register, 5 data bytes, as SOEM ``src/ec_main.c`` ``ec_emcyt`` reads it).

The PDO mapping objects live in ``sim.pdo_mapping``, the standard objects'
builders in ``sim.std_objects``; a device kind's process data and behaviour
in its device model (``sim.coe_model``).
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.mailbox import MailboxDevice, service_error
from pyethercat.sim.od import SimObjectDictionary, SimOdEntry, sdo_abort
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import (
    COE_HEADER_SIZE,
    SDO_HEADER_SIZE,
    CoeHeader,
    CoeMessage,
    CoeService,
    Emergency,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoDownloadSegmentRequest,
    SdoDownloadServer,
    SdoInfoError,
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoGetObjectDescriptionRequest,
    SdoInfoGetObjectDescriptionResponse,
    SdoInfoGetOdListRequest,
    SdoInfoGetOdListResponse,
    SdoInfoMessage,
    SdoInitiateDownloadRequest,
    SdoInitiateUploadRequest,
    SdoUploadSegmentRequest,
    SdoUploadServer,
    ValueInfo,
    decode_coe,
    encode_sdo_info_fragments,
)
from pyethercat.wire.mailbox.datatypes import DataType, encode_value
from pyethercat.wire.mailbox.header import MailboxErrorCode, MailboxHeader, MailboxType
from pyethercat.wire.mailbox.objects import StandardObject
from pyethercat.wire.sii import CoeDetails

__all__ = ["CoeServer", "coe_server"]

_FULL_COE = (CoeDetails.SDO | CoeDetails.SDO_INFO | CoeDetails.PDO_ASSIGN | CoeDetails.PDO_CONFIG
             | CoeDetails.SDO_COMPLETE_ACCESS)
_SDO_REQUEST_MIN = COE_HEADER_SIZE + SDO_HEADER_SIZE
#: Emergencies a server remembers (the oldest go first).
EMERGENCY_HISTORY = 256


class CoeServer:
    """Serves the CoE protocol of one slave (see the module docstring).

    ``send(payload)`` queues one CoE payload for SM1; ``state()`` gives the AL
    state; ``mailbox_size()`` the SM1 length (segment and fragment sizes).
    ``details`` are the SII CoE details: without SDO_INFO the information
    service is "not supported", without SDO_COMPLETE_ACCESS complete access
    aborts with 0x06010000.
    """

    #: The mailbox type this server takes.
    type = int(MailboxType.COE)

    def __init__(self, od: SimObjectDictionary, send: Callable[[bytes], None],
                 state: Callable[[], AlState], mailbox_size: Callable[[], int],
                 details: int = _FULL_COE) -> None:
        self.od = od
        self.send = send
        self.state = state
        self.mailbox_size = mailbox_size
        self.details = CoeDetails(details)
        self._upload: SdoUploadServer | None = None
        self._download: SdoDownloadServer | None = None
        self._download_flags = (True, False)
        #: Emergencies sent (the newest :data:`EMERGENCY_HISTORY`).
        self.emergencies: deque[Emergency] = deque(maxlen=EMERGENCY_HISTORY)

    def reset(self) -> None:
        """The mailbox stopped: transfers in progress are forgotten."""
        self._upload = None
        self._download = None

    def on_state_change(self, old: AlState, new: AlState) -> None:
        """AL state changes need nothing beyond :meth:`reset` (called on INIT)."""

    def emergency(self, code: int, register: int = 0, data: bytes = bytes(5)) -> bool:
        """Send a CoE emergency (and set 0x1001); False when the mailbox is not running."""
        msg = Emergency(code, register, bytes(data).ljust(5, b"\x00")[:5])
        if StandardObject.ERROR_REGISTER in self.od:
            self.od.set_value(StandardObject.ERROR_REGISTER, 0, register)
        if self.state() in (AlState.INIT, AlState.BOOT):
            return False
        self.emergencies.append(msg)
        self.send(msg.encode())
        return True

    def handle(self, header: MailboxHeader, payload: bytes) -> None:
        """One CoE request (mailbox payload, CoE header first)."""
        try:
            msg = decode_coe(payload)
        except MailboxError:
            self._undecodable(payload)
            return
        if isinstance(msg, SdoInitiateUploadRequest):
            self._initiate_upload(msg)
        elif isinstance(msg, SdoUploadSegmentRequest):
            self._upload_segment(msg)
        elif isinstance(msg, SdoInitiateDownloadRequest):
            self._initiate_download(msg)
        elif isinstance(msg, SdoDownloadSegmentRequest):
            self._download_segment(msg)
        elif isinstance(msg, SdoAbortTransfer):
            self._upload = None  # the master gave up: no answer
            self._download = None
        elif isinstance(msg, (SdoInfoGetOdListRequest, SdoInfoGetObjectDescriptionRequest,
                              SdoInfoGetEntryDescriptionRequest)):
            self._info(msg)
        else:
            # Responses, emergencies and PDO services are not requests a slave serves.
            raise service_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED)

    def _undecodable(self, payload: bytes) -> None:
        if len(payload) < COE_HEADER_SIZE:
            raise service_error(MailboxErrorCode.SIZE_TOO_SHORT)
        service = CoeHeader.decode(payload).service
        if service == CoeService.SDO_REQUEST:
            if len(payload) < _SDO_REQUEST_MIN:
                raise service_error(MailboxErrorCode.SIZE_TOO_SHORT)
            # A command specifier we do not know (block transfers): abort it.
            index, subindex = struct.unpack_from("<HB", payload, COE_HEADER_SIZE + 1)
            self._reply(SdoAbortTransfer(index, subindex, SdoAbortCode.INVALID_COMMAND))
            return
        if service == CoeService.SDO_INFORMATION and self.details & CoeDetails.SDO_INFO:
            if len(payload) < COE_HEADER_SIZE + 4:
                raise service_error(MailboxErrorCode.SIZE_TOO_SHORT)
            self._reply(SdoInfoError(SdoAbortCode.INVALID_COMMAND))
            return
        raise service_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED)

    def _reply(self, msg: CoeMessage) -> None:
        self.send(msg.encode())

    def _abort(self, exc: SdoAbort, index: int, subindex: int) -> None:
        self._reply(SdoAbortTransfer(index, subindex, exc.code))

    # --- upload ---------------------------------------------------------------------

    def _initiate_upload(self, msg: SdoInitiateUploadRequest) -> None:
        self._upload = None
        self._download = None
        index, sub, ca = msg.index, msg.subindex, msg.complete_access
        try:
            if ca and not self.details & CoeDetails.SDO_COMPLETE_ACCESS:
                raise sdo_abort(SdoAbortCode.UNSUPPORTED_ACCESS, index, sub,
                                "complete access not supported")
            data = self.od.upload(index, sub, self.state(), ca)
        except SdoAbort as exc:
            self._abort(exc, index, sub)
            return
        server = SdoUploadServer(index, sub, data, mailbox_size=self.mailbox_size(),
                                 complete_access=ca)
        self._reply(server.start())
        if not server.done:
            self._upload = server

    def _upload_segment(self, msg: SdoUploadSegmentRequest) -> None:
        server = self._upload
        if server is None:
            self._reply(SdoAbortTransfer(0, 0, SdoAbortCode.INVALID_COMMAND))
            return
        reply = server.receive(msg)
        if server.done:
            self._upload = None
        self._reply(reply)

    # --- download -------------------------------------------------------------------

    def _initiate_download(self, msg: SdoInitiateDownloadRequest) -> None:
        self._upload = None
        self._download = None
        index, sub, ca = msg.index, msg.subindex, msg.complete_access
        size = msg.total_size if msg.size_indicated else None
        try:
            if ca and not self.details & CoeDetails.SDO_COMPLETE_ACCESS:
                raise sdo_abort(SdoAbortCode.UNSUPPORTED_ACCESS, index, sub,
                                "complete access not supported")
            self.od.check_download(index, sub, None if msg.expedited and not ca else size,
                                   self.state(), ca)
        except SdoAbort as exc:
            self._abort(exc, index, sub)
            return
        server = SdoDownloadServer(msg)
        event = server.start()
        self._download_flags = (msg.size_indicated, msg.expedited)
        if event.data is not None:
            self._store(index, sub, event.data, ca, reply=event.reply)
            return
        self._download = server
        self._reply(event.reply)

    def _download_segment(self, msg: SdoDownloadSegmentRequest) -> None:
        server = self._download
        if server is None:
            self._reply(SdoAbortTransfer(0, 0, SdoAbortCode.INVALID_COMMAND))
            return
        event = server.receive(msg)
        if server.done:
            self._download = None
        if event.data is not None:
            self._store(server.index, server.subindex, event.data, server.complete_access,
                        reply=event.reply)
            return
        self._reply(event.reply)

    def _store(self, index: int, sub: int, data: bytes, ca: bool, *, reply: CoeMessage) -> None:
        size_indicated, expedited = self._download_flags
        try:
            self.od.download(index, sub, data, self.state(), ca, size_indicated, expedited)
        except SdoAbort as exc:
            self._abort(exc, index, sub)
            return
        self._reply(reply)

    # --- SDO information ------------------------------------------------------------

    def _info(self, msg: SdoInfoMessage) -> None:
        if not self.details & CoeDetails.SDO_INFO:
            raise service_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED)
        try:
            answer = self._info_answer(msg)
        except SdoAbort as exc:
            answer = SdoInfoError(exc.code)
        for frame in encode_sdo_info_fragments(answer, self.mailbox_size()):
            self.send(frame)

    def _info_answer(self, msg: SdoInfoMessage) -> SdoInfoMessage:
        od = self.od
        if isinstance(msg, SdoInfoGetOdListRequest):
            return SdoInfoGetOdListResponse(msg.list_type, od.indices(msg.list_type))
        if isinstance(msg, SdoInfoGetObjectDescriptionRequest):
            obj = od.get(msg.index)
            return SdoInfoGetObjectDescriptionResponse(
                obj.index, obj.data_type, obj.max_subindex, int(obj.object_code), obj.name)
        assert isinstance(msg, SdoInfoGetEntryDescriptionRequest)
        e = od.entry(msg.index, msg.subindex)
        vi = msg.value_info
        # The bit length is a 16-bit field: larger entries (domains, big octet
        # strings) are described with length 0, "no fixed length".
        bit_length = e.bit_length if e.bit_length <= 0xFFFF else 0
        size = (bit_length + 7) // 8

        def field(value: object, fallback: bytes) -> bytes:
            raw = fallback
            if value is not None:
                try:
                    raw = encode_value(e.data_type, value)  # type: ignore[arg-type]
                except MailboxError:
                    raw = fallback
            return raw[:size].ljust(size, b"\x00")

        lo, hi = _type_limits(e) if bit_length else (b"", b"")
        return SdoInfoGetEntryDescriptionResponse(
            msg.index, msg.subindex, vi, int(e.data_type), bit_length,
            e.access & 0x03FF, e.name,
            unit_type=e.unit if vi & ValueInfo.UNIT_TYPE else None,
            default_value=field(e.default, bytes(size)) if vi & ValueInfo.DEFAULT_VALUE else None,
            minimum_value=field(e.minimum, lo) if vi & ValueInfo.MINIMUM_VALUE else None,
            maximum_value=field(e.maximum, hi) if vi & ValueInfo.MAXIMUM_VALUE else None,
        )


def _type_limits(e: SimOdEntry) -> tuple[bytes, bytes]:
    """Raw minimum and maximum of the entry's type (zeros for non-numbers)."""
    size = (e.bit_length + 7) // 8
    bits = e.bit_length
    dt = e.data_type
    if e.allowed:
        return (encode_value(dt, min(e.allowed)), encode_value(dt, max(e.allowed)))
    if dt.name.startswith("INTEGER"):
        return ((-(1 << (bits - 1))).to_bytes(size, "little", signed=True),
                ((1 << (bits - 1)) - 1).to_bytes(size, "little", signed=True))
    if dt.name.startswith("UNSIGNED") or dt in (DataType.BOOLEAN, DataType.BYTE) or (
            dt.name.startswith("BIT")):
        return bytes(size), ((1 << bits) - 1).to_bytes(size, "little")
    return bytes(size), bytes(size)


def coe_server(app: DeviceApp | None) -> CoeServer:
    """The CoE server of a slave's application (:class:`ValueError` if it has none)."""
    if isinstance(app, MailboxDevice):
        server = app.protocols.get(int(MailboxType.COE))
        if isinstance(server, CoeServer):
            return server
    raise ValueError(f"{type(app).__name__} serves no CoE")
