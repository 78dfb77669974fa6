"""Sans-IO mailbox codecs shared by the master's clients and the simulator's servers.

Modules: :mod:`.header` (mailbox header, types, error replies, counters),
:mod:`.coe` (CoE: SDO, SDO information, emergency, transfer state machines),
:mod:`.datatypes` (CANopen basic data types), :mod:`.objects` (the standard
CoE object indices and subindices, one table), :mod:`.foe`, :mod:`.eoe`, :mod:`.soe`.

:func:`decode_message` turns a whole mailbox buffer into its header and a typed
message of the protocol the header names.
"""

from __future__ import annotations

from typing import TypeAlias

from pyethercat.errors import MailboxError, MailboxErrorReply
from pyethercat.wire.mailbox.coe import CoeMessage, decode_coe
from pyethercat.wire.mailbox.eoe import EoeMessage, decode_eoe
from pyethercat.wire.mailbox.foe import FoeMessage, decode_foe
from pyethercat.wire.mailbox.header import (
    MAILBOX_HEADER_SIZE,
    MailboxHeader,
    MailboxType,
    decode_mailbox,
    decode_mailbox_error,
    encode_mailbox,
    next_counter,
)
from pyethercat.wire.mailbox.objects import (
    StandardObject,
    SyncSub,
    is_rxpdo_mapping,
    is_txpdo_mapping,
    sm_pdo_assignment,
)
from pyethercat.wire.mailbox.soe import SoeMessage, decode_soe

__all__ = [
    "MAILBOX_HEADER_SIZE",
    "MailboxHeader",
    "MailboxType",
    "ProtocolMessage",
    "StandardObject",
    "SyncSub",
    "decode_mailbox",
    "decode_message",
    "encode_mailbox",
    "is_rxpdo_mapping",
    "is_txpdo_mapping",
    "next_counter",
    "sm_pdo_assignment",
]

#: A decoded mailbox payload of any protocol. (The master's transport calls the raw
#: header + payload it reads a ``MailboxMessage``; this is the typed content.)
ProtocolMessage: TypeAlias = (
    CoeMessage | FoeMessage | EoeMessage | SoeMessage | MailboxErrorReply | bytes
)


def decode_message(
    data: bytes | bytearray | memoryview,
) -> tuple[MailboxHeader, ProtocolMessage]:
    """Header and typed message of a mailbox buffer (may be padded to the SM length).

    Error replies (type 0) come back as a :class:`MailboxErrorReply` instance
    (not raised); AoE and VoE payloads, which are not decoded, as raw bytes.
    Unknown types raise :class:`MailboxError`.
    """
    header, payload = decode_mailbox(data)
    mtype = header.type
    if mtype == MailboxType.COE:
        return header, decode_coe(payload)
    if mtype == MailboxType.ERR:
        return header, decode_mailbox_error(payload)
    if mtype == MailboxType.FOE:
        return header, decode_foe(payload)
    if mtype == MailboxType.EOE:
        return header, decode_eoe(payload)
    if mtype == MailboxType.SOE:
        return header, decode_soe(payload)
    if mtype in (MailboxType.AOE, MailboxType.VOE):
        return header, payload
    raise MailboxError(f"unsupported mailbox type {int(mtype)}")
