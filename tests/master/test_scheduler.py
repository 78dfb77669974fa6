"""The scheduler: the PDU core driven over a link, in virtual or real time, from many threads.

The frame logic itself is tested on the bare core (test_pdu.py); here what
the scheduler adds: the receive loop over a link, virtual time (the clock
moves to deadlines, frames take their wire time), real timeouts, threads
sharing one receive loop, link errors and closing.
"""

from __future__ import annotations

import struct
import threading
import time

import pytest
from fake_esc_segment import FakeSegment, FakeSlave
from master_sii_helpers import io_sii

from pyethercat.clock import VirtualClock
from pyethercat.errors import LinkError, TimeoutError
from pyethercat.link.pair import PairLink
from pyethercat.master import Master
from pyethercat.master.scheduler import Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.sii import build_sii


def _segment(n: int = 3) -> FakeSegment:
    return FakeSegment([FakeSlave(build_sii(io_sii(f"io{i}"))) for i in range(n)])


def _brd() -> Datagram:
    return Datagram.device(Command.BRD, 0, reg.TYPE, 2)


def _virtual(seg: FakeSegment, **kw: object) -> tuple[Scheduler, VirtualClock, list[bytes]]:
    sent: list[bytes] = []

    def record(frame: bytes) -> list[bytes] | bytes | None:
        sent.append(frame)
        return seg.process(frame)

    clock = VirtualClock()
    return Scheduler(PairLink.responder_link(record), clock=clock, **kw), clock, sent  # type: ignore[arg-type]


def test_virtual_time_moves_to_the_deadline_of_a_lost_frame() -> None:
    seg = _segment(1)
    s, clock, sent = _virtual(seg, retries=2, timeout=0.05)
    seg.faults[0] = "drop"
    assert s.transact_one(_brd()).wkc == 1
    assert len(sent) == 2
    # One timeout waited (in virtual time), plus the wire time of the two frames.
    assert 50_000_000 < clock.now_ns() < 50_100_000
    assert s.stats.frames_lost == 1 and s.stats.retries == 1


def test_virtual_time_counts_wire_time_and_sleep_moves_the_clock() -> None:
    s, clock, _ = _virtual(_segment(1))
    s.transact_one(_brd())
    # A 60-byte frame plus preamble, FCS and gap at 80 ns per byte.
    assert clock.now_ns() == (60 + 24) * 80
    t0 = time.monotonic()
    s.sleep(3600.0)
    assert time.monotonic() - t0 < 1.0
    assert clock.now_ns() == (60 + 24) * 80 + 3600 * 10**9
    assert s.now() == pytest.approx(clock.now_ns() * 1e-9)


def test_virtual_timeout_after_the_last_retry() -> None:
    seg = _segment(1)
    s, clock, sent = _virtual(seg, retries=2, timeout=0.5)
    seg.powered = False
    t0 = time.monotonic()
    with pytest.raises(TimeoutError, match="BRD .* after 3 attempts"):
        s.transact_one(_brd())
    assert time.monotonic() - t0 < 1.0  # 1.5 s of virtual time, no real waiting
    assert len(sent) == 3 and clock.now_ns() >= 1_500_000_000


def test_futures_and_flush() -> None:
    s, _, sent = _virtual(_segment(1))
    reqs = s.submit([_brd()] * 3, flush=False)
    assert sent == [] and s.queued == 3
    s.flush()
    assert len(sent) == 1
    assert all(r.result().wkc == 1 for r in reqs)


def test_real_timeout_never_hangs() -> None:
    link = PairLink.responder_link(lambda frame: None)
    s = Scheduler(link, timeout=0.01, retries=1)
    t0 = time.monotonic()
    with pytest.raises(TimeoutError):
        s.transact_one(_brd())
    assert time.monotonic() - t0 < 2.0


def test_link_refusal_fails_the_requests_and_is_raised() -> None:
    a, _b = PairLink.pair()
    s = Scheduler(a)
    _b.close()  # the far end has gone: send raises LinkClosedError
    with pytest.raises(LinkError, match="peer"):
        s.transact_one(_brd())
    assert s.in_flight == 0 and s.stats.frames_sent == 0


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
    s.transact([Datagram.positional(Command.APWR, i, reg.STATION_ADDRESS,
                                    struct.pack("<H", 0x1001 + i)) for i in range(2)])
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
    s, _, _ = _virtual(_segment(1))
    s.close()
    with pytest.raises(LinkError):
        s.transact_one(Datagram.device(Command.BRD, 0, 0, 2))


def test_empty_segment_scan() -> None:
    m = Master(PairLink.responder_link(FakeSegment([]).process), clock=VirtualClock())
    assert m.scan() == [] and m.error_counters().slaves == ()


def test_a_reply_waiting_at_the_link_is_not_lost_after_its_deadline() -> None:
    """A responder that answers inside ``send`` after the frame's deadline (a long send,
    a loaded host): the reply is queued before anyone reads, so the frame is not lost,
    however many frames were in flight and whichever of them is read first."""
    seg = _segment(1)

    def slow(frame: bytes) -> list[bytes] | bytes | None:
        time.sleep(0.005)  # longer than the frames' 1 ms timeout
        return seg.process(frame)

    s = Scheduler(PairLink.responder_link(slow))
    template = s.prepare_cyclic([_brd()])
    tickets = [s.send_prepared(template, timeout=0.001) for _ in range(3)]
    assert all(t.wait_raw() is not None for t in tickets)
    assert s.stats.frames_lost == 0


def test_receive_ready_takes_a_reply_and_sends_nothing_queued() -> None:
    """The isolated engine's event loop between cycles: a reply at the link is taken at
    once; datagrams queued for the next cyclic frame stay queued (no frame of their own
    right before the deadline), and an empty link returns at once."""
    seg = _segment(1)
    sent: list[bytes] = []

    def record(frame: bytes) -> list[bytes] | bytes | None:
        sent.append(frame)
        return seg.process(frame)

    s = Scheduler(PairLink.responder_link(record))
    flown = s.submit([_brd()])[0]  # sent now: its reply waits at the link
    queued = s.submit([_brd()], flush=False)[0]
    assert len(sent) == 1 and s.in_flight == 1 and s.queued == 1
    assert s.receive_ready()
    assert flown.done() and flown.result().wkc == 1
    assert s.in_flight == 0 and s.queued == 1 and not queued.done()
    assert len(sent) == 1
    t0 = time.monotonic()
    assert not s.receive_ready()  # nothing there: no wait
    assert time.monotonic() - t0 < 2.0
    s.flush()
    assert queued.result().wkc == 1 and len(sent) == 2
