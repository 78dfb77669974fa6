"""tshark (Wireshark's EtherCAT mailbox dissector) reads our FoE and SoE traffic.

Our master writes and reads a file over FoE (with BUSY answers and an error
reply) and reads and writes SoE IDNs (with fragments and an error) against
the simulated coe-io device through a capture link. tshark must find the
opcodes, file names, packet numbers, error codes, IDNs and fragment counts
where we put them, and flag nothing as malformed.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import FoeAbort, SoeAbort
from pyethercat.link.capture import CaptureLink
from pyethercat.link.pair import PairLink
from pyethercat.master.foe import FoeClient
from pyethercat.master.master import Master
from pyethercat.master.soe import SoeClient
from pyethercat.sim.topology import parse_topology

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
foe = true
soe = true
foe_busy_every = 3
"""
FILE = bytes(range(256)) * 2  # 512 bytes: 5 packets of 116 bytes


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("foe") / "foe-soe.pcap"
    seg = parse_topology(TOPOLOGY).build()
    m = Master(CaptureLink(PairLink.responder_link(seg.process), str(path)), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    mbx = m.slaves[0].mbx
    assert mbx is not None
    foe = FoeClient(mbx)
    foe.write("file.bin", FILE)
    assert foe.read("file.bin") == FILE
    with pytest.raises(FoeAbort):
        foe.read("missing")
    soe = SoeClient(mbx)
    soe.read_value(24)
    soe.name(1)
    soe.write_value(24, list(range(40, 140)))  # 204 bytes: fragments both ways
    soe.read_value(24)
    with pytest.raises(SoeAbort):
        soe.read(99)
    m.close()
    return path


def rows(tshark: str, path: Path, display: str, *names: str) -> list[list[str]]:
    cmd = [tshark, "-r", str(path), "-n", "-Y", display, "-T", "fields",
           "-E", "occurrence=a", "-E", "aggregator=|"]
    for n in names:
        cmd += ["-e", n]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=120).stdout
    return [line.split("\t") for line in out.splitlines()]


def test_nothing_malformed(tshark: str, capture: Path) -> None:
    bad = subprocess.run(
        [tshark, "-r", str(capture), "-Y",
         "_ws.malformed || _ws.expert.severity >= error || ecat_mailbox.foe.invalid "
         "|| ecat_mailbox.soe.invalid"],
        capture_output=True, text=True, check=True, timeout=120).stdout
    assert bad.strip() == ""


def test_foe_fields(tshark: str, capture: Path) -> None:
    got = rows(tshark, capture, "ecat_mailbox.foe", "ecat_mailbox.foe_opmode",
               "ecat_mailbox.foe_filename", "ecat_mailbox.foe_packetno",
               "ecat_mailbox.foe_errcode", "ecat_mailbox.foe_busydone")
    opmodes = {int(op, 16) for r in got for op in r[0].split("|")}
    assert opmodes == {1, 2, 3, 4, 5, 6}  # RRQ WRQ DATA ACK ERR BUSY
    names = {n for r in got for n in r[1].split("|") if n}
    assert names == {"file.bin", "missing"}
    numbers = {int(n) for r in got for n in r[2].split("|") if n}
    assert numbers == {0, 1, 2, 3, 4, 5}
    codes = {c for r in got for c in r[3].split("|") if c}
    assert codes == {str(0x8001)}


def test_soe_fields(tshark: str, capture: Path) -> None:
    got = rows(tshark, capture, "ecat_mailbox.soe", "ecat_mailbox.soe_opcode",
               "ecat_mailbox.soe_idn", "ecat_mailbox.soe_frag",
               "ecat_mailbox.soe_header_incomplete", "ecat_mailbox.soe_header_error")
    opcodes = {int(op) for r in got for op in r[0].split("|")}
    assert opcodes == {1, 2, 3, 4}
    idns = {int(i, 16) for r in got for i in r[1].split("|") if i}
    assert {0x0018, 0x0001, 0x0063} <= idns
    # fragments carry fragments-left where the IDN goes: the write went in two
    frags = {int(f, 16) for r in got for f in r[2].split("|") if f}
    assert 1 in frags
    assert any("1" in r[3].split("|") for r in got)
    # the refusal has the error bit; Wireshark shows the IDN field as the error
    # (packet-ecatmb.c reads both at the same offset), the code follows the header
    assert any("1" in r[4].split("|") for r in got)
