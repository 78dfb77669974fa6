"""The ETG.8200 mailbox gateway against ``pyethercat sim`` in a process of its own (root, veth).

The simulator serves a CoE IO slave and the seed 002 drive on one end of a
``pyecat-`` veth pair; our master cycles in OP on the other end. UDP clients
written here from the ETG.8200 layout (IgH's ``mailbox_gateway`` README: the
2-byte EtherCAT header with type 5, the 6-byte mailbox header, CoE) ask for
SDO uploads:

- through :class:`MailboxGateway` on the master in this process: expedited
  and normal uploads by station address and by 1000 + position, the
  master's own dictionary at address 0, and three clients at once;
- through ``pyethercat gateway`` attached to ``pyethercat run`` (two
  commands, as a user types them): the gateway process forwards through the
  running master's control socket.

No timing is asserted: answers must be right, the cycle must go on.
"""

from __future__ import annotations

import os
import signal
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT, wait_for

from pyethercat.link.raw import RawLink
from pyethercat.master.gateway import MailboxGateway
from pyethercat.master.master import Master
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire.al import AlState

pytestmark = pytest.mark.root

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""
PEC = 0x00504543
#: Vendor ID of the seed 002 drive (its SII and 0x1018:01)
DRIVE_VENDOR = 0x000000E4


# --- the client, from the layout -----------------------------------------------------------


def upload_request(address: int, index: int, subindex: int, counter: int = 1) -> bytes:
    """EtherCAT header (length, type 5), mailbox header (type 3 CoE), CoE SDO initiate upload."""
    coe = struct.pack("<H", 2 << 12)  # number 0, service 2: SDO request
    sdo = struct.pack("<BHBI", 0x40, index, subindex, 0)  # ccs 2: initiate upload
    mailbox = struct.pack("<HHBB", len(coe) + len(sdo), address, 0, 0x03 | (counter & 7) << 4)
    body = mailbox + coe + sdo
    return struct.pack("<H", len(body) | 5 << 12) + body


def upload_answer(datagram: bytes, index: int, subindex: int) -> tuple[int, bytes]:
    """(mailbox address, value bytes) of an initiate upload response, expedited or normal."""
    word = struct.unpack_from("<H", datagram)[0]
    assert word >> 12 == 5 and word & 0x7FF == len(datagram) - 2, datagram.hex()
    length, address, _channel, type_counter = struct.unpack_from("<HHBB", datagram, 2)
    assert type_counter & 0x0F == 0x03, datagram.hex()
    coe = datagram[8:8 + length]
    assert struct.unpack_from("<H", coe)[0] >> 12 == 3, coe.hex()  # SDO response
    cs, got_index, got_sub = struct.unpack_from("<BHB", coe, 2)
    assert cs >> 5 == 2 and (got_index, got_sub) == (index, subindex), coe.hex()
    if cs & 0x02:  # expedited: 4 - n bytes in the data field
        size = 4 - (cs >> 2 & 0x03) if cs & 0x01 else 4
        return address, coe[6:6 + size]
    complete = struct.unpack_from("<I", coe, 6)[0]
    data = coe[10:]
    assert len(data) == complete, coe.hex()  # fits one mailbox: no segments
    return address, data


def ask(port: int, datagram: bytes, sock: socket.socket | None = None) -> bytes:
    own = sock is None
    s = sock if sock is not None else socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.settimeout(30)
        s.sendto(datagram, ("127.0.0.1", port))
        return s.recvfrom(2048)[0]
    finally:
        if own:
            s.close()


def u32(data: bytes) -> int:
    return int(struct.unpack("<I", data)[0])


def clients_at_once(port: int, jobs: list[tuple[int, int, int, int]], rounds: int
                    ) -> list[str]:
    """Each job (address, index, subindex, expected u32) asked ``rounds`` times by a client
    of its own, all at the same time; what came back wrong."""
    wrong: list[str] = []

    def client(n: int) -> None:
        address, index, sub, expected = jobs[n]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for i in range(rounds):
                try:
                    reply = ask(port, upload_request(address, index, sub, i % 7 + 1), sock)
                except TimeoutError:
                    wrong.append(f"client {n}: no answer")
                    return
                got_address, value = upload_answer(reply, index, sub)
                if (got_address, u32(value)) != (address, expected):
                    wrong.append(f"client {n}: {got_address} 0x{u32(value):08X}")

    threads = [threading.Thread(target=client, args=(n,)) for n in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return wrong


# --- the segment ------------------------------------------------------------------------------


@pytest.fixture
def served(veth_pair: tuple[str, str], tmp_path: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "gateway.toml"
    topo.write_text(TOPOLOGY)
    handle = start_sim_process(topo, link=f"iface:{sim_end}")
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def test_gateway_of_a_cycling_master(served: tuple[SimProcess, str]) -> None:
    _sim, iface = served
    with Master(RawLink(iface), timeout=SIM_FRAME_TIMEOUT) as m:
        io, drive = m.scan()
        m.configure()
        runner = m.start(0.002)
        try:
            with MailboxGateway(m, bind=("127.0.0.1", 0)) as gw:
                port = gw.address[1]
                for slave in (io, drive):
                    for address in (slave.station_address, 1000 + slave.position):
                        got_address, value = upload_answer(
                            ask(port, upload_request(address, 0x1018, 2)), 0x1018, 2)
                        assert got_address == address
                        assert u32(value) == slave.identity.product_code
                # a normal (not expedited) upload: the device name
                _a, name = upload_answer(ask(port, upload_request(1000, 0x1008, 0)), 0x1008, 0)
                assert name == b"PEC-COEIO CoE test IO"
                # address 0: the master's dictionary, one record per slave
                _a, value = upload_answer(ask(port, upload_request(0, 0x8001, 6)), 0x8001, 6)
                assert u32(value) == drive.identity.product_code
                # three clients at once, two on the same slave
                wrong = clients_at_once(port, [
                    (io.station_address, 0x1018, 1, PEC),
                    (1000, 0x1018, 2, io.identity.product_code),
                    (drive.station_address, 0x1018, 2, drive.identity.product_code),
                ], rounds=25)
                assert not wrong
                assert gw.stats.failed == 0 and gw.stats.dropped_total == 0
            assert runner.running
            assert [s.state for s in m.read_states()] == [AlState.OP, AlState.OP]
        finally:
            runner.stop()


def _pyethercat(iface: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "pyethercat", "--iface", iface, *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_pyethercat_gateway_beside_pyethercat_run(served: tuple[SimProcess, str]) -> None:
    sim, iface = served
    run = _pyethercat(iface, "run", "--cycle", "2000")
    gateway = None
    try:
        assert wait_for(lambda: all(s["al_status"] == AlState.OP
                                    for s in sim.control("slaves")["slaves"])), "never in OP"
        port = _free_udp_port()
        gateway = _pyethercat(iface, "gateway", "--bind", f"127.0.0.1:{port}")
        assert gateway.stdout is not None
        first = gateway.stdout.readline()
        assert f"mailbox gateway on udp 127.0.0.1:{port}" in first, gateway.stderr
        assert f"through the master running on raw:{iface}" in first
        wrong = clients_at_once(port, [
            (1000, 0x1018, 1, PEC),
            (1000, 0x1018, 2, 0x00050001),
            (1001, 0x1018, 1, DRIVE_VENDOR),
        ], rounds=10)
        assert not wrong
        gateway.send_signal(signal.SIGINT)
        out, err = gateway.communicate(timeout=60)
        assert gateway.returncode == 0, err
        assert "served 30 of 30 requests (0 to the master, 30 forwarded, 0 failed)" in out
        # the run cycles on with its slaves in OP (a loaded host may stall the cycle past a
        # slave's watchdog now and then; the run then brings it back)
        assert run.poll() is None
        assert wait_for(lambda: all(s["al_status"] == AlState.OP
                                    for s in sim.control("slaves")["slaves"]))
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=60)
        assert run.returncode == 0, err + out
    finally:
        for proc in (gateway, run):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
