"""SimServer: frame loop, non-EtherCAT frames, control channel, stop; with a stand-in segment.

The real segment is exercised end to end by tests/sim/test_topology_build.py and
tests/interop/test_soem_sim.py; here a small fake keeps the server's own logic in view.
"""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from pyethercat.errors import FrameError
from pyethercat.link.pair import PairLink
from pyethercat.link.unix import UnixLink
from pyethercat.sim.server import SimServer
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame


class _Slave:
    def __init__(self, index: int, name: str) -> None:
        self.index = index
        self.name = name

    def u16(self, address: int) -> int:
        return 0x0002 if address == 0x0130 else 0  # AL status: PREOP


class FakeSegment:
    """Adds 1 to every datagram's working counter; records fault calls."""

    def __init__(self) -> None:
        self.slaves = [_Slave(0, "a"), _Slave(1, "b")]
        self.calls: list[tuple[Any, ...]] = []
        self.ticks = 0
        self.lose_next = False

    def process(self, frame: bytes) -> bytes | None:
        if self.lose_next:
            self.lose_next = False
            return None
        f = decode_frame(frame)
        if f.datagrams and f.datagrams[0].address == 0xDEAD:
            raise FrameError("broken on purpose")
        for d in f.datagrams:
            d.wkc += 1
        return encode_frame(f.datagrams, src=b"\x03" + frame[7:12])

    def tick(self) -> None:
        self.ticks += 1

    def break_link(self, slave: int, port: int) -> None:
        self.calls.append(("break_link", slave, port))

    def restore_link(self, slave: int, port: int) -> None:
        self.calls.append(("restore_link", slave, port))

    def power_off(self, slave: int) -> None:
        self.calls.append(("power_off", slave))

    def corrupt_frames(self, slave: int, port: int, count: int = 1) -> None:
        self.calls.append(("corrupt", slave, port, count))

    def drop_probability(self, p: float, seed: int | None = None) -> None:
        self.calls.append(("drop", p, seed))


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[SimServer, FakeSegment, UnixLink, str]]:
    master, child = UnixLink.pair()
    seg = FakeSegment()
    ctl = str(tmp_path / "ctl.sock")
    server = SimServer(seg, child, control=ctl)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        yield server, seg, master, ctl
    finally:
        server.stop()
        thread.join(5)
        assert not thread.is_alive()
        server.close()
        master.close()
        child.close()


def _frame(adp: int = 0) -> bytes:
    return encode_frame([Datagram(Command.BRD, 1, adp, b"\x00\x00")])


def test_answers_frames_and_ignores_others(
    running: tuple[SimServer, FakeSegment, UnixLink, str],
) -> None:
    server, seg, master, _ = running
    master.send(b"\xff" * 6 + b"\x02" * 6 + b"\x08\x00" + bytes(46))  # IPv4, not EtherCAT
    master.send(_frame())
    reply = master.recv(2.0)
    assert reply is not None
    (d,) = decode_frame(reply).datagrams
    assert d.wkc == 1 and reply[6] == 0x03
    seg.lose_next = True
    master.send(_frame())
    assert master.recv(0.1) is None
    master.send(_frame(0xDEAD))  # the segment raises: no reply, counted
    assert master.recv(0.1) is None
    stats = server.call(lambda: server.stats.as_dict())
    assert (stats["frames"], stats["replies"], stats["lost"], stats["ignored"], stats["errors"]) == (
        3,
        1,
        2,
        1,
        1,
    )
    assert "broken on purpose" in stats["last_error"]
    assert seg.ticks > 0  # periodic work runs


def _ask(path: str, *requests: dict[str, Any]) -> list[dict[str, Any]]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(5)
        s.connect(path)
        f = s.makefile("rwb")
        out = []
        for r in requests:
            f.write(json.dumps(r).encode() + b"\n")
            f.flush()
            out.append(json.loads(f.readline()))
        return out


def test_control_channel(running: tuple[SimServer, FakeSegment, UnixLink, str]) -> None:
    _, seg, _, ctl = running
    answers = _ask(
        ctl,
        {"cmd": "ping"},
        {"cmd": "slaves"},
        {"cmd": "break_link", "slave": "b", "port": 1},
        {"cmd": "restore_link", "slave": 1, "port": 1},
        {"cmd": "power_off", "slave": "a"},
        {"cmd": "corrupt", "slave": "a", "port": 0, "count": 2},
        {"cmd": "drop", "probability": 0.5, "seed": 4},
        {"cmd": "break_link", "slave": "zz", "port": 1},
        {"cmd": "melt"},
        {"cmd": "stats"},
    )
    assert answers[0] == {"ok": True}
    assert answers[1]["slaves"] == [{"index": 0, "name": "a", "al_status": 2},
                                    {"index": 1, "name": "b", "al_status": 2}]
    assert all(a["ok"] for a in answers[2:7])
    assert answers[7] == {"ok": False, "error": "no slave named 'zz'"}
    assert answers[8]["ok"] is False and "unknown command" in answers[8]["error"]
    assert answers[9]["ok"] and answers[9]["frames"] == 0
    assert seg.calls == [
        ("break_link", 1, 1),
        ("restore_link", 1, 1),
        ("power_off", 0),
        ("corrupt", 0, 0, 2),
        ("drop", 0.5, 4),
    ]


def test_bad_json_is_answered(running: tuple[SimServer, FakeSegment, UnixLink, str]) -> None:
    server = running[0]
    assert json.loads(server.command_line(b"{not json"))["ok"] is False
    assert json.loads(server.command_line(b"[1]"))["ok"] is False


def test_pair_link_without_fd_and_peer_close() -> None:
    a, b = PairLink.pair()
    server = SimServer(FakeSegment(), b)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    a.send(_frame())
    reply = a.recv(2.0)
    assert reply is not None and decode_frame(reply).datagrams[0].wkc == 1
    server.stop()
    thread.join(5)
    assert not thread.is_alive()
    server.close()


def test_run_returns_when_the_peer_goes() -> None:
    master, child = UnixLink.pair()
    server = SimServer(FakeSegment(), child)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    master.close()
    thread.join(5)
    assert not thread.is_alive()
    server.close()
    child.close()
