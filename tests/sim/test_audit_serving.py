"""`pyethercat sim TOPOLOGY --udp HOST:PORT` answers EtherCAT-over-UDP requests (issue 3 item 11)."""

from __future__ import annotations

import socket
from pathlib import Path

from pyethercat.sim.server import start_sim_process
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_udp_payload, encode_udp_payload

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_sim_serves_the_demo_over_udp() -> None:
    port = _free_udp_port()
    handle = start_sim_process(DEMO, link=f"udp:127.0.0.1:{port}")
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(5.0)
            request = encode_udp_payload([
                Datagram.device(Command.BRD, 0, R.TYPE, 2, index=7),
                Datagram.positional(Command.APRD, 1, R.TYPE, 1, index=8),
            ])
            sock.sendto(request, ("127.0.0.1", port))
            reply, _ = sock.recvfrom(2048)
        brd, aprd = decode_udp_payload(reply).datagrams
        # six slaves count; the one at position 1 is the branch do8 (ET1200), the coupler an ET1100
        assert (brd.index, brd.wkc, brd.adp) == (7, 6, 6)
        assert brd.data[0] == 0x11 | 0x12
        assert (aprd.index, aprd.wkc, aprd.data) == (8, 1, b"\x12")
        stats = handle.control("stats")
        assert stats["frames"] == 1 and stats["replies"] == 1 and stats["errors"] == 0
    finally:
        assert handle.stop() == 0, handle.stderr()
