"""Decode any CoE mailbox payload into its typed message."""

from __future__ import annotations

import struct
from typing import TypeAlias

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.coe.emergency import PDO_SERVICES, CoePdo, Emergency
from pyethercat.wire.mailbox.coe.header import COE_HEADER_SIZE, CoeHeader, CoeService, need
from pyethercat.wire.mailbox.coe.info import (
    SdoInfoFragment,
    SdoInfoMessage,
    decode_sdo_info_body,
)
from pyethercat.wire.mailbox.coe.sdo import SdoMessage, decode_sdo

__all__ = ["CoeMessage", "decode_coe"]

CoeMessage: TypeAlias = SdoMessage | CoePdo | Emergency | SdoInfoMessage | SdoInfoFragment


def decode_coe(payload: bytes | bytearray | memoryview) -> CoeMessage:
    """Typed message from a CoE mailbox payload (CoE header first).

    SDO information frames with the incomplete bit set come back as
    :class:`SdoInfoFragment`; the last fragment of a fragmented response looks
    like a complete frame, so a client in the middle of one uses
    :class:`~pyethercat.wire.mailbox.coe.info.SdoInfoReassembler` on the raw
    payloads instead.

    Raises :class:`MailboxError` for anything malformed or unknown (block
    transfer command specifiers included).
    """
    payload = bytes(payload)
    header = CoeHeader.decode(payload)
    body = payload[COE_HEADER_SIZE:]
    service = header.service
    if service in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE):
        return decode_sdo(service, body)
    if service == CoeService.EMERGENCY:
        need(body, 8, "CoE emergency")
        code, reg = struct.unpack_from("<HB", body, 0)
        return Emergency(code, reg, body[3:8])
    if service in PDO_SERVICES:
        return CoePdo(CoeService(service), header.number, body)
    if service == CoeService.SDO_INFORMATION:
        frag = SdoInfoFragment.from_payload(payload)
        if frag.incomplete:
            return frag
        return decode_sdo_info_body(frag.opcode, frag.data)
    raise MailboxError(f"unknown CoE service {int(service)}")
