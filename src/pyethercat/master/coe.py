"""CoE client (master side): SDO transfers, SDO information, emergencies, PDO mapping.

A :class:`CoeClient` talks CANopen over EtherCAT to one slave through its
:class:`~pyethercat.master.mailbox.Mailbox`. The protocol itself (frames and
the multi-frame SDO state machines) lives in :mod:`pyethercat.wire.mailbox.coe`;
this module drives it over the mailbox:

- ``upload``/``download``: expedited, normal and segmented transfers of any
  size, optionally with complete access (all subindices at once). A slave's
  abort raises :class:`~pyethercat.errors.SdoAbort` with the code and its
  name from the shared table; a protocol violation by the slave (wrong
  toggle, wrong object, unexpected frame) is answered with an abort to the
  slave and raised the same way; no answer in time sends an "SDO protocol
  timeout" abort and raises :class:`~pyethercat.errors.TimeoutError` naming
  the slave and the object.
- ``read``/``write``: the same with CANopen basic data types converted
  (``dtype="uint16"``, ``DataType.REAL32``, ...).
- ``od``: the object dictionary as the SDO information service describes it,
  fetched lazily (the list once, each object's description when first used).
- Emergencies (CoE service 1) arrive whenever the slave posts them: they are
  logged with their error-code class name, queued in ``emergencies`` and
  handed to the callbacks registered with :meth:`CoeClient.on_emergency`.
- PDO configuration: read the assignment objects 0x1C10+n (0x1C12 outputs,
  0x1C13 inputs) and the mapping objects 0x16xx/0x1Axx into the master's
  :class:`~pyethercat.master.config.Pdo` lists, and write a new mapping
  (dynamic PDO) in PRE-OP.
- Start-up commands (the shape of ESI ``InitCmds``): SDO downloads run at
  named state transitions (IP, PS, SO, ...), see :class:`StartupCommand`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar, Self

from pyethercat.errors import ConfigError, EtherCATError, MailboxError, SdoAbort
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.config import MappedPdo, MappedPdoEntry, PdoDirection
from pyethercat.master.mailbox import ClientContext, DropOldestQueue, Mailbox, ReceivedMessage
from pyethercat.wire.al import TRANSITIONS, AlState
from pyethercat.wire.mailbox.coe import (
    COE_HEADER_SIZE,
    CoeMessage,
    CoeService,
    Emergency,
    ErrorRegister,
    ObjectAccess,
    ObjectCode,
    OdListType,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoDownloadClient,
    SdoDownloadSegmentRequest,
    SdoDownloadSegmentResponse,
    SdoInfoError,
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoGetObjectDescriptionRequest,
    SdoInfoGetObjectDescriptionResponse,
    SdoInfoGetOdListRequest,
    SdoInfoGetOdListResponse,
    SdoInfoMessage,
    SdoInfoOpCode,
    SdoInfoReassembler,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoTransferDone,
    SdoUploadClient,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
    ValueInfo,
    decode_coe,
)
from pyethercat.wire.mailbox.datatypes import (
    DataType,
    Value,
    decode_value,
    encode_value,
    format_value,
    parse_type_name,
)
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.mailbox.objects import mapping_word, sm_pdo_assignment, split_mapping_word

__all__ = [
    "DEFAULT_SDO_TIMEOUT",
    "DropOldestQueue",
    "DTypeLike",
    "CoeClient",
    "EmergencyEvent",
    "ObjectDictionary",
    "OdObject",
    "OdEntry",
    "PdoSpec",
    "StartupCommand",
    "resolve_dtype",
    "mapping_word",
    "pdo_mapping_writes",
    "pdo_assignment_writes",
    "split_mapping_word",
]

_log = logging.getLogger("pyethercat.coe")

#: Seconds one SDO transfer (all its segments) may take by default.
DEFAULT_SDO_TIMEOUT = 2.0
#: Value-info bits asked for in entry descriptions: unit, default, minimum, maximum.
_ENTRY_VALUE_INFO = (ValueInfo.UNIT_TYPE | ValueInfo.DEFAULT_VALUE | ValueInfo.MINIMUM_VALUE
                     | ValueInfo.MAXIMUM_VALUE)
#: A data type given by code, enum member or name ("uint16", "REAL32", "0x0007").
DTypeLike = DataType | int | str
#: What ``Slave.set_pdo_mapping`` takes per sync manager: PDO indices (keep their
#: mapping) or (PDO index, entries) pairs whose mapping is rewritten; entries are
#: (index, subindex, bits).
PdoSpec = int | tuple[int, Sequence[tuple[int, int, int]]]


def resolve_dtype(dtype: DTypeLike) -> DataType:
    """The :class:`DataType` a user named; :class:`ConfigError` if unknown."""
    if isinstance(dtype, DataType):
        return dtype
    if isinstance(dtype, int):
        try:
            return DataType(dtype)
        except ValueError:
            raise ConfigError(f"unknown CANopen data type 0x{dtype:04X}") from None
    if dtype.strip().lower() in _SIGN_MAGNITUDE_NAMES:
        # IgH's tool prints these with the sign bit apart; as a CANopen type they
        # would silently decode as two's complement.
        raise ConfigError(f"{dtype!r} is the command line's sign-and-magnitude notation "
                          "(IgH), no CANopen type: read the raw bytes, or an INTEGER type")
    return parse_type_name(dtype)


_SIGN_MAGNITUDE_NAMES = frozenset({"sm8", "sm16", "sm32", "sm64"})


# --- emergencies ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EmergencyEvent:
    """An emergency a slave sent: who, when, and the message."""

    slave: str
    position: int
    emergency: Emergency
    time: float

    @property
    def error_code(self) -> int:
        return self.emergency.error_code

    @property
    def error_register(self) -> int:
        return self.emergency.error_register

    @property
    def data(self) -> bytes:
        return self.emergency.data

    @property
    def name(self) -> str:
        """Class name of the error code (CiA 301 table)."""
        return self.emergency.name

    @property
    def register_names(self) -> tuple[str, ...]:
        """Names of the error register bits set (object 0x1001: generic, current, ...)."""
        return tuple(bit.name.lower().replace("_", " ") for bit in ErrorRegister
                     if self.error_register & bit and bit.name)

    def __str__(self) -> str:
        bits = self.register_names
        reg = f" ({', '.join(bits)})" if bits else ""
        return (f"{self.slave}: emergency 0x{self.error_code:04X} ({self.name}), "
                f"error register 0x{self.error_register:02X}{reg}, data {self.data.hex(' ')}")


# --- the client ---------------------------------------------------------------------------


def _coe_service(msg: ReceivedMessage) -> int | None:
    if msg.header.type != MailboxType.COE or len(msg.payload) < COE_HEADER_SIZE:
        return None
    return msg.payload[1] >> 4  # CoE header bits 15:12 (little-endian u16)


#: The last payload decoded and what it decoded to: the answer a transfer accepted
#: is decoded again to run it, and the same bytes object gives the same message.
_last_decoded: tuple[bytes, CoeMessage] | None = None


def _decode_once(payload: bytes) -> CoeMessage:
    global _last_decoded
    got = _last_decoded
    if got is not None and got[0] is payload:
        return got[1]
    decoded = decode_coe(payload)
    _last_decoded = (payload, decoded)
    return decoded


def _is_sdo(msg: ReceivedMessage) -> bool:
    # An abort may travel in service 2 (what SOES sends) or 3.
    return _coe_service(msg) in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE)


def _sdo_answer(request: CoeMessage, index: int, subindex: int,
                complete_access: bool) -> Callable[[ReceivedMessage], bool]:
    """Whether an SDO message answers ``request`` (a step of the transfer of index:subindex).

    The right response command for the request, with its index and subindex
    (initiate) or its toggle (segments), or an abort of this object. Anything
    else is a late answer to an earlier request (a slow slave, the reply to
    a request another master or an earlier transfer left behind), which the
    mailbox drops: SOEM ``ecx_SDOread`` counts such replies as packet errors.
    """
    want: type[CoeMessage]
    if isinstance(request, SdoInitiateUploadRequest):
        want = SdoInitiateUploadResponse
    elif isinstance(request, SdoInitiateDownloadRequest):
        want = SdoInitiateDownloadResponse
    elif isinstance(request, SdoUploadSegmentRequest):
        want = SdoUploadSegmentResponse
    elif isinstance(request, SdoDownloadSegmentRequest):
        want = SdoDownloadSegmentResponse
    else:
        return _is_sdo
    segment = isinstance(request, (SdoUploadSegmentRequest, SdoDownloadSegmentRequest))

    def same_object(msg: SdoAbortTransfer | SdoInitiateUploadResponse
                    | SdoInitiateDownloadResponse) -> bool:
        return msg.index == index and (msg.subindex == subindex or complete_access)

    def accept(msg: ReceivedMessage) -> bool:
        if not _is_sdo(msg):
            return False
        try:
            coe = _decode_once(msg.payload)
        except MailboxError:
            return True  # malformed: the transfer reports it
        if isinstance(coe, SdoAbortTransfer):
            # some slaves leave the address out of an abort during segments
            return same_object(coe) or (segment and coe.index == 0)
        if not isinstance(coe, want):
            return False
        # A segment's toggle is the transfer's to check (a wrong one aborts
        # it): segments follow an answered initiate, so no double answer of
        # ours can be under way then.
        return segment or same_object(coe)  # type: ignore[arg-type]

    return accept


def _is_info(msg: ReceivedMessage) -> bool:
    return _coe_service(msg) == CoeService.SDO_INFORMATION


def _fragments_left(reply: ReceivedMessage) -> int:
    """The fragments-left word of an SDO-information fragment (CoE header, opcode, reserved)."""
    at = COE_HEADER_SIZE + 2
    return int.from_bytes(reply.payload[at:at + 2], "little") if len(reply.payload) >= at + 2 else 0


def _short_info_error(msg: ReceivedMessage) -> int | None:
    """The abort code of an SDO information error whose length word leaves the code out.

    KickCAT's ESC emulator answers with a mailbox length of 6 (CoE and SDO
    information headers) and the abort code right behind; SOEM reads the code
    whatever the length says (``ecx_readOEsingle``), so do we. None when the
    message is not such an error.
    """
    p = msg.payload
    if len(p) < COE_HEADER_SIZE + 4 or p[COE_HEADER_SIZE] & 0x7F != SdoInfoOpCode.SDO_INFO_ERROR:
        return None
    code = (p[COE_HEADER_SIZE + 4:] + msg.after)[:4]
    if len(code) < 4:
        return None
    _log.debug("SDO information error: abort code outside the mailbox length")
    return int.from_bytes(code, "little")


class CoeClient:
    """CoE services of one slave (see the module text).

    ``label`` names the slave in messages; ``position`` is its ring
    position (carried in emergency events).
    """

    #: The mailbox type this client speaks (the registry key, see ``master.clients``).
    mailbox_type: ClassVar[MailboxType] = MailboxType.COE

    @classmethod
    def for_mailbox(cls, mailbox: Mailbox, context: ClientContext) -> Self:
        """The client a master makes for a slave's mailbox: emergencies go to the master."""
        client = cls(mailbox, position=context.position, emergencies=context.events)
        client.on_emergency(context.report)
        return client

    def __init__(self, mailbox: Mailbox, *, position: int = -1,
                 timeout: float = DEFAULT_SDO_TIMEOUT, emergency_queue_size: int = 256,
                 emergencies: DropOldestQueue[EmergencyEvent] | None = None) -> None:
        self.mailbox = mailbox
        self.label = mailbox.label
        self.position = position
        self.timeout = timeout
        #: Where emergencies are filed (oldest dropped when full). A master gives
        #: every client the master's queue, so all slaves' emergencies wait in one.
        self.emergencies: DropOldestQueue[EmergencyEvent] = (
            DropOldestQueue(emergency_queue_size) if emergencies is None else emergencies)
        self._callbacks: list[Callable[[EmergencyEvent], None]] = []
        self._od: ObjectDictionary | None = None
        mailbox.add_handler(self._unsolicited)

    # -- emergencies -------------------------------------------------------------------

    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None:
        """Call ``callback(event)`` for every emergency (in the thread that read it)."""
        self._callbacks.append(callback)

    def _unsolicited(self, mailbox: Mailbox, msg: ReceivedMessage) -> bool:
        if _coe_service(msg) != CoeService.EMERGENCY:
            return False
        try:
            decoded = decode_coe(msg.payload)
        except MailboxError as exc:
            _log.warning("%s: malformed emergency dropped: %s", self.label, exc)
            return True
        assert isinstance(decoded, Emergency)
        event = EmergencyEvent(self.label, self.position, decoded, time.time())
        _log.warning("%s", event)
        self.emergencies.put(event)
        for cb in list(self._callbacks):
            try:
                cb(event)
            except Exception:  # noqa: BLE001 - a broken callback must not break the mailbox
                _log.exception("%s: emergency callback failed", self.label)
        return True

    # -- SDO -------------------------------------------------------------------------------

    def upload(self, index: int, subindex: int = 0, *, complete_access: bool = False,
               timeout: float | None = None) -> bytes:
        """Read an object (SDO upload); the raw bytes."""
        if complete_access and subindex > 1:
            subindex = 1  # complete access starts at subindex 0 or 1 (SOEM does the same)
        machine = SdoUploadClient(index, subindex, complete_access=complete_access)
        what = f"SDO upload {_addr(index, subindex, complete_access)}"
        return self._run(machine, machine.start(), index, subindex, what, timeout)

    def download(self, index: int, subindex: int, data: bytes | bytearray, *,
                 complete_access: bool = False, timeout: float | None = None,
                 expedited: bool | None = None) -> None:
        """Write an object (SDO download) with the raw bytes ``data``."""
        if complete_access and subindex > 1:
            subindex = 1
        # No data is a normal transfer with complete size 0 (an empty string, say):
        # expedited frames carry 1..4 bytes only.
        machine = SdoDownloadClient(index, subindex, bytes(data),
                                    mailbox_size=min(self.mailbox.rx_size, self.mailbox.tx_size),
                                    complete_access=complete_access, expedited=expedited)
        what = (f"SDO download {_addr(index, subindex, complete_access)} "
                f"({len(data)} byte{'s' if len(data) != 1 else ''})")
        self._run(machine, machine.start(), index, subindex, what, timeout)

    def read(self, index: int, subindex: int = 0, dtype: DTypeLike | None = None, *,
             complete_access: bool = False, timeout: float | None = None) -> Value:
        """SDO upload converted to a Python value (``dtype`` None: the raw bytes)."""
        raw = self.upload(index, subindex, complete_access=complete_access, timeout=timeout)
        if dtype is None:
            return raw
        dt = resolve_dtype(dtype)
        try:
            return decode_value(dt, raw)
        except MailboxError as exc:
            raise MailboxError(f"{self.label}: {_addr(index, subindex)} as {dt.name}: "
                               f"{exc}") from None

    def write(self, index: int, subindex: int, value: Value, dtype: DTypeLike | None = None,
              *, complete_access: bool = False, timeout: float | None = None) -> None:
        """SDO download of ``value`` encoded as ``dtype`` (None: ``value`` must be bytes)."""
        if dtype is None:
            if not isinstance(value, (bytes, bytearray)):
                raise ConfigError(f"{self.label}: writing {_addr(index, subindex)}: give a "
                                  f"dtype for {type(value).__name__} values")
            data = bytes(value)
        else:
            dt = resolve_dtype(dtype)
            try:
                data = encode_value(dt, value)
            except MailboxError as exc:
                raise ConfigError(f"{self.label}: {_addr(index, subindex)}: {exc}") from None
        self.download(index, subindex, data, complete_access=complete_access, timeout=timeout)

    def _run(self, machine: SdoUploadClient | SdoDownloadClient, first: CoeMessage,
             index: int, subindex: int, what: str, timeout: float | None) -> bytes:
        """Drive one SDO transfer state machine over the mailbox."""
        mbx = self.mailbox
        span = self.timeout if timeout is None else timeout
        limit = mbx.clock() + span
        msg: CoeMessage = first
        clock = mbx.clock
        complete_access = bool(getattr(first, "complete_access", False))
        with mbx.lock:
            mbx.drop(_is_sdo)  # answers to transfers that timed out earlier
            while True:
                try:
                    answers = _sdo_answer(msg, index, subindex, complete_access)
                    reply = mbx.transact(MailboxType.COE, msg.encode(), answers, what=what,
                                         timeout=max(0.0, limit - clock()), stale=_is_sdo)
                except EcTimeoutError:
                    self._abort(index, subindex, SdoAbortCode.TIMEOUT)
                    raise
                try:
                    coe = _decode_once(reply.payload)
                except MailboxError as exc:
                    self._abort(index, subindex, SdoAbortCode.INVALID_COMMAND)
                    raise MailboxError(f"{self.label}: malformed answer to {what}: {exc}"
                                       ) from None
                try:
                    step = machine.receive(coe)
                except SdoAbort as exc:
                    if machine.abort_request is not None:
                        self._send_abort(machine.abort_request)
                    exc.args = (f"{self.label}: {what}: {exc}",)
                    raise
                if isinstance(step, SdoTransferDone):
                    return step.data
                msg = step

    def _abort(self, index: int, subindex: int, code: int) -> None:
        self._send_abort(SdoAbortTransfer(index, subindex, code))

    def _send_abort(self, abort: SdoAbortTransfer) -> None:
        """Tell the slave we gave up a transfer (best effort: no answer is expected)."""
        try:
            self.mailbox.send(MailboxType.COE, abort.encode(), what="SDO abort",
                              timeout=0.1, fetch=False)
        except Exception as exc:  # noqa: BLE001 - the original error matters more
            _log.debug("%s: could not send %s: %s", self.label, abort, exc)

    # -- SDO information ---------------------------------------------------------------

    def _info(self, request: SdoInfoGetOdListRequest | SdoInfoGetObjectDescriptionRequest
              | SdoInfoGetEntryDescriptionRequest, what: str, index: int = 0,
              subindex: int = 0, timeout: float | None = None) -> SdoInfoMessage:
        mbx = self.mailbox
        span = self.timeout if timeout is None else timeout
        with mbx.lock:
            mbx.drop(_is_info)
            # The first fragment answers the request (sent again if unanswered).
            reply = mbx.transact(MailboxType.COE, request.encode(), _is_info, what=what,
                                 timeout=span, stale=_is_sdo)
            reasm = SdoInfoReassembler()
            fragments = 1
            while True:
                try:
                    got = reasm.feed(reply.payload)
                except MailboxError as exc:
                    code = _short_info_error(reply)
                    if code is None:
                        raise MailboxError(f"{self.label}: {what}: {exc}") from None
                    got = SdoInfoError(code=code)
                if got is None:
                    # Each fragment gets the whole timeout from the one before: a long
                    # answer (an OD list of hundreds of objects) may take many timeouts
                    # in all while its slave answers every step in time.
                    try:
                        reply = mbx.receive(_is_info, what=f"answer to {what}", timeout=span)
                    except EcTimeoutError:
                        raise EcTimeoutError(
                            f"{self.label}: {what}: fragment {fragments + 1} not received "
                            f"within {span:g} s of fragment {fragments} (the slave announced "
                            f"{_fragments_left(reply)} more)") from None
                    fragments += 1
                    continue
                if isinstance(got, SdoInfoError):
                    err = got.to_error(index, subindex)
                    err.args = (f"{self.label}: {what}: {err}",)
                    raise err
                if got.OPCODE != request.OPCODE + 1:
                    raise MailboxError(f"{self.label}: {what}: answered with "
                                       f"{type(got).__name__}")
                return got

    def od_list(self, list_type: OdListType | int = OdListType.ALL,
                timeout: float | None = None) -> list[int]:
        """Indices of the objects of one list (SDO information, get OD list)."""
        got = self._info(SdoInfoGetOdListRequest(int(list_type)),
                         f"SDO info OD list {int(list_type)}", timeout=timeout)
        assert isinstance(got, SdoInfoGetOdListResponse)
        return list(got.indices)

    def object_description(self, index: int,
                           timeout: float | None = None) -> SdoInfoGetObjectDescriptionResponse:
        """Data type, object code, maximum subindex and name of an object."""
        got = self._info(SdoInfoGetObjectDescriptionRequest(index),
                         f"SDO info object description 0x{index:04X}", index, 0, timeout)
        assert isinstance(got, SdoInfoGetObjectDescriptionResponse)
        return got

    def entry_description(self, index: int, subindex: int,
                          value_info: int = _ENTRY_VALUE_INFO, timeout: float | None = None,
                          ) -> SdoInfoGetEntryDescriptionResponse:
        """Data type, bit length, access rights and name of one entry."""
        got = self._info(SdoInfoGetEntryDescriptionRequest(index, subindex, value_info),
                         f"SDO info entry description {_addr(index, subindex)}",
                         index, subindex, timeout)
        assert isinstance(got, SdoInfoGetEntryDescriptionResponse)
        return got

    @property
    def od(self) -> ObjectDictionary:
        """The object dictionary, browsed lazily through the SDO information service."""
        if self._od is None:
            self._od = ObjectDictionary(self)
        return self._od

    # -- PDO configuration --------------------------------------------------------------

    def read_pdo_assignment(self, sm: int) -> list[int]:
        """PDO indices assigned to sync manager ``sm`` (object 0x1C10 + sm)."""
        obj = sm_pdo_assignment(sm)
        count = int(self.read(obj, 0, DataType.UNSIGNED8))
        return [int(self.read(obj, k, DataType.UNSIGNED16))
                for k in range(1, count + 1)]

    def read_pdo_mapping(self, pdo_index: int) -> list[tuple[int, int, int]]:
        """Entries (index, subindex, bit length) of a PDO mapping object (0x16xx/0x1Axx)."""
        count = int(self.read(pdo_index, 0, DataType.UNSIGNED8))
        return [split_mapping_word(int(self.read(pdo_index, k, DataType.UNSIGNED32)))
                for k in range(1, count + 1)]

    def read_pdos(self, sync_managers: Mapping[int, PdoDirection],
                  names: Callable[[int, int, int], tuple[str, int]] | None = None,
                  pdo_names: Callable[[int], str] | None = None) -> dict[int, list[MappedPdo]]:
        """The PDOs assigned to each process-data sync manager, read over CoE.

        ``sync_managers`` maps SM numbers to their direction. ``names(index,
        subindex, pdo_index)`` gives an entry's (name, data type) and
        ``pdo_names(pdo_index)`` a PDO's name (from the SII or the OD); by
        default entries are named ``0xIIII:SS`` and typed by their size.
        """
        out: dict[int, list[MappedPdo]] = {}
        for sm, direction in sorted(sync_managers.items()):
            pdos: list[MappedPdo] = []
            for pdo_index in self.read_pdo_assignment(sm):
                entries: list[MappedPdoEntry] = []
                for index, sub, bits in self.read_pdo_mapping(pdo_index):
                    if index == 0 or names is None:
                        name, dtype = "", _type_for_bits(bits)
                    else:
                        name, dtype = names(index, sub, pdo_index)
                        dtype = dtype or _type_for_bits(bits)
                    entries.append(MappedPdoEntry(index, sub, bits, dtype if index else 0, name))
                pname = pdo_names(pdo_index) if pdo_names is not None else ""
                pdos.append(MappedPdo(pdo_index, pname, tuple(entries), direction, sm))
            out[sm] = pdos
        return out

    def write_pdo_mapping(self, pdo_index: int, entries: Sequence[tuple[int, int, int]]) -> None:
        """Write a PDO mapping object: sub 0 = 0, the entries, then sub 0 = count (CiA order)."""
        for index, sub, data in pdo_mapping_writes(pdo_index, entries):
            self.download(index, sub, data)

    def write_pdo_assignment(self, sm: int, pdo_indices: Sequence[int]) -> None:
        """Assign PDOs to sync manager ``sm`` (object 0x1C10 + sm), in the CiA order."""
        for index, sub, data in pdo_assignment_writes(sm, pdo_indices):
            self.download(index, sub, data)

    def __repr__(self) -> str:
        return f"<CoeClient {self.label}>"


def pdo_mapping_writes(pdo_index: int, entries: Sequence[tuple[int, int, int]]
                       ) -> list[tuple[int, int, bytes]]:
    """(index, subindex, bytes) downloads that rewrite a PDO mapping object, in CiA order.

    Sub 0 = 0 first (the slave then accepts entries), the mapping words
    ``(index, subindex, bits)``, then sub 0 = the number of entries.
    """
    writes = [(pdo_index, 0, b"\x00")]
    writes += [(pdo_index, k, mapping_word(i, sub, bits).to_bytes(4, "little"))
               for k, (i, sub, bits) in enumerate(entries, start=1)]
    writes.append((pdo_index, 0, bytes([len(entries)])))
    return writes


def pdo_assignment_writes(sm: int, pdo_indices: Sequence[int]) -> list[tuple[int, int, bytes]]:
    """(index, subindex, bytes) downloads that assign PDOs to sync manager ``sm`` (0x1C10 + sm)."""
    obj = sm_pdo_assignment(sm)
    writes = [(obj, 0, b"\x00")]
    writes += [(obj, k, pdo.to_bytes(2, "little")) for k, pdo in enumerate(pdo_indices, start=1)]
    writes.append((obj, 0, bytes([len(pdo_indices)])))
    return writes


def _type_for_bits(bits: int) -> int:
    """A data type for an entry known only by its size (no SII, no SDO information)."""
    return {1: DataType.BOOLEAN, 8: DataType.UNSIGNED8, 16: DataType.UNSIGNED16,
            24: DataType.UNSIGNED24, 32: DataType.UNSIGNED32,
            64: DataType.UNSIGNED64}.get(bits, 0)


def _addr(index: int, subindex: int, complete_access: bool = False) -> str:
    text = f"0x{index:04X}:{subindex:02X}"
    return text + " (complete access)" if complete_access else text


# --- the object dictionary ------------------------------------------------------------------


@dataclass
class OdEntry:
    """One entry (subindex) of an object, as its entry description tells."""

    object: OdObject = field(repr=False)
    subindex: int
    data_type: int
    bit_length: int
    access: int
    name: str
    unit_type: int | None = None
    default: bytes | None = None
    minimum: bytes | None = None
    maximum: bytes | None = None

    @property
    def index(self) -> int:
        return self.object.index

    @property
    def type_name(self) -> str:
        try:
            return DataType(self.data_type).name
        except ValueError:
            return f"0x{self.data_type:04X}"

    @property
    def access_text(self) -> str:
        """IgH style: ``rw`` / ``ro`` / ``wo`` for PRE-OP, SAFE-OP and OP, e.g. ``rwrwro``."""
        out = ""
        for r, w in ((ObjectAccess.READ_PREOP, ObjectAccess.WRITE_PREOP),
                     (ObjectAccess.READ_SAFEOP, ObjectAccess.WRITE_SAFEOP),
                     (ObjectAccess.READ_OP, ObjectAccess.WRITE_OP)):
            out += ("r" if self.access & r else "-") + ("w" if self.access & w else "-")
        return out

    @property
    def pdo_mappable(self) -> bool:
        return bool(self.access & (ObjectAccess.RXPDO_MAPPABLE | ObjectAccess.TXPDO_MAPPABLE))

    def _dtype(self) -> DataType | None:
        try:
            return DataType(self.data_type)
        except ValueError:
            return None

    def read(self) -> Value:
        """Upload the entry, converted by its data type (raw bytes if the type is unknown)."""
        dt = self._dtype()
        return self.object.client.read(self.index, self.subindex, dt)

    def write(self, value: Value) -> None:
        """Download ``value`` converted by the entry's data type."""
        self.object.client.write(self.index, self.subindex, value, self._dtype())

    def format(self, value: Value) -> str:
        """The value as text, by the entry's data type."""
        dt = self._dtype()
        if dt is None:
            return value.hex(" ") if isinstance(value, bytes) else str(value)
        return format_value(dt, value)


class OdObject:
    """One object of the dictionary; entries are described on first use."""

    def __init__(self, client: CoeClient, desc: SdoInfoGetObjectDescriptionResponse) -> None:
        self.client = client
        self.index = desc.index
        self.name = desc.name
        self.data_type = desc.data_type
        self.max_subindex = desc.max_subindex
        self.object_code = desc.object_code
        self._entries: dict[int, OdEntry | None] = {}

    @property
    def object_code_name(self) -> str:
        try:
            return ObjectCode(self.object_code).name
        except ValueError:
            return f"0x{self.object_code:02X}"

    def entry(self, subindex: int) -> OdEntry | None:
        """The description of one subindex (None when the slave has none for it)."""
        if subindex not in self._entries:
            try:
                d = self.client.entry_description(self.index, subindex)
            except SdoAbort:
                self._entries[subindex] = None
            else:
                self._entries[subindex] = OdEntry(self, subindex, d.data_type, d.bit_length,
                                                  d.object_access, d.description, d.unit_type,
                                                  d.default_value, d.minimum_value,
                                                  d.maximum_value)
        return self._entries[subindex]

    def __getitem__(self, subindex: int) -> OdEntry:
        got = self.entry(subindex)
        if got is None:
            raise KeyError(f"{self.client.label}: 0x{self.index:04X} has no subindex {subindex}")
        return got

    @property
    def subindices(self) -> Sequence[int]:
        """The subindices a description may exist for: 0 for a VAR, else 0 to the maximum."""
        return [0] if self.object_code == ObjectCode.VAR else range(self.max_subindex + 1)

    @property
    def entries(self) -> list[OdEntry]:
        """Every described entry, subindex 0 to the maximum subindex."""
        return [e for e in (self.entry(s) for s in self.subindices) if e is not None]

    def __iter__(self) -> Iterator[OdEntry]:
        return iter(self.entries)

    def read(self, subindex: int = 0) -> Value:
        return self[subindex].read()

    def __repr__(self) -> str:
        return f"<OdObject 0x{self.index:04X} {self.object_code_name} {self.name!r}>"


class ObjectDictionary(Mapping[int, OdObject]):
    """A slave's object dictionary through the SDO information service (lazy, cached)."""

    def __init__(self, client: CoeClient) -> None:
        self.client = client
        self._indices: list[int] | None = None
        self._objects: dict[int, OdObject] = {}
        self._lock = threading.Lock()

    def indices(self) -> list[int]:
        """Indices of every object (fetched once)."""
        if self._indices is None:
            self._indices = self.client.od_list(OdListType.ALL)
        return self._indices

    def refresh(self) -> None:
        """Forget what was fetched (after the dictionary changed)."""
        with self._lock:
            self._indices = None
            self._objects.clear()

    def __getitem__(self, index: int) -> OdObject:
        with self._lock:
            obj = self._objects.get(index)
        if obj is None:
            try:
                desc = self.client.object_description(index)
            except SdoAbort as exc:
                if exc.code == SdoAbortCode.NO_OBJECT:
                    raise KeyError(f"{self.client.label}: no object 0x{index:04X}") from None
                raise
            obj = OdObject(self.client, desc)
            with self._lock:
                self._objects[index] = obj
        return obj

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices())

    def __len__(self) -> int:
        return len(self.indices())

    def __contains__(self, index: object) -> bool:
        return index in self.indices()

    def __repr__(self) -> str:
        n = "?" if self._indices is None else str(len(self._indices))
        return f"<ObjectDictionary of {self.client.label}: {n} objects>"


# --- start-up commands ------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class StartupCommand:
    """An SDO download the master does at a state transition (an ESI ``InitCmd``).

    Commands of transitions into PRE-OP (IP) run once the slave is in PRE-OP
    (the mailbox works only from there); all others run in the source state
    just before the target state is requested (PS: in PRE-OP before SAFE-OP).
    """

    position: int
    transition: str
    index: int
    subindex: int
    data: bytes
    complete_access: bool = False
    comment: str = ""
    timeout: float | None = None

    @property
    def runs_after(self) -> bool:
        """Whether the command runs after the transition (IP) rather than before it."""
        origin, target = TRANSITIONS[self.transition]
        return target == AlState.PREOP and origin in (AlState.INIT, AlState.BOOT)

    def describe(self) -> str:
        ca = " CA" if self.complete_access else ""
        note = f" ({self.comment})" if self.comment else ""
        return (f"{self.transition} 0x{self.index:04X}:{self.subindex:02X}{ca} = "
                f"{self.data.hex(' ')}{note}")

    def run(self, client: CoeClient) -> None:
        """Do the download; errors (aborts, timeouts, error replies) name the command."""
        try:
            client.download(self.index, self.subindex, self.data,
                            complete_access=self.complete_access, timeout=self.timeout)
        except EtherCATError as exc:
            exc.args = (f"start-up command {self.describe()}: {exc}",)
            raise

