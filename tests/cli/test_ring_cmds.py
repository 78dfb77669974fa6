"""The command line on a ring: ``--redundant-udp``, ``diag`` and ``demo --redundancy``.

``pyethercat sim`` serves a ring over two UDP addresses (master ports A and
B, no privileges needed); the command line opens both ports as one master,
``diag`` names the state of the ring and, once the simulator's cable between
slaves 2 and 3 is pulled, that cable. ``slaves`` shows the whole segment
through either state of the ring, and the presence of a running master's
hot connect group before and after it is unplugged.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.sim.server import SimProcess, start_sim_process

DEMO = str(Path(__file__).resolve().parents[2] / "examples" / "demo.toml")


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def udp_ring() -> Iterator[tuple[SimProcess, list[str]]]:
    a, b = f"127.0.0.1:{_free_udp_port()}", f"127.0.0.1:{_free_udp_port()}"
    with start_sim_process(DEMO, link=f"udp:{a}", link_b=f"udp:{b}") as sim:
        yield sim, ["--udp", a, "--redundant-udp", b]


def test_diag_over_two_udp_ports_names_the_pulled_cable(
        udp_ring: tuple[SimProcess, list[str]]) -> None:
    sim, ports = udp_ring
    code, out, err = run(*ports, "diag", "--json")
    assert code == 0, err
    closed = json.loads(out)
    assert closed["state"] == "redundant" and closed["faults"] == []
    code, out, _ = run(*ports, "slaves")
    assert code == 0 and len(out.splitlines()) == 6
    # demo.toml in bus order: coupler, the branch do8 on its port 3, then di8, do8, di2,
    # ai2 on port 1; the ring closes at the ai2. The cable pulled: do8 port 1 to di2 port 0.
    sim.control("break_link", slave="do8", port=1)
    code, out, err = run(*ports, "diag")
    assert code == 0, err
    assert "ring: open: reached from both ports" in out
    assert "    4 from B " in out and "    3 from A " in out
    assert "link: between slave 3 port 1 and slave 4 port 0" in out
    code, out, _ = run(*ports, "slaves")  # every slave still reached, from one side or the other
    assert code == 0 and len(out.splitlines()) == 6
    sim.control("restore_link", slave="do8", port=1)
    code, out, _ = run(*ports, "diag", "--json")
    assert code == 0 and json.loads(out)["faults"] == []


def test_demo_redundancy_runs_the_experiment() -> None:
    code, out, err = run("demo", "--redundancy", "--seconds", "0.6", "--faults", "4",
                         "--slaves", "6", "--seed", "3")
    assert code == 0, err
    assert "SendCounter 600  RecvCounter 600  lost 0" in out
    assert "located 4/4" in out


GROUP_TOPOLOGY = """
[segment]
ring = true

[[slave]]
name = "coupler"
device = "builtin:coupler"

[[slave]]
name = "in1"
device = "builtin:di8"

[[slave]]
name = "tool"
device = "builtin:do8"
alias = 0x0100

[[slave]]
name = "tool-in"
device = "builtin:di8"
"""


def test_slaves_shows_a_hot_connect_group_of_a_running_master(tmp_path: Path) -> None:
    from pyethercat.clock import VirtualClock
    from pyethercat.master.control.endpoint import link_spec
    from pyethercat.master.control.server import serve
    from pyethercat.master.master import Master
    from pyethercat.sim.ring import ring_link
    from pyethercat.sim.topology import load_topology

    topo = tmp_path / "tool.toml"
    topo.write_text(GROUP_TOPOLOGY)
    clock = VirtualClock()
    seg = load_topology(topo).build(clock=clock)
    # Faults act between frames, in the loop's thread (the segment is not shared across threads).
    pending: list[Callable[[], None]] = []

    def before(_port: int) -> None:
        while pending:
            pending.pop(0)()

    with Master(ring_link(seg, before=before), clock=clock) as m:
        m.scan()
        m.hot_connect("tool", alias=0x0100, size=2)
        m.configure()
        runner = m.start(0.001)
        server = serve(m, link_spec(sim=str(topo)))
        try:
            code, out, _ = run("--sim", str(topo), "slaves")
            assert code == 0
            assert out.splitlines()[-1] == ("hot connect group tool (alias 0x0100, slaves 2-3): "
                                            "present")
            # the tool (the do8 and the di8 behind it) unplugged
            pending += [lambda: seg.remove_slave(2), lambda: seg.remove_slave(3)]
            for _ in range(400):
                time.sleep(0.05)
                if not m.hotswap.groups(runner.absent)[0].present:
                    break
            code, out, _ = run("--sim", str(topo), "slaves")
            assert out.splitlines()[-1].endswith("slaves 2-3): ABSENT")
        finally:
            server.close()
            runner.stop()


def test_a_master_opened_by_ring_name_serves_the_command_line(
        udp_ring: tuple[SimProcess, list[str]]) -> None:
    import os

    from pyethercat.master.master import Master

    _sim, ports = udp_ring
    a, b = ports[1], ports[3]
    # a reply wait of a loaded host (the simulator is another process)
    with Master.open(f"ring:udp:{a},udp:{b}", timeout=0.5) as m:
        m.scan()
        code, out, _ = run(*ports, "master")  # reaches this master, as for --udp A alone
        assert code == 0 and f"running master, pid {os.getpid()}" in out
        assert "Slaves: 6" in out
