"""One master per wire: commands reach a running master through its control socket.

A master runs the cyclic exchange on a simulated segment (as ``pyethercat
run`` does) and serves its control socket; the command line, given the
same link, reaches it instead of opening a second master: it shows OP
(a fresh master would find INIT), live process data, and uploads through
the running master, while the cycle goes on without a lost frame or a
working-counter error.
"""

from __future__ import annotations

import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from conftest import SIM_FRAME_TIMEOUT

from pyethercat.cli.main import cli
from pyethercat.clock import VirtualClock, WallClock
from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.link.udp import UdpLink
from pyethercat.master.control import messages as msg
from pyethercat.master.control.client import find_master
from pyethercat.master.control.endpoint import endpoint_path, link_spec, runtime_dir
from pyethercat.master.control.protocol import (
    Framer,
    ProtocolError,
    RemoteError,
    decode_reply,
    decode_request,
    encode_error,
    encode_reply,
    encode_request,
    from_json,
    to_json,
)
from pyethercat.master.control.server import serve
from pyethercat.master.master import Master
from pyethercat.sim.server import SimServer
from pyethercat.sim.topology import load_topology

REPO = Path(__file__).resolve().parents[2]
COE = str(REPO / "examples" / "coe.toml")


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture
def running() -> Iterator[tuple[Master, Any]]:
    """A master cycling the coe.toml segment in OP and serving its control socket."""
    segment = load_topology(COE).build()
    m = Master(PairLink.responder_link(segment.process))
    m.scan()
    m.configure()
    runner = m.start(0.002)
    server = serve(m, link_spec(sim=COE))
    try:
        yield m, runner
    finally:
        server.close()
        runner.stop()
        m.close()


def test_commands_reach_the_running_master_without_disturbing_the_cycle(
        running: tuple[Master, Any]) -> None:
    m, runner = running
    before = runner.stats.cycles
    code, out, _ = run("--sim", COE, "slaves")
    assert code == 0
    assert [line.split()[2] for line in out.splitlines()] == ["OP", "OP"]
    code, out, _ = run("--sim", COE, "master")
    assert "Phase: Operation" in out and f"running master, pid {os.getpid()}" in out
    code, out, _ = run("--sim", COE, "states")
    assert [line.split()[2] for line in out.splitlines()] == ["OP", "OP"]
    code, out, _ = run("--sim", COE, "upload", "-p", "0", "0x1018", "1")
    assert code == 0 and out.split()[1] == str(m.slaves[0].identity.vendor_id)
    code, out, _ = run("--sim", COE, "reg_read", "-p", "1", "0x0130", "2")
    assert "(OP)" in out
    code, out, _ = run("--sim", COE, "domains", "-v")
    assert out.startswith("Domain0: LogBaseAddr 0x") and "SlaveConfig 0:1" in out
    result = CliRunner().invoke(cli, ["--sim", COE, "sii_read", "-p", "1"])
    assert result.stdout_bytes == m.slaves[1].sii_image
    code, out, _ = run("--sim", COE, "config")
    assert [line.split()[3] for line in out.splitlines()] == ["OP", "OP"]
    result = CliRunner().invoke(cli, ["--sim", COE, "data"])
    image = bytes(m.images["main"].buffer)
    assert len(result.stdout_bytes) == len(image) > 0
    # A running master refuses a rescan under its cycle.
    code, _, err = run("--sim", COE, "rescan")
    assert code == 1 and "stop the cyclic loop first" in err
    assert runner.running and runner.stats.cycles > before
    assert runner.stats.wkc_errors == 0 and runner.stats.lost_frames == 0


def test_direct_access_warns_and_a_second_master_is_refused(running: tuple[Master, Any]) -> None:
    m, _ = running
    code, out, err = run("--sim", COE, "--direct", "slaves")
    assert code == 0
    assert "warning: a master runs on sim:" in err and "second master on the same wire" in err
    # A second master of its own sees the segment from power-on: INIT.
    assert [line.split()[2] for line in out.splitlines()] == ["INIT", "INIT"]
    with pytest.raises(ConfigError, match="a master already runs on sim:.*one master per wire"):
        serve(m, link_spec(sim=COE))
    code, _, err = run("--sim", COE, "run", "--seconds", "1")
    assert code == 1 and "one master per wire" in err and len(err.strip().splitlines()) == 1
    code, _, err = run("--sim", COE, "eni", "export", "-o", "/tmp/x.xml")
    assert code == 1 and "one master per wire" in err


def test_socket_is_private_and_goes_away_with_the_master() -> None:
    segment = load_topology(COE).build()
    m = Master(PairLink.responder_link(segment.process), clock=VirtualClock())
    m.scan()
    server = serve(m, link_spec(sim=COE))
    path = endpoint_path(link_spec(sim=COE))
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_ISSOCK(path.stat().st_mode)
    assert stat.S_IMODE(runtime_dir().stat().st_mode) == 0o700
    client = find_master(link_spec(sim=COE))
    assert client is not None and client.hello is not None
    with client:
        assert client.hello.pid == os.getpid() and client.hello.slaves == 2
        with pytest.raises(RemoteError) as exc:
            client.call(msg.RegRead(7, 0x130, 2))
        assert exc.value.remote_type == "ConfigError" and "no slave at position 7" in str(exc.value)
    server.close()
    assert not path.exists()
    assert find_master(link_spec(sim=COE)) is None
    m.close()


def test_runtime_dir_must_be_private(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o755)
    shared.chmod(0o755)
    monkeypatch.setenv("PYETHERCAT_RUNTIME_DIR", str(shared))
    with pytest.raises(ConfigError, match="is not private"):
        runtime_dir()


def test_master_open_serves_and_refuses_a_second_master_on_the_link(patient_cli: None) -> None:
    segment = load_topology(COE).build()
    segment.clock = WallClock()
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(segment, link)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    host, port = link.address
    addr = f"{host}:{port}"
    try:
        with Master.open(udp=addr, timeout=SIM_FRAME_TIMEOUT) as m:
            m.scan()
            code, out, _ = run("--udp", addr, "master")
            assert f"running master, pid {os.getpid()}" in out and "Slaves: 2" in out
            code, out, _ = run("--udp", addr, "states", "PREOP", "--wait")
            assert code == 0 and [ln.split()[2] for ln in out.splitlines()] == ["PREOP"] * 2
            assert all(s.al_state_name == "PREOP" for s in m.slaves)  # the same master moved
            with pytest.raises(ConfigError, match="one master per wire"):
                Master.open(udp=addr)
        assert find_master(link_spec(udp=addr)) is None
    finally:
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()


def test_protocol_frames_and_types_round_trip() -> None:
    req = msg.SiiWrite(3, b"\x01\x02", force=True, backup="/x")
    wire = encode_request(req, 7)
    framer = Framer()
    # Bytes arrive in pieces: nothing until the whole message is there.
    assert framer.feed(wire[:3]) == [] and framer.feed(wire[3:-1]) == []
    (message,) = framer.feed(wire[-1:])
    ident, back = decode_request(message)
    assert ident == 7 and back == req
    reply = msg.SiiWriteResult(2, [4, 7], 0x56, True, None, [], 3, 9)
    (rmsg,) = Framer().feed(encode_reply(7, reply))
    assert decode_reply(rmsg, req) == reply
    (emsg,) = Framer().feed(encode_error(7, ConfigError("nope")))
    with pytest.raises(RemoteError, match="nope"):
        decode_reply(emsg, req)
    snap = msg.SlaveList([], True)
    assert from_json(msg.SlaveList, to_json(snap)) == snap
    with pytest.raises(ProtocolError, match="unknown control operation"):
        decode_request({"v": 1, "id": 1, "op": "nosuch", "args": {}})
    with pytest.raises(ProtocolError, match="version"):
        decode_request({"v": 99, "id": 1, "op": "hello", "args": {}})
    with pytest.raises(ProtocolError, match="too large"):
        Framer().feed(b"\xff\xff\xff\xff")


def test_a_master_without_a_usable_runtime_dir_still_opens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o755)  # not private: no socket there
    monkeypatch.setenv("PYETHERCAT_RUNTIME_DIR", str(shared))
    link = UdpLink(bind=("127.0.0.1", 0))
    host, port = link.address
    try:
        with caplog.at_level("WARNING"), Master.open(udp=f"{host}:{port}") as m:
            assert m.control is None
        assert "no control socket for this master" in caplog.text
    finally:
        link.close()
