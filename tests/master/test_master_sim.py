"""The master core against the simulator (in-process, the segment answers as PairLink responder)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import AlStatusError, TopologyMismatchError
from pyethercat.link.pair import PairLink
from pyethercat.master import Identity, Master
from pyethercat.master.listing import slave_table, topology_tree
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import parse_sii, sii_fix_checksum

pytest.importorskip("pyethercat.sim.topology")
from pyethercat.sim.topology import Topology, parse_topology  # noqa: E402

TREE = """
[[slave]]
name = "coupler"
device = "builtin:coupler"

[[slave]]
name = "di8"
device = "builtin:di8"

[[slave]]
name = "do8"
device = "builtin:do8"
alias = 42

[[slave]]
name = "ai2"
device = "builtin:ai2"

[[slave]]
name = "branch-do8"
device = "builtin:do8"
parent = "coupler"
port = 3

[[slave]]
name = "branch-di2"
device = "builtin:di2"
"""


def _open(text: str = TREE) -> tuple[Master, Topology, object]:
    topo = parse_topology(text)
    segment = topo.build()
    link = PairLink.responder_link(segment.process)
    return Master(link, clock=VirtualClock()), topo, segment


def test_scan_matches_what_the_segment_was_built_from() -> None:
    m, topo, _ = _open()
    slaves = m.scan()
    # Frame order: the coupler, then its port-3 branch, then the E-bus line on port 1.
    names = ["coupler", "branch-do8", "branch-di2", "di8", "do8", "ai2"]
    configs = {c.name: c for c in topo.slaves}
    assert len(slaves) == len(names)
    for s, name in zip(slaves, names, strict=True):
        built = configs[name]
        assert s.identity == Identity(built.info.vendor_id, built.info.product_code,
                                      built.info.revision, built.info.serial), name
        assert s.name == built.info.device_name
        # Every category parses to the same values the device image was built from.
        assert s.sii is not None
        assert s.sii.categories == parse_sii(built.sii).categories, name
        assert s.sii == parse_sii(built.sii)
    assert slaves[4].alias == 42
    assert m.slave_by_alias(42).name == configs["do8"].info.device_name


def test_topology_with_a_branch_on_port_3() -> None:
    m, _, _ = _open()
    s = m.scan()
    coupler, bdo, bdi, di8, do8, ai2 = s
    assert coupler.parent is None
    assert (bdo.parent, bdo.parent_port) == (coupler, 3)
    assert (bdi.parent, bdi.parent_port) == (bdo, 1)
    assert (di8.parent, di8.parent_port) == (coupler, 1)
    assert (do8.parent, do8.parent_port) == (di8, 1)
    assert (ai2.parent, ai2.parent_port) == (do8, 1)
    assert m.topology_consistent
    tree = topology_tree(s)
    assert "├─ port 3: 1 " in tree and "└─ port 1: 3 " in tree
    table = slave_table(s).splitlines()
    assert table[0].startswith("#") and len(table) == 7
    assert table[5].split()[:4] == ["4", "0x1005/42", "INIT", "+"]


def test_expected_configuration_against_the_simulator() -> None:
    m, _, _ = _open()
    found = [s.identity for s in m.scan()]
    m.scan(expected=found)
    wrong = list(found)
    wrong[3] = Identity(found[3].vendor_id, 0xDEAD)
    with pytest.raises(TopologyMismatchError, match="position 3: expected .*0x0000DEAD"):
        m.scan(expected=wrong)


def test_states_and_refused_transition_with_its_code() -> None:
    m, _, _ = _open()
    m.scan()
    m.set_state("PREOP")
    assert [s.al_state for s in m.slaves] == [AlState.PREOP] * 6
    # No process-data configuration: the IO slaves refuse SAFEOP with their AL code.
    with pytest.raises(AlStatusError) as err:
        m.set_state("SAFEOP")
    assert err.value.code in (0x001D, 0x001E)
    refused = [s for s in m.slaves if s.al_error]
    assert refused and all(s.al_state == AlState.PREOP for s in refused)
    m.set_state("INIT")
    assert all(s.al_state == AlState.INIT and not s.al_error for s in m.slaves)


def test_multiple_read_takes_one_frame() -> None:
    topo_text = "\n".join(f'[[slave]]\nname = "io{i}"\ndevice = "builtin:di8"\n'
                          for i in range(40))
    topo = parse_topology(topo_text)
    segment = topo.build()
    frames = []

    def counting(frame: bytes) -> bytes | None:
        frames.append(frame)
        return segment.process(frame)  # type: ignore[no-any-return]

    m = Master(PairLink.responder_link(counting), clock=VirtualClock())
    m.scan()
    before = len(frames)
    report = m.error_counters()
    assert len(frames) - before == 1  # 40 x (12 + 20) bytes fit one frame
    assert report.total == 0 and len(report.slaves) == 40
    before = len(frames)
    m.read_states()
    assert len(frames) - before == 1


def test_sii_write_and_reload_change_the_alias() -> None:
    m, _, _ = _open()
    m.scan()
    image = bytearray(m.sii_read(1))
    image[8:10] = struct.pack("<H", 77)  # word 4: station alias
    image = bytearray(sii_fix_checksum(bytes(image)))
    report = m.sii_write(1, bytes(image))
    assert report.written == [4, 7]
    assert m.sii_read(1)[:16] == bytes(image[:16])
    assert m.read(1, reg.STATION_ALIAS, 2) == struct.pack("<H", 77)


def test_demo_topology_file_scans(tmp_path: Path) -> None:
    demo = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
    if not demo.exists():
        pytest.skip("examples/demo.toml not present")
    from pyethercat.sim.topology import load_topology

    segment = load_topology(demo).build()
    m = Master(PairLink.responder_link(segment.process), clock=VirtualClock())
    slaves = m.scan()
    assert slaves and all(s.sii is not None for s in slaves)
