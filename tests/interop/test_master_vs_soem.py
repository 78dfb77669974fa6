"""Side by side with SOEM: both masters scan the same simulated segment over a veth pair.

pysoem (SOEM) and our master each scan the segment served by ``pyethercat
sim`` in a child process and must report the same slave list: count,
identities, names (SOEM uses SII string 1, the order number) and the
process-data sizes (SOEM's mapping vs the SII's PDO bits our scan read).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT, SIM_REALTIME

from pyethercat.master import Master

pysoem = pytest.importorskip("pysoem")
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
name = "do8"
device = "builtin:do8"
[[slave]]
name = "ai2"
device = "builtin:ai2"
[[slave]]
name = "branch"
device = "builtin:di2"
parent = "coupler"
port = 3
"""


def test_same_slave_list_as_soem(veth_pair: tuple[str, str], tmp_path: Path) -> None:
    a, b = veth_pair
    topo = tmp_path / "seg.toml"
    topo.write_text(TOPOLOGY)
    with start_sim_process(topo, link=f"iface:{b}", realtime=SIM_REALTIME):
        soem = pysoem.Master()
        soem.open(a)
        try:
            count = soem.config_init()
            theirs = [(s.man, s.id, s.rev, s.name) for s in soem.slaves]
            soem.config_map()
            their_sizes = [(len(s.input), len(s.output)) for s in soem.slaves]
        finally:
            soem.close()
        with Master.open(iface=a, timeout=SIM_FRAME_TIMEOUT) as m:
            slaves = m.scan()
            ours = [(s.identity.vendor_id, s.identity.product_code, s.identity.revision,
                     s.sii.string(1) if s.sii is not None else None) for s in slaves]
            cfg = m.configure()
    assert count == len(slaves) == 5
    assert ours == theirs
    # Process-data sizes as the SII describes them (what SOEM maps without CoE) ...
    sii_sizes = [((s.sii.input_bits + 7) // 8, (s.sii.output_bits + 7) // 8)
                 for s in slaves if s.sii is not None]
    assert sii_sizes == their_sizes
    # ... and as our configuration maps them into the process image.
    our_sizes = [((cfg.slaves[s.position].input_bits + 7) // 8,
                  (cfg.slaves[s.position].output_bits + 7) // 8) for s in slaves]
    assert our_sizes == their_sizes
    assert sum(i for i, _ in their_sizes) > 0 and sum(o for _, o in their_sizes) > 0
