"""The diagnostic master commands over ``--sim`` (in-process simulator)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("pyethercat.sim.topology")

from pyethercat.cli.main import cli  # noqa: E402
from pyethercat.cli.reg_cmds import format_registers  # noqa: E402
from pyethercat.wire.sii import parse_sii, sii_fix_checksum  # noqa: E402

TOPOLOGY = """
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "di8"
device = "builtin:di8"
[[slave]]
name = "do8"
device = "builtin:do8"
alias = 5
[[slave]]
name = "branch"
device = "builtin:di2"
parent = "coupler"
port = 3
"""


@pytest.fixture
def topo(tmp_path: Path) -> str:
    path = tmp_path / "seg.toml"
    path.write_text(TOPOLOGY)
    return str(path)


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def test_slaves_table(topo: str) -> None:
    code, out, _ = run("--sim", topo, "slaves")
    assert code == 0
    lines = out.splitlines()
    # IgH's layout: position, alias:relative position, state, flag, name.
    rows = [line.split(maxsplit=4) for line in lines]
    assert [r[0] for r in rows] == ["0", "1", "2", "3"]
    # Ring order: the branch on the coupler's port 3 comes first (position 1).
    assert [r[1] for r in rows] == ["0:0", "0:1", "0:2", "5:0"]
    assert {r[2] for r in rows} == {"INIT"} and {r[3] for r in rows} == {"+"}
    assert "coupler" in rows[0][4]
    assert lines[0] == "0  0:0  INIT  +  " + rows[0][4]


def test_slaves_verbose_shows_identity_ports_and_tree(topo: str) -> None:
    code, out, _ = run("--sim", topo, "slaves", "-v")
    assert code == 0
    assert out.count("=== Slave ") == 4
    assert "Vendor ID: 0x" in out and "Product code: 0x" in out
    assert "Parent: slave 0 port 3" in out
    assert "=== Topology ===" in out and "port 3: 1 " in out


def test_states_show_and_request(topo: str) -> None:
    code, out, _ = run("--sim", topo, "states", "PREOP")
    assert code == 0 and out == ""  # IgH: the request is sent, nothing printed
    code, out, _ = run("--sim", topo, "states", "PREOP", "--wait")
    assert code == 0
    assert [line.split()[2] for line in out.splitlines()] == ["PREOP"] * 4
    # A refused request (these devices have no bootstrap mailbox) is one line with its code.
    code, out, err = run("--sim", topo, "states", "BOOT", "--wait")
    assert code != 0
    assert err.startswith("pyethercat: error: ") and "AL status code 0x0013" in err
    assert "Bootstrap not supported" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run("--sim", topo, "states", "FOO")
    assert code != 0 and "unknown AL state" in err


def test_reg_read_and_write(topo: str) -> None:
    code, out, _ = run("--sim", topo, "reg_read", "-p", "1", "0x0130", "6")
    assert code == 0
    first = out.splitlines()[0]
    assert first.startswith("0x0130  ") and "AL status = 0x0001 (INIT)" in first
    code, out, _ = run("--sim", topo, "reg_write", "-p", "1", "0x0F80", "de ad")
    assert code == 0 and "wrote 2 bytes at 0x0F80" in out
    code, _, err = run("--sim", topo, "reg_read", "-p", "7", "0", "2")
    assert code != 0 and "no slave at position 7" in err
    code, _, err = run("--sim", topo, "reg_write", "-p", "0", "0x120", "zz")
    assert code != 0 and "not hex data" in err


def test_sii_read_write_roundtrip(topo: str, tmp_path: Path) -> None:
    out_file = tmp_path / "di8.bin"
    code, out, _ = run("--sim", topo, "sii_read", "-p", "1", "-o", str(out_file))
    assert code == 0
    image = out_file.read_bytes()
    info = parse_sii(image)
    assert info.end_marker and info.device_name is not None
    code, out, _ = run("--sim", topo, "sii_read", "-p", "1", "-v")
    assert code == 0 and "Category GENERAL" in out and info.device_name in out
    # Off a terminal the image itself goes to stdout (IgH: sii_read -p1 > eeprom.bin).
    result = CliRunner().invoke(cli, ["--sim", topo, "sii_read", "-p", "1"])
    assert result.exit_code == 0 and result.stdout_bytes == image
    result = CliRunner().invoke(cli, ["--sim", topo, "sii_read", "-p", "1", "-o", "-"])
    assert result.stdout_bytes == image
    # Each --sim invocation starts a fresh segment: the write is checked in the output.
    changed = bytearray(image)
    changed[8:10] = struct.pack("<H", 3)
    new_file = tmp_path / "new.bin"
    new_file.write_bytes(sii_fix_checksum(bytes(changed)))
    code, out, _ = run("--sim", topo, "sii_write", "-p", "1", str(new_file))
    assert code == 0 and "wrote 2 of " in out and "alias 3" in out
    bad = tmp_path / "bad.bin"
    bad.write_bytes(bytes(changed))  # stale checksum: the writer computes its own
    code, out, err = run("--sim", topo, "sii_write", "-p", "1", str(bad))
    assert code == 0 and "header checksum set to" in out and "wrote 2 of " in out


def test_counters(topo: str) -> None:
    code, out, _ = run("--sim", topo, "counters")
    assert code == 0 and len(out.splitlines()) == 5


def test_no_segment_given_is_a_one_line_error() -> None:
    code, _, err = run("slaves")
    assert code != 0 and "--iface" in err and len(err.strip().splitlines()) == 1


def test_format_registers_names_and_gaps() -> None:
    lines = format_registers(0x0110, bytes([0x30, 0x05, 0, 0]))
    assert lines[0].startswith("0x0110  30 05") and "DL status = 0x0530" in lines[0]
    assert lines[1].startswith("0x0112  00 00")
