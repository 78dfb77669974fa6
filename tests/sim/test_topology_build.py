"""Segments built from topology files answer frames as the file says."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.sim.topology import load_topology, parse_topology
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame
from pyethercat.wire.registers import (
    AL_STATUS,
    SII_ADDRESS,
    SII_CONTROL,
    SII_DATA,
    STATION_ALIAS,
    sm_address,
)

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def _one(segment: object, dg: Datagram) -> Datagram:
    reply = segment.process(encode_frame([dg]))  # type: ignore[attr-defined]
    assert reply is not None
    return decode_frame(reply).datagrams[0]


def _ap(cmd: Command, pos: int, ado: int, data: bytes) -> Datagram:
    return Datagram(cmd, 0, ((-pos) & 0xFFFF) | (ado << 16), data)


def test_demo_counts_and_order() -> None:
    seg = load_topology(DEMO).build(clock=VirtualClock())
    assert _one(seg, Datagram(Command.BRD, 0, 0, b"\0\0")).wkc == 6
    # processing order: the branch on the coupler's port 3 comes before port 1
    names = [seg.slaves[i].name for i in seg.route.passes.tolist()]
    assert names == ["coupler", "branch-do8", "di8", "do8", "di2", "ai2"]


def _sii_word(seg: object, pos: int, word: int) -> int:
    # APWR SII address + read command, then APRD the data
    cmd = struct.pack("<HI", 0x0100, word)
    assert _one(seg, _ap(Command.APWR, pos, SII_CONTROL, cmd)).wkc == 1
    seg.clock.advance(1_000_000)  # any profile's EEPROM read is done
    data = _one(seg, _ap(Command.APRD, pos, SII_DATA, bytes(4))).data
    return int(struct.unpack_from("<H", data)[0])


def test_sii_identity_alias_and_profile_visible_on_the_wire() -> None:
    topo = parse_topology(
        '[[slave]]\nname = "c"\ndevice = "builtin:coupler"\n'
        '[[slave]]\nname = "i"\ndevice = "builtin:di8"\nalias = 0x0BEE\n'
    )
    seg = topo.build(clock=VirtualClock())
    assert _sii_word(seg, 1, 0x08) == 0x4543  # vendor id low word ("PEC")
    assert _sii_word(seg, 1, 0x0A) == 0x0008  # di8 product code low word
    alias = _one(seg, _ap(Command.APRD, 1, STATION_ALIAS, bytes(2))).data
    assert alias == b"\xee\x0b"
    esc_type = _one(seg, _ap(Command.APRD, 0, 0x0000, bytes(1))).data
    assert esc_type == b"\x11"  # ET1100 coupler
    assert _one(seg, _ap(Command.APRD, 1, 0x0000, bytes(1))).data == b"\x12"  # ET1200
    # an ET1200 has 3 FMMUs: FMMU 3 does not answer
    assert _one(seg, _ap(Command.APRD, 1, 0x0630, bytes(16))).wkc == 0
    assert SII_ADDRESS == SII_CONTROL + 2


def test_wire_do8_drives_di8() -> None:
    topo = parse_topology(
        '[[slave]]\nname = "c"\ndevice = "builtin:coupler"\n'
        '[[slave]]\nname = "i"\ndevice = "builtin:di8"\n'
        '[[slave]]\nname = "o"\ndevice = "builtin:do8"\n'
        '[[wire]]\nfrom = "o:0"\nto = "i:0"\n'
    )
    seg = topo.build(clock=VirtualClock())
    # SM0 of both as their SII says, enabled
    sm_in = struct.pack("<HHBBBB", 0x1000, 1, 0x00, 0, 1, 0)
    sm_out = struct.pack("<HHBBBB", 0x1000, 1, 0x44, 0, 1, 0)
    assert _one(seg, _ap(Command.APWR, 1, sm_address(0), sm_in)).wkc == 1
    assert _one(seg, _ap(Command.APWR, 2, sm_address(0), sm_out)).wkc == 1
    assert _one(seg, _ap(Command.APWR, 2, 0x1000, b"\x5a")).wkc == 1
    assert _one(seg, _ap(Command.APRD, 1, 0x1000, b"\x00")).data == b"\x5a"


def test_initial_inputs_and_faults_from_file(corpus_dir: Path) -> None:
    topo = parse_topology(
        '[[slave]]\nname = "c"\ndevice = "builtin:coupler"\n'
        '[[slave]]\nname = "a"\ndevice = "builtin:ai2"\ninputs = "3412cdab"\n'
        '[[slave]]\nname = "b"\ndevice = "builtin:di8"\n'
        f'[[slave]]\nname = "ek"\nsii = "{corpus_dir / "sii" / "ethercrab_ek1100.bin"}"\n'
        '[[fault]]\nkind = "break_link"\nslave = "a"\nport = 1\n'
    )
    seg = topo.build(clock=VirtualClock())
    # the link behind ai2 is broken: only coupler and ai2 answer
    assert _one(seg, Datagram(Command.BRD, 0, 0, b"\0\0")).wkc == 2
    seg.restore_link(1, 1)
    assert _one(seg, Datagram(Command.BRD, 0, 0, b"\0\0")).wkc == 4
    # ai2 has its initial inputs in its SM3 buffer once SM3 is enabled
    sm3 = struct.pack("<HHBBBB", 0x1180, 4, 0x20, 0, 1, 0)
    assert _one(seg, _ap(Command.APWR, 1, sm_address(3), sm3)).wkc == 1
    data = _one(seg, _ap(Command.APRD, 1, 0x1180, bytes(4))).data
    assert data == bytes.fromhex("3412cdab")
    # all start in INIT
    status = _one(seg, Datagram(Command.BRD, 0, AL_STATUS << 16, bytes(2)))
    assert status.data[0] & 0x0F == 0x01


def test_esi_device(corpus_dir: Path) -> None:
    from pyethercat.errors import ConfigError

    esi = corpus_dir / "esi" / "beckhoff_EL1xxx.xml"
    topo = parse_topology(
        '[[slave]]\nname = "c"\ndevice = "builtin:coupler"\n'
        f'[[slave]]\nname = "el1004"\nesi = "{esi}"\nproduct = 0x03EC3052\n'
        "revision = 0x00130000\n"
    )
    s = topo.slaves[1]
    assert (s.info.vendor_id, s.info.product_code, s.info.revision) == (2, 0x03EC3052, 0x00130000)
    # a known device: the profile of the real EL1004 (an ET1200 chip)
    assert s.input_bits == 4 and s.profile.name == "EL1004" and s.profile.family == "ET1200"
    seg = topo.build(clock=VirtualClock())
    assert _sii_word(seg, 1, 0x0A) == 0x3052
    with pytest.raises(ConfigError, match="slave 'x': ESI nothere.xml.*cannot read"):
        parse_topology('[[slave]]\nname = "x"\nesi = "nothere.xml"\n', source="t.toml")
    with pytest.raises(ConfigError, match="slave 'x': ESI"):
        parse_topology(f'[[slave]]\nname = "x"\nesi = "{esi}"\nproduct = 0x1\n', source="t.toml")
