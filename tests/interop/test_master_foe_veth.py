"""Our master uses FoE and SoE against ``pyethercat sim`` over a veth pair: the pysoem scenarios.

The same simulated segment as tests/interop/test_soem_foe.py (the corpus AKD
and Orbita2d SII images, in a child process, raw sockets): a 1 MiB file
written and read back byte-identical, a firmware update through the
Orbita2d's bootstrap mailbox that the next scan sees, and SoE on a drive.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT

from pyethercat.errors import FoeNotFound
from pyethercat.link.raw import RawLink
from pyethercat.master.bootstrap import bootstrap_update
from pyethercat.master.foe import FoeClient
from pyethercat.master.master import Master
from pyethercat.master.soe import SoeClient
from pyethercat.sim.firmware import build_firmware_image
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import parse_sii

CORPUS = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "sii"
AKD = CORPUS / "ethercrab_akd.bin"
ORBITA = CORPUS / "poulpe_Orbita2d.bin"
TOPOLOGY = f"""
[[slave]]
name = "akd"
sii = "{AKD}"
soe = true
[[slave]]
name = "orbita"
sii = "{ORBITA}"
"""
MIB = random.Random(11).randbytes(1 << 20)


@pytest.fixture
def served(veth_pair: tuple[str, str], tmp_path: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "foe.toml"
    topo.write_text(TOPOLOGY)
    handle = start_sim_process(topo, link=f"iface:{sim_end}")
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


@pytest.mark.root
def test_our_master_foe_soe_and_bootstrap_over_veth(served: tuple[SimProcess, str]) -> None:
    _handle, iface = served
    info = parse_sii(ORBITA.read_bytes())
    with Master(RawLink(iface), timeout=SIM_FRAME_TIMEOUT) as m:
        akd, orbita = m.scan()
        m.set_state("PREOP")
        assert akd.mbx is not None
        foe = FoeClient(akd.mbx)
        done: list[int] = []
        foe.write("big.bin", MIB, progress=lambda p: done.append(p.done))
        assert done[-1] == len(MIB)
        assert foe.read("big.bin") == MIB
        with pytest.raises(FoeNotFound):
            foe.read("nothing.bin")

        soe = SoeClient(akd.mbx)
        assert soe.read_value("S-0-0024") == [36, 47]
        soe.write_value(47, 123456)
        assert soe.read_value(47) == 123456

        image = build_firmware_image(info.vendor_id, info.product_code, 0x00000043,
                                     "orbita 43", random.Random(5).randbytes(20_000))
        bootstrap_update(m, orbita, image)
        assert m.read_states([orbita])[0].state == AlState.INIT
        again = m.scan()
        assert again[1].identity.revision == 0x00000043
        assert again[0].identity.revision == parse_sii(AKD.read_bytes()).revision
