"""Fault localisation on a simulated ring and tree: every single fault named exactly.

A ring of 8 slaves (couplers and IO terminals): each cable, each node, each
master port in turn; the diagnosis must name that one fault and nothing
else, with the ports of the cable. Then CRC errors on one cable of a tree,
fault events, and ``pyethercat diag`` on the command line.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.master.ring import FaultBoard, FaultEvent
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import parse_topology

DEVICES = ["coupler", "di8", "do8", "di2", "coupler", "do8", "di8", "ai2"]
N = len(DEVICES)


def ring_segment(ring: bool = True):
    doc = {"segment": {"ring": ring},
           "slave": [{"name": f"s{i}", "device": f"builtin:{d}"} for i, d in enumerate(DEVICES)]}
    return parse_topology(doc).build()


def open_ring():
    seg = ring_segment()
    m = Master(ring_link(seg), clock=VirtualClock())
    m.scan()
    return seg, m


def faults(m: Master) -> list[tuple[str, str]]:
    return [(f.kind, f.where) for f in m.diagnose().faults]


def test_whole_ring_has_no_fault_and_every_slave_is_reached_from_a() -> None:
    _, m = open_ring()
    d = m.diagnose()
    assert d.ok and d.ring_state == "closed"
    assert [r.side for r in d.readings] == ["A"] * N


@pytest.mark.parametrize("k", range(N - 1))
def test_each_broken_link_is_named_with_its_ports(k: int) -> None:
    seg, m = open_ring()
    seg.break_link(k, 1)
    d = m.diagnose()
    assert [(f.kind, f.where) for f in d.faults] == [
        ("link", f"between slave {k} port 1 and slave {k + 1} port 0")]
    assert [r.side for r in d.readings] == ["A"] * (k + 1) + ["B"] * (N - k - 1)
    assert "no link" in d.faults[0].detail
    seg.restore_link(k, 1)
    assert faults(m) == []


@pytest.mark.parametrize("j", range(N))
def test_each_failed_node_is_named(j: int) -> None:
    seg, m = open_ring()
    seg.power_off(j)
    (f,) = m.diagnose().faults
    assert (f.kind, f.where, f.slaves) == ("node", f"slave {j}", (j,))


@pytest.mark.parametrize("port,where", [(0, "master port A (its cable to slave 0 port 0)"),
                                        (1, f"master port B (its cable to slave {N - 1} port 1)")])
def test_master_port_faults(port: int, where: str) -> None:
    seg, m = open_ring()
    seg.master_port_fault(port)
    assert faults(m) == [("port", where)]
    assert m.ring.state() == f"port {'BA'[port]} only"
    seg.master_port_fault(port, broken=False)
    assert faults(m) == []
    assert m.ring.state() == "redundant"


def test_events_tell_when_a_fault_comes_and_goes() -> None:
    seg, m = open_ring()
    got: list[FaultEvent] = []
    m.ring.subscribe(got.append)
    seg.break_link(3, 1)
    m.diagnose()
    m.diagnose()  # the same fault again: no second event
    seg.restore_link(3, 1)
    m.diagnose()
    assert [(e.cleared, e.fault.where) for e in got] == [
        (False, "between slave 3 port 1 and slave 4 port 0"),
        (True, "between slave 3 port 1 and slave 4 port 0")]
    assert list(m.ring.events) == got


def test_the_fault_board_keeps_a_fault_until_its_cleared_line() -> None:
    # the live view's "fault now" lines: from the event lines alone (an isolated
    # engine sends text), past any number of other lines, until cleared
    seg, m = open_ring()
    board = FaultBoard()
    m.ring.subscribe(lambda e: board.take(e.text))
    seg.break_link(3, 1)
    m.diagnose()
    for i in range(500):
        board.take(f"slave {i} vanished")
    (line,) = board.lines
    assert line.startswith("link between slave 3 port 1 and slave 4 port 0 (")
    seg.break_link(5, 1)  # two breaks cut slaves 4 and 5 off: one node fault instead
    m.diagnose()
    (line,) = board.lines
    assert line.startswith("node slaves 4, 5 (")
    seg.restore_link(3, 1)
    seg.restore_link(5, 1)
    m.diagnose()
    assert board.lines == []


def test_an_isolated_engines_fault_lines_reach_the_users_fault_board() -> None:
    # the engine's ring watch runs in its process; its lines come through the shared
    # area's event ring, and the user's runner keeps the standing faults from them
    from collections import deque

    from pyethercat.master.engine.readout import EngineReadout

    cut = "cut between slave 2 port 1 and slave 3 port 0 (or slave 3 failed) (slaves 3-5 silent)"
    lines = [(1.0, "slave 3 (0x1004) vanished"), (2.0, "fault: " + cut)]
    lines += [(3.0 + k, f"recovery of slaves 3-5 not done yet ({k})") for k in range(300)]

    class Area:
        def __init__(self) -> None:
            self.lines: list[tuple[float, str]] = []

        def events_since(self, serial: int) -> tuple[int, list[tuple[float, str]]]:
            return len(self.lines), self.lines[serial:]

    readout = EngineReadout.__new__(EngineReadout)
    readout.__dict__["_events"] = deque(maxlen=200)
    readout.fault_board = FaultBoard()
    readout._event_serial = 0
    area = Area()
    readout.area = area  # type: ignore[assignment]
    area.lines += lines
    readout.poll_events()
    assert readout.fault_board.lines == [cut] and not any(cut in e.text for e in readout._events)
    area.lines.append((400.0, "cleared: " + cut))
    readout.poll_events()
    assert readout.fault_board.lines == []


def test_a_line_without_ring_names_the_cut() -> None:
    seg = ring_segment(ring=False)
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    seg.break_link(4, 1)
    (f,) = m.diagnose().faults
    assert f.kind == "cut" and f.where == "between slave 4 port 1 and slave 5 port 0 (or slave 5 failed)"
    assert f.slaves == (5, 6, 7)


DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


@pytest.mark.parametrize("slave,port,where", [
    (0, 3, "bad cable between slave 0 port 3 and slave 1 port 0"),   # the tree branch
    (2, 1, "bad cable between slave 3 port 1 and slave 4 port 0"),   # on the E-bus line
])
def test_crc_errors_name_the_cable_in_a_tree(slave: int, port: int, where: str) -> None:
    from pyethercat.sim.topology import load_topology

    seg = load_topology(DEMO).build()  # coupler with a branch on port 3 (bus position 1)
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock(), retries=10)
    m.scan()
    m.diagnose()  # the counters as they are now
    seg.crc_error_rate(slave, port, 0.2, seed=7)  # sim indices: file order
    for _ in range(30):
        m.read_states()
    crc = [f for f in m.diagnose().faults if f.kind == "crc"]
    assert [f.where for f in crc] == [where]
    assert "CRC errors" in crc[0].detail


def test_diag_command_prints_the_fault(tmp_path: Path) -> None:
    topo = tmp_path / "ring.toml"
    topo.write_text("""
[segment]
ring = true
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "di8"
device = "builtin:di8"
[[slave]]
name = "do8"
device = "builtin:do8"
[[fault]]
kind = "break_link"
slave = "di8"
port = 1
""")
    res = CliRunner().invoke(cli, ["--sim", str(topo), "diag"])
    assert res.exit_code == 0, res.output
    assert "link: between slave 1 port 1 and slave 2 port 0" in res.output
    assert "    2 from B" in res.output
    res = CliRunner().invoke(cli, ["--sim", str(topo), "diag", "--json"])
    assert '"where": "between slave 1 port 1 and slave 2 port 0"' in res.output
