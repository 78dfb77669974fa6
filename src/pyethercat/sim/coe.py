"""CoE server of a simulated slave: SDO, SDO information, emergency, PDO mapping.

:class:`CoeServer` answers CoE mailboxes against an
:class:`~pyethercat.sim.od.ObjectDictionary`: SDO upload and download
(expedited, normal, segmented with toggle checks, complete access with the
subindex 0 and 1 variants), SDO information (OD lists of every list type,
object and entry descriptions with value info, fragmented to the mailbox
size) and aborts with the codes of facts 7.5. It uses the sans-IO codecs and
transfer state machines of :mod:`pyethercat.wire.mailbox.coe`.

:class:`PdoMapping` makes the mapping objects real: 0x1C12/0x1C13 (PDO
assignment of SM2/SM3) and 0x1600.../0x1A00... (PDO mapping) define the
process-data layout. They are writable in PREOP only, follow the CiA 301
sequence (write subindex 0 = 0, write the entries, write subindex 0 = n) and
are validated (mapped object exists, is mappable in that direction, bit
length matches, the SM buffer is large enough). The resulting byte sizes are
what the ESC compares with the SM2/SM3 lengths on PREOP -> SAFEOP
(``DeviceApp.process_data_sizes``), and the layout is how outputs reach the
dictionary and inputs leave it.

:class:`CoeDevice` puts it together as a device application: a mailbox engine
with CoE registered, the PDO mapping, a process-data exchange on every
completed output buffer, :meth:`CoeDevice.emergency`, and the standard objects
(:func:`add_identity`, :func:`add_sync_manager_objects`, ...).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.sim.device import Pdi
from pyethercat.sim.mailbox import MailboxDevice, service_error
from pyethercat.sim.od import (
    RO,
    RW,
    RW_PREOP,
    ObjectDictionary,
    OdEntry,
    OdObject,
    sdo_abort,
)
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import (
    COE_HEADER_SIZE,
    SDO_HEADER_SIZE,
    CoeHeader,
    CoeMessage,
    CoeService,
    Emergency,
    ObjectAccess,
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
from pyethercat.wire.mailbox.objects import (
    IdentitySub,
    StandardObject,
    SyncMode,
    SyncModeSupported,
    SyncSub,
    assignment_sm,
    is_pdo_mapping,
    is_rxpdo_mapping,
    is_txpdo_mapping,
    mapping_word,
    sm_pdo_assignment,
    split_mapping_word,
)
from pyethercat.wire.sii import CoeDetails, SiiInfo, SyncManagerType

__all__ = [
    "CoeDevice",
    "CoeServer",
    "PdoMapping",
    "MappedEntry",
    "add_device_info",
    "add_identity",
    "add_pdo_assignment",
    "add_pdo_mapping",
    "add_sync_manager_objects",
    "add_sync_parameters",
    "mapping_word",
]

_FULL_COE = (CoeDetails.SDO | CoeDetails.SDO_INFO | CoeDetails.PDO_ASSIGN | CoeDetails.PDO_CONFIG
             | CoeDetails.SDO_COMPLETE_ACCESS)
_SDO_REQUEST_MIN = COE_HEADER_SIZE + SDO_HEADER_SIZE
# Plain ints for the lookups made on every output buffer: cheaper than enum members.
_RX_ASSIGN = int(StandardObject.RXPDO_ASSIGNMENT)
_TX_ASSIGN = int(StandardObject.TXPDO_ASSIGNMENT)
_SM_OUTPUT_SYNC = int(StandardObject.SM_OUTPUT_SYNC)
_CYCLE_TIME_SUB = int(SyncSub.CYCLE_TIME)


# --- the SDO server ------------------------------------------------------------------


class CoeServer:
    """Serves the CoE protocol of one slave (see the module docstring).

    ``send(payload)`` queues one CoE payload for SM1; ``state()`` gives the AL
    state; ``mailbox_size()`` the SM1 length (segment and fragment sizes).
    ``details`` are the SII CoE details: without SDO_INFO the information
    service is "not supported", without SDO_COMPLETE_ACCESS complete access
    aborts with 0x06010000.
    """

    def __init__(self, od: ObjectDictionary, send: Callable[[bytes], None],
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


def _type_limits(e: OdEntry) -> tuple[bytes, bytes]:
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


# --- PDO mapping ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MappedEntry:
    """One entry of the process image: where it sits and which OD entry it is."""

    index: int
    subindex: int
    bit_offset: int
    bits: int
    entry: OdEntry | None  # None: a gap (mapping index 0)


class PdoMapping:
    """The mapping and assignment objects of one slave and the layout they define.

    ``capacity_out``/``capacity_in`` are the largest SM2/SM3 buffers (bytes)
    the device has room for (0x06040042 beyond). ``configurable`` (SII CoE
    detail "PDO configuration") makes 0x16xx/0x1Axx writable in PREOP;
    ``assignable`` ("PDO assign") does the same for 0x1C12/0x1C13.
    ``on_change`` is called after a change of the layout.
    """

    def __init__(self, od: ObjectDictionary, *, capacity_out: int = 128,
                 capacity_in: int = 128, on_change: Callable[[], None] | None = None) -> None:
        self.od = od
        self.capacity = {_RX_ASSIGN: capacity_out, _TX_ASSIGN: capacity_in}
        self.on_change = on_change
        self.outputs: tuple[MappedEntry, ...] = ()
        self.inputs: tuple[MappedEntry, ...] = ()
        self.output_bits = 0
        self.input_bits = 0
        for obj in od:
            if is_pdo_mapping(obj.index) or obj.index in (_RX_ASSIGN, _TX_ASSIGN):
                obj.check = self._check
                obj.after = self._after
        self.rebuild()

    # --- layout -------------------------------------------------------------------

    def _assigned(self, assign_index: int, overlay: dict[int, bytes] | None = None) -> list[int]:
        obj = self.od.find(assign_index)
        if obj is None:
            return []
        count = _u(overlay, obj, 0)
        return [_u(overlay, obj, s) for s in range(1, count + 1) if s in obj.entries]

    def _words(self, pdo: int, overlay: dict[int, bytes] | None = None) -> list[int]:
        obj = self.od.find(pdo)
        if obj is None:
            return []
        count = _u(overlay, obj, 0)
        return [_u(overlay, obj, s) for s in range(1, count + 1) if s in obj.entries]

    def _layout(self, assign_index: int) -> tuple[tuple[MappedEntry, ...], int]:
        out: list[MappedEntry] = []
        pos = 0
        for pdo in self._assigned(assign_index):
            for word in self._words(pdo):
                index, sub, bits = split_mapping_word(word)
                entry = None
                if index:
                    obj = self.od.find(index)
                    entry = obj.entries.get(sub) if obj is not None else None
                out.append(MappedEntry(index, sub, pos, bits, entry))
                pos += bits
        return tuple(out), pos

    def rebuild(self) -> None:
        """Recompute the layout from the current objects."""
        self.outputs, self.output_bits = self._layout(_RX_ASSIGN)
        self.inputs, self.input_bits = self._layout(_TX_ASSIGN)
        self.od.rx_mapped = frozenset((m.index, m.subindex) for m in self.outputs if m.entry)
        self._out_plan = _plan(self.outputs)
        self._in_plan = _plan(self.inputs)

    def sizes(self) -> tuple[int, int]:
        """(output bytes, input bytes) the SM2/SM3 buffers must have."""
        return (self.output_bits + 7) // 8, (self.input_bits + 7) // 8

    # --- process data --------------------------------------------------------------

    def unpack_outputs(self, data: bytes) -> None:
        """Store an SM2 buffer's values into the mapped OD entries."""
        for entry, byte, nbytes, shift, bits in self._out_plan:
            if shift < 0:
                entry.raw[:nbytes] = data[byte: byte + nbytes]
            else:
                chunk = int.from_bytes(data[byte: byte + nbytes + 1], "little")
                value = (chunk >> shift) & ((1 << bits) - 1)
                entry.raw[:] = value.to_bytes(len(entry.raw) or 1, "little")

    def pack_inputs(self) -> bytes:
        """The SM3 buffer built from the mapped OD entries."""
        out = bytearray((self.input_bits + 7) // 8)
        acc = 0
        for entry, byte, nbytes, shift, bits in self._in_plan:
            raw = entry.read()
            if shift < 0:
                out[byte: byte + nbytes] = raw[:nbytes].ljust(nbytes, b"\x00")
            else:
                acc |= (int.from_bytes(raw, "little") & ((1 << bits) - 1)) << (8 * byte + shift)
        if acc:
            merged = int.from_bytes(out, "little") | acc
            out = bytearray(merged.to_bytes(len(out), "little"))
        return bytes(out)

    # --- validation hooks ------------------------------------------------------------

    def _check(self, obj: OdObject, changes: dict[int, bytes], complete: bool) -> None:
        index = obj.index
        if not complete:
            subs = [s for s in changes if s != 0]
            if subs and obj.count() != 0:
                raise sdo_abort(SdoAbortCode.SUBINDEX_WRITE, index, subs[0],
                                "write subindex 0 = 0 first")
        if index in (_RX_ASSIGN, _TX_ASSIGN):
            self._check_assignment(obj, changes)
        else:
            self._check_mapping(obj, changes)

    def _check_mapping(self, obj: OdObject, changes: dict[int, bytes]) -> None:
        index = obj.index
        rx = is_rxpdo_mapping(index)
        flag = int(ObjectAccess.RXPDO_MAPPABLE if rx else ObjectAccess.TXPDO_MAPPABLE)
        for sub, raw in changes.items():
            if sub:
                self._check_word(index, sub, int.from_bytes(raw, "little"), flag)
        if 0 in changes:
            words = self._words(index, changes)
            for n, word in enumerate(words, 1):
                self._check_word(index, n, word, flag)
            bits = sum(w & 0xFF for w in words)
            assign = _RX_ASSIGN if rx else _TX_ASSIGN
            total = bits + sum(sum(w & 0xFF for w in self._words(p))
                               for p in self._assigned(assign) if p != index)
            limit = 8 * self.capacity[assign]
            if bits > limit or (index in self._assigned(assign) and total > limit):
                raise sdo_abort(SdoAbortCode.PDO_LENGTH_EXCEEDED, index, 0,
                                f"{bits} bits, SM buffer holds {limit}")

    def _check_word(self, pdo: int, sub: int, word: int, flag: int) -> None:
        index, subindex, bits = split_mapping_word(word)
        if index == 0:
            return  # a gap of `bits` bits
        obj = self.od.find(index)
        if obj is None:
            raise sdo_abort(SdoAbortCode.NO_OBJECT, pdo, sub, f"0x{index:04X} does not exist")
        e = obj.entries.get(subindex)
        if e is None:
            raise sdo_abort(SdoAbortCode.NO_SUBINDEX, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} does not exist")
        if not e.access & flag:
            raise sdo_abort(SdoAbortCode.NOT_MAPPABLE, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} is not mappable here")
        if bits != e.bit_length:
            raise sdo_abort(SdoAbortCode.PARAMETER_INCOMPATIBLE, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} has {e.bit_length} bits, not {bits}")

    def _check_assignment(self, obj: OdObject, changes: dict[int, bytes]) -> None:
        index = obj.index
        of_direction = is_rxpdo_mapping if index == _RX_ASSIGN else is_txpdo_mapping
        for sub, raw in changes.items():
            if sub:
                pdo = int.from_bytes(raw, "little")
                if not (of_direction(pdo) and pdo in self.od):
                    raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, sub,
                                    f"0x{pdo:04X} is no PDO of this direction")
        if 0 in changes:
            pdos = self._assigned(index, changes)
            for n, pdo in enumerate(pdos, 1):
                if not (of_direction(pdo) and pdo in self.od):
                    raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, n,
                                    f"0x{pdo:04X} is no PDO of this direction")
            if len(set(pdos)) != len(pdos):
                raise sdo_abort(SdoAbortCode.PARAMETER_INCOMPATIBLE, index, 0,
                                "a PDO is assigned twice")
            bits = sum(sum(w & 0xFF for w in self._words(p)) for p in pdos)
            if bits > 8 * self.capacity[index]:
                raise sdo_abort(SdoAbortCode.PDO_LENGTH_EXCEEDED, index, 0,
                                f"{bits} bits, SM buffer holds {8 * self.capacity[index]}")

    def _after(self, obj: OdObject, changes: dict[int, bytes], complete: bool) -> None:
        self.rebuild()
        if self.on_change is not None:
            self.on_change()


def _u(overlay: dict[int, bytes] | None, obj: OdObject, sub: int) -> int:
    if overlay is not None and sub in overlay:
        return int.from_bytes(overlay[sub], "little")
    e = obj.entries.get(sub)
    return int.from_bytes(e.read(), "little") if e is not None else 0


_Plan = list[tuple[OdEntry, int, int, int, int]]


def _plan(layout: Sequence[MappedEntry]) -> _Plan:
    """Copy operations: (entry, byte, nbytes, shift, bits); shift -1 for whole bytes."""
    plan: _Plan = []
    for m in layout:
        if m.entry is None:
            continue
        byte, shift = divmod(m.bit_offset, 8)
        if shift == 0 and m.bits % 8 == 0:
            plan.append((m.entry, byte, m.bits // 8, -1, m.bits))
        else:
            plan.append((m.entry, byte, (shift + m.bits + 7) // 8, shift, m.bits))
    return plan


# --- standard objects ----------------------------------------------------------------


def add_device_info(od: ObjectDictionary, device_type: int, name: str, hardware: str = "",
                    software: str = "") -> None:
    """0x1000 device type, 0x1001 error register and the 0x1008/0x1009/0x100A strings."""
    std = StandardObject
    od.var(std.DEVICE_TYPE, "Device type", DataType.UNSIGNED32, RO, device_type)
    od.var(std.ERROR_REGISTER, "Error register", DataType.UNSIGNED8, RO, 0)
    od.var(std.DEVICE_NAME, "Manufacturer device name", DataType.VISIBLE_STRING, RO, name)
    if hardware:
        od.var(std.HARDWARE_VERSION, "Manufacturer hardware version", DataType.VISIBLE_STRING,
               RO, hardware)
    if software:
        od.var(std.SOFTWARE_VERSION, "Manufacturer software version", DataType.VISIBLE_STRING,
               RO, software)


def add_identity(od: ObjectDictionary, vendor: int, product: int, revision: int,
                 serial: int = 0) -> None:
    """0x1018 identity (vendor id, product code, revision, serial number)."""
    od.record(StandardObject.IDENTITY, "Identity", [
        OdEntry(IdentitySub.VENDOR_ID, "Vendor ID", DataType.UNSIGNED32, RO, vendor),
        OdEntry(IdentitySub.PRODUCT_CODE, "Product code", DataType.UNSIGNED32, RO, product),
        OdEntry(IdentitySub.REVISION, "Revision", DataType.UNSIGNED32, RO, revision),
        OdEntry(IdentitySub.SERIAL_NUMBER, "Serial number", DataType.UNSIGNED32, RO, serial),
    ], data_type=int(DataType.IDENTITY))


def add_pdo_mapping(od: ObjectDictionary, index: int, name: str,
                    entries: Iterable[tuple[int, int, int]], *, max_entries: int = 8,
                    access: int = RW_PREOP) -> OdObject:
    """A PDO mapping object 0x16xx/0x1Axx with ``(index, subindex, bits)`` entries."""
    words = [mapping_word(*e) for e in entries]
    obj = od.array(index, name, DataType.UNSIGNED32, words, access, count_access=access,
                   length=max_entries,
                   names=[f"SubIndex {n:03d}" for n in range(1, max_entries + 1)])
    return obj


def add_pdo_assignment(od: ObjectDictionary, index: int, pdos: Sequence[int], *,
                       max_entries: int = 4, access: int = RW_PREOP,
                       assigned: int | None = None) -> OdObject:
    """0x1C12/0x1C13: subindex n = PDO index; subindex 0 = ``assigned`` (default: all)."""
    name = ("RxPDO assign" if index == _RX_ASSIGN else "TxPDO assign" if index == _TX_ASSIGN
            else f"SM{assignment_sm(index)} PDO assign")
    obj = od.array(index, name, DataType.UNSIGNED16, list(pdos), access, count_access=access,
                   length=max_entries)
    if assigned is not None:
        obj.entries[0].raw[:] = bytes([assigned])
    return obj


#: SM communication types (0x1C00) of the usual SM0-SM3 layout.
_STANDARD_SM_TYPES = (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN,
                      SyncManagerType.OUTPUTS, SyncManagerType.INPUTS)


def add_sync_manager_objects(od: ObjectDictionary,
                             types: Sequence[int] = _STANDARD_SM_TYPES) -> None:
    """0x1C00 SM communication types and the (empty) 0x1C10/0x1C11 mailbox assignments.

    ``types`` are SII SyncM type codes (:class:`~pyethercat.wire.sii.SyncManagerType`),
    the numbering 0x1C00 uses too.
    """
    od.array(StandardObject.SM_COMM_TYPE, "Sync manager type", DataType.UNSIGNED8,
             [int(t) for t in types], RO)
    for n, t in enumerate(types[:2]):
        if t in (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN):
            od.array(sm_pdo_assignment(n), f"SM{n} PDO assign", DataType.UNSIGNED16, [], RO)


_DEFAULT_SYNC_SUPPORT = int(SyncModeSupported.FREE_RUN | SyncModeSupported.SYNCHRONOUS
                            | SyncModeSupported.DC_SYNC0)


def add_sync_parameters(od: ObjectDictionary, index: int, *, mode: int,
                        supported: int = _DEFAULT_SYNC_SUPPORT,
                        min_cycle_ns: int = 100_000) -> None:
    """0x1C32 (outputs) or 0x1C33 (inputs) synchronisation parameters (facts 7.9)."""
    name = "SM output parameter" if index == _SM_OUTPUT_SYNC else "SM input parameter"
    u16, u32 = DataType.UNSIGNED16, DataType.UNSIGNED32
    modes = frozenset(int(m) for m in SyncMode)
    S = SyncSub
    od.record(index, name, [
        OdEntry(S.SYNC_MODE, "Sync mode", u16, RW_PREOP, mode, allowed=modes),
        OdEntry(S.CYCLE_TIME, "Cycle time", u32, RO, 0),
        OdEntry(S.SHIFT_TIME, "Shift time", u32, RO, 0),
        OdEntry(S.SYNC_MODES_SUPPORTED, "Sync modes supported", u16, RO, supported),
        OdEntry(S.MIN_CYCLE_TIME, "Minimum cycle time", u32, RO, min_cycle_ns),
        OdEntry(S.CALC_AND_COPY_TIME, "Calc and copy time", u32, RO, 0),
        OdEntry(S.MIN_DELAY_TIME, "Minimum delay time", u32, RO, 0),
        OdEntry(S.GET_CYCLE_TIME, "Get cycle time", u16, RW, 0, maximum=3),
        OdEntry(S.DELAY_TIME, "Delay time", u32, RO, 0),
        OdEntry(S.SYNC0_CYCLE_TIME, "Sync0 cycle time", u32, RW_PREOP, 0),
        OdEntry(S.SM_EVENT_MISSED, "SM event missed", u16, RO, 0),
        OdEntry(S.CYCLE_TIME_TOO_SMALL, "Cycle time too small", u16, RO, 0),
        OdEntry(S.SYNC_ERROR, "Sync error", DataType.BOOLEAN, RO, False),
    ], data_type=int(DataType.SYNC_PAR))


# --- the device application ----------------------------------------------------------


class CoeDevice(MailboxDevice):
    """A slave with a CoE server, PDO mapping and process-data exchange.

    Subclasses build the dictionary (``od``) before calling ``__init__`` of
    this class, or pass one, and override :meth:`update` to compute inputs
    from outputs. ``details`` are the SII CoE details the device announces.
    """

    wants_output_events = True

    def __init__(self, od: ObjectDictionary, *, details: int = _FULL_COE,
                 capacity_out: int = 128, capacity_in: int = 128) -> None:
        super().__init__()
        self.od = od
        self.pdo = PdoMapping(od, capacity_out=capacity_out, capacity_in=capacity_in,
                              on_change=self._mapping_changed)
        self.coe = CoeServer(od, self._send_coe, self._state, self._mailbox_size, details)
        self.mailbox.register(MailboxType.COE, self.coe.handle)
        self._last_outputs_ns: int | None = None
        self.emergencies: list[Emergency] = []

    # --- ESC glue -----------------------------------------------------------------

    def _send_coe(self, payload: bytes) -> None:
        self.mailbox.send(MailboxType.COE, payload)

    def _state(self) -> AlState:
        return self.pdi.al_state() if self.pdi is not None else AlState.PREOP

    def _mailbox_size(self) -> int:
        if self.pdi is None:
            return 128
        raw = self.pdi.read(R.sm_address(1) + R.SM_LENGTH, 2)
        return int.from_bytes(raw, "little") or 128

    def process_data_sizes(self) -> tuple[int, int]:
        """(output bytes, input bytes) from the current PDO assignment and mapping."""
        return self.pdo.sizes()

    def attach(self, pdi: Pdi) -> None:
        super().attach(pdi)
        self.on_attach(pdi)

    def on_attach(self, pdi: Pdi) -> None:
        """Hook for subclasses: the PDI is available."""

    def on_state_change(self, old: AlState, new: AlState) -> None:
        super().on_state_change(old, new)
        if new in (AlState.SAFEOP, AlState.OP) and old not in (AlState.SAFEOP, AlState.OP):
            self._last_outputs_ns = None
            self.update()
            self.publish_inputs()

    def on_outputs(self) -> None:
        pdi = self.pdi
        if pdi is None:
            return
        data = pdi.outputs()
        if data:
            self.pdo.unpack_outputs(data)
        now = pdi.now_ns()
        if self._last_outputs_ns is not None and _SM_OUTPUT_SYNC in self.od:
            cycle = max(0, min(now - self._last_outputs_ns, 0xFFFFFFFF))
            self.od.entry(_SM_OUTPUT_SYNC, _CYCLE_TIME_SUB).raw[:] = cycle.to_bytes(4, "little")
        self._last_outputs_ns = now
        self.update()
        self.publish_inputs()

    def _mapping_changed(self) -> None:
        """The layout changed (in PREOP): nothing is exchanged until SAFEOP."""

    # --- application API ----------------------------------------------------------

    def update(self) -> None:
        """Compute inputs from outputs (called after each output buffer); default: nothing."""

    def publish_inputs(self) -> None:
        """Write the mapped input entries into the SM3 buffer."""
        if self.pdi is not None and self.pdo.input_bits:
            self.pdi.set_inputs(self.pdo.pack_inputs())

    def emergency(self, code: int, register: int = 0, data: bytes = bytes(5)) -> bool:
        """Send a CoE emergency (and set 0x1001); False when the mailbox is not running."""
        msg = Emergency(code, register, bytes(data).ljust(5, b"\x00")[:5])
        if StandardObject.ERROR_REGISTER in self.od:
            self.od.set_value(StandardObject.ERROR_REGISTER, 0, register)
        if self._state() in (AlState.INIT, AlState.BOOT):
            return False
        self.emergencies.append(msg)
        self.mailbox.send(MailboxType.COE, msg.encode())
        return True


def identity_from_sii(info: SiiInfo) -> tuple[int, int, int, int]:
    """(vendor, product, revision, serial) of an SII image, for 0x1018."""
    return info.vendor_id, info.product_code, info.revision, info.serial
