"""The master's own object dictionary (ETG.1510 basics), served to mailbox gateway clients.

A gateway request addressed to 0 is for the master (ETG.8200). Engineering
tools read its identity and the list of slaves from it:

======  =====================================================================
0x1000  device type (u32, 0)
0x1008  device name ("pyethercat")
0x100A  software version (the package version)
0x1018  identity: vendor, product code, revision, serial
0x8nnn  slave n (ring position): 1 station address, 2 type (order number),
        3 name, 4 device type, 5-8 vendor/product/revision/serial, 33/34
        mailbox out/in sizes, 35 link status (bits 4-7: ports 0-3 link),
        38 port physics, 39 mailbox protocols
======  =====================================================================

(KickCAT ``lib/master/src/MasterOD.cc`` and IgH ``master/master.c``
``ec_master_obj_dict`` serve the same entries; subindex 1 is the station
address as ETG.1510 names it, where IgH reports position + 1000.)

Read-only: downloads are aborted with 0x06010002. Uploads are expedited,
normal or segmented, one mailbox per gateway request; a segmented upload
keeps its state per requester.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from importlib import metadata

from pyethercat.master.slave import Slave
from pyethercat.wire.mailbox.coe import (
    CoeService,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoInitiateDownloadRequest,
    SdoInitiateUploadRequest,
    SdoUploadSegmentRequest,
    SdoUploadServer,
    decode_coe,
)
from pyethercat.wire.mailbox.header import (
    MAILBOX_HEADER_SIZE,
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
    encode_mailbox_error,
)

__all__ = ["MASTER_PRODUCT_CODE", "MASTER_VENDOR_ID", "MasterObjectDictionary"]

#: "PEC" in ASCII, the project's (unassigned) vendor id, as the built-in simulated devices carry.
MASTER_VENDOR_ID = 0x00504543
#: Product code of the master in its identity object (0x1018:02).
MASTER_PRODUCT_CODE = 0x00000001

_STATION, _TYPE, _NAME, _DEVTYPE = 1, 2, 3, 4
_VENDOR, _PRODUCT, _REVISION, _SERIAL = 5, 6, 7, 8
_MBX_OUT, _MBX_IN, _LINK, _PHYSICS, _PROTOCOLS = 33, 34, 35, 38, 39


def _version() -> str:
    try:
        return metadata.version("pyethercat")
    except metadata.PackageNotFoundError:
        return "0"


def _u(value: int, size: int) -> bytes:
    return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def _slave_entry(s: Slave, sub: int) -> bytes | None:
    ident = s.identity
    sii = s.sii
    mbx = s.mailbox
    if sub == 0:
        return _u(_PROTOCOLS, 1)
    if sub == _STATION:
        return _u(s.station_address, 2)
    if sub == _TYPE:
        return ((sii.order_number if sii is not None else "") or "").encode("latin-1", "replace")
    if sub == _NAME:
        return s.name.encode("latin-1", "replace")
    if sub == _DEVTYPE:
        return _u(0, 4)
    if sub in (_VENDOR, _PRODUCT, _REVISION, _SERIAL):
        value = {_VENDOR: ident.vendor_id, _PRODUCT: ident.product_code,
                 _REVISION: ident.revision, _SERIAL: ident.serial}[sub]
        return _u(value or 0, 4)
    if sub == _MBX_OUT:
        return _u(mbx.rx_size if mbx is not None else 0, 2)
    if sub == _MBX_IN:
        return _u(mbx.tx_size if mbx is not None else 0, 2)
    if sub == _LINK:
        return _u(sum(1 << (4 + p.number) for p in s.ports if p.link), 1)
    if sub == _PHYSICS:
        return _u(sum(int(p.type) << (4 * p.number) for p in s.ports), 2)
    if sub == _PROTOCOLS:
        return _u(mbx.protocols if mbx is not None else 0, 2)
    return None


class MasterObjectDictionary:
    """Answers CoE requests addressed to the master (see the module text).

    ``slaves()`` gives the master's current slave list; ``mailbox_size`` the
    mailbox size the answers are cut for.
    """

    def __init__(self, slaves: Callable[[], Sequence[Slave]], *, name: str = "pyethercat",
                 serial: int = 0, mailbox_size: int = 1024) -> None:
        self.slaves = slaves
        self.name = name
        self.serial = serial
        self.mailbox_size = mailbox_size
        self._uploads: dict[object, SdoUploadServer] = {}

    def value(self, index: int, subindex: int) -> bytes | None:
        """The raw value of an entry, or None when there is none."""
        if index == 0x1000 and subindex == 0:
            return _u(0, 4)
        if index == 0x1008 and subindex == 0:
            return self.name.encode("latin-1", "replace")
        if index == 0x100A and subindex == 0:
            return _version().encode()
        if index == 0x1018:
            values = {0: _u(4, 1), 1: _u(MASTER_VENDOR_ID, 4), 2: _u(MASTER_PRODUCT_CODE, 4),
                      3: _u(1, 4), 4: _u(self.serial, 4)}
            return values.get(subindex)
        slaves = self.slaves()
        if 0x8000 <= index < 0x8000 + min(len(slaves), 0xFFF):
            return _slave_entry(slaves[index - 0x8000], subindex)
        return None

    def exists(self, index: int) -> bool:
        """Whether the object exists at all (the abort code differs)."""
        return (index in (0x1000, 0x1008, 0x100A, 0x1018)
                or 0x8000 <= index < 0x8000 + min(len(self.slaves()), 0xFFF))

    def handle(self, mailbox: bytes, requester: object = None) -> bytes:
        """The reply mailbox (header + data) to one request mailbox."""
        header = MailboxHeader.decode(mailbox)
        payload = mailbox[MAILBOX_HEADER_SIZE:MAILBOX_HEADER_SIZE + header.length]

        def reply(mtype: int, data: bytes) -> bytes:
            return encode_mailbox(mtype, data, address=header.address)

        if header.type != MailboxType.COE:
            return reply(MailboxType.ERR,
                         encode_mailbox_error(MailboxErrorCode.UNSUPPORTED_PROTOCOL))
        try:
            msg = decode_coe(payload)
        except Exception:  # noqa: BLE001 - MailboxError: a request we do not understand
            return reply(MailboxType.ERR,
                         encode_mailbox_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED))
        if isinstance(msg, SdoInitiateUploadRequest):
            if msg.complete_access:
                return reply(MailboxType.COE, SdoAbortTransfer(
                    msg.index, msg.subindex, SdoAbortCode.CA_VARIABLE_LENGTH).encode())
            data = self.value(msg.index, msg.subindex)
            if data is None:
                code = (SdoAbortCode.NO_SUBINDEX if self.exists(msg.index)
                        else SdoAbortCode.NO_OBJECT)
                return reply(MailboxType.COE,
                             SdoAbortTransfer(msg.index, msg.subindex, code).encode())
            server = SdoUploadServer(msg.index, msg.subindex, data,
                                     mailbox_size=self.mailbox_size)
            first = server.start()
            if not server.done:
                self._uploads[requester] = server
            return reply(MailboxType.COE, first.encode())
        if isinstance(msg, SdoUploadSegmentRequest):
            pending = self._uploads.get(requester)
            if pending is None:
                return reply(MailboxType.COE, SdoAbortTransfer(
                    0, 0, SdoAbortCode.INVALID_COMMAND, CoeService.SDO_REQUEST).encode())
            answer = pending.receive(msg)
            if pending.done:
                self._uploads.pop(requester, None)
            return reply(MailboxType.COE, answer.encode())
        if isinstance(msg, SdoInitiateDownloadRequest):
            return reply(MailboxType.COE, SdoAbortTransfer(
                msg.index, msg.subindex, SdoAbortCode.READ_ONLY).encode())
        return reply(MailboxType.ERR,
                     encode_mailbox_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED))
