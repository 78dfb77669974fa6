"""Master mailbox transport over the simulator's ESC (real SM0/SM1 gating and repeat)."""

from __future__ import annotations

import struct
import sys
import threading

import pytest
from mini_coe import MiniCoe, coe_segment

from pyethercat.clock import VirtualClock
from pyethercat.errors import MailboxError, MailboxErrorReply, SdoAbort
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.mailbox import Mailbox, MailboxPoller, ReceivedMessage
from pyethercat.master.master import Master
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.coe import SdoAbortCode, SdoAbortTransfer
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType, encode_mailbox


def _master(count: int = 1, **kw: object) -> tuple[Master, list[MiniCoe], object]:
    _seg, apps, drop, link = coe_segment(count, **kw)  # type: ignore[arg-type]
    m = Master(link, clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    return m, apps, drop


def _sm0_writes(frames: list[bytes], station: int, offset: int) -> list[bytes]:
    out = []
    for raw in frames:
        for d in decode_frame(raw).datagrams:
            if d.command == Command.FPWR and d.adp == station and d.ado == offset:
                out.append(bytes(d.data))
    return out


def test_counter_runs_1_to_7_and_wraps() -> None:
    m, _apps, drop = _master()
    s = m.slaves[0]
    assert s.mbx is not None
    before = len(drop.frames)
    for _ in range(10):
        assert s.sdo_read(0x1018, 1, "uint32") == 0x00504543
    writes = _sm0_writes(drop.frames[before:], s.station_address, s.mbx.rx_offset)
    counters = [MailboxHeader.decode(w).counter for w in writes]
    assert counters == [1, 2, 3, 4, 5, 6, 7, 1, 2, 3]
    # the whole SM0 is written every time (the ESC completes the buffer on its last byte)
    assert {len(w) for w in writes} == {s.mbx.rx_size}


def test_expedited_sdo_frames() -> None:
    m, _apps, drop = _master()
    s = m.slaves[0]
    before = len(drop.frames)
    s.sdo_read(0x1000, 0)
    # FPWR SM0 + speculative FPRD SM1 in one frame; the firmware answers once that
    # frame has passed (never within it), so the read finds SM1 empty (WKC 0); the
    # next frame reads SM1 at once (no status poll first) and finds the answer.
    assert s.mbx is not None
    frames = drop.frames[before:]
    assert len(frames) == 2
    assert [d.command for d in decode_frame(frames[0]).datagrams] == [Command.FPWR, Command.FPRD]
    (read,) = decode_frame(frames[1]).datagrams
    assert read.command == Command.FPRD and read.ado == s.mbx.tx_offset
    assert s.mbx.stats.early_replies == 0 and s.mbx.stats.status_polls == 0


def test_mailbox_error_reply_is_typed() -> None:
    m, _apps, _drop = _master()
    s = m.slaves[0]
    assert s.mbx is not None
    with pytest.raises(MailboxErrorReply) as err:
        s.mbx.transact(MailboxType.FOE, b"\x01\x00\x00\x00\x00\x00x", what="FoE read")
    assert err.value.code == 0x0002
    assert "protocol not supported" in err.value.name
    assert s.describe() in str(err.value)


def test_unanswered_request_is_sent_again_with_the_next_counter() -> None:
    m, apps, drop = _master()
    s = m.slaves[0]
    assert s.mbx is not None
    apps[0].silent = 1  # the slave drops the first request (as it drops a repeated counter)
    before = len(drop.frames)
    assert s.sdo_read(0x1018, 2, "uint32", timeout=0.2) == 0x00040002
    writes = _sm0_writes(drop.frames[before:], s.station_address, s.mbx.rx_offset)
    assert [MailboxHeader.decode(w).counter for w in writes] == [1, 2]
    assert writes[0][6:] == writes[1][6:]  # the same request
    assert s.mbx.stats.resent == 1


def test_timeout_names_slave_and_what_and_aborts() -> None:
    m, apps, _drop = _master()
    s = m.slaves[0]
    apps[0].silent = 2  # the request and its second sending
    with pytest.raises(EcTimeoutError) as err:
        s.sdo_read(0x1018, 2, timeout=0.05)
    text = str(err.value)
    assert s.describe() in text and "0x1018:02" in text
    assert "sent twice" in text
    # the master told the slave it gave up: SDO protocol timeout
    aborts = [r for r in apps[0].requests if isinstance(r, SdoAbortTransfer)]
    assert aborts and aborts[-1].code == SdoAbortCode.TIMEOUT
    # and the mailbox still works afterwards
    assert s.sdo_read(0x1018, 2, "uint32") == 0x00040002


def _reads_sm1(reply: bytes, tx_offset: int) -> bool:
    return any(d.command == Command.FPRD and d.ado == tx_offset and d.wkc == 1
               and len(d.data) > 8 for d in decode_frame(reply).datagrams)


@pytest.mark.parametrize("size", [4, 4096])
def test_lost_reply_recovered_by_repeat_request(size: int) -> None:
    m, _apps, drop = _master()
    s = m.slaves[0]
    assert s.mbx is not None
    tx = s.mbx.tx_offset
    drop.drop_when = lambda reply: _reads_sm1(reply, tx)  # type: ignore[attr-defined]
    got = s.sdo_read(0x2001 if size > 4 else 0x1018, 0 if size > 4 else 1)
    assert drop.dropped == 1  # type: ignore[attr-defined]
    if size > 4:
        assert got == bytes(range(256)) * 16
    else:
        assert got == struct.pack("<I", 0x00504543)
    assert s.mbx.stats.repeat_requests == 1
    # the repeat request toggled SM1 activate bit 1 (0x080E)
    act = reg.sm_address(1) + reg.SM_ACTIVATE
    toggles = [d for f in drop.frames for d in decode_frame(f).datagrams  # type: ignore[attr-defined]
               if d.command == Command.FPWR and d.ado == act]
    assert toggles and toggles[-1].data[0] & reg.SM_ACTIVATE_REPEAT


def test_duplicate_counter_dropped_and_handlers_first() -> None:
    m, _apps, _drop = _master()
    s = m.slaves[0]
    box = s.mbx
    assert box is not None
    raw = encode_mailbox(MailboxType.VOE, b"abcdefgh", counter=3, size=box.tx_size)
    box.inbox.deliver(raw)
    box.inbox.deliver(raw)  # same counter: a repetition
    assert box.stats.duplicates == 1
    taken: list[ReceivedMessage] = []
    box.add_handler(lambda _b, msg: taken.append(msg) or True)
    box.inbox.deliver(encode_mailbox(MailboxType.VOE, b"12345678", counter=4, size=box.tx_size))
    assert [t.payload for t in taken] == [b"12345678"]
    assert [p.payload for p in box.pending()] == [b"abcdefgh"]


def test_lying_length_is_an_error() -> None:
    m, _apps, _drop = _master()
    box = m.slaves[0].mbx
    assert box is not None
    bad = bytearray(box.tx_size)
    struct.pack_into("<HHBB", bad, 0, box.tx_size, 0, 0, 0x13)
    with pytest.raises(MailboxError, match="exceeds"):
        box.inbox.deliver(bytes(bad))


def test_message_too_large_for_sm0() -> None:
    m, _apps, _drop = _master()
    box = m.slaves[0].mbx
    assert box is not None
    with pytest.raises(MailboxError, match="carries"):
        box.send(MailboxType.COE, bytes(box.rx_size))


def test_poller_batches_slaves_in_one_frame() -> None:
    m, _apps, drop = _master(3)
    boxes = [s.mbx for s in m.slaves]
    poller = MailboxPoller(m.scheduler)
    # three waiters register before the round: one frame reads all three statuses
    for b in boxes:
        assert b is not None
        poller._pending[b] = None
    before = len(drop.frames)  # type: ignore[attr-defined]
    first = boxes[0]
    assert first is not None
    status = poller.status(first)
    assert status is not None and not status & reg.SM_STATUS_MAILBOX_FULL
    frames = drop.frames[before:]  # type: ignore[attr-defined]
    assert len(frames) == 1
    reads = [d for d in decode_frame(frames[0]).datagrams
             if d.ado == reg.sm_address(1) + reg.SM_STATUS]
    assert len(reads) == 3
    assert poller.rounds == 1 and poller.polled == 3


def test_two_slaves_transfers_interleave() -> None:
    m, _apps, drop = _master(2)
    a, b = m.slaves
    results: dict[int, bytes] = {}
    barrier = threading.Barrier(2)

    def work(slave: object) -> None:
        barrier.wait()
        for _ in range(3):
            results[slave.position] = slave.sdo_read(0x2001)  # type: ignore[attr-defined]

    threads = [threading.Thread(target=work, args=(s,)) for s in (a, b)]
    before = len(drop.frames)  # type: ignore[attr-defined]
    # A step takes less than the GIL's 5 ms slice: switch threads often, so that
    # interleaving shows whenever nothing serialises the two transfers.
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
    finally:
        sys.setswitchinterval(interval)
    assert results == {0: bytes(range(256)) * 16, 1: bytes(range(256)) * 16}
    # the SM0 writes of both slaves alternate: neither waited for the other's transfer
    order = []
    for raw in drop.frames[before:]:  # type: ignore[attr-defined]
        for d in decode_frame(raw).datagrams:
            if d.command == Command.FPWR and d.ado == a.mbx.rx_offset:  # type: ignore[union-attr]
                order.append(d.adp)
    switches = sum(1 for x, y in zip(order, order[1:], strict=False) if x != y)
    assert switches >= 4, order


def test_emergency_delivered_while_waiting_for_an_answer() -> None:
    m, apps, _drop = _master()
    s = m.slaves[0]
    seen = []
    m.on_emergency(seen.append)
    apps[0].emergency(0x8110, 0x11, b"\x01\x02\x03\x04\x05")
    assert s.sdo_read(0x1018, 1, "uint32") == 0x00504543
    assert len(seen) == 1
    ev = seen[0]
    assert ev.error_code == 0x8110 and ev.error_register == 0x11
    assert ev.name == "CAN overrun (objects lost)"
    assert ev.data == b"\x01\x02\x03\x04\x05"
    # one queue: the slave's client files into the master's
    assert s.coe is not None and s.coe.emergencies is m.emergencies
    assert m.emergencies.get_nowait() is ev and m.emergencies.empty()


def test_emergency_queue_drops_the_oldest_without_blocking() -> None:
    from pyethercat.master.coe import DropOldestQueue
    q: DropOldestQueue[int] = DropOldestQueue(3)
    for i in range(5):
        q.put(i)  # would block forever on a full queue.Queue
    assert [q.get_nowait() for _ in range(3)] == [2, 3, 4]


def test_emergency_polled_without_transaction() -> None:
    m, apps, _drop = _master()
    apps[0].emergency(0x4210)
    assert m.poll_mailboxes() == 1
    assert m.emergencies.get_nowait().name == "device temperature"


def test_poll_leaves_sm1_to_a_transaction_in_progress() -> None:
    """A poll (a dashboard's, a drive group's) while another thread's transfer holds the
    mailbox does not read SM1: two readers can deliver a segmented answer's pieces out of
    order, and one can empty SM1 under the other, which then asks for a needless repeat."""
    m, apps, _drop = _master()
    box = m.mailboxes.mailbox_of(0)
    assert box is not None
    apps[0].emergency(0x4210)
    held, release = threading.Event(), threading.Event()

    def transfer() -> None:  # stands in for a segmented SDO upload between two steps
        with box.lock:
            held.set()
            release.wait(10)

    t = threading.Thread(target=transfer)
    t.start()
    try:
        assert held.wait(10)
        fetches = box.stats.fetches
        assert m.poll_mailboxes() == 0
        assert box.stats.fetches == fetches  # SM1 not read: the emergency waits there
        assert m.emergencies.empty()
    finally:
        release.set()
        t.join()
    assert m.poll_mailboxes() == 1  # the transfer is over: the poll reads it
    assert m.emergencies.get_nowait().name == "device temperature"


def test_abort_from_slave_in_service_2() -> None:
    m, apps, _drop = _master()
    apps[0].aborts[(0x2000, 0)] = SdoAbortCode.READ_ONLY
    with pytest.raises(SdoAbort) as err:
        m.slaves[0].sdo_write(0x2000, 0, 5, "uint32")
    assert err.value.code == 0x06010002 and err.value.index == 0x2000


def test_mailbox_sizes_checked() -> None:
    m, _apps, _drop = _master()
    with pytest.raises(MailboxError):
        Mailbox(m.scheduler, 0x1001, "x", rx_offset=0x1000, rx_size=4, tx_offset=0x1080,
                tx_size=128)


def test_mailbox_frame_lost_every_time_times_out_then_recovers() -> None:
    m, _apps, drop = _master()
    s = m.slaves[0]
    box = s.mbx
    assert box is not None
    inner = drop.process  # type: ignore[attr-defined]

    def lossy(frame: bytes) -> bytes | None:
        if any(d.command == Command.FPWR and d.ado == box.rx_offset
               for d in decode_frame(frame).datagrams):
            return None  # the frame with the SM0 write never comes back
        return inner(frame)

    drop.process = lossy  # type: ignore[attr-defined]
    before = len(drop.frames)  # type: ignore[attr-defined]
    with pytest.raises(EcTimeoutError) as err:
        s.sdo_read(0x1018, 1)
    assert s.describe() in str(err.value) and "attempts" in str(err.value)
    # the first try and the scheduler's retries, each with the same counter
    writes = _sm0_writes(drop.frames[before:], s.station_address, box.rx_offset)  # type: ignore[attr-defined]
    assert len(writes) >= 1 + m.scheduler.retries
    assert len({MailboxHeader.decode(w).counter for w in writes[:1 + m.scheduler.retries]}) == 1
    drop.process = inner  # type: ignore[attr-defined]
    assert s.sdo_read(0x1018, 1, "uint32") == 0x00504543


@pytest.mark.parametrize("size", [128, 800])
def test_segmented_both_ways_with_small_and_large_mailboxes(size: int) -> None:
    # 800-byte mailboxes: SM0 write + SM1 read do not fit one frame, the
    # speculative read goes out as separate requests instead of the prepared frame
    _seg, _apps, drop, link = coe_segment(1, mailbox_size=size)
    m = Master(link, clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    s = m.slaves[0]
    data = bytes((i * 31) & 0xFF for i in range(5000))
    s.sdo_write(0x2001, 0, data)
    assert s.sdo_read(0x2001) == data
    assert s.mbx is not None and s.mbx.stats.received > 0
    # 128 bytes: the speculative read rides in the request's frame and finds SM1 still
    # empty (see test_expedited_sdo_frames); 800 bytes: it is a frame of its own, after
    # the request's had passed, and finds every answer.
    assert s.mbx.stats.early_replies == (0 if size == 128 else s.mbx.stats.received)
    assert (s.mbx.frame.template is None) == (size == 800)
