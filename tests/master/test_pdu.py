"""The PDU core on its own: packing, index matching, retries, stale/duplicate replies, errors.

No link, no thread, no real time: a small driver hands the core's frames to a
fake segment, feeds the replies back and moves a virtual clock to the core's
next deadline when nothing more comes back.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable

import pytest
from fake_esc_segment import FakeSegment, FakeSlave
from hypothesis import given, settings
from hypothesis import strategies as st
from master_sii_helpers import io_sii

from pyethercat.clock import VirtualClock
from pyethercat.errors import FrameError, FrameTooLargeError, LinkError, TimeoutError
from pyethercat.master.pdu import PduCore, Request
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import MAX_DATA, Command, Datagram
from pyethercat.wire.frame import MASTER_MAC, decode_frame, encode_frame, returned_source_mac
from pyethercat.wire.sii import build_sii


def _segment(n: int = 3) -> FakeSegment:
    return FakeSegment([FakeSlave(build_sii(io_sii(f"io{i}"))) for i in range(n)])


class Wire:
    """Drives a core against a responder in virtual time (what the scheduler does, minus I/O)."""

    def __init__(self, responder: Callable[[bytes], list[bytes] | bytes | None],
                 **options: object) -> None:
        self.core = PduCore(**options)  # type: ignore[arg-type]
        self.clock = VirtualClock()
        self.responder = responder
        self.sent: list[bytes] = []
        self.returned: deque[bytes] = deque()

    @property
    def now(self) -> float:
        return self.clock.now_ns() * 1e-9

    def put(self, raw: bytes) -> None:
        self.sent.append(raw)
        out = self.responder(raw)
        if out is None:
            return
        self.returned.extend([out] if isinstance(out, bytes | bytearray) else out)

    def flush(self, force: bool = False) -> None:
        for _idx, raw in self.core.next_frames(self.now, force=force):
            self.put(raw)

    def run(self, done: Callable[[], bool]) -> None:
        """Receive and expire until ``done()`` or nothing is pending."""
        core = self.core
        while not done():
            self.flush()
            if self.returned:
                core.on_frame(self.returned.popleft(), self.now)
                continue
            deadline = core.next_deadline()
            if deadline is None:
                return
            self.clock.sleep_until(round(deadline * 1e9))
            core.expire(max(self.now, deadline))

    def transact(self, datagrams: list[Datagram], **kw: int) -> list[Datagram]:
        reqs = self.core.submit(datagrams, self.now, **kw)
        self.run(lambda: all(r.done() for r in reqs))
        return [r.result() for r in reqs]


def _address_all(w: Wire, n: int) -> None:
    w.transact([Datagram.positional(Command.APWR, i, reg.STATION_ADDRESS,
                                    struct.pack("<H", 0x1001 + i)) for i in range(n)])


def _brd() -> Datagram:
    return Datagram.device(Command.BRD, 0, reg.TYPE, 2)


def test_batch_is_packed_into_few_frames_with_one_index_each() -> None:
    seg = _segment(3)
    w = Wire(seg.process)
    _address_all(w, 3)
    assert len(w.sent) == 1
    reads = [Datagram.device(Command.FPRD, 0x1001 + i % 3, reg.AL_STATUS, 2) for i in range(150)]
    replies = w.transact(reads)
    # 150 x (12 + 2) bytes = 2100 bytes: two frames of at most 1498 bytes.
    assert len(w.sent) == 3
    for raw in w.sent[1:]:
        f = decode_frame(raw)
        assert len({d.index for d in f.datagrams}) == 1
        assert sum(d.size for d in f.datagrams) <= 1498
    assert decode_frame(w.sent[1]).datagrams[0].index != decode_frame(w.sent[2]).datagrams[0].index
    assert [r.wkc for r in replies] == [1] * 150
    assert all(r.data == struct.pack("<H", 2) for r in replies)  # PREOP after power-up


def test_order_and_data_are_preserved_per_request() -> None:
    seg = _segment(2)
    w = Wire(seg.process)
    _address_all(w, 2)
    w.transact([Datagram.device(Command.FPWR, 0x1002, 0x0F80, b"\x11\x22\x33")])
    reps = w.transact([Datagram.device(Command.FPRD, 0x1001, 0x0F80, 3),
                       Datagram.device(Command.FPRD, 0x1002, 0x0F80, 3),
                       Datagram.device(Command.BRD, 0, 0x0F80, 3)])
    assert [r.data for r in reps] == [b"\0\0\0", b"\x11\x22\x33", b"\x11\x22\x33"]
    assert [r.wkc for r in reps] == [0 + 1, 1, 2]
    assert reps[2].adp == 2  # every slave incremented ADP


def test_nothing_is_sent_before_next_frames_and_the_budget_limits_frames() -> None:
    w = Wire(_segment(1).process, max_in_flight=2)
    big = [Datagram.device(Command.BRD, 0, 0x1000, 1000) for _ in range(5)]
    reqs = w.core.submit(big, w.now)
    assert w.core.queued == 5 and w.core.in_flight == 0
    frames = w.core.next_frames(w.now)
    assert len(frames) == 2 and w.core.in_flight == 2 and w.core.queued == 3
    assert w.core.next_frame(w.now) is None  # budget used up
    assert len({idx for idx, _ in frames}) == 2
    for _, raw in frames:
        w.put(raw)
    w.run(lambda: all(r.done() for r in reqs))
    assert all(r.result().wkc == 1 for r in reqs)


def test_lost_frame_is_retried_with_a_new_index_at_its_deadline() -> None:
    seg = _segment(1)
    w = Wire(seg.process, retries=2, timeout=0.05)
    seg.faults[0] = "drop"
    req = w.core.submit([_brd()], w.now)[0]
    w.flush()
    assert w.core.next_deadline() == pytest.approx(0.05)
    assert not w.core.expire(0.049)  # not yet
    w.run(req.done)
    assert req.result().wkc == 1
    assert w.now == pytest.approx(0.05, abs=1e-9)
    assert len(w.sent) == 2
    i0 = decode_frame(w.sent[0]).datagrams[0].index
    i1 = decode_frame(w.sent[1]).datagrams[0].index
    assert i0 != i1
    assert w.core.stats.frames_lost == 1 and w.core.stats.retries == 1


def test_timeout_after_the_last_retry_is_a_typed_error() -> None:
    seg = _segment(1)
    w = Wire(seg.process, retries=2, timeout=0.01)
    seg.powered = False
    with pytest.raises(TimeoutError, match=r"BRD .* after 3 attempts \(0.01 s each\) on link"):
        w.transact([_brd()])
    assert len(w.sent) == 3
    assert w.now == pytest.approx(0.03, abs=1e-6)
    assert w.core.stats.timeouts == 1


def test_duplicate_reply_is_dropped() -> None:
    seg = _segment(1)
    w = Wire(seg.process)
    seg.faults[0] = "dup"
    assert w.transact([_brd()])[0].wkc == 1
    # The second copy is still queued; the next transaction receives and drops it.
    assert w.transact([_brd()])[0].wkc == 1
    assert w.core.stats.duplicates == 1


def test_stale_reply_after_retry_is_dropped() -> None:
    seg = _segment(1)
    w = Wire(seg.process, retries=3)
    seg.faults[0] = "late"  # reply 0 arrives together with the reply to the retry
    assert w.transact([_brd()])[0].wkc == 1
    assert w.core.stats.stale == 1
    assert w.core.stats.frames_received == 1


def test_own_frame_looped_back_is_ignored_when_asked() -> None:
    seg = _segment(1)
    w = Wire(seg.process)
    seg.faults[0] = "echo"  # our frame (no LA bit) comes back before the reply
    assert w.transact([_brd()])[0].wkc == 1
    assert w.core.stats.looped_back == 1


def test_reply_with_our_own_source_mac_is_a_reply_without_own_frame_check() -> None:
    """A responder that does not set the locally administered bit is still answered."""
    seg = _segment(1)

    def same_mac(frame: bytes) -> bytes | None:
        out = seg.process(frame)
        assert isinstance(out, list)
        return out[0][:6] + MASTER_MAC + out[0][12:]

    w = Wire(same_mac, drop_own_frames=False)
    assert w.transact([_brd()])[0].wkc == 1
    assert w.core.stats.looped_back == 0
    dropping = Wire(same_mac, retries=1)
    with pytest.raises(TimeoutError):
        dropping.transact([_brd()])
    assert dropping.core.stats.looped_back == 2


def test_truncated_reply_is_a_frame_error() -> None:
    seg = _segment(1)
    w = Wire(seg.process)

    def cut(reply: bytes) -> bytes:
        # Claim more datagram bytes than the frame holds.
        raw = bytearray(reply)
        struct.pack_into("<H", raw, 14, 0x1000 | 0x7FF)
        return bytes(raw)

    seg.faults[0] = cut
    with pytest.raises(FrameError, match="malformed reply"):
        w.transact([_brd()])
    assert w.core.in_flight == 0


def test_reply_with_changed_length_is_a_frame_error() -> None:
    seg = _segment(1)
    w = Wire(seg.process)

    def other(reply: bytes) -> bytes:
        f = decode_frame(reply)
        d = f.datagrams[0]
        return encode_frame([Datagram(d.command, d.index, d.address, b"\0" * 4, 0, 1)],
                            src=f.src)

    seg.faults[0] = other
    with pytest.raises(FrameError, match="does not match.*4 data bytes, sent 2"):
        w.transact([_brd()])


def test_reply_with_another_command_at_our_index_is_stale_not_an_answer() -> None:
    seg = _segment(1)

    def foreign_first(frame: bytes) -> list[bytes]:
        out = seg.process(frame)
        assert isinstance(out, list)
        f = decode_frame(out[0])
        # Another master's LRD that happens to carry our index, then our reply.
        lrd = Datagram(Command.LRD, f.datagrams[0].index, 0x10000, b"\0\0", 0, 0)
        return [encode_frame([lrd], src=f.src), *out]

    w = Wire(foreign_first, retries=1)
    assert w.transact([_brd()])[0].wkc == 1
    assert w.core.stats.stale == 1 and w.core.stats.malformed == 0


def test_too_large_datagram_is_refused() -> None:
    w = Wire(_segment(1).process)
    with pytest.raises(FrameTooLargeError):
        w.core.submit([Datagram.device(Command.BWR, 0, 0x1000, bytes(MAX_DATA + 1))], w.now)
    # The largest one fits alone.
    assert w.transact([Datagram.device(Command.BRD, 0, 0x1000, MAX_DATA)])[0].wkc == 1


def test_cyclic_frame_carries_queued_acyclic_datagrams() -> None:
    seg = _segment(2)
    w = Wire(seg.process)
    _address_all(w, 2)
    core = w.core
    core.acyclic_hold = 10.0  # acyclic traffic waits for a cyclic frame
    reqs = core.submit([Datagram.device(Command.FPRD, 0x1001 + i, reg.AL_STATUS, 2)
                        for i in range(2)], w.now)
    w.flush()
    assert len(w.sent) == 1  # held back
    assert core.next_deadline() == pytest.approx(w.now + 10.0)
    template = core.prepare_cyclic([Datagram.logical(Command.LRW, 0x10000, bytes(4))])
    ticket, _idx, raw = core.send_prepared(template, w.now)
    w.put(raw)
    assert ticket.carried == 2
    w.run(ticket.done)
    assert ticket.raw is not None and template.wkc(ticket.raw, 0) == 0
    replies = ticket.wait()
    assert replies is not None and len(replies) == 1 and replies[0].command == Command.LRW
    assert [r.result().wkc for r in reqs] == [1, 1]
    assert len(decode_frame(w.sent[1]).datagrams) == 3


def test_held_request_goes_out_on_its_own_when_no_cyclic_frame_comes() -> None:
    w = Wire(_segment(1).process)
    w.core.acyclic_hold = 0.002
    req = w.core.submit([_brd()], w.now)[0]
    w.flush()
    assert w.sent == []
    w.run(req.done)
    assert req.result().wkc == 1
    assert w.now == pytest.approx(0.002, abs=1e-9)


def test_lost_cyclic_frame_reports_none_and_retries_the_carried() -> None:
    seg = _segment(1)
    w = Wire(seg.process)
    core = w.core
    core.acyclic_hold = 10.0
    req = core.submit([_brd()], w.now)[0]
    seg.faults[0] = "drop"
    ticket, _, raw = core.send_prepared(
        core.prepare_cyclic([Datagram.logical(Command.LRD, 0, bytes(2))]), w.now)
    w.put(raw)
    w.run(ticket.done)
    assert ticket.lost and ticket.wait() is None
    assert core.queued == 1  # the carried request is back in the queue, not held
    w.run(req.done)
    assert req.result().wkc == 1
    assert req.attempts == 2


def test_send_failure_fails_the_frame_and_uncounts_it() -> None:
    w = Wire(_segment(1).process)
    reqs = w.core.submit([_brd(), _brd()], w.now)
    (idx, _raw), = w.core.next_frames(w.now)
    err = LinkError("network interface x is down")
    w.core.send_failed(idx, err)
    assert all(r.error is err for r in reqs)
    assert w.core.in_flight == 0 and w.core.stats.frames_sent == 0
    assert w.core.stats.datagrams_sent == 0


def test_closed_core_fails_pending_and_refuses_work() -> None:
    w = Wire(_segment(1).process)
    queued = w.core.submit([_brd()], w.now)[0]
    w.core.close()
    with pytest.raises(LinkError, match="closed"):
        queued.result()
    with pytest.raises(LinkError):
        w.core.submit([_brd()], w.now)


def test_result_of_a_request_without_driver_says_it_is_pending() -> None:
    req = Request(None, _brd(), 0)
    with pytest.raises(TimeoutError, match="no reply to BRD"):
        req.result()


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
    w = Wire(seg.process, retries=len(drops) + 1)
    dgs = [Datagram.device(Command.BWR, 0, 0x1000 + 3 * n, bytes([n % 256]) * size)
           for n, size in enumerate(sizes)]
    replies = w.transact(dgs)
    assert [len(r.data) for r in replies] == sizes
    assert [r.ado for r in replies] == [d.ado for d in dgs]
    assert all(r.wkc == 1 for r in replies)
    for raw in w.sent:
        assert sum(d.size for d in decode_frame(raw).datagrams) <= 1498
    assert w.core.in_flight == 0 and w.core.queued == 0
