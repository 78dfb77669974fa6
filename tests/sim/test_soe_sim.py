"""The simulator's SoE drive profile, read and written by our master's SoE client in process."""

from __future__ import annotations

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import SoeAbort
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.master.soe import SoeClient
from pyethercat.sim.soe import SoeProtocol
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.mailbox.soe import SoeElement, parse_idn
from pyethercat.wire.mailbox.soe_transfer import SoeDataType

TOPOLOGY = """
[[slave]]
name = "drive"
device = "builtin:coe-io"
soe = true
"""


@pytest.fixture
def drive() -> tuple[Master, SoeClient, SoeProtocol]:
    seg = parse_topology(TOPOLOGY).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    server = seg.slaves[0].spec.app.protocols[MailboxType.SOE]  # type: ignore[union-attr]
    return m, m.slaves[0].client(SoeClient), server  # type: ignore[return-value]


def test_the_profile_idns_with_their_elements(drive: tuple[Master, SoeClient, SoeProtocol]
                                              ) -> None:
    _m, c, _srv = drive
    assert c.read_value("S-0-0001") == 1000 and c.unit(1) == "us"
    assert c.name(32) == "Primary operation mode" and c.read_value(32) == 0x000B
    assert c.read_value(33) == 2
    a36 = c.attribute(36)
    assert (a36.length, a36.data_type, a36.is_list) == (4, SoeDataType.SIGNED, False)
    assert c.read(36, elements=SoeElement.MAXIMUM) == (6000).to_bytes(4, "little")
    assert c.read(36, elements=SoeElement.MINIMUM) == (-6000).to_bytes(4, "little", signed=True)
    assert c.read_value(47) == 0
    assert c.read_value("S-0-0016") == [51]
    assert c.read_value("S-0-0024") == [36, 47]
    assert c.attribute(24).data_type == SoeDataType.IDN
    # two elements in one request come in flag order: attribute, then value
    both = c.read(1, elements=SoeElement.ATTRIBUTE | SoeElement.VALUE)
    assert both[4:] == (1000).to_bytes(2, "little")


def test_writes_checked_like_a_drive(drive: tuple[Master, SoeClient, SoeProtocol]) -> None:
    m, c, srv = drive
    c.write_value(36, -1234)
    assert c.read_value(36) == -1234
    with pytest.raises(SoeAbort) as info:
        c.write_value(36, 7000)
    assert info.value.code == 0x7007 and info.value.idn == "S-0-0036"
    with pytest.raises(SoeAbort, match="0x7006"):
        c.write_value(36, -7000)
    with pytest.raises(SoeAbort, match="0x7004"):  # position feedback is read-only
        c.write_value(51, 5)
    with pytest.raises(SoeAbort, match="0x7002"):
        c.write(36, b"\x01")
    with pytest.raises(SoeAbort, match="0x7003"):
        c.write(36, b"\x01" * 5)
    with pytest.raises(SoeAbort, match="0x2004"):
        c.write(36, b"\x00\x00\x00\x00", elements=SoeElement.NAME)
    with pytest.raises(SoeAbort, match="0x1001"):
        c.read("P-0-0099")
    with pytest.raises(SoeAbort, match="0x800A"):
        c.read(1, drive=5)
    with pytest.raises(SoeAbort, match="0x4001"):
        c.unit(32)
    m.set_state("SAFEOP", configure=True)
    with pytest.raises(SoeAbort, match="0x7005"):  # cycle time: PRE-OP only
        c.write_value(1, 500)
    assert srv.errors[-1] == 0x7005


def test_long_lists_are_fragmented_both_ways(drive: tuple[Master, SoeClient, SoeProtocol]
                                             ) -> None:
    m, c, _srv = drive
    idns = [parse_idn(f"S-0-{n:04d}") for n in range(40, 140)]  # 204 bytes > one 128-byte mailbox
    c.write_value(24, idns)
    assert c.read_value(24) == idns
    mbx = m.slaves[0].mbx
    assert mbx is not None and mbx.stats.received >= 2  # answer came in fragments
    with pytest.raises(SoeAbort, match="0x7003"):  # more than the list's maximum
        c.write_value(24, list(range(40, 200)))
    assert m.read_states()[0].state == AlState.PREOP
