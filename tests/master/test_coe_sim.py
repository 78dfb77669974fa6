"""Our master against the simulator's CoE devices (builtin:coe-io, seed002-drive), in process.

The same scenarios the pysoem interop test runs: SDOs expedited, segmented and
with complete access, the object dictionary list and descriptions, OP with the
CoE-derived mapping, and a dynamic remap in PRE-OP that changes the image.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import SdoAbort
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import SdoAbortCode

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "io2"
device = "builtin:coe-io"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""

PATTERN = bytes(i & 0xFF for i in range(4096))


@pytest.fixture
def sim(tmp_path: Path) -> tuple[object, Master]:
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "coe.toml"
    path.write_text(TOPOLOGY)
    seg = load_topology(path).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    return seg, m


def test_sdo_expedited_segmented_and_complete_access(sim: tuple[object, Master]) -> None:
    _seg, m = sim
    io = m.slaves[0]
    assert io.sdo_read(0x1018, 1, "uint32") == 0x00504543
    assert io.sdo_read(0x2000) == PATTERN  # 4 KiB octet string, segmented
    back = PATTERN[::-1]
    io.sdo_write(0x2000, 0, back)
    assert io.sdo_read(0x2000) == back
    raw = io.sdo_read(0x1018, 0, complete_access=True)
    count, vendor = struct.unpack_from("<HI", raw, 0)
    assert (count & 0xFF, vendor) == (4, 0x00504543)
    io.sdo_write(0x8001, 1, b"\xf6\xff\x0a\x00", complete_access=True)  # subs 1..2
    assert io.sdo_read(0x8001, 1, "int16") == -10
    assert io.sdo_read(0x8001, 2, "int16") == 10
    io.sdo_write(0x8000, 5, 2.5, "real32")
    assert io.sdo_read(0x8000, 5, "real32") == 2.5
    io.sdo_write(0x8000, 6, "pump", "string")
    assert io.sdo_read(0x8000, 6, "string") == "pump"


@pytest.mark.parametrize("op,code", [
    (lambda s: s.sdo_read(0x9999), SdoAbortCode.NO_OBJECT),
    (lambda s: s.sdo_read(0x1018, 9), SdoAbortCode.NO_SUBINDEX),
    (lambda s: s.sdo_write(0x1018, 1, 5, "uint32"), SdoAbortCode.READ_ONLY),
    (lambda s: s.sdo_read(0x2001), SdoAbortCode.WRITE_ONLY),
    (lambda s: s.sdo_write(0x8000, 1, 20000, "uint16"), SdoAbortCode.VALUE_TOO_HIGH),
    (lambda s: s.sdo_write(0x8000, 2, -2_000_000, "int32"), SdoAbortCode.VALUE_TOO_LOW),
    (lambda s: s.sdo_write(0x8000, 1, 5, "uint32"), SdoAbortCode.LENGTH_TOO_HIGH),
    (lambda s: s.sdo_write(0x8000, 2, 5, "uint16"), SdoAbortCode.LENGTH_TOO_LOW),
])
def test_aborts_from_the_simulator(sim: tuple[object, Master], op: object, code: int) -> None:
    _seg, m = sim
    with pytest.raises(SdoAbort) as err:
        op(m.slaves[0])  # type: ignore[operator]
    assert err.value.code == code


def test_object_dictionary(sim: tuple[object, Master]) -> None:
    _seg, m = sim
    od = m.slaves[0].od
    assert {0x1000, 0x1018, 0x1C12, 0x1C13, 0x2000, 0x8000} <= set(od)
    assert od[0x1018].name == "Identity"
    assert [e.name for e in od[0x1018].entries][1] == "Vendor ID"
    gain = od[0x8000][5]
    assert gain.type_name == "REAL32"
    assert gain.read() == 1.0
    drive = m.slaves[2]
    assert drive.sdo_read(0x1018, 1, "uint32") == 0xE4


def _run_to_op(m: Master) -> CyclicRunner:
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=VirtualClock(),
                     check_interval=0)
    r.run(cycles=2)
    m.set_state("OP")
    return r


def test_op_with_coe_mapping_and_dynamic_remap(sim: tuple[object, Master]) -> None:
    _seg, m = sim
    r = _run_to_op(m)
    io = m.slaves[0]
    assert io.al_state == AlState.OP
    assert io.pdo_mapping is not None  # the layout came from 0x1C12/0x1C13
    io.outputs["Value 16"] = 0x1234
    io.outputs["Digital outputs"] = 0x5A
    r.run(cycles=3)
    assert io.inputs["Value 16"] == 0x1234
    assert io.inputs["Digital inputs"] == 0x5A
    before = m.process_data.slaves[0].input_bits  # type: ignore[union-attr]
    # back to PRE-OP, remap: inputs are now the cycle counter and value 32 only
    m.set_state("PREOP", [io])
    io.set_pdo_mapping({0x1C13: [(0x1A03, [(0x6000, 4, 16), (0x6000, 3, 32)])]})
    r = _run_to_op(m)
    sc = m.process_data.slaves[0]  # type: ignore[union-attr]
    assert sc.input_bits == 48 != before
    assert [v.name for v in sc.variables if v.direction.value == "inputs"] == [
        "Cycle counter", "Value 32"]
    io.outputs["Value 32"] = 77
    first = io.inputs["Cycle counter"]
    r.run(cycles=4)
    assert io.inputs["Value 32"] == 77
    assert io.inputs["Cycle counter"] != first
    assert all(s.al_state == AlState.OP for s in m.slaves)


def test_remap_one_sm_before_configure_keeps_the_other(sim: tuple[object, Master]) -> None:
    """set_pdo_mapping of SM3 alone on a master that never configured: SM2 keeps
    the slave's current outputs (was: left out, so the slave refused SAFE-OP
    with 0x001D "Invalid output configuration")."""
    _seg, m = sim
    io = m.slaves[0]
    assert io.pdo_mapping is None
    io.set_pdo_mapping({0x1C13: [(0x1A03, [(0x6000, 4, 16), (0x6000, 3, 32)]), 0x1A00]})
    assert io.pdo_mapping is not None
    assert [p.index for p in io.pdo_mapping[2]] == [0x1600, 0x1601]
    assert [p.index for p in io.pdo_mapping[3]] == [0x1A03, 0x1A00]
    r = _run_to_op(m)
    assert io.al_state == AlState.OP
    io.outputs["Value 32"] = 0x01020304
    r.run(cycles=3)
    assert io.inputs["Value 32"] == 0x01020304
    assert io.inputs["Cycle counter"] > 0
