"""The PDU loop: packing, index matching, retries, stale/duplicate replies, errors."""

from __future__ import annotations

import struct
import threading
import time

import pytest
from fake_esc_segment import FakeSegment, FakeSlave
from hypothesis import given, settings
from hypothesis import strategies as st
from master_sii_helpers import io_sii

from pyethercat.errors import FrameError, FrameTooLargeError, LinkError, TimeoutError
from pyethercat.link.pair import PairLink
from pyethercat.master import Master
from pyethercat.master.scheduler import Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import MAX_DATA, Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame, returned_source_mac
from pyethercat.wire.sii import build_sii


def _segment(n: int = 3) -> FakeSegment:
    return FakeSegment([FakeSlave(build_sii(io_sii(f"io{i}"))) for i in range(n)])


class Recorder:
    """Responder wrapper that keeps every frame sent."""

    def __init__(self, segment: FakeSegment) -> None:
        self.segment = segment
        self.sent: list[bytes] = []

    def __call__(self, frame: bytes) -> list[bytes] | bytes | None:
        self.sent.append(frame)
        return self.segment.process(frame)


def _sched(seg: FakeSegment, **kw: object) -> tuple[Scheduler, Recorder]:
    rec = Recorder(seg)
    link = PairLink.responder_link(rec)
    kw.setdefault("deterministic", True)
    return Scheduler(link, **kw), rec  # type: ignore[arg-type]


def _address_all(s: Scheduler, n: int) -> None:
    s.transact([Datagram.positional(Command.APWR, i, reg.STATION_ADDRESS,
                                    struct.pack("<H", 0x1001 + i)) for i in range(n)])


def test_batch_is_packed_into_few_frames_with_one_index_each() -> None:
    seg = _segment(3)
    s, rec = _sched(seg)
    _address_all(s, 3)
    assert len(rec.sent) == 1
    reads = [Datagram.device(Command.FPRD, 0x1001 + i % 3, reg.AL_STATUS, 2) for i in range(150)]
    replies = s.transact(reads)
    # 150 x (12 + 2) bytes = 2100 bytes: two frames of at most 1498 bytes.
    assert len(rec.sent) == 3
    for raw in rec.sent[1:]:
        f = decode_frame(raw)
        assert len({d.index for d in f.datagrams}) == 1
        assert sum(d.size for d in f.datagrams) <= 1498
    assert decode_frame(rec.sent[1]).datagrams[0].index != decode_frame(rec.sent[2]).datagrams[0].index
    assert [r.wkc for r in replies] == [1] * 150
    assert all(r.data == struct.pack("<H", 2) for r in replies)  # PREOP after power-up


def test_order_and_data_are_preserved_per_request() -> None:
    seg = _segment(2)
    s, _ = _sched(seg)
    _address_all(s, 2)
    s.transact([Datagram.device(Command.FPWR, 0x1002, 0x0F80, b"\x11\x22\x33")])
    reps = s.transact([Datagram.device(Command.FPRD, 0x1001, 0x0F80, 3),
                       Datagram.device(Command.FPRD, 0x1002, 0x0F80, 3),
                       Datagram.device(Command.BRD, 0, 0x0F80, 3)])
    assert [r.data for r in reps] == [b"\0\0\0", b"\x11\x22\x33", b"\x11\x22\x33"]
    assert [r.wkc for r in reps] == [0 + 1, 1, 2]
    assert reps[2].adp == 2  # every slave incremented ADP


def test_futures_and_flush() -> None:
    seg = _segment(1)
    s, rec = _sched(seg)
    reqs = s.submit([Datagram.device(Command.BRD, 0, reg.TYPE, 2)] * 3, flush=False)
    assert rec.sent == [] and s.queued == 3
    s.flush()
    assert len(rec.sent) == 1
    assert all(r.result().wkc == 1 for r in reqs)


def test_lost_frame_is_retried_with_a_new_index() -> None:
    seg = _segment(1)
    s, rec = _sched(seg, retries=2)
    seg.faults[0] = "drop"
    reply = s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))
    assert reply.wkc == 1
    assert len(rec.sent) == 2
    i0 = decode_frame(rec.sent[0]).datagrams[0].index
    i1 = decode_frame(rec.sent[1]).datagrams[0].index
    assert i0 != i1
    assert s.stats.frames_lost == 1 and s.stats.retries == 1


def test_timeout_after_the_last_retry_is_a_typed_error() -> None:
    seg = _segment(1)
    s, rec = _sched(seg, retries=2)
    seg.powered = False
    with pytest.raises(TimeoutError, match="BRD .* after 3 attempts"):
        s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))
    assert len(rec.sent) == 3
    assert s.stats.timeouts == 1


def test_real_timeout_never_hangs() -> None:
    link = PairLink.responder_link(lambda frame: None)
    s = Scheduler(link, timeout=0.01, retries=1)
    t0 = time.monotonic()
    with pytest.raises(TimeoutError):
        s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))
    assert time.monotonic() - t0 < 2.0


def test_duplicate_reply_is_dropped() -> None:
    seg = _segment(1)
    s, _ = _sched(seg)
    seg.faults[0] = "dup"
    assert s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2)).wkc == 1
    # The second copy is still queued; the next transaction receives and drops it.
    assert s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2)).wkc == 1
    assert s.stats.duplicates == 1


def test_stale_reply_after_retry_is_dropped() -> None:
    seg = _segment(1)
    s, rec = _sched(seg, retries=3)
    seg.faults[0] = "late"  # reply 0 arrives together with the reply to the retry
    reply = s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))
    assert reply.wkc == 1
    assert s.stats.stale == 1
    assert s.stats.frames_received == 1


def test_own_frame_looped_back_is_ignored() -> None:
    seg = _segment(1)
    s, _ = _sched(seg)
    seg.faults[0] = "echo"  # our frame (no LA bit) comes back before the reply
    assert s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2)).wkc == 1
    assert s.stats.looped_back == 1


def test_truncated_reply_is_a_frame_error() -> None:
    seg = _segment(1)
    s, _ = _sched(seg)

    def cut(reply: bytes) -> bytes:
        # Claim more datagram bytes than the frame holds.
        raw = bytearray(reply)
        struct.pack_into("<H", raw, 14, 0x1000 | 0x7FF)
        return bytes(raw)

    seg.faults[0] = cut
    with pytest.raises(FrameError, match="malformed reply"):
        s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))


def test_reply_with_changed_length_is_a_frame_error() -> None:
    seg = _segment(1)
    s, _ = _sched(seg)

    def other(reply: bytes) -> bytes:
        f = decode_frame(reply)
        d = f.datagrams[0]
        return encode_frame([Datagram(d.command, d.index, d.address, b"\0" * 4, 0, 1)],
                            src=f.src)

    seg.faults[0] = other
    with pytest.raises(FrameError, match="does not match.*4 data bytes, sent 2"):
        s.transact_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))


def test_too_large_datagram_is_refused() -> None:
    s, _ = _sched(_segment(1))
    with pytest.raises(FrameTooLargeError):
        s.submit([Datagram.device(Command.BWR, 0, 0x1000, bytes(MAX_DATA + 1))])
    # The largest one fits alone.
    assert s.transact_one(Datagram.device(Command.BRD, 0, 0x1000, MAX_DATA)).wkc == 1


def test_cyclic_frame_carries_queued_acyclic_datagrams() -> None:
    seg = _segment(2)
    s, rec = _sched(seg)
    _address_all(s, 2)
    s.acyclic_hold = 10.0  # acyclic traffic waits for a cyclic frame
    reqs = s.submit([Datagram.device(Command.FPRD, 0x1001 + i, reg.AL_STATUS, 2)
                     for i in range(2)])
    assert len(rec.sent) == 1  # held back
    ticket = s.send_cyclic([Datagram.logical(Command.LRW, 0x10000, bytes(4))])
    assert len(rec.sent) == 2
    assert ticket.carried == 2
    replies = ticket.wait()
    assert replies is not None and len(replies) == 1
    assert replies[0].command == Command.LRW
    assert [r.result().wkc for r in reqs] == [1, 1]
    assert len(decode_frame(rec.sent[1]).datagrams) == 3


def test_lost_cyclic_frame_reports_none_and_retries_the_carried() -> None:
    seg = _segment(1)
    s, rec = _sched(seg)
    s.acyclic_hold = 10.0
    req = s.submit_one(Datagram.device(Command.BRD, 0, reg.TYPE, 2))
    seg.faults[0] = "drop"
    assert s.exchange_cyclic([Datagram.logical(Command.LRD, 0, bytes(2))]) is None
    s.acyclic_hold = 0.0
    assert req.result().wkc == 1


def test_threads_share_the_loop() -> None:
    """Several threads transact at once over a threaded peer; all get their replies."""
    seg = _segment(2)
    a, b = PairLink.pair()
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            raw = b.recv(0.05)
            if raw is not None:
                out = seg.process(raw)
                for r in out if isinstance(out, list) else [out]:
                    if r is not None:
                        b.send(r)

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    s = Scheduler(a, timeout=0.5)
    _address_all(s, 2)
    errors: list[BaseException] = []

    def worker(k: int) -> None:
        try:
            for _ in range(20):
                st = 0x1001 + k % 2
                r = s.transact([Datagram.device(Command.FPRD, st, reg.STATION_ADDRESS, 2)])
                assert struct.unpack("<H", r[0].data)[0] == st
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    stop.set()
    server.join(1)
    assert not errors
    assert s.in_flight == 0


def test_closed_scheduler_refuses_work() -> None:
    s, _ = _sched(_segment(1))
    s.close()
    with pytest.raises(LinkError):
        s.transact_one(Datagram.device(Command.BRD, 0, 0, 2))


def test_returned_mac_helper_sets_the_la_bit() -> None:
    assert returned_source_mac(b"\x01\x01\x01\x01\x01\x01")[0] == 0x03


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(0, 700), min_size=1, max_size=40),
       drops=st.sets(st.integers(0, 10), max_size=3))
def test_packing_property(sizes: list[int], drops: set[int]) -> None:
    """Any batch: frames stay within 1498 bytes, replies come back in order, all answered."""
    seg = _segment(1)
    for n in drops:
        seg.faults[n] = "drop"
    s, rec = _sched(seg, retries=len(drops) + 1)
    dgs = [Datagram.device(Command.BWR, 0, 0x1000 + 3 * n, bytes([n % 256]) * size)
           for n, size in enumerate(sizes)]
    replies = s.transact(dgs)
    assert [len(r.data) for r in replies] == sizes
    assert [r.ado for r in replies] == [d.ado for d in dgs]
    assert all(r.wkc == 1 for r in replies)
    for raw in rec.sent:
        assert sum(d.size for d in decode_frame(raw).datagrams) <= 1498
    assert s.in_flight == 0 and s.queued == 0


def test_empty_segment_scan() -> None:
    m = Master(PairLink.responder_link(FakeSegment([]).process), deterministic=True)
    assert m.scan() == [] and m.error_counters().slaves == ()
