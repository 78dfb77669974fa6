"""Simulated slaves made from ESI files: SII, PDO layout and object dictionary served over CoE.

Each device is brought to OP by our master (in-process pair link); the
process-data layout the master configures (SM lengths, PDO assignment) must
be the one the ESI declares (``EsiDevice.pdo_layout()``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError
from pyethercat.esi import load_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.sii_from_esi import esi_to_sii
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.sim.coe import coe_server
from pyethercat.sim.devices.esi_device import EsiCoeModel, EsiSlave, esi_dictionary
from pyethercat.sim.topology import load_topology, parse_topology
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import parse_sii

CASES = [
    # (topology lines, ESI file, product, revision)
    ("soes_linux_lan9252demo.xml", None, None),  # SII without PDOs: layout over CoE
    ("soes_rtl_xmc4_dynpdo.xml", None, None),
    ("poulpe_Orbita2d.xml", None, None),  # vendor SM names, two TxPDOs on SM3
    ("kickcat_wdc_foot.xml", None, None),
    ("kickcat_ingenia_esi.xml", None, None),  # 440 kB dictionary
    ("beckhoff_EL1xxx.xml", 0x03EC3052, 0x00130000),  # EL1004, no mailbox
]


# The same layouts written out by hand from the ESI text ({SM: (bytes, PDO indices)}),
# so that a fault in EsiDevice.pdo_layout() itself cannot hide behind the comparison.
LAYOUTS = [
    {2: (3, (0x1600,)), 3: (7, (0x1A00,))},  # seed drive: 16+8 bit out, 16+8+32 bit in
    {2: (2, (0x1600,)), 3: (1, (0x1A00,))},
    {2: (2, (0x1600, 0x1601, 0x1602)), 3: (1, (0x1A00, 0x1A01))},
    {2: (43, (0x1600,)), 3: (66, (0x1700, 0x1800))},  # two Fixed/Mandatory TxPDOs on SM3
    {2: (2, (0x1600,)), 3: (28, (0x1A00,))},
    {2: (11, (0x1600,)), 3: (11, (0x1A00,))},  # the Sm-less PDOs are only selectable
    {0: (1, (0x1A00, 0x1A01, 0x1A02, 0x1A03))},  # EL1004: 4 x 1 bit on SM0
]


def _topology(tmp_path: Path, corpus_dir: Path) -> Path:
    lines = [f'[[slave]]\nname = "seed"\nesi = "{bundled_esi()}"\n']
    for n, (name, product, revision) in enumerate(CASES):
        text = f'[[slave]]\nname = "s{n}"\nesi = "{corpus_dir / "esi" / name}"\n'
        if product is not None:
            text += f"product = {product:#x}\nrevision = {revision:#x}\n"
        lines.append(text)
    path = tmp_path / "esi.toml"
    path.write_text("\n".join(lines))
    return path


def test_esi_slaves_reach_op_with_the_declared_layout(tmp_path: Path, corpus_dir: Path) -> None:
    topo = load_topology(_topology(tmp_path, corpus_dir))
    seg = topo.build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    cfg = m.configure()
    files = [bundled_esi()] + [corpus_dir / "esi" / c[0] for c in CASES]
    products = [None] + [c[1] for c in CASES]
    for slave, path, product, by_hand in zip(m.slaves, files, products, LAYOUTS, strict=True):
        esi = load_esi(path)
        dev = esi.find_device(product) if product else esi.devices[0]
        assert slave.identity.product_code == dev.product_code
        layout = dev.pdo_layout()
        got = {
            sm.index: (sm.length, tuple(p.index for p in sm.pdos))
            for sm in cfg.slaves[slave.position].process_data_sync_managers
        }
        want = {s.sm.index: (s.byte_size, s.pdo_indices) for s in layout.sms if s.pdos}
        assert got == want == by_hand, path.name
    with m.start(cycle=0.002) as runner:  # (its orderly stop takes them back to PREOP)
        assert all(s.al_state == AlState.OP for s in m.slaves)
        assert runner.wait_exchanges("main", 20, 5.0)
    assert runner.stats.wkc_errors == 0
    # The dictionary is served: identity and a default value from the ESI.
    seed = m.slaves[0]
    assert int.from_bytes(seed.sdo_read(0x1018, 2), "little") == 0x264860D2  # type: ignore[attr-defined]
    assert int.from_bytes(seed.sdo_read(0x1000, 0), "little") == 0x00020192  # type: ignore[attr-defined]


def test_dictionary_consistent_with_the_esi_pdos() -> None:
    esi = load_esi(bundled_esi())
    dev = esi.devices[0]
    od = esi_dictionary(dev, vendor_id=esi.vendor.id, serial=9)
    assert od.value(0x1018, 4) == 9 and od.value(0x1018, 1) == 0xE4
    assert od.value(0x1C12, 0) == 1 and od.value(0x1C12, 1) == 0x1600
    assert od.value(0x1600, 0) == 2 and od.value(0x1600, 1) == 0x60400010
    model = EsiCoeModel(EsiSlave(bundled_esi(), esi.vendor.id, dev, b""), 0x05)
    info = parse_sii(esi_to_sii(dev, vendor_id=esi.vendor.id, serial=9).image)
    _, app = model.instance_app(info)
    assert app.process_data_sizes() == (3, 7)
    assert coe_server(app).od.value(0x1018, 4) == 9


def test_unknown_product_is_a_config_error(tmp_path: Path) -> None:
    text = f'[[slave]]\nname = "x"\nesi = "{bundled_esi()}"\nproduct = 0x99\n'
    with pytest.raises(ConfigError, match=r"slave 'x'.*no device with product code 0x00000099"):
        parse_topology(text, tmp_path, "t.toml")
