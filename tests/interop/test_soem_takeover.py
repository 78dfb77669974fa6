"""Our ``upload`` after SOEM used the slave's mailbox (pysoem over a veth pair, root).

SOEM (pysoem) brings a simulated builtin:coe-io to PREOP, reads an object k
times (k = 0..8) and closes, leaving the slave in PREOP with SOEM's last
mailbox counter (1, 2, ... 7, 1, 2). Then ``pyethercat --iface A upload``
must read 0x1018:01: the slave drops a request whose counter repeats its last
one, so after k = 1 and k = 8 our first request (counter 1) goes unanswered
and has to be sent again with the next counter. The capture of the whole
session shows the counters SOEM and we used.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from pyethercat.sim.server import start_sim_process
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.header import MailboxHeader
from pyethercat.wire.pcap import read_capture

pysoem = pytest.importorskip("pysoem")

pytestmark = pytest.mark.root

TOPOLOGY = '[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n'
VENDOR = 0x00504543


def sm0_counters(pcap: Path) -> list[int]:
    """Counters of every mailbox written to SM0 (0x1000), in order, as the slave saw them."""
    out = []
    with pcap.open("rb") as f:
        for rec in read_capture(f):
            for d in decode_frame(rec.data).datagrams:
                if d.command == Command.FPWR and d.ado == 0x1000 and d.wkc == 1:
                    out.append(MailboxHeader.decode(d.data).counter)
    return out


def test_upload_after_soem_did_k_sdo_reads(veth_pair: tuple[str, str], tmp_path: Path) -> None:
    master_end, sim_end = veth_pair
    topo = tmp_path / "io.toml"
    topo.write_text(TOPOLOGY)
    pcap = tmp_path / "takeover.pcapng"
    # The simulator records what reached it: the replies it wrote carry WKC 1.
    with start_sim_process(topo, link=f"iface:{sim_end}", pcap=pcap, realtime=10) as sim:
        for k in range(9):
            soem = pysoem.Master()
            soem.open(master_end)
            try:
                assert soem.config_init() == 1
                io = soem.slaves[0]
                for _ in range(k):
                    assert int.from_bytes(io.sdo_read(0x1018, 1), "little") == VENDOR
            finally:
                soem.close()
            got = subprocess.run(
                [sys.executable, "-m", "pyethercat", "--iface", master_end, "upload", "-p", "0",
                 "0x1018", "1"], capture_output=True, text=True, timeout=60)
            assert got.returncode == 0, f"after {k} SOEM reads: {got.stderr}"
            assert int(got.stdout.split()[0], 0) == VENDOR, got.stdout
        stats = sim.control("stats")
    assert stats["errors"] == 0
    # Per session: SOEM's k requests numbered from 1 (it starts again after its INIT ->
    # PREOP), then ours: the SDO information request for the type and the upload. Where
    # SOEM's last counter was 1, our first request was dropped and went again as 2.
    want: list[int] = []
    for k in range(9):
        want += [i % 7 + 1 for i in range(k)]
        want += [1, 2, 3] if k % 7 == 1 else [1, 2]
    assert sm0_counters(pcap) == want
