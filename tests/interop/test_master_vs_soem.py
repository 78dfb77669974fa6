"""Our master and SOEM (pysoem) side by side on the same simulated segment over a veth pair.

``pyethercat sim`` serves the demo topology plus a real EL2004 SII on one end
of a veth pair; first pysoem and then our master scan it and map its process
data. Both must report the same slave list, identities and process-data
sizes, and both must reach OP.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from pyethercat.master.master import Master
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire.al import AlState

pysoem = pytest.importorskip("pysoem")

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


@pytest.fixture
def topology(tmp_path: Path, corpus_dir: Path) -> Path:
    path = tmp_path / "side-by-side.toml"
    el2004 = corpus_dir / "sii" / "ethercrab_el2004.bin"
    path.write_text(DEMO.read_text() + f'\n[[slave]]\nname = "el2004"\nsii = "{el2004}"\n')
    return path


@pytest.fixture
def served(veth_pair: tuple[str, str], topology: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    handle = start_sim_process(topology, link=f"iface:{sim_end}")
    try:
        yield handle, master_end
    finally:
        handle.stop()


def soem_view(iface: str) -> list[tuple[int, int, int, int, int]]:
    m = pysoem.Master()
    m.open(iface)
    try:
        assert m.config_init() > 0
        m.config_map()
        out = [(s.man, s.id, s.rev, len(s.output), len(s.input)) for s in m.slaves]
        assert m.state_check(pysoem.SAFEOP_STATE, 500000) == pysoem.SAFEOP_STATE
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(200):
            m.send_processdata()
            m.receive_processdata(2000)
            if m.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                break
            time.sleep(0.001)
        assert m.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE
        m.state = pysoem.INIT_STATE
        m.write_state()
        return out
    finally:
        m.close()


def our_view(iface: str) -> list[tuple[int, int, int, int, int]]:
    with Master.open(iface) as m:
        m.scan()
        cfg = m.configure(layout="byte")  # SOEM reports whole bytes per slave
        out = [(s.identity.vendor_id, s.identity.product_code, s.identity.revision or 0,
                cfg.slaves[s.position].output_bytes, cfg.slaves[s.position].input_bytes)
               for s in m.slaves]
        with m.start(cycle=0.001):
            assert all(s.al_state == AlState.OP for s in m.slaves)
        m.set_state("INIT")
        return out


def test_same_slaves_identities_and_sizes(served):
    _, iface = served
    theirs = soem_view(iface)
    ours = our_view(iface)
    assert len(ours) == 7
    assert ours == theirs
