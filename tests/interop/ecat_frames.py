"""Shared by the interop tests: a set of test frames, a pcap of them, tshark field extraction.

Not a test module (no ``test_`` prefix); imported by the interop tests.
"""

from __future__ import annotations

import io
import struct
import subprocess
from dataclasses import dataclass
from pathlib import Path

from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import (
    UDP_PORT,
    decode_frame,
    decode_udp_payload,
    encode_frame,
    encode_udp_payload,
)
from pyethercat.wire.pcap import PcapngWriter, PcapWriter

#: A unicast source MAC: SOEM's 01:01:01:01:01:01 has the group bit set, which
#: Wireshark flags ("Source MAC must not be a group address").
SRC_MAC = b"\x02\x00\x00\x00\x00\x01"

TSHARK_FIELDS = [
    "frame.number",
    "ecat.cmd",
    "ecat.idx",
    "ecat.adp",
    "ecat.ado",
    "ecat.lad",
    "ecat.subframe.length",
    "ecat.subframe.more",
    "ecat.subframe.circulating",
    "ecat.int",
    "ecat.cnt",
    "_ws.expert",
    "_ws.malformed",
]


@dataclass
class SampleFrame:
    datagrams: list[Datagram]
    udp: bool = False


def _dev(cmd: Command, adp: int, ado: int, data: bytes, idx: int, **kw: int | bool) -> Datagram:
    d = Datagram.device(cmd, adp, ado, data, idx)
    for key, value in kw.items():
        setattr(d, key, value)
    return d


def _log(cmd: Command, lad: int, data: bytes, idx: int, **kw: int | bool) -> Datagram:
    d = Datagram.logical(cmd, lad, data, idx)
    for key, value in kw.items():
        setattr(d, key, value)
    return d


def sample_frames() -> list[SampleFrame]:
    """Every command alone, multi-datagram frames, C bit, IRQ, WKC values, UDP frames."""
    frames: list[SampleFrame] = []
    for i, cmd in enumerate(Command):
        data = bytes(range(i + 1, i + 1 + (i % 5) + 1))
        if cmd.is_logical:
            frames.append(SampleFrame([_log(cmd, 0x00010000 + i * 0x10, data, i, wkc=i)]))
        else:
            frames.append(
                SampleFrame([_dev(cmd, (0x1000 + i) & 0xFFFF, 0x0130 + i, data, i, wkc=i)])
            )
    # Multi-datagram frames mixing addressing modes (no NOP: scapy lacks it).
    frames.append(
        SampleFrame(
            [
                _dev(Command.FRMW, 0x1000, 0x0910, bytes(8), 0xE6),
                _log(Command.LRW, 0x12345678, bytes(range(3)), 0xE7, wkc=3),
                _dev(Command.FPRD, 0x1001, 0x0130, bytes(2), 0xE8, wkc=1),
                _dev(Command.APRD, 0xFFFF, 0x0000, bytes(4), 0xE9, irq=0x0004),
                _dev(Command.BRD, 0x0000, 0x0000, bytes(2), 0xEA, wkc=65535),
            ]
        )
    )
    # Circulating bit, IRQ values, a large datagram, a zero-length datagram.
    frames.append(SampleFrame([_dev(Command.BWR, 0x0003, 0x0101, b"\x01", 0x41, circulating=True)]))
    frames.append(
        SampleFrame(
            [
                _dev(Command.APWR, 0x0000, 0x0010, b"\x01\x10", 0xFF, irq=0xFFFF, circulating=True),
                _log(Command.LRD, 0xFFFFFFFF, bytes(1), 0x00, irq=0x8001),
            ]
        )
    )
    frames.append(SampleFrame([_log(Command.LWR, 0x00001000, bytes(range(256)) * 5, 0x10, wkc=2)]))
    frames.append(SampleFrame([_dev(Command.FPRD, 0x03E9, 0x0000, b"", 0x11)]))
    # EtherCAT over UDP.
    frames.append(SampleFrame([_dev(Command.BRD, 0, 0x0000, bytes(2), 0x20, wkc=2)], udp=True))
    frames.append(
        SampleFrame(
            [
                _log(Command.LRW, 0x00020000, bytes(8), 0x21, wkc=6),
                _dev(Command.FPRD, 0x1002, 0x0130, bytes(2), 0x22, circulating=True, irq=0x10),
            ],
            udp=True,
        )
    )
    return frames


def _ip_checksum(header: bytes) -> int:
    total = sum(struct.unpack(f">{len(header) // 2}H", header))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def udp_frame(payload: bytes, src_mac: bytes = SRC_MAC) -> bytes:
    """An Ethernet/IPv4/UDP frame (ports 34980 both ways) around ``payload``."""
    udp = struct.pack(">HHHH", UDP_PORT, UDP_PORT, 8 + len(payload), 0) + payload
    ip = struct.pack(
        ">BBHHHBBH4s4s",
        0x45,
        0,
        20 + len(udp),
        1,
        0,
        64,
        17,
        0,
        bytes([10, 0, 0, 1]),
        bytes([10, 0, 0, 2]),
    )
    ip = ip[:10] + struct.pack(">H", _ip_checksum(ip)) + ip[12:]
    frame = b"\xff" * 6 + src_mac + b"\x08\x00" + ip + udp
    return frame + bytes(max(0, 60 - len(frame)))


def encode_test_frame(frame: SampleFrame) -> bytes:
    """The Ethernet bytes of a test frame."""
    if frame.udp:
        return udp_frame(encode_udp_payload(frame.datagrams))
    return encode_frame(frame.datagrams, src=SRC_MAC)


def decoded(frame: SampleFrame) -> list[Datagram]:
    """The datagrams of a sample frame as our codec reads its bytes back (M bits set)."""
    raw = encode_test_frame(frame)
    if frame.udp:
        return decode_udp_payload(raw[42:]).datagrams
    return decode_frame(raw).datagrams


def write_capture(
    path: Path, frames: list[SampleFrame], pcapng: bool = False, extra: bytes | None = None
) -> None:
    """Write ``frames`` (and optionally one non-EtherCAT packet first) to a capture file."""
    out = io.BytesIO()
    writer: PcapWriter | PcapngWriter = PcapngWriter(out) if pcapng else PcapWriter(out)
    ts = 1_700_000_000_000_000_000
    if extra is not None:
        writer.write(ts, extra)
    for i, frame in enumerate(frames):
        writer.write(ts + (i + 1) * 1_000_123, encode_test_frame(frame))
    path.write_bytes(out.getvalue())


def tshark_rows(tshark: str, path: Path) -> dict[int, dict[str, list[str]]]:
    """Per frame number: each tshark field as a list of its occurrences (frames with ecat only)."""
    cmd = [
        tshark,
        "-r",
        str(path),
        "-n",
        "-Y",
        "ecat",
        "-T",
        "fields",
        "-E",
        "occurrence=a",
        "-E",
        "aggregator=|",
    ]
    for name in TSHARK_FIELDS:
        cmd += ["-e", name]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=300)
    rows: dict[int, dict[str, list[str]]] = {}
    for line in proc.stdout.splitlines():
        parts = line.split("\t")
        values = {
            name: (parts[i].split("|") if parts[i] else []) for i, name in enumerate(TSHARK_FIELDS)
        }
        rows[int(values["frame.number"][0])] = values
    return rows


def expected_tshark(datagrams: list[Datagram]) -> dict[str, list[str]]:
    """The tshark fields that ``datagrams`` (one frame, as decoded) should produce."""
    return {
        "ecat.cmd": [f"0x{int(d.command):02x}" for d in datagrams],
        "ecat.idx": [f"0x{d.index:02x}" for d in datagrams],
        "ecat.adp": [f"0x{d.adp:04x}" for d in datagrams if not d.is_logical],
        "ecat.ado": [f"0x{d.ado:04x}" for d in datagrams if not d.is_logical],
        "ecat.lad": [f"0x{d.logical_address:08x}" for d in datagrams if d.is_logical],
        "ecat.subframe.length": [str(len(d.data)) for d in datagrams],
        "ecat.subframe.more": [str(int(d.more)) for d in datagrams],
        "ecat.subframe.circulating": [str(int(d.circulating)) for d in datagrams],
        "ecat.int": [f"0x{d.irq:04x}" for d in datagrams],
        "ecat.cnt": [str(d.wkc) for d in datagrams],
    }


def json_to_tshark(objs: list[dict[str, object]]) -> dict[str, list[str]]:
    """The tshark fields that ``pyethercat decode --json`` objects of one frame correspond to."""

    def num(key: str, width: int) -> list[str]:
        return [f"0x{o[key]:0{width}x}" for o in objs if o[key] is not None]

    return {
        "ecat.cmd": [f"0x{o['cmd']:02x}" for o in objs],
        "ecat.idx": num("idx", 2),
        "ecat.adp": num("adp", 4),
        "ecat.ado": num("ado", 4),
        "ecat.lad": num("lad", 8),
        "ecat.subframe.length": [str(o["len"]) for o in objs],
        "ecat.subframe.more": [str(int(bool(o["more"]))) for o in objs],
        "ecat.subframe.circulating": [str(int(bool(o["circulating"]))) for o in objs],
        "ecat.int": num("irq", 4),
        "ecat.cnt": [str(o["wkc"]) for o in objs],
    }
