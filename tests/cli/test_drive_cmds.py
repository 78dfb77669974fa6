"""``pyethercat drive``: drives through a running master's control socket, and by SDO without one.

A master cycles two simulated drives (built from the C-series ESI) and
serves its control socket, as ``pyethercat run`` does; the command line
reaches it and walks a drive through enable, a profile-position move,
homing, a mode change and disable, printing the drives after each action.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.clock import WallClock
from pyethercat.link.pair import PairLink
from pyethercat.master.control.endpoint import link_spec
from pyethercat.master.control.server import serve
from pyethercat.master.master import Master
from pyethercat.sim.topology import load_topology

TOPOLOGY = """
[[slave]]
name = "x"
esi = "builtin:seed002_drive.xml"
[[slave]]
name = "y"
esi = "builtin:seed002_drive.xml"
"""


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture
def topo(tmp_path: Path) -> str:
    path = tmp_path / "drives.toml"
    path.write_text(TOPOLOGY)
    return str(path)


@pytest.fixture
def running(topo: str) -> Iterator[Master]:
    segment = load_topology(topo).build(clock=WallClock())  # the drives move in real time
    segment.advance_clock = False
    m = Master(PairLink.responder_link(segment.process))
    m.scan()
    m.set_state("PREOP")
    for s in m.slaves:  # the ESI's assignment plus the target position (its 0x1601)
        s.set_pdo_mapping({0x1C12: [0x1600, 0x1601]})
    m.configure()
    # The drives move in real time: a cycle thread held up for 100 ms (a loaded host) can trip
    # their SM watchdog, and a drive that leaves OP while enabled faults (0x7500). When we
    # may, the cycle thread runs at SCHED_FIFO (it inherits the policy of this thread).
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))
    try:
        runner = m.start(0.002)
    finally:
        os.sched_setscheduler(0, before[0], before[1])
    server = serve(m, link_spec(sim=topo))
    try:
        yield m
    finally:
        server.close()
        runner.stop()
        m.close()


def test_drive_actions_through_the_running_master(topo: str, running: Master) -> None:
    code, out, _ = run("--sim", topo, "drive", "status")
    assert code == 0
    lines = out.splitlines()
    assert len(lines) == 2 and all("Switch on disabled" in line for line in lines)
    code, out, err = run("--sim", topo, "drive", "enable", "-p", "0")
    assert code == 0, err
    assert "Operation enabled" in out and out.startswith("0 ")
    code, out, err = run("--sim", topo, "drive", "move", "20000", "-p", "0",
                         "--velocity", "400000", "--accel", "4000000")
    assert code == 0, err
    assert " PP " in out
    position = int(out.split("position ")[1].split()[0])
    assert abs(position - 20000) <= 100                      # target reached: position window
    code, out, err = run("--sim", topo, "drive", "home", "37", "-p", "0")
    assert code == 0, err
    assert " HM " in out and "position 0" in out             # current position is home, offset 0
    code, out, err = run("--sim", topo, "drive", "mode", "csp", "-p", "0")
    assert code == 0, err and " CSP " in out
    code, out, err = run("--sim", topo, "drive", "disable", "--json")
    assert code == 0, err
    states = [d["state"] for d in json.loads(out)["drives"]]
    assert states == ["Switch on disabled", "Switch on disabled"]


def test_drive_errors_are_one_line(topo: str, running: Master) -> None:
    for args, text in ((("mode",), "needs MODE"), (("mode", "zz"), "unknown mode of operation"),
                       (("enable", "3"), "takes no argument"),
                       (("status", "-p", "7"), "no slave at position 7")):
        code, out, err = run("--sim", topo, "drive", *args)
        assert code != 0 and text in err, (args, err)
        assert err.count("\n") == 1 and "Traceback" not in err


def test_without_a_running_master_status_reads_sdos_and_actions_refuse(topo: str) -> None:
    code, out, err = run("--sim", topo, "drive", "status", "-p", "1")
    assert code == 0, err
    assert out.startswith("1  Switch on disabled") and "statusword 0x0250" in out
    code, out, err = run("--sim", topo, "drive", "enable")
    assert code == 1 and "needs a master that exchanges process data" in err
