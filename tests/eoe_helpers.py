"""Frames and a topology shared by the EoE tests (in process and against tshark)."""

from __future__ import annotations

import struct

from pyethercat.sim.eoe import _checksum

TOPOLOGY = """
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = { ip = "10.9.0.2/24" }
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = { ip = "10.9.0.3/24" }
"""
HOST_MAC = bytes.fromhex("020000000001")
HOST_IP = bytes([10, 9, 0, 1])


def arp_request(target: bytes) -> bytes:
    return (b"\xff" * 6 + HOST_MAC + b"\x08\x06"
            + struct.pack("!HHBBH6s4s6s4s", 1, 0x800, 6, 4, 1, HOST_MAC, HOST_IP, bytes(6),
                          target))


def ping(dst_mac: bytes, dst_ip: bytes, size: int, seq: int) -> bytes:
    data = bytes((seq + i) & 0xFF for i in range(size))
    icmp = struct.pack("!BBHHH", 8, 0, 0, 0x1234, seq) + data
    icmp = icmp[:2] + struct.pack("!H", _checksum(icmp)) + icmp[4:]
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(icmp), seq, 0, 64, 1, 0, HOST_IP, dst_ip)
    ip = ip[:10] + struct.pack("!H", _checksum(ip)) + ip[12:]
    return dst_mac + HOST_MAC + b"\x08\x00" + ip + icmp
