"""EoE between our master and the simulator in process (no privileges): the echo IP stack.

Real bytes both ways through SM0/SM1: Set/Get IP parameter with result
codes, the address filter, ARP and ICMP echo of frames large enough to need
many fragments (128-byte mailboxes of the seed 002 drive), the time-request
flag, the learning switch between two slaves and a host port, and the
service riding in the cyclic frame with the status byte from the FMMU.
"""

from __future__ import annotations

import ipaddress
import time
from types import SimpleNamespace

import pytest
from conftest import wait_for
from eoe_helpers import TOPOLOGY, arp_request, ping

from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.master.clients import registered_clients
from pyethercat.master.eoe import EoeClient, EoeError, EoeService, eoe_client, eoe_clients
from pyethercat.master.eoe_switch import TAP_QUEUE, EoeBridge, EoeSwitch
from pyethercat.master.master import Master
from pyethercat.sim.eoe import eoe_server
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.eoe import EoeIpParameters, EoeResult
from pyethercat.wire.mailbox.eoe_stream import EoeSender
from pyethercat.wire.mailbox.header import MailboxType


@pytest.fixture
def eoe() -> tuple[Master, dict[int, EoeClient], object, list[bytes]]:
    seg = parse_topology(TOPOLOGY).build()
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    m.set_state("PREOP")
    clients = eoe_clients(m.slaves)
    got: list[bytes] = []
    for c in clients.values():
        c.on_frame = got.append
    return m, clients, seg, got


def test_set_and_get_ip_parameters(eoe: tuple[Master, dict[int, EoeClient], object, list[bytes]]
                                   ) -> None:
    _m, clients, _seg, _got = eoe
    assert set(clients) == {0, 1}
    params = EoeIpParameters(mac=bytes.fromhex("02aabbccddee"),
                             ip=ipaddress.IPv4Address("10.9.0.33"),
                             subnet=ipaddress.IPv4Address("255.255.0.0"),
                             gateway=ipaddress.IPv4Address("10.9.0.1"),
                             dns_server=ipaddress.IPv4Address("10.9.0.53"), dns_name="drive-1")
    clients[1].set_ip(params)
    assert clients[1].get_ip() == params


def test_address_filter_set_get_and_effect(
        eoe: tuple[Master, dict[int, EoeClient], object, list[bytes]]) -> None:
    m, clients, seg, got = eoe
    web = clients[0]
    own = web.get_ip().mac
    assert own is not None
    web.set_address_filter([own], no_broadcast=True)
    assert web.get_address_filter() == ([own], True)
    svc = EoeService(m.scheduler, list(clients.values())).start()
    try:
        web.send(arp_request(bytes([10, 9, 0, 2])))  # broadcast: filtered out now
        web.send(ping(own, bytes([10, 9, 0, 2]), 32, 1))  # to its own MAC: passes
        assert wait_for(lambda: len(got) == 1)
        server = eoe_server(seg.slaves[0].spec.app)
        assert server.stats.filtered == 1
    finally:
        svc.stop()


def test_arp_and_fragmented_ping_both_ways(
        eoe: tuple[Master, dict[int, EoeClient], object, list[bytes]]) -> None:
    m, clients, _seg, got = eoe
    svc = EoeService(m.scheduler, list(clients.values())).start()
    try:
        drive = clients[1]
        drive.send(arp_request(bytes([10, 9, 0, 3])))
        assert wait_for(lambda: len(got) == 1)
        reply = got.pop()
        assert reply[12:14] == b"\x08\x06" and reply[20:22] == b"\x00\x02"
        drive_mac = reply[22:28]
        for seq, size in enumerate((8, 300, 1472), start=1):  # 1472: a full 1514-byte frame
            frame = ping(drive_mac, bytes([10, 9, 0, 3]), size, seq)
            drive.send(frame, request_time=True)
            assert wait_for(lambda: len(got) == 1)
            echo = got.pop()
            assert len(echo) == len(frame)
            assert echo[34] == 0 and echo[42:] == frame[42:]  # ICMP echo reply, same data
        # 128-byte mailbox: 96 data bytes per fragment, 16 fragments for 1514 bytes
        assert drive.stats.tx.fragments >= 16 and drive.stats.rx.fragments >= 16
        assert drive.stats.rx.errors == 0 and drive.stats.timestamps == 3
        assert drive.last_timestamp is not None
    finally:
        svc.stop()


def test_the_master_makes_the_eoe_client_of_every_mailbox_slave() -> None:
    seg = parse_topology(TOPOLOGY).build()
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    m.set_state("PREOP")
    assert registered_clients()[MailboxType.EOE] is EoeClient
    made = m.slaves[1].client(EoeClient)
    assert eoe_client(m.slaves[1]) is made and eoe_clients(m.slaves)[1] is made
    assert made.position == 1
    # From the scan on it is the mailbox's EoE handler: the ARP reply the slave posts is
    # taken out of an SM1 read that was not the EoE client's (an SDO upload's), and
    # rebuilt, although nobody called eoe_client() before.
    got: list[bytes] = []
    made.on_frame = got.append
    box = m.slaves[1].mbx
    assert box is not None
    sender = EoeSender(box.rx_size)
    assert sender.push(arp_request(bytes([10, 9, 0, 3])), time.monotonic())
    fragment = sender.current(time.monotonic())
    assert fragment is not None
    box.send(MailboxType.EOE, fragment, fetch=False)
    m.slaves[1].sdo_read(0x1018, 1)
    assert wait_for(lambda: len(got) == 1)
    assert got[0][12:14] == b"\x08\x06" and got[0][20:22] == b"\x00\x02"  # ARP reply
    assert box.pending() == []


def test_mailbox_datagrams_that_do_not_fit_the_cyclic_frame_leave_at_the_tick() -> None:
    # builtin:eoe-web has 1024-byte mailboxes: its SM0 write and SM1 read do not both fit
    # beside the process data. Queued for the next cycle they left right behind its frame,
    # and the tick after that frame found them still on their way: the slave got a
    # mailbox datagram every other cycle only. Sent at the tick, they are back in time.
    seg = parse_topology(TOPOLOGY).build()
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    m.configure()
    runner = m.start(cycle=0.001)
    try:
        clients = eoe_clients(m.slaves)
        web = clients[0]
        assert web.mailbox.rx_size == web.mailbox.tx_size == 1024
        got: list[bytes] = []
        web.on_frame = got.append
        svc = EoeService(m.scheduler, list(clients.values()))
        svc.attach(runner, {p: (runner.config.slaves[p].group,
                                runner.config.slaves[p].mailbox_status_offset) for p in clients})
        web.send(arp_request(bytes([10, 9, 0, 2])))
        assert wait_for(lambda: len(got) == 1)
        mac = got.pop()[22:28]
        reads = web.stats.reads
        for seq in range(1, 9):  # full-size frames: two fragments each way
            web.send(ping(mac, bytes([10, 9, 0, 2]), 1472, seq))
        assert wait_for(lambda: len(got) == 8, 20.0)
        svc.detach()
        assert web.stats.reads - reads >= 16 and web.stats.rx.errors == 0
        assert web.stats.late == 0
    finally:
        runner.stop()


def test_set_ip_result_code_raises() -> None:
    class Refusing:
        def __call__(self, params: EoeIpParameters) -> int:
            return EoeResult.NO_IP_SUPPORT

    seg = parse_topology(TOPOLOGY).build()
    eoe_server(seg.slaves[0].spec.app).endpoint.configure = Refusing()  # type: ignore[union-attr]
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    m.set_state("PREOP")
    client = eoe_clients(m.slaves)[0]
    with pytest.raises(EoeError) as err:
        client.set_ip(EoeIpParameters(ip=ipaddress.IPv4Address("10.1.1.1")))
    assert err.value.code == EoeResult.NO_IP_SUPPORT and "no IP support" in str(err.value)


def test_switch_learns_floods_and_switches_between_ports() -> None:
    sw = EoeSwitch()
    out: dict[int, list[bytes]] = {0: [], 1: [], 2: []}
    for n in range(3):
        sw.add_port(f"p{n}", lambda f, n=n: out[n].append(f) is None)
    a, b, h = (bytes([2, 0, 0, 0, 0, k]) for k in (0xA, 0xB, 0xC))
    sw.forward(0, b"\xff" * 6 + a + b"\x08\x06" + bytes(28))  # broadcast from a: flooded
    assert [len(out[n]) for n in range(3)] == [0, 1, 1]
    sw.forward(1, a + b + b"\x08\x00" + bytes(40))  # b -> a: a is known on port 0
    assert [len(out[n]) for n in range(3)] == [1, 1, 1]
    sw.forward(0, b + a + b"\x08\x00" + bytes(40))  # a -> b: only port 1, never the host
    assert [len(out[n]) for n in range(3)] == [1, 2, 1]
    sw.forward(2, bytes([2, 9, 9, 9, 9, 9]) + h + b"\x08\x00" + bytes(40))  # unknown: flood
    assert [len(out[n]) for n in range(3)] == [2, 3, 1]
    assert sw.lookup(h) == 2 and sw.ports[2].stats.frames_in == 1


def test_a_full_port_refuses_and_the_sending_slave_counts_the_drop() -> None:
    # the host's TAP queue holds TAP_QUEUE frames (its writer thread empties it); a
    # frame it refuses is lost, and the handler of the slave that sent it counts it
    bridge = EoeBridge.__new__(EoeBridge)
    bridge._writers = []
    tap = SimpleNamespace(name="pyecat-t0")
    to_host = bridge._to_tap(tap)  # type: ignore[arg-type]  (no writer started)
    sw = EoeSwitch()
    got: list[bytes] = []
    sw.add_port("slave 0", lambda f: got.append(f) is None)
    sw.add_port("host", to_host)
    client = SimpleNamespace(stats=SimpleNamespace(rx=SimpleNamespace(dropped=0)))
    from_slave = EoeBridge._from_slave(sw, 0, client)  # type: ignore[arg-type]
    a, h = bytes([2, 0, 0, 0, 0, 0xA]), bytes([2, 0, 0, 0, 0, 0xC])
    sw.forward(1, b"\xff" * 6 + h + b"\x08\x06" + bytes(28))  # the host is learnt on port 1
    frame = h + a + b"\x08\x00" + bytes(40)
    for _ in range(TAP_QUEUE):
        from_slave(frame)
    assert client.stats.rx.dropped == 0 and bridge._writers[0][1].qsize() == TAP_QUEUE
    from_slave(frame)
    assert client.stats.rx.dropped == 1 and sw.ports[1].stats.dropped == 1
    assert sw.forward(0, frame) == 1 and sw.forward(1, a + h + b"\x08\x00" + bytes(40)) == 0


def test_service_rides_in_the_cyclic_frame_with_the_mapped_status_byte() -> None:
    seg = parse_topology(TOPOLOGY).build()
    sent: list[bytes] = []
    link = PairLink.responder_link(lambda f: (sent.append(f), seg.process(f))[1])
    m = Master(link)
    m.scan()
    m.configure()
    runner = m.start(cycle=0.001)
    try:
        clients = eoe_clients(m.slaves)
        got: list[bytes] = []
        for c in clients.values():
            c.on_frame = got.append
        svc = EoeService(m.scheduler, list(clients.values()))
        offsets = {p: (runner.config.slaves[p].group, runner.config.slaves[p].mailbox_status_offset)
                   for p in clients}
        assert all(o >= 0 for _g, o in offsets.values())
        svc.attach(runner, offsets)
        before = len(sent)
        clients[0].send(arp_request(bytes([10, 9, 0, 2])))
        assert wait_for(lambda: len(got) == 1)
        svc.detach()
        frames = [decode_frame(f) for f in sent[before:]]
        # the SM1 status reads come from the cyclic frame's FMMU, never a poll of 0x080D
        assert not any(d.command == Command.FPRD and d.ado == 0x080D
                       for f in frames for d in f.datagrams)
        # the EoE write rode behind the process data (an LRW/LRD) in one frame
        assert any(any(d.command == Command.FPWR and d.ado == 0x1000 for d in f.datagrams)
                   and any(d.is_logical for d in f.datagrams) for f in frames)
    finally:
        runner.stop()


def test_time_appended_flag_both_ways(
        eoe: tuple[Master, dict[int, EoeClient], object, list[bytes]]) -> None:
    """The master appends its time to a frame, then asks the slave (Set IP flag bit 16) to
    append the slave's: each side takes the time off and passes the frame on unchanged."""
    m, clients, seg, got = eoe
    drive = clients[1]
    server = eoe_server(seg.slaves[1].spec.app)  # type: ignore[attr-defined]
    assert server is not None
    mac = drive.get_ip().mac
    assert mac is not None
    with pytest.raises(ConfigError, match="32 bits"):
        drive.send(ping(mac, bytes([10, 9, 0, 3]), 8, 1), timestamp=1 << 32)
    svc = EoeService(m.scheduler, [drive]).start()
    try:
        # 300 bytes of ICMP data: a 342-byte frame, 4 fragments of the 128-byte mailbox
        frame = ping(mac, bytes([10, 9, 0, 3]), 300, 1)
        assert drive.send(frame, timestamp=0xA1B2C3D4)
        assert wait_for(lambda: len(got) == 1)
        assert server.receiver.timestamp == 0xA1B2C3D4
        assert frame in server.endpoint.received  # type: ignore[attr-defined]
        echo = got.pop()
        assert drive.receiver.timestamp is None  # the slave appends nothing unless asked

        drive.set_ip(EoeIpParameters(), append_timestamp=True)
        assert server.append_timestamp
        before = server.clock_ns() & 0xFFFF_FFFF
        assert drive.send(ping(mac, bytes([10, 9, 0, 3]), 300, 2))
        assert wait_for(lambda: len(got) == 1)
        after = server.clock_ns() & 0xFFFF_FFFF
        echo2 = got.pop()
        stamp = drive.receiver.timestamp
        assert stamp is not None and drive.last_timestamp == stamp
        # the slave's clock when it sent the reply (32 bits: compared modulo 2**32)
        assert (stamp - before) & 0xFFFF_FFFF <= (after - before) & 0xFFFF_FFFF
        assert len(echo2) == len(echo) == len(frame)  # the 4 time bytes are not in the frame
        assert echo2[42:] == ping(mac, bytes([10, 9, 0, 3]), 300, 2)[42:]
        assert drive.stats.rx.errors == 0
    finally:
        svc.stop()
