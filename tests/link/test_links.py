"""Link-specific behaviour: pair responder, socketpair across processes, UDP edge
conversion, raw-socket filtering and errors, capture tee."""

from __future__ import annotations

import errno
import io
import os
import socket
import struct
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest

from pyethercat import errors
from pyethercat.errors import LinkClosedError, LinkError
from pyethercat.link import CaptureLink, PairLink, RawLink, UdpLink, UnixLink
from pyethercat.link.udp import frame_to_udp_payload, parse_hostport, udp_payload_to_frame
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import (
    MASTER_MAC,
    decode_frame,
    encode_frame,
    encode_udp_payload,
    returned_source_mac,
)
from pyethercat.wire.pcap import CaptureFormat, PacketDirection, read_capture


def _frame(index: int, size: int = 2) -> bytes:
    return encode_frame([Datagram.device(Command.APRD, 0, 0x0000, size, index)])


# --- pair ------------------------------------------------------------------------


def test_pair_responder_answers_inside_send() -> None:
    seen: list[bytes] = []

    def respond(frame: bytes) -> bytes:
        seen.append(frame)
        decoded = decode_frame(frame)
        for d in decoded.datagrams:
            d.wkc = 1
        return encode_frame(decoded.datagrams)

    link = PairLink.responder_link(respond)
    link.send(_frame(7))
    assert seen == [_frame(7)]
    assert link.pending() == 1
    reply = link.recv(0)
    assert reply is not None
    assert decode_frame(reply).datagrams[0].wkc == 1


def test_pair_responder_may_return_nothing_or_several() -> None:
    replies: list[list[bytes]] = [[], [b"x" * 60, b"y" * 60]]
    link = PairLink.responder_link(lambda f: replies.pop(0))
    link.send(_frame(1))
    assert link.recv(0) is None
    link.send(_frame(2))
    assert [link.recv(0), link.recv(0)] == [b"x" * 60, b"y" * 60]


def test_pair_copies_the_buffer() -> None:
    a, b = PairLink.pair()
    buf = bytearray(_frame(1))
    a.send(buf)
    buf[20] ^= 0xFF
    assert b.recv(0) == _frame(1)


def test_pair_peer_close_is_reported() -> None:
    a, b = PairLink.pair()
    a.send(_frame(1))
    b.close()
    with pytest.raises(LinkClosedError, match="peer"):
        a.send(_frame(2))
    with pytest.raises(LinkClosedError, match="peer"):
        a.recv(None)


def test_pair_blocking_recv_wakes_on_send_from_other_thread() -> None:
    a, b = PairLink.pair()
    timer = threading.Timer(0.05, lambda: a.send(_frame(9)))
    timer.start()
    assert b.recv(None) == _frame(9)
    timer.join()


def test_pair_full_queue_drops() -> None:
    a, b = PairLink.pair()
    b.max_queue = 2
    for i in range(5):
        a.send(_frame(i))
    assert b.dropped == 3
    assert [b.recv(0), b.recv(0), b.recv(0)] == [_frame(0), _frame(1), None]


# --- unix socketpair ------------------------------------------------------------------

_CHILD = textwrap.dedent(
    """
    import sys
    from pyethercat.link import UnixLink
    from pyethercat.wire.frame import decode_frame, encode_frame
    link = UnixLink.from_fd(int(sys.argv[1]), "child")
    while True:
        frame = link.recv(10)
        if frame is None:
            break
        dgrams = decode_frame(frame).datagrams
        for d in dgrams:
            d.wkc += 1
        link.send(encode_frame(dgrams))
    """
)


def test_unix_link_across_a_child_process() -> None:
    parent, child = UnixLink.pair()
    fd = child.detach()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(fd)], pass_fds=[fd])
    os.close(fd)
    try:
        for i in range(5):
            parent.send(_frame(i))
            reply = parent.recv(10)
            assert reply is not None
            (d,) = decode_frame(reply).datagrams
            assert (d.index, d.wkc) == (i, 1)
    finally:
        parent.close()  # the child sees the close and exits
        assert proc.wait(10) in (0, 1)


def test_unix_peer_close_raises_on_recv() -> None:
    a, b = UnixLink.pair()
    b.close()
    with pytest.raises(LinkClosedError):
        a.recv(1.0)
    with pytest.raises(LinkClosedError):
        a.send(_frame(1))
    a.close()


def test_unix_from_bad_fd() -> None:
    with pytest.raises(LinkError, match="fd"):
        UnixLink.from_fd(987654)


# --- UDP ------------------------------------------------------------------------------


def test_udp_wire_form_is_the_ecat_payload_without_padding() -> None:
    dgrams = [Datagram.device(Command.FPRD, 0x1001, 0x0130, 2, 3)]
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    server.settimeout(2)
    with UdpLink(peer=server.getsockname()) as link:
        link.send(encode_frame(dgrams))
        payload, addr = server.recvfrom(2000)
        assert payload == encode_udp_payload(dgrams)
        assert addr == link.address
        # Answer from the right peer: delivered with a synthetic Ethernet header whose
        # source looks returned by a slave (locally administered bit set).
        server.sendto(payload, addr)
        assert link.recv(2) == encode_frame(dgrams, src=returned_source_mac(MASTER_MAC))
        # A datagram from another address is ignored.
        other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        other.sendto(payload, addr)
        assert link.recv(0.1) is None
        other.close()
    server.close()


def test_udp_server_answers_last_sender_and_refuses_early_send() -> None:
    with UdpLink(bind="127.0.0.1:0") as server:
        with pytest.raises(LinkError, match="no peer"):
            server.send(_frame(1))
        with UdpLink(peer=server.address) as client:
            client.send(_frame(1))
            assert server.recv(2) == _frame(1)  # source: the master's MAC
            assert server.peer == client.address
            server.send(_frame(2))
            reply = client.recv(2)
        assert server.peer is not None
    # What the client gets back carries the returned-frame source MAC, so a master
    # using the default MAC does not take the reply for its own frame looped back.
    assert reply == b"\xff" * 6 + returned_source_mac(MASTER_MAC) + _frame(2)[12:]
    assert reply[6:12] != MASTER_MAC


def test_udp_synthetic_macs_are_configurable_and_checked() -> None:
    src, dst = b"\x02\x00\x00\x00\x00\x07", b"\x02\x00\x00\x00\x00\x08"
    with UdpLink(bind="127.0.0.1:0", rx_src=src, rx_dst=dst) as server, UdpLink(
        peer=server.address
    ) as client:
        client.send(_frame(3))
        assert server.recv(2) == dst + src + _frame(3)[12:]
    with pytest.raises(LinkError, match="6-byte"):
        UdpLink(rx_src=b"\x01")


def test_udp_edge_conversion_helpers() -> None:
    frame = _frame(1)
    payload = frame_to_udp_payload(frame)
    assert payload == frame[14 : 14 + 2 + 14]
    assert udp_payload_to_frame(payload) == frame
    vlan = frame[:12] + b"\x81\x00\x00\x05" + frame[12:]
    assert frame_to_udp_payload(vlan) == payload
    with pytest.raises(LinkError, match="0x0800"):
        frame_to_udp_payload(frame[:12] + b"\x08\x00" + frame[14:])
    with pytest.raises(LinkError, match="too short"):
        frame_to_udp_payload(frame[:15])
    assert parse_hostport("10.0.0.1") == ("10.0.0.1", 34980)
    assert parse_hostport("host:0x88a4") == ("host", 34980)
    with pytest.raises(LinkError, match="port"):
        parse_hostport("host:nope")


def test_udp_drops_and_counts_payloads_no_ethernet_frame_can_carry(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # The Link API promises frames of at most 1514 bytes (no FCS): a UDP payload
    # longer than 1500 bytes (1514 - Ethernet header) or shorter than the 2-byte
    # EtherCAT header is not a frame. recv drops it, counts it, logs it, and goes on.
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender.bind(("127.0.0.1", 0))
    good = frame_to_udp_payload(_frame(5))
    largest = good + bytes(1500 - len(good))
    with UdpLink(peer=sender.getsockname()) as link, caplog.at_level(
        "DEBUG", logger="pyethercat.link"
    ):
        assert link.dropped_too_long == 0 and link.dropped_too_short == 0
        sender.sendto(largest + b"\x00", link.address)
        sender.sendto(b"\x0e", link.address)
        sender.sendto(largest, link.address)
        frame = link.recv(2)
        assert frame is not None and len(frame) == 1514
        assert frame[14:] == largest
        sender.sendto(bytes(4000), link.address)
        sender.sendto(b"", link.address)
        sender.sendto(good, link.address)
        assert link.recv(2) == udp_payload_to_frame(good, returned_source_mac(MASTER_MAC))
        assert link.recv(0.05) is None
        assert link.dropped_too_long == 2
        assert link.dropped_too_short == 2
    text = caplog.text
    assert "dropped a 1501-byte UDP payload" in text and "longer than" in text
    assert "dropped a 1-byte UDP payload" in text and "shorter than" in text
    assert link.name in text
    sender.close()


def test_udp_bind_failure_is_a_link_error() -> None:
    with UdpLink() as first, pytest.raises(LinkError, match="cannot bind"):
        UdpLink(bind=first.address)


# --- raw --------------------------------------------------------------------------------


def test_raw_missing_interface() -> None:
    with pytest.raises(LinkError, match="no such network interface: pyecat-nonexistent"):
        RawLink("pyecat-nonexistent")


def test_raw_without_privilege(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> socket.socket:
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(socket, "if_nametoindex", lambda name: 1)
    monkeypatch.setattr(socket, "socket", refuse)
    with pytest.raises(errors.PermissionError) as info:
        RawLink("eth-any")
    message = str(info.value)
    assert "run as root" in message
    assert f"sudo setcap cap_net_raw+ep {os.path.realpath(sys.executable)}" in message
    assert isinstance(info.value, PermissionError)  # also the builtin


def test_raw_filters_non_ethercat_and_supports_promiscuous(veth_pair: tuple[str, str]) -> None:
    a_name, b_name = veth_pair
    with RawLink(b_name, promiscuous=True) as b:
        sender = socket.socket(socket.AF_PACKET, socket.SOCK_RAW)
        sender.bind((a_name, 0))
        try:
            ipv4 = b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x01" + b"\x08\x00" + bytes(46)
            other = (
                b"\x02\x00\x00\x00\x00\x09"
                + b"\x02\x00\x00\x00\x00\x01"
                + b"\x88\xa4"
                + _frame(1)[14:]
            )
            sender.send(ipv4)
            sender.send(_frame(1))
            sender.send(ipv4)
            sender.send(other)  # unicast to another MAC: seen because promiscuous
            assert b.recv(2) == _frame(1)
            assert b.recv(2) == other
            assert b.recv(0.05) is None
        finally:
            sender.close()


def test_raw_interface_down(veth_pair: tuple[str, str]) -> None:
    a_name, _ = veth_pair
    subprocess.run(["ip", "link", "set", a_name, "down"], check=True)
    with RawLink(a_name) as a, pytest.raises(LinkError, match="down"):
        a.send(_frame(1))


def test_raw_interface_going_down_during_recv(veth_pair: tuple[str, str]) -> None:
    a_name, b_name = veth_pair
    outcome: list[object] = []
    with RawLink(a_name) as a, RawLink(b_name) as b:

        def wait() -> None:
            try:
                outcome.append(a.recv(10.0))
            except LinkError as exc:
                outcome.append(exc)

        waiter = threading.Thread(target=wait)
        waiter.start()
        threading.Event().wait(0.2)
        subprocess.run(["ip", "link", "set", a_name, "down"], check=True)
        waiter.join(5)
        assert not waiter.is_alive(), "recv did not notice the interface going down"
        assert len(outcome) == 1 and isinstance(outcome[0], LinkError)
        assert "down" in str(outcome[0])
        # The link is usable again once the interface is back.
        subprocess.run(["ip", "link", "set", a_name, "up"], check=True)
        deadline = threading.Event()
        for _ in range(50):  # the veth carrier needs a moment
            b.send(_frame(4))
            if a.recv(0.1) == _frame(4):
                break
            deadline.wait(0.05)
        else:
            pytest.fail("no frame received after the interface came back up")


def test_raw_interface_deleted_is_reported_by_recv(veth_pair: tuple[str, str]) -> None:
    # The kernel reports a deleted interface once (ENETDOWN, as if it went down) and
    # then recv would wait for nothing forever: the link must say the interface has
    # gone, on every later call, naming it.
    a_name, _ = veth_pair
    with RawLink(a_name) as a:
        subprocess.run(["ip", "link", "del", a_name], check=True)
        for _ in range(3):
            with pytest.raises(LinkError, match=f"network interface {a_name} has gone"):
                a.recv(0.2)
        with pytest.raises(LinkError, match=f"{a_name} has gone"):
            a.recv(0)
        with pytest.raises(LinkError, match=f"{a_name} has gone"):
            a.send(_frame(1))


def test_raw_interface_deleted_while_down_or_waiting(veth_pair: tuple[str, str]) -> None:
    # Deleted while down: the kernel says nothing at all. A blocking recv notices
    # within its wait slices; the check is rate-limited, not per call.
    a_name, b_name = veth_pair
    with RawLink(a_name) as a, RawLink(b_name) as b:
        subprocess.run(["ip", "link", "set", a_name, "down"], check=True)
        with pytest.raises(LinkError, match="down"):
            a.recv(0.1)
        outcome: list[object] = []

        def wait() -> None:
            try:
                outcome.append(a.recv(None))
            except LinkError as exc:
                outcome.append(exc)

        waiter = threading.Thread(target=wait)
        waiter.start()
        threading.Event().wait(0.1)
        subprocess.run(["ip", "link", "del", a_name], check=True)
        waiter.join(5)
        assert not waiter.is_alive(), "recv(None) did not notice the interface was deleted"
        assert len(outcome) == 1 and isinstance(outcome[0], LinkError)
        assert f"network interface {a_name} has gone" in str(outcome[0])
        # The peer of the veth went with it.
        with pytest.raises(LinkError, match=f"{b_name} has gone"):
            for _ in range(10):
                b.recv(0.3)


# --- capture ---------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", [CaptureFormat.PCAPNG, CaptureFormat.PCAP])
def test_capture_tees_both_directions(fmt: CaptureFormat) -> None:
    clock = iter(range(1000, 10**6, 1000))
    link = PairLink.responder_link(lambda f: f[:6] + b"\x03" + f[7:])
    out = io.BytesIO()
    cap = CaptureLink(link, out, fmt=fmt, clock=lambda: next(clock))
    cap.send(_frame(1))
    reply = cap.recv(0)
    assert cap.recv(0) is None
    assert cap.count == 2
    cap.close()
    assert link.closed
    recs = list(read_capture(io.BytesIO(out.getvalue())))
    assert [r.data for r in recs] == [_frame(1), reply]
    assert [r.timestamp_ns for r in recs] == [1000, 2000]
    if fmt is CaptureFormat.PCAPNG:
        assert [r.direction for r in recs] == [PacketDirection.OUTBOUND, PacketDirection.INBOUND]


def test_capture_to_path_by_suffix(tmp_path: Path) -> None:
    a, b = PairLink.pair()
    path = tmp_path / "x.pcap"
    with CaptureLink(a, path, flush=True) as cap:
        cap.send(_frame(1))
        assert path.read_bytes()[:4] == struct.pack("<I", 0xA1B23C4D)
    with path.open("rb") as f:
        assert [r.data for r in read_capture(f)] == [_frame(1)]
    assert b.recv(0) == _frame(1)


def test_capture_wall_clock_stamps_and_interface_name(tmp_path: Path) -> None:
    import time

    with CaptureLink(PairLink.pair()[0], tmp_path / "RUN.PCAP") as cap:
        assert cap.format is CaptureFormat.PCAP  # suffix compared without case
    before = time.time_ns()
    echo = PairLink.responder_link(lambda f: f, name="master-end")
    with CaptureLink(echo, tmp_path / "run.pcapng") as cap:
        for i in range(3):
            cap.send(_frame(i))
            assert cap.recv(0) == _frame(i)
    after = time.time_ns()
    raw = (tmp_path / "run.pcapng").read_bytes()
    recs = list(read_capture(io.BytesIO(raw)))
    stamps = [r.timestamp_ns for r in recs]
    assert len(recs) == 6 and stamps == sorted(stamps)
    assert before <= stamps[0] and stamps[-1] <= after
    assert [r.direction for r in recs] == [PacketDirection.OUTBOUND, PacketDirection.INBOUND] * 3
    assert b"master-end" in raw  # the interface is named after the inner link


def test_udp_link_named_by_the_address_given() -> None:
    """A master's link is named by its peer (errors say where nothing answered), a
    server's by the address it is bound to."""
    with UdpLink(bind=("127.0.0.1", 0)) as server, UdpLink(peer=("127.0.0.1", 9)) as master:
        host, port = server.address
        assert server.name == f"udp:{host}:{port}"
        assert master.name == "udp:127.0.0.1:9"


def test_ring_name_opens_both_ports_as_one_link() -> None:
    from pyethercat.link.redundant import RedundantLink
    from pyethercat.link.registry import open_link

    with UdpLink(bind="127.0.0.1:0") as side_a, UdpLink(bind="127.0.0.1:0") as side_b:
        name = f"ring:udp:127.0.0.1:{side_a.address[1]},udp:127.0.0.1:{side_b.address[1]}"
        with open_link(name) as ring:
            assert isinstance(ring, RedundantLink)
            ring.send(_frame(7))  # one send: a copy out of each port
            assert side_a.recv(2) == _frame(7)
            assert side_b.recv(2) == _frame(7)
            side_b.send(_frame(8))
            got = ring.recv_from(2)
            assert got is not None and got[1] == 1 and got[0][14:] == _frame(8)[14:]


@pytest.mark.parametrize("name", ["ring:", "ring:eth1", "ring:eth1,", "ring:,eth2"])
def test_ring_name_needs_both_ports(name: str) -> None:
    from pyethercat.link.registry import open_link

    with pytest.raises(LinkError, match="give both ports"):
        open_link(name)
