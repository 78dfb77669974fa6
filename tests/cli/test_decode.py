"""`pyethercat decode`: text and JSON output, counting, malformed frames, exit codes."""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.cli.decode import DecodeStats, decode_records
from pyethercat.cli.main import cli
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame, encode_mailbox_frame, encode_udp_payload
from pyethercat.wire.pcap import CaptureRecord, PcapngWriter, PcapWriter

SRC = b"\x02\x00\x00\x00\x00\x01"
T0 = 1_700_000_000_000_000_000


def _write(path: Path, frames: list[bytes], pcapng: bool = False) -> Path:
    out = io.BytesIO()
    writer: PcapWriter | PcapngWriter = PcapngWriter(out) if pcapng else PcapWriter(out)
    for i, frame in enumerate(frames):
        writer.write(T0 + i * 1_500_000, frame)
    path.write_bytes(out.getvalue())
    return path


def _run(*args: str) -> Result:
    return CliRunner().invoke(cli, ["decode", *args])


def _udp(payload: bytes, v6: bool = False) -> bytes:
    udp = struct.pack(">HHHH", 34980, 34980, 8 + len(payload), 0) + payload
    if v6:
        ip = struct.pack(">IHBB16s16s", 0x60000000, len(udp), 17, 64, bytes(16), bytes(16))
        return b"\xff" * 6 + SRC + b"\x86\xdd" + ip + udp
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, bytes(4), bytes(4))
    return b"\xff" * 6 + SRC + b"\x08\x00" + ip + udp


BRD = Datagram.device(Command.BRD, 0, 0x0000, 2, 0)
FPRD = Datagram.device(Command.FPRD, 0x1001, 0x0130, 2, 0x05)
LRW = Datagram.logical(Command.LRW, 0x00010000, 8, 0x80)


@pytest.mark.parametrize("pcapng", [False, True])
def test_text_lines(tmp_path: Path, pcapng: bool) -> None:
    replied = Datagram.device(Command.FPRD, 0x1001, 0x0130, b"\x08\x00", 0x05)
    replied.wkc = 1
    circ = Datagram.device(Command.BWR, 3, 0x0101, 1, 0x41)
    circ.circulating = True
    circ.irq = 0x0004
    path = _write(
        tmp_path / ("c.pcapng" if pcapng else "c.pcap"),
        [
            encode_frame([BRD], SRC),
            encode_frame([LRW, replied], SRC),
            b"\xff" * 12 + b"\x08\x06" + bytes(46),  # ARP-ish: not EtherCAT
            encode_frame([circ], SRC),
        ],
        pcapng,
    )
    result = _run(str(path))
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines() == [
        "     1    0.000000 BRD  idx=0x00 addr=0x0000:0x0000   len=2    irq=0x0000 wkc=0     --- Type",
        "     2    0.001500 LRW  idx=0x80 lad=0x00010000       len=8    irq=0x0000 wkc=0     M--",
        "     2    0.001500 FPRD idx=0x05 addr=0x1001:0x0130   len=2    irq=0x0000 wkc=1     --- AL status",
        "     4    0.004500 BWR  idx=0x41 addr=0x0003:0x0101   len=1    irq=0x0004 wkc=0     -C- DL control+1",
    ]
    fields = result.stdout.splitlines()[1].split()
    assert fields == [
        "2",
        "0.001500",
        "LRW",
        "idx=0x80",
        "lad=0x00010000",
        "len=8",
        "irq=0x0000",
        "wkc=0",
        "M--",
    ]
    assert result.stderr.strip() == (
        "pyethercat decode: 4 packets: 3 EtherCAT frames (0 over UDP), 4 datagrams, "
        "1 non-EtherCAT packets skipped, 0 EtherCAT frames without datagrams, "
        "0 with bytes after the last datagram, 0 malformed"
    )


def test_json_objects(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "j.pcap",
        [
            encode_frame([FPRD, LRW], SRC),
            _udp(encode_udp_payload([BRD])),
            _udp(encode_udp_payload([LRW]), v6=True),
        ],
    )
    result = _run("--json", str(path))
    assert result.exit_code == 0, result.output
    objs = [json.loads(line) for line in result.stdout.splitlines()]
    assert objs[0] == {
        "frame": 1,
        "time": 0.0,
        "udp": False,
        "cmd": 4,
        "cmd_name": "FPRD",
        "idx": 5,
        "adp": 0x1001,
        "ado": 0x0130,
        "lad": None,
        "len": 2,
        "irq": 0,
        "wkc": 0,
        "more": True,
        "circulating": False,
        "register": "AL status",
    }
    assert (objs[1]["adp"], objs[1]["ado"], objs[1]["lad"], objs[1]["more"]) == (
        None,
        None,
        0x10000,
        False,
    )
    assert objs[1]["register"] is None
    assert [(o["frame"], o["udp"], o["cmd_name"]) for o in objs[2:]] == [
        (2, True, "BRD"),
        (3, True, "LRW"),
    ]
    assert objs[2]["time"] == 0.0015
    assert "3 EtherCAT frames (2 over UDP)" in result.stderr


def test_vlan_tagged_frame(tmp_path: Path) -> None:
    frame = encode_frame([FPRD], SRC)
    tagged = frame[:12] + b"\x81\x00\x00\x07" + frame[12:]
    result = _run("--json", str(_write(tmp_path / "v.pcap", [tagged])))
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["adp"] == 0x1001


def test_malformed_frames_are_reported_and_decoding_goes_on(tmp_path: Path) -> None:
    good = encode_frame([BRD], SRC)
    lying = bytearray(encode_frame([FPRD], SRC))
    lying[14:16] = struct.pack("<H", 0x1000 | 200)  # EtherCAT length past the frame end
    truncated = bytearray(encode_frame([FPRD], SRC))
    truncated[22:24] = struct.pack("<H", 40)  # datagram length past the EtherCAT length
    path = _write(tmp_path / "m.pcap", [bytes(lying), good, bytes(truncated)[:40]])
    result = _run(str(path))
    assert result.exit_code == 3
    assert len(result.stdout.splitlines()) == 1
    assert "frame 1: malformed EtherCAT frame: EtherCAT header says 200 bytes" in result.stderr
    assert "frame 3: malformed EtherCAT frame:" in result.stderr
    assert "2 malformed" in result.stderr


def test_trailing_byte_inside_length_is_tolerated(tmp_path: Path) -> None:
    # TwinCAT sends an EtherCAT length one byte longer than its datagrams; Wireshark accepts it.
    frame = bytearray(encode_frame([BRD], SRC))
    frame[14:16] = struct.pack("<H", 0x1000 | 15)
    result = _run("--json", str(_write(tmp_path / "t.pcap", [bytes(frame)])))
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["cmd_name"] == "BRD"
    assert "1 with bytes after the last datagram" in result.stderr


def test_mailbox_gateway_frames_are_counted(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "g.pcap", [encode_mailbox_frame(bytes(16), SRC), encode_frame([BRD], SRC)]
    )
    result = _run(str(path))
    assert result.exit_code == 0
    assert "1 EtherCAT frames without datagrams" in result.stderr
    assert len(result.stdout.splitlines()) == 1


def test_unreadable_and_bad_files(tmp_path: Path) -> None:
    missing = _run(str(tmp_path / "nope.pcap"))
    assert missing.exit_code == 1
    assert "cannot read" in missing.stderr
    (tmp_path / "bad.pcap").write_bytes(b"this is not a capture")
    bad = _run(str(tmp_path / "bad.pcap"))
    assert bad.exit_code == 1
    assert "not a pcap or pcapng file" in bad.stderr
    good = _write(tmp_path / "cut.pcap", [encode_frame([BRD], SRC)] * 2)
    (tmp_path / "cut.pcap").write_bytes(good.read_bytes()[:-10])
    cut = _run(str(tmp_path / "cut.pcap"))
    assert cut.exit_code == 1
    assert len(cut.stdout.splitlines()) == 1  # the first frame was printed before the error
    assert "truncated pcap record data" in cut.stderr


def test_frame_cut_inside_the_ethercat_header_is_malformed_not_a_crash(tmp_path: Path) -> None:
    header_only = b"\xff" * 6 + SRC + b"\x88\xa4"
    path = _write(tmp_path / "h.pcap", [header_only, header_only + b"\x0e", encode_frame([BRD], SRC)])
    result = _run(str(path))
    assert result.exit_code == 3, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert len(result.stdout.splitlines()) == 1
    assert "frame 1: malformed EtherCAT frame: EtherCAT header truncated" in result.stderr
    assert "frame 2: malformed EtherCAT frame: EtherCAT header truncated" in result.stderr


_PREFIXES = [
    b"\xff" * 6 + SRC + b"\x88\xa4",
    b"\xff" * 6 + SRC + b"\x81\x00\x00\x01\x88\xa4",
    b"\xff" * 6 + SRC + b"\x88\xa8\x00\x01\x81\x00\x00\x01\x88\xa4",
    _udp(b""),
    _udp(b"", v6=True),
]


@settings(max_examples=500)
@given(st.sampled_from(_PREFIXES), st.binary(max_size=80))
def test_any_packet_is_decoded_counted_or_reported(prefix: bytes, tail: bytes) -> None:
    stats = DecodeStats()
    rows = list(decode_records([CaptureRecord(0, prefix + tail)], stats))
    assert stats.packets == 1
    assert len(rows) == stats.datagrams
    # Exactly one verdict per packet.
    verdicts = (stats.ethercat - stats.other_types - len(stats.malformed) > 0) + stats.non_ethercat
    assert verdicts + stats.other_types + len(stats.malformed) == 1


def test_linux_cooked_captures_are_decoded(tmp_path: Path) -> None:
    """``tcpdump -i any`` writes SLL (113) or SLL2 (276) headers instead of Ethernet ones.

    The captures are written by scapy (its CookedLinux layers), not by us.
    """
    scapy_all = pytest.importorskip("scapy.all")
    from scapy.layers.l2 import CookedLinux, CookedLinuxV2

    frame = encode_frame([FPRD, LRW], src=SRC)
    payload = frame[14:]
    sll = CookedLinux(pkttype=4, lladdrtype=1, lladdrlen=6, src=SRC + b"\0\0",
                      proto=0x88A4) / scapy_all.Raw(payload)
    sll2 = CookedLinuxV2(proto=0x88A4, ifindex=3, lladdrtype=1, pkttype=4, lladdrlen=6,
                         src=SRC + b"\0\0") / scapy_all.Raw(payload)
    want = [line for line in _run(str(_write(tmp_path / "e.pcap", [frame]))).stdout.splitlines()]
    for name, pkt in (("sll.pcap", sll), ("sll2.pcap", sll2)):
        scapy_all.wrpcap(str(tmp_path / name), [pkt, pkt])
        result = _run(str(tmp_path / name))
        assert result.exit_code == 0, result.stderr
        lines = result.stdout.splitlines()
        assert len(lines) == 4
        # Same datagrams as from the Ethernet capture (times differ).
        assert [ln.split()[2:] for ln in lines[:2]] == [ln.split()[2:] for ln in want]
        assert "2 EtherCAT frames" in result.stderr and "not decoded" not in result.stderr


def test_other_link_types_are_named(tmp_path: Path) -> None:
    out = io.BytesIO()
    writer = PcapWriter(out, linktype=101)  # LINKTYPE_RAW: IP packets without a link header
    writer.write(T0, b"\x45" + bytes(27))
    path = tmp_path / "raw.pcap"
    path.write_bytes(out.getvalue())
    result = _run(str(path))
    assert result.exit_code == 0
    assert result.stdout == ""
    assert "1 packets of LINKTYPE_RAW (101) not decoded" in result.stderr
