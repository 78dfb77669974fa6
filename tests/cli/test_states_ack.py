"""``pyethercat slaves`` / ``states`` with slaves in error, against one simulator that
keeps its state between commands (a SimServer over UDP in a thread).

A device-emulation slave (EL2004 SII dump) and a firmware slave (builtin:coe-io):
``slaves`` shows the error flag and the AL status code name, ``states`` the
state with ``+ERR`` and the code, ``states --ack`` acknowledges without a
state change, ``states STATE`` acknowledges before the request.
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

pytest.importorskip("pyethercat.sim.topology")

from pyethercat.cli.main import cli  # noqa: E402
from pyethercat.link.udp import UdpLink  # noqa: E402
from pyethercat.sim.server import SimServer  # noqa: E402
from pyethercat.sim.topology import load_topology  # noqa: E402
from pyethercat.wire.al import AlState, AlStatusCode  # noqa: E402


@pytest.fixture
def server(corpus_dir: Path, tmp_path: Path,
           patient_cli: None) -> Iterator[tuple[SimServer, str]]:
    shutil.copy(corpus_dir / "sii" / "ethercrab_el2004.bin", tmp_path / "el2004.bin")
    path = tmp_path / "t.toml"
    path.write_text('[[slave]]\nname = "el2004"\nsii = "el2004.bin"\n'
                    '[[slave]]\nname = "fw"\ndevice = "builtin:coe-io"\n')
    seg = load_topology(path).build()
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(seg, link)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    host, port = link.address
    try:
        yield srv, f"{host}:{port}"
    finally:
        srv.stop()
        thread.join(5)
        srv.close()


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def _rows(out: str) -> list[list[str]]:
    return [line.split() for line in out.splitlines() if not line.startswith("#")]


def _set_error(srv: SimServer, index: int, code: int, state: AlState | None = None) -> None:
    seg: Any = srv.segment
    srv.call(lambda: seg.slave(index).esc.set_al_error(code, state))


def test_slaves_and_states_show_errors_and_ack_clears_them(
    server: tuple[SimServer, str],
) -> None:
    srv, addr = server
    code, out, _ = run("--udp", addr, "states", "PREOP", "--wait")
    assert code == 0, out
    _set_error(srv, 0, AlStatusCode.SM_WATCHDOG)
    _set_error(srv, 1, AlStatusCode.INVALID_OUTPUT_CONFIG)

    code, out, _ = run("--udp", addr, "slaves")
    assert code == 0
    rows = out.splitlines()
    assert len(rows) == 2
    for row in rows:
        assert row.split()[2:4] == ["PREOP+ERROR", "E"]
    assert rows[0].endswith("[0x001B Sync manager watchdog]"), rows[0]
    assert rows[1].endswith("[0x001D Invalid output configuration]"), rows[1]
    code, out, _ = run("--udp", addr, "slaves", "-v", "-p", "1")
    assert "State: PREOP+ERR" in out
    assert "AL status code: 0x001D Invalid output configuration" in out

    code, out, _ = run("--udp", addr, "states")
    assert code == 0
    assert _rows(out) == [
        ["0", "0x1001", "PREOP+ERR", "0x001B", "Sync", "manager", "watchdog"],
        ["1", "0x1002", "PREOP+ERR", "0x001D", "Invalid", "output", "configuration"],
    ]

    # Acknowledge only: states stay, flags go (also on the device-emulation slave).
    code, out, _ = run("--udp", addr, "states", "--ack")
    assert code == 0, out
    assert "acknowledged 2 slaves" in out
    assert _rows(out)[-2:] == [["0", "0x1001", "PREOP"], ["1", "0x1002", "PREOP"]]
    code, out, _ = run("--udp", addr, "states", "--ack", "-p", "1")
    assert code == 0 and "acknowledged 0 slaves" in out

    # A request acknowledges first (as IgH's tool does).
    _set_error(srv, 0, AlStatusCode.SM_WATCHDOG)
    _set_error(srv, 1, AlStatusCode.INVALID_OUTPUT_CONFIG)
    code, out, _ = run("--udp", addr, "states", "INIT", "--wait")
    assert code == 0
    assert _rows(out) == [["0", "0x1001", "INIT"], ["1", "0x1002", "INIT"]]


def test_states_ack_with_a_state_is_refused(server: tuple[SimServer, str]) -> None:
    _srv, addr = server
    code, _, err = run("--udp", addr, "states", "--ack", "OP")
    assert code != 0 and "--ack" in err
