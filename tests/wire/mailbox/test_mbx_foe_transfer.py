"""FoE transfer state machines: clients against the server, and against hand-made slaves."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import (
    FoeAbort,
    FoeChecksumError,
    FoeDiskFull,
    FoeIllegal,
    FoeNoRights,
    FoeNotFound,
    FoePacketNumberWrong,
    FoeTimeoutError,
)
from pyethercat.wire.mailbox.foe import (
    FoeAck,
    FoeBusy,
    FoeData,
    FoeError,
    FoeErrorCode,
    FoeMessage,
    FoeReadRequest,
    FoeWriteRequest,
    decode_foe,
)
from pyethercat.wire.mailbox.foe_transfer import (
    FoeReadClient,
    FoeServer,
    FoeWriteClient,
    abort,
)


class Files:
    """An in-memory file store with a password and a size limit, as a slave has."""

    def __init__(self, limit: int | None = None) -> None:
        self.files: dict[str, bytes] = {}
        self.limit = limit
        self.password = 0

    def open_read(self, name: str, password: int) -> bytes:
        if name not in self.files:
            raise abort(FoeErrorCode.NOT_FOUND, name)
        return self.files[name]

    def open_write(self, name: str, password: int) -> int | None:
        if password != self.password:
            raise abort(FoeErrorCode.NO_RIGHTS)
        return self.limit

    def close_write(self, name: str, data: bytes) -> None:
        if name.endswith(".bad"):
            raise abort(FoeErrorCode.CHECKSUM_ERROR, "image check failed")
        self.files[name] = data


def wire(msg: FoeMessage) -> FoeMessage:
    """Through encode/decode, as on the mailbox."""
    return decode_foe(msg.encode())


def run_write(client: FoeWriteClient, server: FoeServer, size: int,
              busy_at: set[int] = frozenset()) -> list[FoeMessage]:  # type: ignore[assignment]
    sent: list[FoeMessage] = []
    msg: FoeMessage | None = client.start(0.0)
    busy_left = set(busy_at)
    while msg is not None:
        sent.append(msg)
        if isinstance(msg, FoeData) and msg.packet in busy_left:
            busy_left.discard(msg.packet)
            reply: FoeMessage | None = FoeBusy(msg.packet, 100)
        else:
            reply = server.receive(wire(msg), size, size)
        assert reply is not None
        msg = client.receive(wire(reply), 0.0)
    return sent


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 700), st.integers(13, 80))
def test_write_then_read_any_size(length: int, mailbox: int) -> None:
    data = bytes((i * 7 + 3) & 0xFF for i in range(length))
    files = Files()
    server = FoeServer(files)
    client = FoeWriteClient("f.bin", data, mailbox_size=mailbox)
    sent = run_write(client, server, mailbox)
    full = mailbox - 12
    datas = [m for m in sent if isinstance(m, FoeData)]
    assert [m.packet for m in datas] == list(range(1, len(datas) + 1))
    assert all(len(m.data) == full for m in datas[:-1]) and len(datas[-1].data) < full
    if length % full == 0:
        assert datas[-1].data == b""  # the 0-byte final packet
    assert client.done and files.files["f.bin"] == data
    assert client.progress.done == length and client.progress.fraction == 1.0

    reader = FoeReadClient("f.bin", mailbox_size=mailbox)
    msg: FoeMessage | None = reader.start(0.0)
    while not reader.done:
        assert msg is not None
        reply = server.receive(wire(msg), mailbox, mailbox)
        assert reply is not None
        msg = reader.receive(wire(reply), 0.0)
    assert reader.data == data
    assert isinstance(msg, FoeAck)  # the last packet is acknowledged too (as SOEM does)
    assert server.receive(wire(msg), mailbox, mailbox) is None and not server.busy_transfer


def test_busy_makes_the_master_resend_the_same_packet() -> None:
    files = Files()
    server = FoeServer(files)
    data = bytes(range(200))
    client = FoeWriteClient("x", data, mailbox_size=32)
    seen: list[FoeBusy | None] = []
    sent: list[FoeMessage] = []
    msg: FoeMessage | None = client.start(0.0)
    while msg is not None:
        sent.append(msg)
        if isinstance(msg, FoeData) and msg.packet == 3 and client.busy_count < 2:
            reply: FoeMessage | None = FoeBusy(40, 100, "flashing")
        else:
            reply = server.receive(wire(msg), 32, 32)
        assert reply is not None
        msg = client.receive(wire(reply), 0.0)
        seen.append(client.progress.busy)
    assert files.files["x"] == data
    threes = [m for m in sent if isinstance(m, FoeData) and m.packet == 3]
    assert len(threes) == 3 and len({m.data for m in threes}) == 1
    assert client.busy_count == 2
    assert any(b is not None and b.done == 40 and b.text == "flashing" for b in seen)


def test_busy_before_the_first_packet_is_waited_out() -> None:
    client = FoeWriteClient("x", b"abc", mailbox_size=32)
    client.start(0.0)
    assert client.receive(FoeBusy(0, 0), 1.0) is None  # SOEM: ignore, keep waiting
    nxt = client.receive(FoeAck(0), 1.5)
    assert nxt == FoeData(1, b"abc")


def test_busy_in_a_read_repeats_the_last_message() -> None:
    reader = FoeReadClient("f", mailbox_size=32)
    rrq = reader.start(0.0)
    assert reader.receive(FoeBusy(), 0.1) == rrq
    ack = reader.receive(FoeData(1, bytes(20)), 0.2)
    assert ack == FoeAck(1)
    assert reader.receive(FoeBusy(), 0.3) == ack


@pytest.mark.parametrize("code,cls", [
    (FoeErrorCode.NOT_FOUND, FoeNotFound),
    (FoeErrorCode.NO_RIGHTS, FoeNoRights),
    (FoeErrorCode.CHECKSUM_ERROR, FoeChecksumError),
    (FoeErrorCode.DISK_FULL, FoeDiskFull),
    (0x8123, FoeAbort),
])
def test_every_error_is_typed_with_its_text(code: int, cls: type[FoeAbort]) -> None:
    client = FoeWriteClient("x", b"", mailbox_size=32)
    client.start(0.0)
    with pytest.raises(cls) as info:
        client.receive(wire(FoeError(code, "said the slave")), 0.0)
    assert type(info.value) is cls and info.value.code == code
    assert "said the slave" in str(info.value) and not info.value.by_master
    assert client.done and client.abort_request is None


def test_all_thirteen_codes_have_their_class() -> None:
    for code in FoeErrorCode:
        exc = abort(code)
        assert code == type(exc).CODE and exc.name in str(exc)


def test_server_refusals_reach_the_client_typed() -> None:
    files = Files(limit=50)
    files.files["a"] = b"x"
    server = FoeServer(files)
    with pytest.raises(FoeNotFound, match="nope"):
        reader = FoeReadClient("nope", mailbox_size=32)
        reader.receive(server.receive(reader.start(0.0), 32, 32) or FoeAck(0), 0.0)
    files.password = 7
    with pytest.raises(FoeNoRights):
        run_write(FoeWriteClient("w", b"1", mailbox_size=32), server, 32)
    files.password = 0
    with pytest.raises(FoeDiskFull):
        run_write(FoeWriteClient("w", bytes(60), mailbox_size=32), server, 32)
    with pytest.raises(FoeChecksumError, match="image check failed"):
        run_write(FoeWriteClient("fw.bad", bytes(30), mailbox_size=32), server, 32)
    assert "w" not in files.files and "fw.bad" not in files.files


def test_wrong_packet_number_aborts_with_the_err_to_send() -> None:
    client = FoeWriteClient("x", bytes(100), mailbox_size=32)
    client.start(0.0)
    client.receive(FoeAck(0), 0.0)
    with pytest.raises(FoePacketNumberWrong) as info:
        client.receive(FoeAck(5), 0.0)
    assert info.value.by_master
    assert client.abort_request == FoeError(FoeErrorCode.PACKET_NUMBER_WRONG, "ACK 5, expected 1")
    reader = FoeReadClient("x", mailbox_size=32)
    reader.start(0.0)
    with pytest.raises(FoeIllegal):
        reader.receive(FoeAck(1), 0.0)
    assert reader.abort_request is not None and reader.abort_request.code == FoeErrorCode.ILLEGAL


def test_deadline_per_packet() -> None:
    client = FoeWriteClient("x", bytes(100), mailbox_size=32, packet_timeout=0.5)
    client.start(10.0)
    assert client.deadline == 10.5
    client.check_deadline(10.4)
    client.receive(FoeAck(0), 10.4)
    assert client.deadline == pytest.approx(10.9)  # re-armed by each packet
    client.receive(FoeBusy(1, 2), 10.8)  # a BUSY is an answer: the slave lives
    assert client.deadline == pytest.approx(11.3)
    with pytest.raises(FoeTimeoutError, match="no answer to FoeData within 0.5 s"):
        client.check_deadline(11.3)
    assert client.done and client.abort_request is not None
    assert client.abort_request.code == FoeErrorCode.NOT_DEFINED


def test_packet_numbers_beyond_65535_and_slaves_that_wrap_at_256() -> None:
    files = Files()
    # 70000 packets of 1 byte: numbers beyond the u16 range on the wire
    data = bytes(i & 0xFF for i in range(70000))
    server = FoeServer(files)
    client = FoeWriteClient("big", data, mailbox_size=13)
    msg: FoeMessage | None = client.start(0.0)
    last = 0
    while msg is not None:
        if isinstance(msg, FoeData):
            last = msg.packet
        reply = server.receive(msg, 13, 13)
        assert reply is not None
        msg = client.receive(reply, 0.0)
    assert last == 70001 and files.files["big"] == data
    # a slave that numbers its DATA modulo 256 (and wants its ACKs so)
    wrapping = FoeServer(files, wrap=256)
    reader = FoeReadClient("big", mailbox_size=13)
    acks: list[int] = []
    msg = reader.start(0.0)
    while not reader.done:
        assert msg is not None
        reply = wrapping.receive(msg, 13, 13)
        assert reply is not None
        msg = reader.receive(reply, 0.0)
        assert isinstance(msg, FoeAck)
        acks.append(msg.packet)
    assert reader.data == data
    assert max(acks) == 255 and acks[255] == 0  # the 256th packet is acknowledged as 0
    # and a master told to wrap at 256 writes to such a slave
    client = FoeWriteClient("w256", bytes(600), mailbox_size=13, wrap=256)
    msg = client.start(0.0)
    numbers = []
    while msg is not None:
        if isinstance(msg, FoeData):
            numbers.append(msg.packet)
        reply = FoeAck(msg.packet) if isinstance(msg, FoeData) else FoeAck(0)
        msg = client.receive(reply, 0.0)
    assert numbers[254:258] == [255, 0, 1, 2] and client.done


def test_server_repeats_ack_for_a_duplicate_and_refuses_a_gap() -> None:
    files = Files()
    server = FoeServer(files)
    assert server.receive(FoeWriteRequest("x"), 32, 32) == FoeAck(0)
    assert server.receive(FoeData(1, bytes(20)), 32, 32) == FoeAck(1)
    assert server.receive(FoeData(1, bytes(20)), 32, 32) == FoeAck(1)  # lost ACK, resent
    assert server.received == 20
    reply = server.receive(FoeData(3, bytes(20)), 32, 32)
    assert isinstance(reply, FoeError) and reply.code == FoeErrorCode.PACKET_NUMBER_WRONG
    assert not server.busy_transfer
    # the master's ERR ends a transfer silently
    server.receive(FoeWriteRequest("y"), 32, 32)
    assert server.receive(FoeError(0x8000, "abort"), 32, 32) is None
    assert not server.busy_transfer
    bad = server.receive(FoeData(1, b"x"), 32, 32)
    assert isinstance(bad, FoeError) and bad.code == FoeErrorCode.ILLEGAL
    assert isinstance(server.receive(FoeReadRequest("missing"), 32, 32), FoeError)


def test_read_client_refuses_more_than_max_size() -> None:
    reader = FoeReadClient("f", mailbox_size=32, max_size=30)
    reader.start(0.0)
    reader.receive(FoeData(1, bytes(20)), 0.0)
    with pytest.raises(FoeDiskFull):
        reader.receive(FoeData(2, bytes(20)), 0.0)
    assert reader.abort_request is not None


def test_read_client_acks_a_repeated_packet_without_keeping_it_twice() -> None:
    reader = FoeReadClient("f", mailbox_size=32)
    reader.start(0.0)
    reader.receive(FoeData(1, bytes(20)), 0.0)
    assert reader.receive(FoeData(1, bytes(20)), 0.0) == FoeAck(1)
    reader.receive(FoeData(2, b"xy"), 0.0)
    assert reader.done and len(reader.data) == 22
