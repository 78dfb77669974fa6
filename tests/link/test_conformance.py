"""The same behaviour checks over every link: pair, unix socketpair, UDP loopback, raw veth."""

from __future__ import annotations

import select
import threading
from collections.abc import Callable, Iterator

import pytest

from pyethercat.errors import LinkClosedError, LinkError
from pyethercat.link import Link, PairLink, RawLink, UdpLink, UnixLink
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import MASTER_MAC, decode_frame, encode_frame

LinkPair = tuple[Link, Link]
#: How long a receive waits for a frame that was sent: it comes at once on an idle
#: machine; the limit only ends a test whose frame is lost (loaded CI machines
#: keep a receiving thread off the CPU for a while).
ARRIVE = 10.0


def _frame(index: int, size: int = 2) -> bytes:
    return encode_frame(
        [Datagram.device(Command.BRD, 0, 0x0130, bytes([index & 0xFF]) * size, index)]
    )


def _make_pair() -> LinkPair:
    return PairLink.pair()


def _make_unix() -> LinkPair:
    return UnixLink.pair()


def _make_udp() -> LinkPair:
    server = UdpLink(bind=("127.0.0.1", 0), name="udp-server")
    # UDP carries no MACs: the client's synthetic source is set to the one our test
    # frames carry, so that "unchanged" can be checked byte for byte.
    client = UdpLink(peer=server.address, name="udp-client", rx_src=MASTER_MAC)
    # The server learns its peer from the first datagram it receives.
    client.send(_frame(0xEE))
    assert server.recv(ARRIVE) == _frame(0xEE)
    return client, server


@pytest.fixture(params=["pair", "unix", "udp", "raw"])
def links(request: pytest.FixtureRequest) -> Iterator[LinkPair]:
    kind = request.param
    if kind == "raw":
        a_name, b_name = request.getfixturevalue("veth_pair")
        made: LinkPair = (RawLink(a_name), RawLink(b_name))
    else:
        factory: Callable[[], LinkPair] = {
            "pair": _make_pair,
            "unix": _make_unix,
            "udp": _make_udp,
        }[kind]
        made = factory()
    try:
        yield made
    finally:
        for link in made:
            link.close()


def test_frames_arrive_unchanged_both_ways(links: LinkPair) -> None:
    a, b = links
    a.send(_frame(1))
    assert b.recv(ARRIVE) == _frame(1)
    b.send(_frame(2))
    assert a.recv(ARRIVE) == _frame(2)


def test_order_and_sizes_up_to_a_full_frame(links: LinkPair) -> None:
    a, b = links
    sizes = [1, 2, 40, 100, 500, 1000, 1486]
    sent = [_frame(i, size) for i, size in enumerate(sizes)]
    assert len(sent[-1]) == 1514
    for frame in sent:
        a.send(frame)
    got = [b.recv(ARRIVE) for _ in sent]
    assert got == sent
    assert [len(decode_frame(f).datagrams[0].data) for f in got if f] == sizes


def test_recv_times_out_with_none(links: LinkPair) -> None:
    a, b = links
    assert a.recv(0) is None
    assert b.recv(0.05) is None


def test_no_echo_of_own_frames(links: LinkPair) -> None:
    a, b = links
    a.send(_frame(3))
    assert a.recv(0.05) is None
    assert b.recv(ARRIVE) == _frame(3)


def test_fileno_polls_readable(links: LinkPair) -> None:
    a, b = links
    fd = b.fileno()
    if fd is None:
        assert isinstance(b, PairLink)  # the only link without an OS handle
        return
    assert select.select([fd], [], [], 0)[0] == []
    a.send(_frame(4))
    assert select.select([fd], [], [], ARRIVE)[0] == [fd]
    assert b.recv(0) == _frame(4)


def test_threaded_echo(links: LinkPair) -> None:
    a, b = links
    done = threading.Event()

    def echo() -> None:
        for _ in range(20):
            frame = b.recv(ARRIVE)
            if frame is None:
                return
            b.send(frame)
        done.set()

    thread = threading.Thread(target=echo)
    thread.start()
    try:
        for i in range(20):
            a.send(_frame(i))
            assert a.recv(ARRIVE) == _frame(i)
    finally:
        thread.join(ARRIVE)
    assert done.is_set()


def test_closed_link_raises(links: LinkPair) -> None:
    a, _b = links
    with a:
        pass
    assert a.closed
    a.close()  # idempotent
    with pytest.raises(LinkClosedError):
        a.send(_frame(5))
    with pytest.raises(LinkClosedError):
        a.recv(0)
    assert a.fileno() is None


def test_name_is_set(links: LinkPair) -> None:
    a, b = links
    assert a.name and b.name
    assert a.name in repr(a)


@pytest.mark.parametrize("size", [0, 1, 13])
def test_frames_shorter_than_an_ethernet_header_are_refused(links: LinkPair, size: int) -> None:
    a, b = links
    with pytest.raises(LinkError):
        a.send(b"\xff" * size)
    # Nothing arrived, and the link still works (an empty socketpair message used to
    # read as the peer's close).
    assert b.recv(0.05) is None
    a.send(_frame(6))
    assert b.recv(ARRIVE) == _frame(6)
