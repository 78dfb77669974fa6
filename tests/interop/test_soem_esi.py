"""SOEM (pysoem) brings slaves simulated from ESI files to OP, with the ESI's PDO layout.

``pyethercat sim`` serves a topology of ESI-made slaves on one end of a veth
pair; pysoem drives the other end: scan (identities), process-data mapping
(SOEM reads the PDO assignment over CoE where the SII says CoE, else from the
SII PDO categories), SAFE-OP, OP and cyclic exchange. Each slave's output and
input byte counts must be those of ``EsiDevice.pdo_layout()``, and the
working counter of an OP cycle must be exactly what the ESCs give.

Machine speed: the simulator is a Python process and the CI machine may be
busy (2 cores, the whole suite running). At SOEM's default 2 ms frame timeout
a reply that is merely late counts as lost: SOEM then reads a station
address as 0 in ``config_init`` or gives up an SDO of the PDO-assignment
upload (an Orbita with one TxPDO of two, 35 input bytes instead of 66). A
master on a slow segment raises its timeouts, and so does this test (and
restores them); for the same reason it sets the process-data watchdog of
every slave to 2 s, as a master may (0x0420), so that a scheduling gap of
the test process in OP is not taken for a dead master. Nothing here is a
timed assertion.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_REALTIME

from pyethercat.esi import load_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.model import PdoLayout
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire import registers as R

pysoem = pytest.importorskip("pysoem")

# (name, ESI file in the corpus or None for the bundled seed drive, product, revision)
SLAVES = [
    ("drive", None, None, None),
    ("foot", "kickcat_wdc_foot.xml", None, None),
    ("soes", "soes_linux_lan9252demo.xml", None, None),  # SII without PDOs: CoE only
    ("orbita", "poulpe_Orbita2d.xml", None, None),
    ("el1004", "beckhoff_EL1xxx.xml", 0x03EC3052, 0x00130000),
]

#: SOEM timeouts for this test, in us (defaults: ret 2000, safe/eeprom/tx_mailbox
#: 20000, rx_mailbox 700000). ``ret`` is the per-frame timeout (x3 in config_init).
SLOW_SEGMENT_TIMEOUTS = {"ret": 50_000, "safe": 200_000, "eeprom": 200_000,
                         "tx_mailbox": 200_000, "rx_mailbox": 2_000_000}  # fmt: skip
PD_WATCHDOG_MS = 2000
FRAME_TIMEOUT_US = SLOW_SEGMENT_TIMEOUTS["ret"]


def _path(corpus_dir: Path, file: str | None) -> Path:
    return bundled_esi() if file is None else corpus_dir / "esi" / file


@pytest.fixture
def soem_timeouts() -> Iterator[None]:
    """Raise pysoem's (process-wide) timeouts for the test, restore them after."""
    t = pysoem.settings.timeouts
    saved = {name: getattr(t, name) for name in SLOW_SEGMENT_TIMEOUTS}
    for name, value in SLOW_SEGMENT_TIMEOUTS.items():
        setattr(t, name, value)
    try:
        yield
    finally:
        for name, value in saved.items():
            setattr(t, name, value)


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
    handle = start_sim_process(topo, link=f"iface:{sim_end}", realtime=SIM_REALTIME)
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def _set_pd_watchdog(slave: object, ms: int) -> None:
    """Write the process-data watchdog time (0x0420) in units of the slave's divider.

    As pysoem's ``set_watchdog`` does, but with the test's frame timeout
    (pysoem's own helper reads the divider with a fixed 2 ms timeout).
    """
    raw = slave._fprd(R.WATCHDOG_DIVIDER, 2, FRAME_TIMEOUT_US)  # type: ignore[attr-defined]
    unit_ns = R.watchdog_unit_ns(int.from_bytes(raw, "little"))
    units = min(0xFFFF, ms * 1_000_000 // unit_ns)
    slave._fpwr(R.WATCHDOG_TIME_PROCESS_DATA, units.to_bytes(2, "little"),  # type: ignore[attr-defined]
                FRAME_TIMEOUT_US)  # fmt: skip
    back = slave._fprd(R.WATCHDOG_TIME_PROCESS_DATA, 2, FRAME_TIMEOUT_US)  # type: ignore[attr-defined]
    assert int.from_bytes(back, "little") == units


def _esc_wkc(layouts: list[PdoLayout]) -> int:
    """WKC of one LRW over every slave's process data, by the ESC rule.

    Each ESC adds 1 when the LRW reads from it (inputs) and 2 when it writes
    to it (outputs), once per datagram however many FMMUs it has.
    """
    return sum(2 * (lay.output_bits > 0) + (lay.input_bits > 0) for lay in layouts)


@pytest.mark.root
def test_soem_brings_esi_slaves_to_op(
    served: tuple[SimProcess, str], corpus_dir: Path, soem_timeouts: None
) -> None:
    _handle, iface = served
    master = pysoem.Master()
    master.always_release_gil = True
    master.open(iface)
    try:
        assert master.config_init() == len(SLAVES)
        master.config_map()
        layouts = []
        for slave, (name, file, product, revision) in zip(master.slaves, SLAVES, strict=True):
            esi = load_esi(_path(corpus_dir, file))
            dev = esi.find_device(product, revision) if product else esi.devices[0]
            assert (slave.man, slave.id, slave.rev) == (esi.vendor.id, dev.product_code,
                                                         dev.revision), name  # fmt: skip
            layout = dev.pdo_layout()
            layouts.append(layout)
            assert (len(slave.output), len(slave.input)) == (
                (layout.output_bits + 7) // 8,
                (layout.input_bits + 7) // 8,
            ), name
            _set_pd_watchdog(slave, PD_WATCHDOG_MS)
        wkc_esc = _esc_wkc(layouts)
        assert wkc_esc == 13  # 4 slaves with outputs and inputs, the EL1004 inputs only
        # SOEM (as built into pysoem 1.1.x) adds a slave to its expected WKC only
        # when the slave's mapping moved the logical address on ("if this slave
        # added input data": diff = LogAddr - oLogAddr). The EL1004's 4 input
        # bits start a new byte and leave LogAddr where it was, so SOEM expects
        # one less than the ESCs answer, though the EL1004 does answer the LRW.
        assert master.expected_wkc == wkc_esc - 1
        assert master.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE
        master.state = pysoem.OP_STATE
        master.write_state()
        for _ in range(400):
            master.send_processdata()
            master.receive_processdata(50_000)
            time.sleep(0.001)
            if master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                break
        master.read_state()
        assert [s.state for s in master.slaves] == [pysoem.OP_STATE] * len(SLAVES)
        wkcs = []
        for _ in range(5):
            master.send_processdata()
            wkcs.append(master.receive_processdata(50_000))
        assert wkcs == [wkc_esc] * 5
    finally:
        master.close()
