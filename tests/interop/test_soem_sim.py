"""SOEM (through pysoem) runs our simulated segment over a veth pair.

``pyethercat sim`` serves a topology on one end of a veth pair in a child
process; pysoem, a master nobody here wrote, drives the other end: scan,
process-data mapping, DC, SAFEOP and OP, looped-back outputs, a refused state
request, a link break injected at runtime through the simulator's control
channel, and recovery. The simulator records a capture of the run, which
tshark must dissect without malformed-packet flags.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.sim.topology import Topology, load_topology
from pyethercat.wire.al import AlStatusCode

pysoem = pytest.importorskip("pysoem")

TOPOLOGY = """
# coupler with a branch on port 3 and a line of terminals on port 1
[[slave]]
name = "coupler"
device = "builtin:coupler"

[[slave]]
name = "di8"
device = "builtin:di8"

[[slave]]
name = "do8"
device = "builtin:do8"

[[slave]]
name = "di2"
device = "builtin:di2"

[[slave]]
name = "ai2"
device = "builtin:ai2"
inputs = "3412cdab"

[[slave]]
name = "el2004"
sii = "{el2004}"

[[slave]]
name = "branch-do8"
device = "builtin:do8"
parent = "coupler"
port = 3

[[slave]]
name = "branch-di8"
device = "builtin:di8"

[[wire]]
from = "do8:0"
to = "di8:0"

[[wire]]
from = "branch-do8:0"
to = "branch-di8:0"

[[wire]]
from = "branch-do8:6"
to = "di2:0"
bits = 2

[[wire]]
from = "el2004:0"
to = "ai2:0"
bits = 4
"""


def processing_order(topo: Topology) -> list[str]:
    """Slave names in the order a frame reaches them: port order 3, 1, 2 below each."""
    children: dict[str, dict[int, str]] = {s.name: {} for s in topo.slaves}
    for s in topo.slaves:
        if s.parent is not None and s.port is not None:
            children[s.parent][s.port] = s.name
    out: list[str] = []

    def visit(name: str) -> None:
        out.append(name)
        for port in (3, 1, 2):
            if port in children[name]:
                visit(children[name][port])

    visit(topo.slaves[0].name)
    return out


@pytest.fixture
def sim_topology(tmp_path: Path, corpus_dir: Path) -> Path:
    path = tmp_path / "interop.toml"
    path.write_text(TOPOLOGY.format(el2004=corpus_dir / "sii" / "ethercrab_el2004.bin"))
    return path


@pytest.fixture
def served(
    veth_pair: tuple[str, str], sim_topology: Path, tmp_path: Path
) -> Iterator[tuple[SimProcess, str, Path]]:
    sim_end, master_end = veth_pair
    pcap = tmp_path / "soem-sim.pcapng"
    # SCHED_FIFO: on a loaded host a simulator at normal priority may not get the
    # CPU within SOEM's 2 ms frame timeout (SII words then read 0). The priority
    # changes no behaviour; SOEM keeps its default timeouts.
    handle = start_sim_process(sim_topology, link=f"iface:{sim_end}", pcap=pcap, realtime=10)
    try:
        yield handle, master_end, pcap
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def cycle(master: Any, n: int = 1, retries: int = 5) -> int:
    """``n`` process-data cycles; the working counter of the last one.

    A cycle whose reply missed SOEM's 2 ms timeout (EC_NOFRAME, -1: the host
    was busy) is repeated up to ``retries`` times. That the simulator itself
    lost no frame is checked at the end from its counters (lost == 0,
    replies == frames).
    """
    wkc = 0
    for _ in range(n):
        for _attempt in range(retries + 1):
            master.send_processdata()
            wkc = master.receive_processdata(2000)
            time.sleep(0.001)
            if wkc >= 0:
                break
    return int(wkc)


def run_until(master: Any, cond: Any, cycles: int = 400) -> bool:
    for _ in range(cycles):
        cycle(master)
        if cond():
            return True
    return False


def check_and_recover(master: Any) -> None:
    """SOEM's usual supervision step (as in its examples) for every slave not in OP."""
    master.read_state()
    for slave in master.slaves:
        if slave.state == pysoem.OP_STATE:
            slave.is_lost = False
            continue
        if slave.state == pysoem.SAFEOP_STATE + pysoem.STATE_ERROR:
            slave.state = pysoem.SAFEOP_STATE + pysoem.STATE_ACK
            slave.write_state()
        elif slave.state == pysoem.SAFEOP_STATE:
            slave.state = pysoem.OP_STATE
            slave.write_state()
        elif slave.state > pysoem.NONE_STATE:
            if slave.reconfig():
                slave.is_lost = False
        elif not slave.is_lost:
            slave.state_check(pysoem.OP_STATE, 1000)
            if slave.state == pysoem.NONE_STATE:
                slave.is_lost = True
        if slave.is_lost and slave.state == pysoem.NONE_STATE and slave.recover():
            slave.is_lost = False


@pytest.mark.root
def test_soem_runs_the_simulated_segment(
    served: tuple[SimProcess, str, Path], sim_topology: Path, tshark: str
) -> None:
    handle, iface, pcap = served
    topo = load_topology(sim_topology)
    order = processing_order(topo)
    by_name = {s.name: s for s in topo.slaves}

    master = pysoem.Master()
    master.always_release_gil = True
    master.open(iface)
    try:
        # --- scan: every slave, in processing order, with names and identities
        assert master.config_init() == len(order)
        slaves = {name: master.slaves[i] for i, name in enumerate(order)}
        for name, slave in slaves.items():
            info = by_name[name].info
            assert (slave.man, slave.id, slave.rev) == (
                info.vendor_id,
                info.product_code,
                info.revision,
            ), name
            # SOEM names a slave by SII string 1 (the order number in these images)
            assert slave.name == info.string(1), name
        assert slaves["el2004"].name == "EL2004"
        assert slaves["di8"].name == "PEC-DI8"

        # --- a refused state request: PRE-OP -> OP is not a valid transition
        ai2 = slaves["ai2"]
        assert ai2.state_check(pysoem.PREOP_STATE, 50_000) == pysoem.PREOP_STATE
        ai2.state = pysoem.OP_STATE
        ai2.write_state()
        # state_check returns bits 3:0; the slave's state keeps the error flag
        assert ai2.state_check(pysoem.OP_STATE, 50_000) == pysoem.PREOP_STATE
        assert ai2.state == pysoem.PREOP_STATE + pysoem.STATE_ERROR
        assert ai2.al_status == AlStatusCode.INVALID_STATE_CHANGE  # 0x0011, facts 4.3
        ai2.state = pysoem.PREOP_STATE + pysoem.STATE_ACK
        ai2.write_state()
        assert ai2.state_check(pysoem.PREOP_STATE, 50_000) == pysoem.PREOP_STATE

        # --- process image as SOEM lays it out
        size = master.config_map()
        sizes = {name: (len(s.output), len(s.input)) for name, s in slaves.items()}
        assert sizes == {
            "coupler": (0, 0),
            "branch-do8": (1, 0),
            "branch-di8": (0, 1),
            "di8": (0, 1),
            "do8": (1, 0),
            "di2": (0, 1),
            "ai2": (0, 4),
            "el2004": (1, 0),
        }
        # outputs: branch-do8, do8, el2004 (4 bits, own byte); inputs: branch-di8,
        # di8, di2 (2 bits, own byte), ai2
        assert size == 3 + 7
        assert master.config_dc()
        assert master.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE

        # --- SAFEOP -> OP with cyclic exchange. Every slave whose output FMMU
        # the LRW writes adds 2, every slave whose input FMMU it reads adds 1.
        # (SOEM's own expected_wkc leaves out its bit-packed slaves, el2004 and
        # di2, so it asks for 2*2 + 3 = 7: applications compare with >=.)
        expected = 2 * 3 + 4
        assert master.expected_wkc <= expected
        cycle(master, 5)
        master.state = pysoem.OP_STATE
        master.write_state()
        assert run_until(
            master, lambda: master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE
        ), [hex(s.al_status) for s in master.slaves]
        assert cycle(master) == expected

        # --- outputs come back on the wired inputs
        slaves["do8"].output = b"\xa5"
        slaves["branch-do8"].output = b"\xc3"  # bits 6,7 = 1,1 -> di2 bits 0,1
        slaves["el2004"].output = b"\x05"
        assert run_until(master, lambda: slaves["di8"].input == b"\xa5", 50)
        assert slaves["branch-di8"].input == b"\xc3"
        assert slaves["di2"].input[0] & 0x03 == 0x03
        ai_in = slaves["ai2"].input
        assert ai_in[0] & 0x0F == 0x05 and ai_in[1:] == b"\x12\xcd\xab"

        # --- break the line behind di2: ai2 and el2004 are lost, the rest runs on
        handle.control("break_link", slave="di2", port=1)
        wkc = cycle(master, 3)
        assert 0 < wkc < expected
        master.read_state()
        lost = {name for name, s in slaves.items() if s.state == pysoem.NONE_STATE}
        assert lost == {"ai2", "el2004"}
        slaves["do8"].output = b"\x3c"
        assert run_until(master, lambda: slaves["di8"].input == b"\x3c", 50)
        for name in ("coupler", "di8", "do8", "di2", "branch-do8", "branch-di8"):
            assert slaves[name].state == pysoem.OP_STATE, name

        # --- restore: SOEM's supervision brings the lost slaves back to OP
        handle.control("restore_link", slave="di2", port=1)

        def all_op() -> bool:
            check_and_recover(master)
            return all(s.state == pysoem.OP_STATE for s in master.slaves)

        assert run_until(master, all_op, 300), {
            name: (hex(s.state), hex(s.al_status)) for name, s in slaves.items()
        }
        assert run_until(master, lambda: cycle(master) == expected, 50)
        slaves["el2004"].output = b"\x0a"
        assert run_until(master, lambda: slaves["ai2"].input[0] & 0x0F == 0x0A, 50)

        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()

    stats = handle.control("stats")
    assert stats["frames"] > 100 and stats["errors"] == 0
    # every frame came back (a link break closes the loop, nothing is lost), so a
    # cycle repeated above was the host's timing, not the simulator
    assert stats["lost"] == 0 and stats["replies"] == stats["frames"], stats
    handle.stop()

    # --- tshark reads the capture the simulator wrote, nothing malformed
    out = subprocess.run(
        [tshark, "-r", str(pcap), "-Y", "ecat", "-T", "fields", "-e", "frame.number"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert len(out.stdout.split()) == stats["frames"] + stats["replies"]
    bad = subprocess.run(
        [tshark, "-r", str(pcap), "-Y", "_ws.malformed || _ws.expert.severity >= error"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert bad.stdout.strip() == "", bad.stdout[:2000]
