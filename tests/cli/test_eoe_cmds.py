"""``eoe`` and ``ip`` on a simulated segment (the echo IP stack: no privileges needed)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from pyethercat.cli.eoe_cmds import parse_ip_args
from pyethercat.cli.main import cli
from pyethercat.errors import ConfigError

TOPOLOGY = """
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = { ip = "10.9.0.2/24", gateway = "10.9.0.1" }
[[slave]]
name = "di"
device = "builtin:di8"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""


@pytest.fixture
def topo(tmp_path: Path) -> str:
    path = tmp_path / "eoe.toml"
    path.write_text(TOPOLOGY)
    return str(path)


def run(topo: str, *args: str) -> Result:
    return CliRunner().invoke(cli, ["--sim", topo, *args])


def test_eoe_lists_handlers_in_igh_columns_and_ip_parameters(topo: str) -> None:
    r = run(topo, "eoe", "-v")
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0].split()[:8] == ["Interface", "Slave", "State", "RxBytes", "RxRate", "TxBytes",
                                    "TxRate", "TxQueue"]
    assert [ln.split()[1] for ln in lines[1:3]] == ["0", "2"]  # the di8 speaks no EoE
    assert "slave 0: ip 10.9.0.2/255.255.255.0" in r.output and "gateway 10.9.0.1" in r.output


def test_ip_sends_set_ip_parameter_with_options_or_igh_pairs(topo: str) -> None:
    r = run(topo, "ip", "-p", "2", "--ip", "10.9.0.3/24", "--gw", "10.9.0.1",
            "--mac", "02:00:00:00:00:33", "--dns", "10.9.0.53", "--name", "drive")
    assert r.exit_code == 0, r.output
    r = run(topo, "ip", "-p", "2", "addr", "10.9.0.4/16", "link", "02-00-00-00-00-44")
    assert r.exit_code == 0, r.output
    r = run(topo, "ip", "-p", "1", "--ip", "10.9.0.5/24")
    assert r.exit_code == 1 and "does not speak EoE" in r.output


@pytest.mark.parametrize("args,given,message", [
    ((), {"ip": None}, "nothing to set"),
    (("addr",), {}, "pairs"),
    (("color", "red"), {}, "unknown argument 'color'"),
    ((), {"ip": "10.1.2.300/24"}, "ip:"),
    ((), {"mac": "02:00:00"}, "invalid MAC address"),
    ((), {"name": "x" * 33}, "longer than 32 bytes"),
])
def test_bad_ip_arguments_are_one_line_errors(args: tuple[str, ...], given: dict[str, str | None],
                                              message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_ip_args(args, given)


def test_parse_ip_args_builds_the_parameters() -> None:
    p = parse_ip_args(("addr", "192.168.100.10/24", "default", "192.168.100.1"),
                      {"dns": "192.168.100.53", "name": "drive"})
    assert str(p.ip) == "192.168.100.10" and str(p.subnet) == "255.255.255.0"
    assert str(p.gateway) == "192.168.100.1" and str(p.dns_server) == "192.168.100.53"
    assert p.dns_name == "drive" and p.mac is None
