"""tshark (Wireshark's EtherCAT mailbox dissector) reads the CoE traffic our master sends.

Our master runs SDO transfers of every kind against the simulated coe-io
device through a capture link; tshark must find index, subindex, data and
abort code where we put them, and flag nothing as malformed.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import SdoAbort
from pyethercat.link.capture import CaptureLink
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
"""


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pyethercat.sim.topology import load_topology

    d = tmp_path_factory.mktemp("coe")
    (d / "coe.toml").write_text(TOPOLOGY)
    seg = load_topology(d / "coe.toml").build()
    path = d / "coe.pcap"
    m = Master(CaptureLink(PairLink.responder_link(seg.process), str(path)),
               clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    io = m.slaves[0]
    io.sdo_read(0x1018, 1)                                   # expedited upload
    io.sdo_read(0x2000)                                      # segmented upload, 4 KiB
    io.sdo_write(0x8000, 1, 0x1234, "uint16")                # expedited download
    io.sdo_write(0x2000, 0, bytes(range(200)) * 3)           # segmented download
    with pytest.raises(SdoAbort):
        io.sdo_read(0x9999)                                  # abort
    io.sdo_read(0x1018, 0, complete_access=True)             # complete access
    _ = io.od[0x1018][1]                                     # SDO information
    m.close()
    return path


def fields(tshark: str, path: Path, display: str, *names: str) -> list[list[str]]:
    cmd = [tshark, "-r", str(path), "-n", "-Y", display, "-T", "fields",
           "-E", "occurrence=a", "-E", "aggregator=|"]
    for n in names:
        cmd += ["-e", n]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=120).stdout
    return [line.split("\t") for line in out.splitlines()]


def test_expedited_upload_fields(tshark: str, capture: Path) -> None:
    rows = fields(tshark, capture, "ecat_mailbox.coe.sdoidx == 0x1018",
                  "ecat_mailbox.coe.type", "ecat_mailbox.coe.sdosub", "ecat_mailbox.coe.sdodata")
    # our request (service 2) goes out with the mailbox write; the slave's response
    # (service 3) comes back in a later read, as from real firmware (which answers
    # after the frame has passed, never within it)
    request = next(i for i, r in enumerate(rows) if r[0].split("|")[0] == "2" and r[1].startswith("0x01"))
    assert any(r[0].split("|")[-1] == "3" and r[1].split("|")[-1] == "0x01" and r[2].endswith("0x00504543")
               for r in rows[request:])


def test_expedited_download_fields(tshark: str, capture: Path) -> None:
    rows = fields(tshark, capture, "ecat_mailbox.coe.sdoidx == 0x8000",
                  "ecat_mailbox.coe.type", "ecat_mailbox.coe.sdosub", "ecat_mailbox.coe.sdodata")
    assert rows and rows[0][1].split("|")[0] == "0x01"
    assert int(rows[0][2].split("|")[0], 16) == 0x1234


def test_abort_code(tshark: str, capture: Path) -> None:
    rows = fields(tshark, capture, "ecat_mailbox.coe.abortcode", "frame.number",
                  "ecat_mailbox.coe.abortcode")
    assert rows and rows[0][1] == "0x06020000"
    # the abort answers the request for the object that does not exist (0x9999)
    asked = fields(tshark, capture, "ecat_mailbox.coe.sdoidx == 0x9999", "frame.number")
    assert asked and int(asked[0][0]) <= int(rows[0][0])


def test_segments_and_complete_access(tshark: str, capture: Path) -> None:
    up = fields(tshark, capture, "ecat_mailbox.coe.sdoscsus", "frame.number")
    down = fields(tshark, capture, "ecat_mailbox.coe.sdoccsds", "frame.number")
    # 4096 bytes: 112 in the initiate, 119 per segment -> 34 segments; 600 bytes -> 5
    assert len(up) >= 34
    assert len(down) >= 5
    ca = fields(tshark, capture, "ecat_mailbox.coe.sdoccsid.complete == 1",
                "ecat_mailbox.coe.sdoidx")
    assert ca and ca[0][0].startswith("0x1018")


def test_sdo_information(tshark: str, capture: Path) -> None:
    rows = fields(tshark, capture, "ecat_mailbox.coe.sdoinfoopcode",
                  "ecat_mailbox.coe.sdoinfoopcode", "ecat_mailbox.coe.sdoinfoindex",
                  "ecat_mailbox.coe.sdoinfoname")
    opcodes = {op for r in rows for op in r[0].split("|")}
    assert {"3", "4", "5", "6"} <= opcodes
    assert any(r[2] == "Identity" for r in rows)


def test_nothing_malformed(tshark: str, capture: Path) -> None:
    assert fields(tshark, capture, "ecat_mailbox.coe", "frame.number")
    # Errors only: Wireshark does not parse the optional unit/default/min/max fields of
    # an entry description (value info 0x78) and warns "trailing stray characters" about
    # its name field; the layout is the one ETG.1000.6 gives (facts 7.6).
    bad = fields(tshark, capture, "_ws.malformed || _ws.expert.severity >= 8388608",
                 "frame.number", "_ws.expert.message")
    assert bad == []
