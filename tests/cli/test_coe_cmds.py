"""``upload``, ``download``, ``sdos`` and the CoE mapping in ``pdos``, on a simulated segment."""

from __future__ import annotations

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
    r = run(topo, "upload", "-p", "0", "0x1018", "1", "--type", "uint16")
    assert r.output == "0x4543 17731\n"
    r = run(topo, "upload", "-p", "0", "0x1008", "0")
    assert r.output.startswith("PEC-COEIO")
    r = run(topo, "upload", "-p", "0", "0x2000", "0", "--type", "octet_string")
    assert r.output.startswith("00 01 02 03") and len(r.output.split()) == 4096


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
