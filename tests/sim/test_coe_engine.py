"""Mailbox engine and CoE server without a segment: reply queue, limits, odd requests."""

from __future__ import annotations

from pyethercat.errors import MailboxError
from pyethercat.sim.coe import CoeServer
from pyethercat.sim.mailbox import QUEUE_LIMIT, MailboxEngine
from pyethercat.sim.od import RW, SimObjectDictionary
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import (
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoReassembler,
    ValueInfo,
)
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.header import (
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
)


class FakePdi:
    """SM1 that holds one mailbox until ``read()``."""

    def __init__(self) -> None:
        self.sm1: bytes | None = None

    def post_mailbox(self, data: bytes) -> bool:
        if self.sm1 is not None:
            return False
        self.sm1 = data
        return True

    def read(self) -> bytes | None:
        data, self.sm1 = self.sm1, None
        return data


def engine() -> tuple[MailboxEngine, FakePdi]:
    pdi = FakePdi()
    return MailboxEngine(pdi), pdi  # type: ignore[arg-type]


def request(mtype: int, payload: bytes, counter: int = 0) -> bytes:
    return encode_mailbox(mtype, payload, counter=counter, size=128)


def test_replies_queue_while_sm1_is_full_and_keep_order() -> None:
    eng, pdi = engine()
    for n in range(3):
        eng.send(MailboxType.COE, bytes([n]))
    assert len(eng.queue) == 2
    got = []
    while (raw := pdi.read()) is not None:
        got.append(raw[6])
        eng.flush()
    assert got == [0, 1, 2]
    assert eng.last_reply[6] == 2


def test_full_queue_answers_no_more_memory() -> None:
    eng, pdi = engine()
    eng.register(MailboxType.COE, lambda h, p: eng.send(MailboxType.COE, p))
    for _ in range(QUEUE_LIMIT + 1):
        eng.send(MailboxType.COE, b"x")
    eng.receive(request(MailboxType.COE, b"\x00\x20"))
    assert len(eng.queue) == QUEUE_LIMIT
    header, msg = decode_message(eng.queue[-1])
    assert header.type == MailboxType.ERR
    assert msg.code == MailboxErrorCode.NO_MORE_MEMORY  # type: ignore[union-attr]


def test_handler_codec_failure_becomes_a_mailbox_error() -> None:
    eng, pdi = engine()

    def broken(header: MailboxHeader, payload: bytes) -> None:
        raise MailboxError("cannot encode that")

    eng.register(MailboxType.COE, broken)
    eng.receive(request(MailboxType.COE, b"\x00\x20", counter=1))
    header, msg = decode_message(pdi.read() or b"")
    assert header.type == MailboxType.ERR
    assert msg.code == MailboxErrorCode.SERVICE_NOT_SUPPORTED  # type: ignore[union-attr]


def test_short_buffer_is_a_syntax_error() -> None:
    eng, pdi = engine()
    eng.receive(b"\x01\x02")
    _h, msg = decode_message(pdi.read() or b"")
    assert msg.code == MailboxErrorCode.SYNTAX  # type: ignore[union-attr]


def test_entry_description_of_an_entry_longer_than_16_bit_lengths() -> None:
    od = SimObjectDictionary()
    od.var(0x2003, "Large", DataType.OCTET_STRING, RW, bytes(9000), max_length=9000)
    od.var(0x2004, "Small", DataType.OCTET_STRING, RW, bytes(8), max_length=8)
    sent: list[bytes] = []
    server = CoeServer(od, sent.append, lambda: AlState.PREOP, lambda: 128)
    vi = int(ValueInfo.DEFAULT_VALUE | ValueInfo.MAXIMUM_VALUE)
    for index, bits in ((0x2003, 0), (0x2004, 64)):
        sent.clear()
        req = SdoInfoGetEntryDescriptionRequest(index, 0, vi).encode()
        server.handle(MailboxHeader(len(req), MailboxType.COE), req)
        r = SdoInfoReassembler()
        out = [r.feed(p) for p in sent][-1]
        assert isinstance(out, SdoInfoGetEntryDescriptionResponse)
        assert out.bit_length == bits and out.default_value == bytes(bits // 8)
