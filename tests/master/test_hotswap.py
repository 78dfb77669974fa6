"""Hot swap while cycling: a slave unplugged and plugged back is identified and back in OP.

In-process simulator on virtual time, the loop and its ring watch riding
along: the other slaves keep exchanging all the while. The device plugged
back is the same one, another unit of the same kind (another serial
number), another product (refused: its process data differs), or one
carrying another alias than its place asks for (refused). With distributed
clocks the device plugged back gets the delay of its place and an offset
that puts its system time on the reference's.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pyethercat.clock import VirtualClock
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.master.ringwatch import RingWatch
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import device_spec, load_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def start(topology: str = "demo.toml", dc: bool = False):
    clock = VirtualClock()
    seg = load_topology(EXAMPLES / topology).build(clock=clock)
    m = Master(ring_link(seg), clock=clock)
    m.scan()
    if dc:
        m.dc.setup()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0.05,
                     recover=m.hotswap.recover)
    m.pd.runner = r
    r.riders.append(RingWatch(m.ring, log=r.log))
    r.supervising = False
    r.run(cycles=3)
    m.set_state(AlState.OP)
    r.supervising = True
    r.run(cycles=20)
    return seg, m, r


def plug_cycle(seg, r, index: int, spec=None, off_cycles: int = 30) -> int:
    """Unplug sim slave ``index``, plug ``spec`` (None: the same) in; cycles until back in OP."""
    seg.remove_slave(index)
    r.run(cycles=off_cycles)
    seg.insert_slave(index, spec)
    for n in range(1, 500):
        r.run(cycles=1)
        if seg.escs[index].al_state() == AlState.OP and r.groups[0].wkc_ok:
            return n
    return -1


def test_the_same_device_comes_back_in_op_while_the_others_exchange() -> None:
    seg, m, r = start()
    lost = r.stats.lost_frames
    n = plug_cycle(seg, r, 2)  # the do8 at bus position 3
    assert 0 < n <= 100
    (ev,) = list(m.hotswap.events)
    assert (ev.position, ev.outcome) == (3, "same")
    assert r.stats.lost_frames == lost and r.stats.incomplete <= 1
    # its outputs flow again: wired to the di8 at bus position 2
    for i in range(8):
        m.slaves[3].outputs[f"Output {i + 1}"] = (0x5A >> i) & 1
    r.run(cycles=3)
    assert sum(int(m.slaves[2].inputs[f"Input {i + 1}"]) << i for i in range(8)) == 0x5A


def test_another_unit_of_the_same_device_takes_the_place() -> None:
    seg, m, r = start()
    n = plug_cycle(seg, r, 2, device_spec("builtin:do8", "do8-new", serial=4242))
    assert 0 < n <= 100
    (ev,) = list(m.hotswap.events)
    assert ev.outcome == "replaced" and ev.found is not None and ev.found.serial == 4242
    assert "another unit took its place" in ev.text


def test_another_product_with_other_process_data_is_refused() -> None:
    seg, m, r = start()
    n = plug_cycle(seg, r, 2, device_spec("builtin:ai2", "intruder"), off_cycles=30)
    assert n == -1  # never in OP
    ev = list(m.hotswap.events)[-1]
    assert ev.outcome == "refused" and "not configured" in ev.text
    assert seg.escs[2].al_state() == AlState.INIT
    # the others never stopped
    assert all(seg.escs[i].al_state() == AlState.OP for i in (0, 1, 3, 4, 5))


def test_a_device_with_another_alias_is_refused() -> None:
    seg, m, r = start()
    m.slaves[3].alias = 0x0300  # the place asks for this alias
    n = plug_cycle(seg, r, 2, device_spec("builtin:do8", "do8-new", alias=0x0777))
    assert n == -1
    ev = list(m.hotswap.events)[-1]
    assert ev.outcome == "refused" and "alias 0x0777, its place wants 0x0300" in ev.text


def test_distributed_clock_of_the_device_plugged_back() -> None:
    seg, m, r = start("dc-tree-20.toml", dc=True)
    report = m.dc.report
    assert report is not None
    victim = next(s for s in report.slaves if s.system_time and not s.reference
                  and s.delay_ns and s.position > 3)
    station = m.slaves[victim.position].station_address
    index = next(i for i, e in enumerate(seg.escs) if e.u16(R.STATION_ADDRESS) == station)
    assert plug_cycle(seg, r, index) > 0
    # the delay of its place, and a system time on the reference's (0x092C: |difference|)
    delay = struct.unpack("<I", m.read(victim.position, R.DC_SYSTEM_TIME_DELAY, 4))[0]
    assert delay == victim.delay_ns
    r.run(cycles=50)
    diff = struct.unpack("<I", m.read(victim.position, R.DC_SYSTEM_TIME_DIFFERENCE, 4))[0]
    assert diff & 0x7FFF_FFFF < 1000, f"system time difference {diff & 0x7FFFFFFF} ns"


def test_coe_start_up_commands_are_applied_again_to_the_device_plugged_back() -> None:
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock()
    doc = {"segment": {"ring": True},
           "slave": [{"name": "coupler", "device": "builtin:coupler"},
                     {"name": "io", "device": "builtin:coe-io"},
                     {"name": "do", "device": "builtin:do8"}]}
    seg = parse_topology(doc).build(clock=clock)
    m = Master(ring_link(seg), clock=clock)
    m.scan()
    # A PRE-OP -> SAFE-OP start-up SDO (ESI InitCmd): the sync manager 2 cycle time.
    m.add_startup_command(1, "PS", 0x10F1, 2, (1234).to_bytes(2, "little"))
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0.05,
                     recover=m.hotswap.recover)
    m.pd.runner = r
    r.riders.append(RingWatch(m.ring, log=r.log))
    r.supervising = False
    r.run(cycles=3)
    m.set_state(AlState.OP)
    r.supervising = True
    r.run(cycles=20)

    def value() -> int:
        return int(seg.escs[1].app.protocols[3].od.value(0x10F1, 2))

    assert value() == 1234
    spec = device_spec("builtin:coe-io", "io-new", serial=77)
    seg.remove_slave(1)
    r.run(cycles=30)
    seg.insert_slave(1, spec)
    assert value() != 1234  # a fresh device: its own default
    for _ in range(100):
        r.run(cycles=1)
        if seg.escs[1].al_state() == AlState.OP and r.groups[0].wkc_ok:
            break
    assert seg.escs[1].al_state() == AlState.OP
    assert value() == 1234
    assert [e.outcome for e in m.hotswap.events][-1] == "replaced"


def test_a_hot_connect_group_goes_and_comes_back() -> None:
    from pyethercat.master.control import ring_ops
    from pyethercat.master.control.handlers import MasterContext, dispatch

    clock = VirtualClock()
    doc = {"segment": {"ring": True},
           "slave": [{"name": "coupler", "device": "builtin:coupler"},
                     {"name": "in1", "device": "builtin:di8"},
                     {"name": "tool", "device": "builtin:do8", "alias": 0x0100},
                     {"name": "tool-in", "device": "builtin:di8"},
                     {"name": "tail", "device": "builtin:do8"}]}
    from pyethercat.sim.topology import parse_topology

    seg = parse_topology(doc).build(clock=clock)
    m = Master(ring_link(seg), clock=clock)
    m.scan()
    presence = m.hot_connect("tool", alias=0x0100, size=2)
    assert presence.positions == (2, 3) and presence.present
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0.05,
                     recover=m.hotswap.recover)
    m.pd.runner = r
    r.riders.append(RingWatch(m.ring, log=r.log,
                              on_reading=lambda _d, absent: m.hotswap.update_groups(absent)))
    r.supervising = False
    r.run(cycles=3)
    m.set_state(AlState.OP)
    r.supervising = True
    r.run(cycles=20)
    # the tool (two slaves) is unplugged: the rest keep exchanging, the group is absent
    seg.remove_slave(2)
    seg.remove_slave(3)
    r.run(cycles=30)
    assert [g.present for g in m.hotswap.groups(r.absent)] == [False]
    assert r.groups[0].present_ok
    ctx = MasterContext(m, "sim")
    (item,) = dispatch(ctx, ring_ops.HotConnectGroups()).groups
    assert item.text == "hot connect group tool (alias 0x0100, slaves 2-3): ABSENT"
    # plugged back: configured again, both in OP, the group present
    seg.insert_slave(2)
    seg.insert_slave(3)
    for _ in range(300):
        r.run(cycles=1)
        if r.groups[0].wkc_ok and all(seg.escs[i].al_state() == AlState.OP for i in (2, 3)):
            break
    assert all(seg.escs[i].al_state() == AlState.OP for i in (2, 3))
    r.run(cycles=300)
    assert [g.present for g in m.hotswap.groups(r.absent)] == [True]
    outcomes = [e.outcome for e in m.hotswap.events]
    assert outcomes[0] == "group absent" and "group present" in outcomes
    assert outcomes.count("same") == 2


TOOL_RING = {"segment": {"ring": "junction:1"},
             "slave": [{"name": "coupler", "device": "builtin:coupler"},
                       {"name": "in1", "device": "builtin:di8"},
                       {"name": "out1", "device": "builtin:do8"},
                       # the ring's last slave: port 1 to master port B, the tool on port 3
                       {"name": "junction", "device": "builtin:coupler"},
                       {"name": "tool", "device": "builtin:do8", "alias": 0x0200,
                        "parent": "junction", "port": 3},
                       {"name": "tool-in", "device": "builtin:di8"}],
             # what the master writes to the tool comes back from the tool's input terminal
             "wire": [{"from": "tool:0", "to": "tool-in:0", "bits": 8}]}


def test_a_hot_connect_group_absent_at_the_scan_is_configured_when_it_appears() -> None:
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock()
    seg = parse_topology(TOOL_RING).build(clock=clock)
    seg.remove_slave(4)  # the tool is not there when the master starts
    seg.remove_slave(5)
    m = Master(ring_link(seg), clock=clock)
    m.scan()
    assert len(m.slaves) == 4
    presence = m.hot_connect("tool", alias=0x0200, size=2)
    assert (presence.present, presence.positions) == (False, ())
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0.05,
                     recover=m.hotswap.recover)
    m.pd.runner = r
    m.hotswap.log = r.log
    r.riders.append(RingWatch(m.ring, log=r.log,
                              on_reading=lambda d, absent: m.hotswap.update_groups(absent, d)))
    r.supervising = False
    r.run(cycles=3)
    m.set_state(AlState.OP)
    r.supervising = True
    r.run(cycles=50)
    assert [g.present for g in m.hotswap.groups(r.absent)] == [False]
    assert r.groups[0].wkc_ok and m.ring.faults == ()
    # the tool is plugged into the junction's free port
    seg.insert_slave(4)
    seg.insert_slave(5)
    for _ in range(300):
        r.run(cycles=1)
        if all(seg.escs[i].al_state() == AlState.OP for i in (4, 5)) and \
                all(g.wkc_ok for g in r.groups) and m.hotswap.groups(r.absent)[0].present:
            break
    assert all(seg.escs[i].al_state() == AlState.OP for i in (4, 5))
    assert len(m.slaves) == 6 and m.slaves[4].alias == 0x0200
    assert [s.name for s in m.slaves][4:] == ["PEC-DO8 8Ch. digital output",
                                              "PEC-DI8 8Ch. digital input"]
    (g,) = m.hotswap.groups(r.absent)
    assert (g.present, g.positions) == (True, (4, 5))
    assert [e.outcome for e in m.hotswap.events] == ["group connected"]
    # its process data is a group of its own, after the others': the old one unchanged
    assert [x.name for x in r.groups] == ["main", "tool"]
    assert cfg.group("tool").logical_base >= cfg.group("main").logical_end
    for value in (0x5A, 0xC3):
        for i in range(8):
            m.slaves[4].outputs[f"Output {i + 1}"] = (value >> i) & 1
            m.slaves[2].outputs[f"Output {i + 1}"] = (value >> i) & 1
        r.run(cycles=3)
        assert sum(int(m.slaves[5].inputs[f"Input {i + 1}"]) << i for i in range(8)) == value
        assert int(seg.pdio.outputs(np.array([2], np.int64), 1)[0, 0]) == value
    assert all(x.wkc_ok for x in r.groups)
    assert m.ring.faults == () and m.ring.state() == "redundant"
    # from now on it goes and comes back as a group found at the scan
    seg.remove_slave(4)
    seg.remove_slave(5)
    r.run(cycles=30)
    assert [g.present for g in m.hotswap.groups(r.absent)] == [False]
    assert r.groups[0].wkc_ok
    seg.insert_slave(4)
    seg.insert_slave(5)
    r.run(cycles=300)
    assert [g.present for g in m.hotswap.groups(r.absent)] == [True]
    assert all(x.wkc_ok for x in r.groups)
    assert [e.outcome for e in m.hotswap.events][1:] == ["group absent", "same", "same",
                                                         "group present"]


def test_the_masters_own_loop_connects_a_group_that_appears() -> None:
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock()
    seg = parse_topology(TOOL_RING).build(clock=clock)
    seg.remove_slave(4)
    seg.remove_slave(5)
    # Faults act between frames, in the loop's thread (the segment is not shared across threads).
    pending: list[Callable[[], None]] = []

    def before(_port: int) -> None:
        while pending:
            pending.pop(0)()

    with Master(ring_link(seg, before=before), clock=clock) as m:
        m.scan()
        m.hot_connect("tool", alias=0x0200, size=2)
        m.configure()
        runner = m.start(0.001)  # the master's own ring watch rides in this loop
        try:
            pending += [lambda: seg.insert_slave(4), lambda: seg.insert_slave(5)]
            for _ in range(400):
                if m.hotswap.groups(runner.absent)[0].present and \
                        all(g.wkc_ok for g in runner.groups):
                    break
                time.sleep(0.05)
            assert m.hotswap.groups(runner.absent)[0].present
            assert [g.name for g in runner.groups] == ["main", "tool"]
            assert all(seg.escs[i].al_state() == AlState.OP for i in (4, 5))
        finally:
            runner.stop()


def test_run_starts_with_a_hot_connect_group_absent(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from pyethercat.cli.main import cli

    topo = tmp_path / "tool.toml"
    topo.write_text("""
[segment]
ring = "junction:1"
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "in1"
device = "builtin:di8"
[[slave]]
name = "junction"
device = "builtin:coupler"
[[slave]]
name = "tool"
device = "builtin:do8"
alias = 0x0200
parent = "junction"
port = 3
[[fault]]
kind = "power_off"
slave = "tool"
""")
    res = CliRunner().invoke(cli, ["--sim", str(topo), "run", "--seconds", "0.1",
                                   "--hot-connect", "tool=0x200:1"])
    assert res.exit_code == 0, res.output
    assert "WKC errors: 0" in res.output
