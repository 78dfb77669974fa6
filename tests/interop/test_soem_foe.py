"""SOEM (through pysoem) uses FoE against the simulator over a veth pair.

``pyethercat sim`` serves two slaves from real SII images of the corpus, in
a child process on one end of a ``pyecat-`` veth pair:

- the Kollmorgen AKD (SII announces FoE, 1 KiB mailboxes): pysoem writes and
  reads back a 1 MiB file, byte-identical;
- the Pollen Orbita2d (SII with a bootstrap mailbox whose send half differs
  from the standard one): pysoem updates its firmware as SOEM's
  ``firm_update`` sample does (INIT, SM0/SM1 moved to the bootstrap mailbox of
  SII words 0x0014-0x0017, BOOT, FoE write, INIT), and a new SOEM scan reads
  the new revision from the EEPROM.

Our own master does the same over veth (tests/interop/test_master_foe_veth.py).
"""

from __future__ import annotations

import random
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from pyethercat.sim.firmware import build_firmware_image
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire.sii import parse_sii

pysoem = pytest.importorskip("pysoem")

CORPUS = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "sii"
AKD = CORPUS / "ethercrab_akd.bin"
ORBITA = CORPUS / "poulpe_Orbita2d.bin"
TOPOLOGY = f"""
[[slave]]
name = "akd"
sii = "{AKD}"
[[slave]]
name = "orbita"
sii = "{ORBITA}"
"""
#: SCHED_FIFO priority of the simulator process (SOEM gives a mailbox read up after 2 ms).
SIM_PRIORITY = 10
MIB = random.Random(7).randbytes(1 << 20)


@pytest.fixture
def served(veth_pair: tuple[str, str], tmp_path: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "foe.toml"
    topo.write_text(TOPOLOGY)
    handle = start_sim_process(topo, link=f"iface:{sim_end}", realtime=SIM_PRIORITY)
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def _open(iface: str) -> Any:
    master = pysoem.Master()
    master.open(iface)
    assert master.config_init() == 2
    return master


def _to(slave: Any, state: int) -> None:
    slave.state = state
    slave.write_state()
    assert slave.state_check(state, 2_000_000) == state, hex(slave.al_status)


def test_soem_foe_write_and_read_one_mib(served: tuple[SimProcess, str]) -> None:
    _handle, iface = served
    master = _open(iface)
    try:
        akd = master.slaves[0]
        t0 = time.monotonic()
        akd.foe_write("big.bin", 0, MIB, 10_000_000)
        back = akd.foe_read("big.bin", 0, len(MIB) + 4096, 10_000_000)
        assert time.monotonic() - t0 < 600
        assert bytes(back) == MIB
    finally:
        master.close()


def test_soem_bootstrap_update_seen_by_its_next_scan(served: tuple[SimProcess, str]) -> None:
    _handle, iface = served
    info = parse_sii(ORBITA.read_bytes())
    image = build_firmware_image(info.vendor_id, info.product_code, 0x00000042, "orbita 42",
                                 random.Random(3).randbytes(20_000))
    master = _open(iface)
    try:
        orbita = master.slaves[1]
        assert orbita.rev == info.revision
        _to(orbita, pysoem.INIT_STATE)
        # firm_update: the bootstrap mailbox from SII words 0x0014 (receive) and 0x0016 (send)
        rx_off, rx_size = struct.unpack("<HH", orbita.eeprom_read(0x14))
        tx_off, tx_size = struct.unpack("<HH", orbita.eeprom_read(0x16))
        assert (tx_off, tx_size) == (info.boot_tx_mailbox_offset, info.boot_tx_mailbox_size)
        orbita.amend_mbx("out", rx_off, rx_size)
        orbita.amend_mbx("in", tx_off, tx_size)
        assert struct.unpack_from("<HH", orbita._fprd(0x0808, 8))[0] == tx_off
        _to(orbita, pysoem.BOOT_STATE)
        orbita.foe_write("firmware", 0, image, 5_000_000)
        _to(orbita, pysoem.INIT_STATE)
    finally:
        master.close()
    master = _open(iface)
    try:
        assert master.slaves[1].rev == 0x00000042
        assert master.slaves[0].rev == parse_sii(AKD.read_bytes()).revision
    finally:
        master.close()
