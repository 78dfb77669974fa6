"""The ETG.8200 mailbox gateway: a UDP client written here from the layout, against the simulator.

The client builds its datagrams byte by byte: the EtherCAT header (11-bit
length, type 5), the mailbox header (length, address, channel/priority, type
and counter) and a CoE SDO upload request, as IgH's mailbox_gateway README
spells them out.
"""

from __future__ import annotations

import inspect
import socket
import struct
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.gateway import DEFAULT_BIND, MailboxGateway
from pyethercat.master.master import Master
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.mailbox.coe import (
    SdoInitiateUploadResponse,
    SdoTransferDone,
    SdoUploadClient,
    SdoUploadSegmentResponse,
    decode_coe,
)

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""
PATTERN = bytes(i & 0xFF for i in range(4096))  # coe-io's 0x2000 octet string


def request(address: int, index: int, subindex: int, counter: int = 1) -> bytes:
    """An SDO upload request datagram, from the layout."""
    coe = struct.pack("<H", 2 << 12)  # CoE header: number 0, service 2 (SDO request)
    sdo = struct.pack("<BHBI", 2 << 5, index, subindex, 0)  # initiate upload
    mbx = struct.pack("<HHBB", len(coe) + len(sdo), address, 0, 0x03 | counter << 4)
    body = mbx + coe + sdo
    return struct.pack("<H", len(body) | 5 << 12) + body


def parse(datagram: bytes) -> tuple[int, int, bytes]:
    """(mailbox address, mailbox type, payload) of a reply datagram."""
    word = struct.unpack_from("<H", datagram)[0]
    assert word >> 12 == 5 and (word & 0x7FF) == len(datagram) - 2
    length, address, _ch, tc = struct.unpack_from("<HHBB", datagram, 2)
    return address, tc & 0x0F, datagram[8:8 + length]


def expedited_u32(payload: bytes) -> int:
    service = struct.unpack_from("<H", payload)[0] >> 12
    cs, _index, _sub, value = struct.unpack_from("<BHBI", payload, 2)
    assert service == 3 and cs >> 5 == 2 and cs & 0x03 == 0x03, payload.hex()
    return int(value)


class LateReplies:
    """The segment's responder; the first slave (io) posts each reply ``hold`` frames late.

    Stands in for the slave's PDI (as a slow slave's firmware): while a reply
    waits, the slave may already take the next request from SM0, so two
    requests can be open at once and their answers come one after the other.
    """

    def __init__(self, segment: Any, hold: int) -> None:
        self.segment = segment
        self.hold = hold
        self.engine = segment.slaves[0].spec.app.mailbox
        self.pdi = self.engine.pdi
        self.engine.pdi = self
        self.frames = 0
        self.due: int | None = None
        self._lock = threading.Lock()

    def post_mailbox(self, data: bytes) -> bool:
        if self.due is None:
            self.due = self.frames + self.hold
        if self.frames < self.due or not self.pdi.post_mailbox(data):
            return False
        self.due = None
        return True

    def __getattr__(self, name: str) -> Any:
        return getattr(self.pdi, name)

    def __call__(self, frame: bytes) -> bytes | None:
        with self._lock:  # (gateway workers share the link)
            self.frames += 1
            reply = self.segment.process(frame)
            self.engine.flush()  # the slave's firmware loop
            return reply  # type: ignore[no-any-return]


def _gateway(hold: int = 0) -> Iterator[tuple[Master, MailboxGateway]]:
    seg = parse_topology(TOPOLOGY).build()
    responder = LateReplies(seg, hold) if hold else seg.process
    m = Master(PairLink.responder_link(responder), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    with MailboxGateway(m, bind=("127.0.0.1", 0)) as gw:
        yield m, gw


@pytest.fixture
def gateway() -> Iterator[tuple[Master, MailboxGateway]]:
    yield from _gateway()


@pytest.fixture
def late_gateway() -> Iterator[tuple[Master, MailboxGateway]]:
    """The io slave answers each request a few frames late."""
    yield from _gateway(hold=20)


def _client() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.settimeout(5.0)
    return s


def ask(sock: socket.socket, gw: MailboxGateway, datagram: bytes) -> bytes:
    sock.sendto(datagram, gw.address)
    data, _ = sock.recvfrom(2048)
    return data


def test_sdo_upload_by_station_address_and_by_igh_position(
        gateway: tuple[Master, MailboxGateway]) -> None:
    m, gw = gateway
    sock = _client()
    drive = m.slaves[1]
    for address in (drive.station_address, 1000 + drive.position):
        got_addr, mtype, payload = parse(ask(sock, gw, request(address, 0x1018, 2)))
        assert got_addr == address and mtype == 3  # the requester's address comes back
        assert expedited_u32(payload) == drive.identity.product_code
    assert gw.stats.forwarded == 2 and gw.stats.answered == 2


def test_master_object_dictionary_at_address_zero(gateway: tuple[Master, MailboxGateway]
                                                  ) -> None:
    m, gw = gateway
    sock = _client()
    _a, _t, payload = parse(ask(sock, gw, request(0, 0x1018, 1)))
    assert expedited_u32(payload) == 0x00504543
    for pos, s in enumerate(m.slaves):
        _a, _t, payload = parse(ask(sock, gw, request(0, 0x8000 + pos, 1)))
        assert expedited_u32(payload) & 0xFFFF == s.station_address
        _a, _t, payload = parse(ask(sock, gw, request(0, 0x8000 + pos, 6)))
        assert expedited_u32(payload) == s.identity.product_code
    _a, _t, payload = parse(ask(sock, gw, request(0, 0x8005, 1)))
    assert payload[2] >> 5 == 4  # abort: no such slave
    assert struct.unpack_from("<I", payload, 6)[0] == 0x06020000
    assert gw.stats.to_master == 2 * len(m.slaves) + 2


def test_segmented_upload_through_the_gateway(gateway: tuple[Master, MailboxGateway]) -> None:
    m, gw = gateway
    sock = _client()
    io = m.slaves[0]
    sm = SdoUploadClient(0x2000, 0)
    msg = sm.start().encode()
    counter = 1
    while True:
        body = struct.pack("<HHBB", len(msg), io.station_address, 0, 0x03 | counter << 4) + msg
        counter = counter % 7 + 1
        _a, _t, payload = parse(ask(sock, gw, struct.pack("<H", len(body) | 0x5000) + body))
        reply = decode_coe(payload)
        assert isinstance(reply, SdoInitiateUploadResponse | SdoUploadSegmentResponse)
        step = sm.receive(reply)
        if isinstance(step, SdoTransferDone):
            assert step.data == PATTERN
            break
        msg = step.encode()


def test_two_clients_at_once_never_interleave(late_gateway: tuple[Master, MailboxGateway]
                                              ) -> None:
    """Each answer goes to its own requester although the slave answers late.

    Without the per-slave lock from request to answer, the second client's
    request reaches the slave while the first one's answer is still held
    back, and whichever waiting client reads first takes the first answer:
    one client gets the other's value.
    """
    m, gw = late_gateway
    io, drive = m.slaves
    jobs = [  # two clients on the same slave, one on the other slave
        (io.station_address, 0x1018, 1, io.identity.vendor_id),
        (io.station_address, 0x1018, 2, io.identity.product_code),
        (1001, 0x1018, 2, drive.identity.product_code),
    ]
    wrong: list[str] = []
    answered = [0] * len(jobs)

    def run(n: int) -> None:
        address, index, sub, expected = jobs[n]
        sock = _client()
        for i in range(40):
            try:
                reply = ask(sock, gw, request(address, index, sub, i % 7 + 1))
            except TimeoutError:
                wrong.append(f"client {n}: no answer")
                return
            value = expedited_u32(parse(reply)[2])
            if value != expected:
                wrong.append(f"client {n}: got 0x{value:08X}")
            answered[n] += 1

    threads = [threading.Thread(target=run, args=(n,)) for n in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not wrong and answered == [40, 40, 40]
    assert gw.stats.failed == 0 and gw.stats.dropped_total == 0


def test_bad_datagrams_are_dropped_and_counted(gateway: tuple[Master, MailboxGateway]) -> None:
    m, gw = gateway
    sock = _client()
    sock.sendto(b"\x05", gw.address)
    sock.sendto(struct.pack("<H", 0x1000 | 16) + request(0x1001, 0x1018, 1)[2:], gw.address)
    sock.sendto(request(0x4444, 0x1018, 1), gw.address)  # nobody
    broken = bytearray(request(0x1001, 0x1018, 1))
    broken[2] = 200  # mailbox length past the end
    sock.sendto(bytes(broken), gw.address)
    # a good one after them is still served
    assert expedited_u32(parse(ask(sock, gw, request(0x1001, 0x1018, 1)))[2]) == 0x00504543
    deadline = time.monotonic() + 5
    while gw.stats.dropped_total < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert gw.stats.dropped == {"short": 1, "type": 1, "address": 1, "length": 1}
    assert gw.stats.received == 5 and gw.stats.answered == 1


def test_mailbox_error_reply_is_forwarded(gateway: tuple[Master, MailboxGateway]) -> None:
    m, gw = gateway
    sock = _client()
    body = struct.pack("<HHBB", 6, 0x1001, 0, 0x05 | 1 << 4) + bytes(6)  # SoE: not served
    _a, mtype, payload = parse(ask(sock, gw, struct.pack("<H", len(body) | 0x5000) + body))
    assert mtype == 0 and struct.unpack("<HH", payload) == (1, 0x0002)


def test_loopback_is_the_default() -> None:
    assert DEFAULT_BIND == ("127.0.0.1", 34980)
    bind = inspect.signature(MailboxGateway).parameters["bind"].default
    assert bind == DEFAULT_BIND
