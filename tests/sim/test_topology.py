"""Topology files: parsing, placement, wiring, faults and the errors they raise."""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.errors import ConfigError
from pyethercat.sim.topology import load_topology, parse_topology
from pyethercat.wire.registers import PortType

REPO = Path(__file__).resolve().parents[2]

LINE = """
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "in"
device = "builtin:di8"
[[slave]]
name = "out"
device = "builtin:do8"
"""


def test_line_in_file_order() -> None:
    topo = parse_topology(LINE, source="t.toml")
    assert [s.name for s in topo.slaves] == ["coupler", "in", "out"]
    assert [(s.parent, s.port) for s in topo.slaves] == [(None, None), ("coupler", 1), ("in", 1)]
    assert topo.slaves[1].builtin is not None and topo.slaves[1].input_bits == 8


def test_branch_on_port_3_and_defaults() -> None:
    topo = parse_topology(
        LINE
        + """
[[slave]]
name = "branch"
device = "builtin:di2"
parent = "coupler"
port = 3
alias = 0x1234
drift_ppm = -12.5
forwarding_delay_ns = 300
cable_delay_ns = 20
profile = "IPCORE"
inputs = "03"
"""
    )
    b = topo.slaves[3]
    assert (b.parent, b.port) == ("coupler", 3)
    assert (b.alias, b.drift_ppm, b.forwarding_delay_ns, b.cable_delay_ns) == (0x1234, -12.5, 300, 20)
    assert b.inputs == b"\x03"
    # the IPCORE chip, with the ports the device's SII wires (E-Bus 0 and 1)
    assert b.profile.name == "IPCORE"
    assert b.profile.ports[:2] == (PortType.EBUS, PortType.EBUS)
    assert b.profile.implemented_ports == (0, 1)


def test_default_profiles() -> None:
    topo = parse_topology(LINE)
    assert [s.profile.name for s in topo.slaves] == ["ET1100", "ET1200", "ET1200"]
    # the coupler's four ports: 0 MII, 1 E-Bus, 2 and 3 MII
    assert topo.slaves[0].profile.ports == (PortType.MII, PortType.EBUS, PortType.MII, PortType.MII)


def test_wire_defaults_and_ranges() -> None:
    topo = parse_topology(LINE + '[[wire]]\nfrom = "out"\nto = "in:2"\n')
    (w,) = topo.wires
    assert (w.src, w.src_bit, w.dst, w.dst_bit, w.bits) == ("out", 0, "in", 2, 6)
    with pytest.raises(ConfigError, match="wire #1.*8 input bits"):
        parse_topology(LINE + '[[wire]]\nfrom = "out:0"\nto = "in:4"\nbits = 8\n', source="t.toml")
    with pytest.raises(ConfigError, match="'coupler' has no outputs"):
        parse_topology(LINE + '[[wire]]\nfrom = "coupler"\nto = "in"\n')
    with pytest.raises(ConfigError, match="no slave named 'nope'"):
        parse_topology(LINE + '[[wire]]\nfrom = "nope"\nto = "in"\n')


def test_faults_and_segment_table() -> None:
    topo = parse_topology(
        "[segment]\ndrop_probability = 0.25\nseed = 3\n"
        + LINE
        + '[[fault]]\nkind = "break_link"\nslave = "in"\nport = 1\n'
        + '[[fault]]\nkind = "corrupt"\nslave = "out"\nport = 0\ncount = 2\n'
        + '[[fault]]\nkind = "power_off"\nslave = "out"\n'
    )
    assert (topo.drop_probability, topo.seed) == (0.25, 3)
    assert [(f.kind, f.slave, f.port, f.count) for f in topo.faults] == [
        ("break_link", "in", 1, 1),
        ("corrupt", "out", 0, 2),
        ("power_off", "out", 0, 1),
    ]


def test_sii_dump_relative_to_file(tmp_path: Path, corpus_dir: Path) -> None:
    el2004 = corpus_dir / "sii" / "ethercrab_el2004.bin"
    (tmp_path / "sub").mkdir()
    # a relative path is taken from the topology file's folder
    rel = Path("..") / Path(*[".."] * len(tmp_path.parts[1:])) / el2004.relative_to("/")
    f = tmp_path / "sub" / "t.toml"
    f.write_text(LINE + f'[[slave]]\nname = "el2004"\nsii = "{rel.as_posix()}"\n')
    topo = load_topology(f)
    s = topo.slaves[3]
    assert s.sii == el2004.read_bytes()
    assert s.info.order_number == "EL2004" and s.output_bits == 4
    assert s.builtin is None
    assert s.profile.name == "ET1200"  # two E-Bus ports: a terminal chip


def test_ek1100_dump_gets_its_sii_ports(corpus_dir: Path) -> None:
    ek = corpus_dir / "sii" / "ethercrab_ek1100.bin"
    topo = parse_topology(f'[[slave]]\nname = "ek"\nsii = "{ek}"\n')
    p = topo.slaves[0].profile
    assert p.name == "EK1100"  # known device: the real EK1100's profile
    assert p.family == "ET1100"
    # EK1100 SII: port 0 MII, 1 E-Bus, 2 MII, 3 unused
    assert p.ports == (PortType.MII, PortType.EBUS, PortType.MII, PortType.NOT_IMPLEMENTED)


def test_examples_load() -> None:
    for path in sorted((REPO / "examples").glob("*.toml")):
        topo = load_topology(path)
        assert topo.slaves, path


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no \\[\\[slave\\]\\] tables"),
        ("x = 1", "unknown top-level key"),
        ("[[slave]]\ndevice = 'builtin:di8'", "slave #1: every \\[\\[slave\\]\\] needs a name"),
        ("[[slave]]\nname = 'a'", "slave 'a': give exactly one of"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:x'", "slave 'a': unknown built-in device 'x'"),
        ("[[slave]]\nname = 'a'\ndevice = 'di8'", "must be \"builtin:<name>\""),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\ncolour = 1", "unknown key\\(s\\) colour"),
        ("[[slave]]\nname = 'a'\nsii = 'missing.bin'", "slave 'a': cannot read SII file"),
        ("[[slave]]\nname = 'a'\nesi = 'x.xml'\nproduct = 1", "slave 'a': ESI x.xml"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\nprofile = 'ET9999'", "unknown ESC profile"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\nalias = 70000", "alias: 70000 is out of range"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\ninputs = 'zz'", "not hex"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\ninputs = '0102'", "2 bytes.*1 input bytes"),
        ("[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\nparent = 'a'\nport = 1", "first slave"),
        ("not toml [", "not valid TOML"),
    ],
)
def test_errors_name_file_and_slave(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        parse_topology(text, source="bad.toml")
    assert str(info.value).startswith("bad.toml")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("[[slave]]\nname = 'in'\ndevice = 'builtin:di8'", "slave 'in': the name is used twice"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'zz'\nport = 3", "not a slave"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'in'\nport = 3", "has no port 3"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'coupler'\nport = 1", "already in use"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'coupler'", "needs a port"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nport = 2", "port needs a parent"),
        ("[[fault]]\nkind = 'melt'\nslave = 'in'", "fault #1: kind must be"),
        ("[[fault]]\nkind = 'break_link'\nslave = 'in'", "needs a port"),
    ],
)
def test_placement_errors(extra: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_topology(LINE + extra, source="t.toml")


def test_parent_must_come_earlier() -> None:
    text = (
        "[[slave]]\nname = 'a'\ndevice = 'builtin:coupler'\n"
        "[[slave]]\nname = 'b'\ndevice = 'builtin:di8'\nparent = 'c'\nport = 1\n"
        "[[slave]]\nname = 'c'\ndevice = 'builtin:coupler'\n"
    )
    with pytest.raises(ConfigError, match="must come earlier"):
        parse_topology(text)


def test_line_after_a_full_slave_needs_parent() -> None:
    # a di8 has ports 0 and 1 only: after 'x' took port 1 of 'in', the next line
    # slave would need a free port of 'x', which exists; but a slave placed on
    # 'in' port 1 explicitly leaves nothing for a line slave following 'in'.
    text = LINE + "[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'out'\nport = 1\n"
    topo = parse_topology(text)
    assert (topo.slaves[3].parent, topo.slaves[3].port) == ("out", 1)
