"""Runtime faults on a port the slave does not have, or that has no cable, are refused.

``Segment.break_link`` / ``restore_link`` / ``corrupt_frames`` raise a
ConfigError naming the slave and the port; the server's control channel
answers such a command with ``ok: false`` and that message.
"""

from __future__ import annotations

import json

import pytest
from simhelp import line

from pyethercat.errors import ConfigError
from pyethercat.link.unix import UnixLink
from pyethercat.sim.segment import Segment
from pyethercat.sim.server import SimServer
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame


def _seg() -> Segment:
    return line(3, profile="ET1200")  # ports 0 and 1 only; s2's port 1 has no cable


@pytest.mark.parametrize("method", ["break_link", "restore_link", "corrupt_frames"])
def test_port_the_chip_does_not_have(method: str) -> None:
    seg = _seg()
    with pytest.raises(ConfigError, match=r"slave 's1' \(index 1\).*no port 3"):
        getattr(seg, method)(1, 3)


@pytest.mark.parametrize("method", ["break_link", "restore_link", "corrupt_frames"])
def test_port_without_cable(method: str) -> None:
    seg = _seg()
    with pytest.raises(ConfigError, match=r"slave 's2' \(index 2\).*port 1 has no cable"):
        getattr(seg, method)(2, 1)


@pytest.mark.parametrize(("slave", "port"), [(-1, 0), (3, 0), (0, 4), (0, -1)])
def test_slave_or_port_out_of_range(slave: int, port: int) -> None:
    with pytest.raises(ConfigError, match=f"slave {slave}|port {port}"):
        _seg().break_link(slave, port)


def test_refused_fault_changes_nothing_and_cabled_ports_still_work() -> None:
    seg = _seg()
    frame = encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])
    with pytest.raises(ConfigError):
        seg.corrupt_frames(2, 1)
    reply = seg.process(frame)
    assert reply is not None
    seg.break_link(0, 0)  # the master's cable into slave 0 counts as a cable
    assert seg.process(frame) is None
    seg.restore_link(0, 0)
    seg.break_link(1, 0)  # the cable between s0 and s1, named from s1's side
    seg.restore_link(0, 1)  # ...restored from the other end
    assert seg.process(frame) is not None


def test_control_channel_answers_an_error_for_a_missing_port() -> None:
    master, child = UnixLink.pair()
    server = SimServer(_seg(), child)
    try:
        for cmd in ("break_link", "restore_link", "corrupt"):
            answer = json.loads(server.command_line(
                json.dumps({"cmd": cmd, "slave": "s2", "port": 1}).encode()))
            assert answer["ok"] is False
            assert "'s2'" in answer["error"] and "port 1" in answer["error"]
            answer = json.loads(server.command_line(
                json.dumps({"cmd": cmd, "slave": "s0", "port": 3}).encode()))
            assert answer["ok"] is False and "no port 3" in answer["error"]
        answer = json.loads(server.command_line(b'{"cmd": "break_link", "slave": "s1", "port": 1}'))
        assert answer == {"ok": True}
    finally:
        server.close()
        master.close()
        child.close()
