"""RedundantLink: two ports as one link (in-process pairs and UDP sockets)."""

from __future__ import annotations

import pytest

from pyethercat.errors import LinkClosedError, LinkError
from pyethercat.link.pair import PairLink
from pyethercat.link.redundant import RedundantLink
from pyethercat.link.udp import UdpLink
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame

FRAME = encode_frame([Datagram.device(Command.BRD, 0, 0, 2)])


def pairs() -> tuple[RedundantLink, PairLink, PairLink]:
    a, far_a = PairLink.pair("A", "far-A")
    b, far_b = PairLink.pair("B", "far-B")
    return RedundantLink(a, b), far_a, far_b


def test_send_goes_out_on_both_ports() -> None:
    link, far_a, far_b = pairs()
    link.send(FRAME)
    assert far_a.recv(0) == FRAME and far_b.recv(0) == FRAME
    assert (link.stats[0].sent, link.stats[1].sent) == (1, 1)


def test_recv_from_names_the_port_and_ports_take_turns() -> None:
    link, far_a, far_b = pairs()
    for _ in range(2):
        far_a.send(FRAME + b"a")
        far_b.send(FRAME + b"b")
    got = [link.recv_from(0) for _ in range(4)]
    assert [(f[-1:], p) for f, p in got] == [(b"a", 0), (b"b", 1), (b"a", 0), (b"b", 1)]
    assert link.recv_from(0) is None


def test_one_refusing_port_does_not_fail_the_send() -> None:
    link, far_a, far_b = pairs()
    far_b.close()  # port B's partner is gone
    link.send(FRAME)
    assert far_a.recv(0) == FRAME
    assert link.stats[1].refused == 1 and "closed" in link.stats[1].last_error
    with pytest.raises(LinkClosedError):
        link.send_on(1, FRAME)


def test_no_port_taking_the_frame_raises() -> None:
    link, far_a, far_b = pairs()
    far_a.close()
    far_b.close()
    with pytest.raises(LinkError):
        link.send(FRAME)


def test_udp_ports_wait_in_one_select() -> None:
    far_a, far_b = UdpLink(bind=("127.0.0.1", 0)), UdpLink(bind=("127.0.0.1", 0))
    link = RedundantLink(UdpLink(peer=far_a.address), UdpLink(peer=far_b.address))
    try:
        link.send(FRAME)
        assert far_a.recv(1.0) is not None and far_b.recv(1.0) is not None
        far_b.send(FRAME)
        got = link.recv_from(1.0)
        assert got is not None and got[1] == 1
        assert link.recv_from(0.01) is None
        assert link.carrier() is None  # UDP cannot tell
    finally:
        link.close()
        far_a.close()
        far_b.close()
    assert link.primary.closed and link.secondary.closed
