"""``upload``, ``download``, ``sdos`` and the CoE mapping in ``pdos``, on a simulated segment."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from pyethercat.cli.main import cli

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "di"
device = "builtin:di8"
"""


@pytest.fixture
def topo(tmp_path: Path) -> str:
    path = tmp_path / "coe.toml"
    path.write_text(TOPOLOGY)
    return str(path)


def run(topo: str, *args: str) -> Result:
    return CliRunner().invoke(cli, ["--sim", topo, *args])


def test_upload_by_described_type_and_given_type(topo: str) -> None:
    r = run(topo, "upload", "-p", "0", "0x1018", "1")
    assert r.exit_code == 0, r.output
    assert r.output == "0x00504543 5260611\n"
    # IgH refuses a type whose size differs from what the slave sent
    r = run(topo, "upload", "-p", "0", "0x1018", "1", "--type", "uint16")
    assert r.exit_code == 1
    assert "Data type mismatch. Expected uint16 with 2 bytes, but got 4 bytes" in r.output
    r = run(topo, "upload", "-p", "0", "0x1008", "0")
    assert r.output.startswith("PEC-COEIO")
    # octet strings and raw data as IgH's printRawData shows bytes
    r = run(topo, "upload", "-p", "0", "0x2000", "0", "--type", "octet_string")
    assert r.output.startswith("0x00 0x01 0x02 0x03") and len(r.output.split()) == 4096
    r = run(topo, "upload", "-p", "0", "0x2000", "0", "--type", "raw")
    assert r.output.startswith("0x00 0x01 0x02 0x03")


def test_upload_formats_as_igh_prints_them() -> None:
    from pyethercat.cli.coe_cmds import format_upload, upload_type
    from pyethercat.errors import ConfigError

    def out(t: str, raw: bytes) -> str:
        return format_upload(upload_type(t), raw)

    # integers: hex of the bytes (two's complement, type width) then decimal
    assert out("int16", b"\xf6\xff") == "0xfff6 -10"
    assert out("int8", b"\xf6") == "0xf6 -10"
    assert out("int32", (-2).to_bytes(4, "little", signed=True)) == "0xfffffffe -2"
    assert out("int64", (-1).to_bytes(8, "little", signed=True)) == "0xffffffffffffffff -1"
    assert out("uint8", b"\x07") == "0x07 7"
    assert out("uint64", (1 << 40).to_bytes(8, "little")) == "0x0000010000000000 1099511627776"
    assert out("bool", b"\x01") == "0x01 1"
    # sign-and-magnitude: the top bit is the sign, the rest the magnitude
    assert out("sm16", b"\x05\x80") == "0x8005 -5"
    assert out("sm8", b"\x05") == "0x05 5"
    # floats as C++ streams them (6 significant digits)
    assert out("float", b"\x00\x00\x20\x40") == "2.5"
    assert out("double", struct.pack("<d", 3.14159265)) == "3.14159"
    assert out("string", b"pump\x00\x00") == "pump"
    with pytest.raises(ConfigError, match="Expected int32 with 4 bytes, but got 2 bytes"):
        out("int32", b"\x01\x02")


def test_download_sign_magnitude(topo: str) -> None:
    from pyethercat.cli.coe_cmds import encode_download, upload_type

    assert encode_download(upload_type("sm16"), "-5") == b"\x05\x80"
    assert encode_download(upload_type("sm32"), "7") == b"\x07\x00\x00\x00"
    r = run(topo, "download", "-p", "0", "--type", "sm16", "0x8001", "1", "--", "-5")
    assert r.exit_code == 0, r.output


def test_download_typed_by_description_and_option(topo: str) -> None:
    # each command builds the segment afresh: a value out of range would abort (see below)
    r = run(topo, "download", "-p", "0", "0x8000", "5", "2.5")
    assert r.exit_code == 0, r.output
    r = run(topo, "download", "-p", "0", "0x8000", "1", "0x20", "--type", "uint16")
    assert r.exit_code == 0, r.output


def test_errors_are_one_line(topo: str) -> None:
    r = run(topo, "upload", "-p", "0", "0x9999", "0")
    assert r.exit_code == 1
    assert "SDO abort 0x06020000" in r.output and r.output.count("\n") == 1
    r = run(topo, "download", "-p", "0", "0x8000", "1", "20000")
    assert r.exit_code == 1 and "0x06090031" in r.output
    r = run(topo, "upload", "-p", "1", "0x1000", "0")
    assert r.exit_code == 1 and "no mailbox" in r.output
    r = run(topo, "upload", "-p", "0", "0x1000", "0", "--type", "nonsense")
    assert r.exit_code == 1 and "unknown data type" in r.output
    r = run(topo, "upload", "-p", "0", "0x10000", "0")
    assert r.exit_code == 1 and "out of range" in r.output


def test_sdos_listing(topo: str) -> None:
    r = run(topo, "sdos", "-p", "0")
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert 'SDO 0x1018, "Identity"' in lines
    assert '  0x1018:01, r-r-r-, uint32, 32 bit, "Vendor ID"' in lines
    r = run(topo, "sdos", "-q")
    assert r.output.splitlines()[0].startswith("=== slave 0")
    assert not any(line.startswith("  ") for line in r.output.splitlines())


def test_pdos_show_the_coe_mapping(topo: str) -> None:
    r = run(topo, "pdos", "-p", "0")
    assert r.exit_code == 0, r.output
    assert 'TxPDO 0x1A01 "Value inputs"' in r.output
    assert "PDO entry 0x6000:03, 32 bit" in r.output
