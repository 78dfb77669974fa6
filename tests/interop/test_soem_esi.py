"""SOEM (pysoem) brings slaves simulated from ESI files to OP, with the ESI's PDO layout.

``pyethercat sim`` serves a topology of ESI-made slaves on one end of a veth
pair; pysoem drives the other end: scan (identities), process-data mapping
(SOEM reads the PDO assignment over CoE where the SII says CoE, else from the
SII PDO categories), SAFE-OP, OP and cyclic exchange. Each slave's output and
input byte counts must be those of ``EsiDevice.pdo_layout()``.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from pyethercat.esi import load_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.sim.server import SimProcess, start_sim_process

pysoem = pytest.importorskip("pysoem")

# (name, ESI file in the corpus or None for the bundled seed drive, product, revision)
SLAVES = [
    ("drive", None, None, None),
    ("foot", "kickcat_wdc_foot.xml", None, None),
    ("soes", "soes_linux_lan9252demo.xml", None, None),  # SII without PDOs: CoE only
    ("orbita", "poulpe_Orbita2d.xml", None, None),
    ("el1004", "beckhoff_EL1xxx.xml", 0x03EC3052, 0x00130000),
]


def _path(corpus_dir: Path, file: str | None) -> Path:
    return bundled_esi() if file is None else corpus_dir / "esi" / file


@pytest.fixture
def served(
    veth_pair: tuple[str, str], tmp_path: Path, corpus_dir: Path
) -> Iterator[tuple[SimProcess, str]]:
    text = []
    for name, file, product, revision in SLAVES:
        entry = f'[[slave]]\nname = "{name}"\nesi = "{_path(corpus_dir, file)}"\n'
        if product is not None:
            entry += f"product = {product:#x}\nrevision = {revision:#x}\n"
        text.append(entry)
    topo = tmp_path / "esi.toml"
    topo.write_text("\n".join(text))
    sim_end, master_end = veth_pair
    handle = start_sim_process(topo, link=f"iface:{sim_end}")
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


@pytest.mark.root
def test_soem_brings_esi_slaves_to_op(served: tuple[SimProcess, str], corpus_dir: Path) -> None:
    _handle, iface = served
    master = pysoem.Master()
    master.always_release_gil = True
    master.open(iface)
    try:
        assert master.config_init() == len(SLAVES)
        master.config_map()
        for slave, (name, file, product, revision) in zip(master.slaves, SLAVES, strict=True):
            esi = load_esi(_path(corpus_dir, file))
            dev = esi.find_device(product, revision) if product else esi.devices[0]
            assert (slave.man, slave.id, slave.rev) == (esi.vendor.id, dev.product_code,
                                                         dev.revision), name  # fmt: skip
            layout = dev.pdo_layout()
            assert (len(slave.output), len(slave.input)) == (
                (layout.output_bits + 7) // 8,
                (layout.input_bits + 7) // 8,
            ), name
        assert master.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE
        master.state = pysoem.OP_STATE
        master.write_state()
        wkc = 0
        for _ in range(400):
            master.send_processdata()
            wkc = master.receive_processdata(2000)
            time.sleep(0.001)
            if master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                break
        master.read_state()
        assert [s.state for s in master.slaves] == [pysoem.OP_STATE] * len(SLAVES)
        # SOEM's expected_wkc counts 2 per output slave and 1 per input slave; the
        # run above sees one more (open question, see the ESI-2 report), never less.
        assert wkc >= master.expected_wkc
    finally:
        master.close()
