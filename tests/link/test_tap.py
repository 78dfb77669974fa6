"""The TAP link against the Linux kernel: the host's stack answers ARP written into it."""

from __future__ import annotations

import struct
import subprocess
import uuid

import pytest

from pyethercat.errors import ConfigError
from pyethercat.link.tap import TapLink, format_mac, parse_mac

PEER = bytes.fromhex("020000000077")


def _mtu(name: str) -> int:
    with open(f"/sys/class/net/{name}/mtu") as f:
        return int(f.read())


def test_names_and_macs_are_checked() -> None:
    with pytest.raises(ConfigError, match="interface name"):
        TapLink("x" * 16)
    assert parse_mac("02-00-00-00-00-0A") == bytes.fromhex("02000000000a")
    assert format_mac(bytes.fromhex("02000000000a")) == "02:00:00:00:00:0a"
    with pytest.raises(ConfigError):
        parse_mac("02:00:00:00:00")


def test_kernel_answers_arp_through_the_tap(root: None) -> None:
    name = f"pyecat-{uuid.uuid4().hex[:6]}"
    with TapLink(name, mac=bytes.fromhex("020000000042"), address="10.215.0.1/24") as tap:
        show = subprocess.run(["ip", "-o", "addr", "show", name], capture_output=True, text=True)
        assert "10.215.0.1/24" in show.stdout
        assert _mtu(name) == 1500  # a standard Ethernet payload, what EoE carries
        tap.configure(mtu=1400)
        assert _mtu(name) == 1400
        tap.configure(mtu=1500)
        assert tap.mac == bytes.fromhex("020000000042")
        request = (b"\xff" * 6 + PEER + b"\x08\x06"
                   + struct.pack("!HHBBH6s4s6s4s", 1, 0x0800, 6, 4, 1, PEER,
                                 bytes([10, 215, 0, 2]), bytes(6), bytes([10, 215, 0, 1])))
        tap.send(request)
        reply = None
        for _ in range(50):
            got = tap.recv(0.1)
            if got is not None and got[12:14] == b"\x08\x06" and got[20:22] == b"\x00\x02":
                reply = got
                break
        assert reply is not None, "the kernel did not answer ARP on the TAP"
        assert reply[:6] == PEER and reply[22:28] == bytes.fromhex("020000000042")
    gone = subprocess.run(["ip", "link", "show", name], capture_output=True)
    assert gone.returncode != 0  # removed on close
