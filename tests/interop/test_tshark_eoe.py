"""tshark dissects the EoE fragments our master and the simulator exchange.

A ping of 1472 bytes (a full 1514-byte frame) to the seed 002 drive (128-byte
mailboxes: 16 fragments each way) is captured on the master's link. tshark
must decode every fragment's header (``ecat_mailbox.eoe.fragno``,
``.offset``, ``.frame``, ``.last``) and data (``ecat_mailbox.eoe.fragment``);
the inner frames rebuilt from tshark's own output, by the standard rules
written out here (not our reassembler), must equal the frames sent and
received. Wireshark 4.0's dissector does not reassemble by itself: it hands
fragment 0 to the Ethernet dissector, so tshark shows the inner Ethernet
and IPv4 headers of each frame's first fragment (checked too).

The Init request (Set IP parameter) our master sends, with every field and
the append-timestamp flag, must show in tshark's ``ecat_mailbox.eoe.init.*``
fields, and a frame sent with an appended timestamp in
``ecat_mailbox.eoe.timestampapp``/``.timestamp``.
"""

from __future__ import annotations

import ipaddress
import subprocess
import time
from pathlib import Path

from eoe_helpers import TOPOLOGY, ping

from pyethercat.link.capture import CaptureLink
from pyethercat.link.pair import PairLink
from pyethercat.master.eoe import EoeService, eoe_clients
from pyethercat.master.master import Master
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.mailbox.eoe import EoeIpParameters


def test_tshark_decodes_fragments_and_the_inner_frames_rebuild(tshark: str,
                                                               tmp_path: Path) -> None:
    seg = parse_topology(TOPOLOGY).build()
    path = tmp_path / "eoe.pcap"
    m = Master(CaptureLink(PairLink.responder_link(seg.process), str(path)))
    m.scan()
    m.set_state("PREOP")
    clients = eoe_clients(m.slaves)
    drive = clients[1]
    got: list[bytes] = []
    drive.on_frame = got.append
    svc = EoeService(m.scheduler, [drive]).start()
    mac = drive.get_ip().mac
    assert mac is not None
    sent = ping(mac, bytes([10, 9, 0, 3]), 1472, 5)
    drive.send(sent)
    end = time.monotonic() + 10
    while not got and time.monotonic() < end:
        time.sleep(0.01)
    svc.stop()
    m.close()
    assert got and len(got[0]) == 1514
    out = subprocess.run(
        [tshark, "-r", str(path), "-n", "-Y", "ecat_mailbox.eoe.type == 0", "-T", "fields",
         "-E", "occurrence=a", "-E", "aggregator=|", "-e", "ecat_mailbox.eoe.frame",
         "-e", "ecat_mailbox.eoe.fragno", "-e", "ecat_mailbox.eoe.offset",
         "-e", "ecat_mailbox.eoe.last", "-e", "ecat_mailbox.eoe.fragment"],
        capture_output=True, text=True, check=True, timeout=120).stdout
    fragments: list[tuple[int, int, int, int, bytes]] = []
    for line in out.splitlines():
        cols = [c.split("|") for c in line.split("\t")]
        for fr, no, off, last, data in zip(*cols, strict=True):
            frag = (int(fr, 0), int(no, 0), int(off, 0), int(last, 0),
                    bytes.fromhex(data.replace(":", "")))
            if not fragments or fragments[-1] != frag:  # a reply echoes what was sent
                fragments.append(frag)
    # rebuild by the rules; tshark shows the offset field in bytes (blocks x 32): the
    # frame size for fragment 0, the byte offset for the others
    rebuilt: list[bytes] = []
    buf = bytearray()
    for _fr, no, off, last, data in fragments:
        if no == 0:
            buf = bytearray(data)
        elif off == len(buf):
            buf += data
        else:
            continue  # a repeat of an earlier fragment
        if last:
            rebuilt.append(bytes(buf))
    assert sent in rebuilt and got[0] in rebuilt
    inner = subprocess.run(
        [tshark, "-r", str(path), "-n", "-Y", "ecat_mailbox.eoe.fragno == 0 && icmp",
         "-T", "fields", "-e", "ip.src", "-e", "icmp.type"],
        capture_output=True, text=True, check=True, timeout=120).stdout
    assert "10.9.0.1\t8" in inner and "10.9.0.3\t0" in inner


def _fields(tshark: str, path: Path, filt: str, *fields: str) -> list[list[str]]:
    args = [tshark, "-r", str(path), "-n", "-Y", filt, "-T", "fields", "-E", "occurrence=f"]
    for f in fields:
        args += ["-e", f]
    out = subprocess.run(args, capture_output=True, text=True, check=True, timeout=120).stdout
    return [line.split("\t") for line in out.splitlines()]


def test_tshark_decodes_set_ip_fields_and_an_appended_timestamp(tshark: str,
                                                               tmp_path: Path) -> None:
    seg = parse_topology(TOPOLOGY).build()
    path = tmp_path / "eoe-init.pcap"
    m = Master(CaptureLink(PairLink.responder_link(seg.process), str(path)))
    m.scan()
    m.set_state("PREOP")
    drive = eoe_clients(m.slaves)[1]
    params = EoeIpParameters(mac=bytes.fromhex("02aabbccdd10"),
                             ip=ipaddress.IPv4Address("10.9.0.3"),
                             subnet=ipaddress.IPv4Address("255.255.255.0"),
                             gateway=ipaddress.IPv4Address("10.9.0.1"),
                             dns_server=ipaddress.IPv4Address("10.9.0.53"), dns_name="drive-1")
    drive.set_ip(params, append_timestamp=True)
    got: list[bytes] = []
    drive.on_frame = got.append
    svc = EoeService(m.scheduler, [drive]).start()
    drive.send(ping(bytes.fromhex("02aabbccdd10"), bytes([10, 9, 0, 3]), 8, 1),
               timestamp=0x11223344)
    end = time.monotonic() + 10
    while not got and time.monotonic() < end:
        time.sleep(0.01)
    svc.stop()
    m.close()
    assert got
    init = _fields(tshark, path, "ecat_mailbox.eoe.type == 2",
                   "ecat_mailbox.eoe.init.contains_macaddr", "ecat_mailbox.eoe.init.contains_ipaddr",
                   "ecat_mailbox.eoe.init.contains_subnetmask",
                   "ecat_mailbox.eoe.init.contains_defaultgateway",
                   "ecat_mailbox.eoe.init.contains_dnsserver",
                   "ecat_mailbox.eoe.init.contains_dnsname",
                   "ecat_mailbox.eoe.init.append_timestamp", "ecat_mailbox.eoe.init.macaddr",
                   "ecat_mailbox.eoe.init.ipaddr", "ecat_mailbox.eoe.init.subnetmask",
                   "ecat_mailbox.eoe.init.defaultgateway", "ecat_mailbox.eoe.init.dnsserver",
                   "ecat_mailbox.eoe.init.dnsname")
    assert init, "tshark found no EoE Init (Set IP parameter) request"
    assert init[0] == ["1"] * 7 + ["02:aa:bb:cc:dd:10", "10.9.0.3", "255.255.255.0", "10.9.0.1",
                                   "10.9.0.53", "drive-1"]
    # the master's time on the last (here: only) fragment of the frame it sent; the
    # slave's reply carries the slave's time (the Init asked for it)
    stamped = _fields(tshark, path, "ecat_mailbox.eoe.type == 0 && ecat_mailbox.eoe.timestampapp == 1",
                      "ecat.cmd", "ecat_mailbox.eoe.timestamp")
    assert any(int(stamp, 0) == 0x11223344 for _cmd, stamp in stamped), stamped
    assert any(int(stamp, 0) != 0x11223344 for _cmd, stamp in stamped), stamped
