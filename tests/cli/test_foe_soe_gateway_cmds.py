"""``foe_read``/``foe_write`` (with ``--boot``), ``soe_read``/``soe_write`` and ``gateway``."""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from pyethercat.cli.main import cli
from pyethercat.sim.firmware import build_firmware_image
from pyethercat.sim.server import start_sim_process
from pyethercat.wire.al import AlState

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
foe = true
foe_dir = "files"
soe = true
[[slave]]
name = "di"
device = "builtin:di8"
"""


@pytest.fixture
def topo(tmp_path: Path) -> str:
    (tmp_path / "files").mkdir()
    path = tmp_path / "foe.toml"
    path.write_text(TOPOLOGY)
    return str(path)


def run(topo: str, *args: str, stdin: bytes | None = None) -> Result:
    return CliRunner().invoke(cli, ["--sim", topo, *args], input=stdin)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def udp_sim(topo: str) -> Iterator[list[str]]:
    """One simulator process for several commands (each its own master session):
    the slaves keep their state, files and mailbox counters between commands."""
    address = f"127.0.0.1:{_free_udp_port()}"
    with start_sim_process(topo, link=f"udp:{address}"):
        yield ["--udp", address]


def on(link: list[str], *args: str) -> Result:
    return CliRunner().invoke(cli, [*link, *args])


def test_foe_write_then_read(topo: str, tmp_path: Path) -> None:
    blob = bytes((i * 7) & 0xFF for i in range(30_000))
    local = tmp_path / "local.bin"
    local.write_bytes(blob)
    r = run(topo, "foe_write", "-p", "0", str(local))
    assert r.exit_code == 0, r.output
    assert (tmp_path / "files" / "local.bin").read_bytes() == blob  # the base name, as IgH
    r = run(topo, "foe_write", "-p", "0", str(local), "-o", "other.bin")
    assert (tmp_path / "files" / "other.bin").read_bytes() == blob
    out = tmp_path / "back.bin"
    r = run(topo, "foe_read", "-p", "0", "other.bin", "-o", str(out))
    assert r.exit_code == 0, r.output
    assert out.read_bytes() == blob
    # stdin / stdout as IgH's '-'
    r = run(topo, "foe_write", "-p", "0", "-", "--name", "piped.txt", stdin=b"hello")
    assert r.exit_code == 0, r.output
    r = run(topo, "foe_read", "-p", "0", "piped.txt")
    assert r.exit_code == 0 and r.stdout_bytes == b"hello"


def _on_a_terminal(args: list[str]) -> tuple[int, str]:
    """Run pyethercat with its stderr on a pseudo-terminal; (exit status, what it drew there)."""
    import os
    import pty
    import re

    master_fd, slave_fd = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "pyethercat", *args],
                            stdout=subprocess.DEVNULL, stderr=slave_fd,
                            env={**os.environ, "COLUMNS": "120", "TERM": "xterm"})
    os.close(slave_fd)
    drawn = bytearray()
    try:
        while True:
            try:
                chunk = os.read(master_fd, 65536)
            except OSError:  # EIO: the process is gone and the terminal closed
                break
            if not chunk:
                break
            drawn += chunk
    finally:
        os.close(master_fd)
    code = proc.wait(timeout=120)
    # without the terminal's control sequences
    return code, re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", drawn.decode("utf-8", "replace"))


def test_foe_write_draws_a_progress_bar_on_a_terminal(topo: str, tmp_path: Path) -> None:
    blob = bytes((i * 13) & 0xFF for i in range(300_000))
    local = tmp_path / "bar.bin"
    local.write_bytes(blob)
    code, drawn = _on_a_terminal(["--sim", topo, "foe_write", "-p", "0", str(local)])
    assert code == 0, drawn
    assert (tmp_path / "files" / "bar.bin").read_bytes() == blob
    # the bar's last picture: the whole file acknowledged, in rich's download column
    assert "FoE write bar.bin" in drawn and "━" in drawn
    assert "300.0/300.0 kB" in drawn, drawn
    code, drawn = _on_a_terminal(["--sim", topo, "foe_write", "-q", "-p", "0", str(local)])
    assert code == 0 and "FoE write" not in drawn, drawn  # (the scan's bar may show)


def test_foe_errors_are_one_line(topo: str, tmp_path: Path) -> None:
    r = run(topo, "foe_read", "-p", "0", "missing.bin")
    assert r.exit_code == 1
    assert r.output.strip().count("\n") == 0
    assert "FoE error 0x8001 (slave says: not found)" in r.output
    r = run(topo, "foe_write", "-p", "0", "-", stdin=b"x")
    assert r.exit_code == 1 and "give the file name on the slave with --name" in r.output
    r = run(topo, "foe_read", "-p", "1", "x")
    assert r.exit_code == 1 and "has no mailbox: no FoE" in r.output
    r = run(topo, "foe_read", "-p", "0", "x", "5", "--password", "6")
    assert r.exit_code == 1 and "give the password once" in r.output


def test_foe_write_boot_updates_firmware(topo: str, tmp_path: Path) -> None:
    image = tmp_path / "fw.efw"
    image.write_bytes(build_firmware_image(0x00504543, 0x00050001, 0x00030000, "v3", bytes(900)))
    r = run(topo, "foe_write", "-p", "0", "--boot", str(image))
    assert r.exit_code == 0, r.output
    # each --sim invocation builds the segment anew: the new revision shows in
    # test_foe_write_boot_shows_the_new_revision (one simulator for several commands)
    bad = tmp_path / "bad.efw"
    bad.write_bytes(build_firmware_image(1, 2, 3, "x", b""))
    r = run(topo, "foe_write", "-p", "0", "--boot", str(bad))
    assert r.exit_code == 1 and "FoE error 0x8004" in r.output and "image is for vendor" in r.output


def test_sessions_back_to_back_on_one_simulator(udp_sim: list[str]) -> None:
    """Each command is a new master whose first mailbox counter is 1; the one before ended
    on 1 too (one FoE read request, one SoE read), so the slave drops the repetition and
    only the same request sent again with counter 2 gets the answer."""
    for _ in range(3):
        r = on(udp_sim, "foe_read", "-p", "0", "nothere")
        assert r.exit_code == 1 and "FoE error 0x8001 (slave says: not found)" in r.output, \
            r.output
    for _ in range(3):
        r = on(udp_sim, "soe_read", "-p", "0", "1", "--type", "uint16")
        assert r.exit_code == 0 and r.output == "0x03e8 1000\n", r.output


def test_foe_write_boot_shows_the_new_revision(udp_sim: list[str], tmp_path: Path) -> None:
    """The simulated slave lives on between commands: the update is visible to the next."""
    r = on(udp_sim, "upload", "-p", "0", "0x1018", "3", "--type", "uint32")
    assert r.exit_code == 0 and "0x00030000" not in r.output, r.output
    image = tmp_path / "fw.efw"
    image.write_bytes(build_firmware_image(0x00504543, 0x00050001, 0x00030000, "v3", bytes(900)))
    r = on(udp_sim, "foe_write", "-p", "0", "--boot", str(image))
    assert r.exit_code == 0, r.output
    r = on(udp_sim, "upload", "-p", "0", "0x1018", "3", "--type", "uint32")
    assert r.exit_code == 0 and r.output == "0x00030000 196608\n", r.output
    r = on(udp_sim, "upload", "-p", "0", "0x100A", "0", "--type", "string")
    assert r.exit_code == 0 and r.output.strip() == "v3", r.output
    r = on(udp_sim, "slaves", "-p", "0", "-v")
    assert r.exit_code == 0 and "0x00030000" in r.output, r.output


def test_soe_read_and_write_as_igh(topo: str) -> None:
    r = run(topo, "soe_read", "-p", "0", "S-0-0024")
    assert r.exit_code == 0, r.output
    assert r.output == "S-0-0036 S-0-0047\n"
    assert run(topo, "soe_read", "-p", "0", "0", "1", "-e", "name").output == \
        "Control unit cycle time (TNcyc)\n"
    assert run(topo, "soe_read", "-p", "0", "1").output == "1000\n"
    # with --type the CANopen-style rendering of upload
    assert run(topo, "soe_read", "-p", "0", "1", "--type", "uint16").output == "0x03e8 1000\n"
    assert run(topo, "soe_write", "-p", "0", "36", "-500").exit_code == 0
    r = run(topo, "soe_write", "-p", "0", "36", "99999")
    assert r.exit_code == 1 and "SoE error 0x7007" in r.output
    r = run(topo, "soe_write", "-p", "0", "S-0-0024", "S-0-0036 S-0-0040")
    assert r.exit_code == 0, r.output
    r = run(topo, "soe_read", "-p", "0", "9", "1")
    assert r.exit_code == 1 and "drive 9 out of range" in r.output


def _upload_request(address: int, index: int, subindex: int) -> bytes:
    """An ETG.8200 datagram: EtherCAT header (type 5), mailbox header, CoE SDO upload."""
    coe = struct.pack("<HBHBI", 2 << 12, 0x40, index, subindex, 0)
    body = struct.pack("<HHBB", len(coe), address, 0, 0x13) + coe
    return struct.pack("<H", len(body) | 0x5000) + body


def _ask(port: int, datagram: bytes) -> bytes:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(30)
        sock.sendto(datagram, ("127.0.0.1", port))
        reply, _ = sock.recvfrom(1024)
    return reply


def _value(reply: bytes) -> int:
    """The 32-bit value of an expedited upload answer (mailbox header at 2, CoE at 8)."""
    assert struct.unpack_from("<H", reply, 11)[0] == 0x1018 and reply[10] & 0xE3 == 0x43, \
        reply.hex()
    return int(struct.unpack_from("<I", reply, 14)[0])


def _gateway(topo: str, port: int, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pyethercat", "--sim", topo, "gateway", "--bind",
         f"127.0.0.1:{port}", "--seconds", "120", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _stop(proc: subprocess.Popen[str]) -> str:
    """Ctrl-C the gateway; the rest of its output (what it served)."""
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    return out


def test_gateway_command_serves_and_reports(topo: str) -> None:
    port = _free_udp_port()
    proc = _gateway(topo, port)
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert f"mailbox gateway on udp 127.0.0.1:{port}" in first, proc.stderr
        assert _value(_ask(port, _upload_request(1000, 0x1018, 1))) == 0x00504543
        assert "served 1 of 1 requests (0 to the master, 1 forwarded, 0 failed)" in _stop(proc)
    finally:
        proc.kill()
        proc.wait(timeout=10)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_gateway_ends_in_order_on_a_signal_also_with_sigint_ignored(topo: str, sig: int) -> None:
    """A gateway started as a script's background job (SIGINT ignored) or stopped with
    SIGTERM still ends in order and reports what it served."""
    port = _free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "pyethercat", "--sim", topo, "gateway", "--bind",
         f"127.0.0.1:{port}", "--seconds", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        assert proc.stdout is not None
        assert f"mailbox gateway on udp 127.0.0.1:{port}" in proc.stdout.readline()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
        assert "served 0 of 0 requests" in out
    finally:
        proc.kill()
        proc.wait(timeout=10)


def test_gateway_with_its_own_master_in_op(topo: str) -> None:
    """--state OP: the gateway's master cycles (OP needs the process data exchange)."""
    port = _free_udp_port()
    proc = _gateway(topo, port, "--state", "OP", "--cycle", "2000")
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert f"mailbox gateway on udp 127.0.0.1:{port}" in first, proc.stderr
        assert _value(_ask(port, _upload_request(1000, 0x1018, 2))) == 0x00050001
        # other commands reach the gateway's master through its control socket
        r = run(topo, "slaves")
        assert r.exit_code == 0 and r.output.split("\n")[0].split()[2] == "OP", r.output
        assert "served 1 of 1 requests" in _stop(proc)
    finally:
        proc.kill()
        proc.wait(timeout=10)


def test_gateway_attaches_to_a_running_master(topo: str) -> None:
    """A master cycles in OP (as 'pyethercat run' does); the gateway forwards through it."""
    from pyethercat.link.pair import PairLink
    from pyethercat.master.control.endpoint import link_spec
    from pyethercat.master.control.server import serve
    from pyethercat.master.master import Master
    from pyethercat.sim.topology import load_topology

    segment = load_topology(topo).build()
    m = Master(PairLink.responder_link(segment.process))
    m.scan()
    m.configure()
    runner = m.start(0.002)
    server = serve(m, link_spec(sim=topo))
    port = _free_udp_port()
    proc = None
    try:
        r = run(topo, "gateway", "--state", "PREOP", "--seconds", "1")
        assert r.exit_code == 1 and "leaves its slaves' states alone" in r.output
        assert r.output.count("\n") == 1
        proc = _gateway(topo, port)
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert "through the master running on sim:" in first, proc.stderr
        io = m.slaves[0]
        served = io.mbx.stats.received  # type: ignore[union-attr]
        assert _value(_ask(port, _upload_request(1000, 0x1018, 2))) == 0x00050001
        assert _value(_ask(port, _upload_request(io.station_address, 0x1018, 1))) == 0x00504543
        # the running master's own mailbox of the slave carried them
        assert io.mbx.stats.received - served == 2  # type: ignore[union-attr]
        # address 0: the master's object dictionary, from the running master's scan
        reply = _ask(port, _upload_request(0, 0x8001, 1))
        assert struct.unpack_from("<I", reply, 14)[0] & 0xFFFF == m.slaves[1].station_address
        # a slave without mailbox: dropped
        _ask_nothing = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        _ask_nothing.sendto(_upload_request(1001, 0x1018, 1), ("127.0.0.1", port))
        _ask_nothing.close()
        out = _stop(proc)
        assert "served 3 of 4 requests (1 to the master, 2 forwarded, 0 failed); " \
               "dropped: no mailbox 1" in out, out
        assert runner.running and runner.stats.wkc_errors == 0
        assert m.read_states()[0].state == AlState.OP
    finally:
        if proc is not None:
            proc.kill()
            proc.wait(timeout=10)
        server.close()
        runner.stop()
        m.close()


def test_foe_and_soe_reach_a_running_master(topo: str, tmp_path: Path) -> None:
    """The verbs go through the control socket of a master cycling in OP."""
    from pyethercat.link.pair import PairLink
    from pyethercat.master.control.endpoint import link_spec
    from pyethercat.master.control.server import serve
    from pyethercat.master.master import Master
    from pyethercat.sim.topology import load_topology

    segment = load_topology(topo).build()
    m = Master(PairLink.responder_link(segment.process))
    m.scan()
    m.configure()
    runner = m.start(0.002)
    server = serve(m, link_spec(sim=topo))
    try:
        blob = bytes(range(256)) * 20
        local = tmp_path / "cycle.bin"
        local.write_bytes(blob)
        r = run(topo, "foe_write", "-p", "0", str(local))
        assert r.exit_code == 0, r.output
        assert (tmp_path / "files" / "cycle.bin").read_bytes() == blob
        r = run(topo, "foe_read", "-p", "0", "cycle.bin")
        assert r.exit_code == 0 and r.stdout_bytes == blob
        assert run(topo, "soe_read", "-p", "0", "S-0-0024").output == "S-0-0036 S-0-0047\n"
        r = run(topo, "soe_write", "-p", "0", "S-0-0001", "500")  # PRE-OP only
        assert r.exit_code == 1 and "SoE error 0x7005" in r.output
        assert runner.running and runner.stats.wkc_errors == 0
        assert runner.stats.lost_frames == 0
        assert m.read_states()[0].state == AlState.OP
    finally:
        server.close()
        runner.stop()
        m.close()
