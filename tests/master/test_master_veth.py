"""The master core over a veth pair: raw sockets on one end, the simulator (child process) on the other."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT

from pyethercat.master import Master
from pyethercat.wire.al import AlState

pytest.importorskip("pyethercat.sim.server")
from pyethercat.sim.server import start_sim_process  # noqa: E402

TOPOLOGY = """
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "di8"
device = "builtin:di8"
[[slave]]
name = "ai2"
device = "builtin:ai2"
[[slave]]
name = "branch"
device = "builtin:do8"
parent = "coupler"
port = 3
"""


def test_scan_states_and_counters_over_veth(veth_pair: tuple[str, str], tmp_path: Path) -> None:
    a, b = veth_pair
    topo = tmp_path / "seg.toml"
    topo.write_text(TOPOLOGY)
    with start_sim_process(topo, link=f"iface:{b}"), Master.open(iface=a, timeout=SIM_FRAME_TIMEOUT) as m:
        slaves = m.scan()
        assert [s.name.split()[0] for s in slaves] == ["PEC-CU4", "PEC-DO8", "PEC-DI8",
                                                       "PEC-AI2"]
        assert (slaves[1].parent, slaves[1].parent_port) == (slaves[0], 3)
        assert (slaves[2].parent, slaves[2].parent_port) == (slaves[0], 1)
        m.set_state("PREOP")
        assert all(s.al_state == AlState.PREOP for s in slaves)
        assert m.error_counters().total == 0
        assert m.scheduler.stats.timeouts == 0
