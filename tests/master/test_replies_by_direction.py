"""Replies are recognised by index and by the direction the link reports, not by source MAC.

KickCAT's ESC emulator returns frames with the master's own source MAC (an ESC
sets the locally administered bit; an emulator need not). Over a veth pair a
raw socket tells incoming frames from our own transmissions, so such replies
must be taken; on a link that cannot tell direction, a frame with our own
unchanged source MAC is still our frame seen again.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT

from pyethercat.clock import VirtualClock
from pyethercat.errors import TimeoutError
from pyethercat.link.pair import PairLink
from pyethercat.link.raw import RawLink
from pyethercat.master import Master
from pyethercat.wire.al import AlState
from pyethercat.wire.frame import MASTER_MAC

pytest.importorskip("pyethercat.sim.topology")
from pyethercat.sim.topology import load_topology  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def _same_mac(segment_process: object) -> object:
    """A responder returning the segment's replies with the source MAC the master sent."""

    def respond(frame: bytes) -> bytes | None:
        reply = segment_process(frame)  # type: ignore[operator]
        if reply is None:
            return None
        return bytes(reply[:6]) + bytes(frame[6:12]) + bytes(reply[12:])

    return respond


@pytest.fixture
def unmarked_segment(veth_pair: tuple[str, str]) -> Iterator[str]:
    """The demo segment behind one end of a veth pair, replying with the sender's own MAC."""
    a, b = veth_pair
    segment = load_topology(DEMO).build()
    respond = _same_mac(segment.process)
    far = RawLink(b)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            frame = far.recv(0.05)
            if frame is not None:
                reply = respond(frame)  # type: ignore[operator]
                if reply is not None:
                    far.send(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield a
    finally:
        stop.set()
        thread.join(2)
        far.close()


def test_replies_carrying_our_own_source_mac_are_taken_over_a_raw_link(
        unmarked_segment: str) -> None:
    with Master.open(iface=unmarked_segment, timeout=SIM_FRAME_TIMEOUT, control=False) as m:
        slaves = m.scan()
        assert len(slaves) == len(load_topology(DEMO).build().slaves)
        m.set_state("PREOP")
        assert all(s.al_state == AlState.PREOP for s in slaves)
        stats = m.scheduler.stats
        assert stats.looped_back == 0 and stats.timeouts == 0
        assert m.scheduler.core.drop_own_frames is False


def test_a_link_that_cannot_tell_direction_still_drops_its_own_frames() -> None:
    segment = load_topology(DEMO).build()
    link = PairLink.responder_link(_same_mac(segment.process))  # type: ignore[arg-type]
    link.sees_own_frames = True  # as a medium that shows our transmissions would
    m = Master(link, clock=VirtualClock(), retries=1)
    with pytest.raises(TimeoutError, match="after 2 attempts"):
        m.count_slaves()
    assert m.scheduler.stats.looped_back == 2
    # The same responder on a link that knows direction: the replies are taken.
    ok = Master(PairLink.responder_link(_same_mac(segment.process)),  # type: ignore[arg-type]
                clock=VirtualClock())
    assert ok.count_slaves() == len(segment.slaves)
    assert ok.scheduler.src == MASTER_MAC
