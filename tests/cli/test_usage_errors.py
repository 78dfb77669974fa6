"""The CLI contract: every failure is one line on stderr, exit status 1, never a traceback.

A table of bad invocations, each run as the installed program runs it
(``cli.main`` in standalone mode: usage errors, library errors, errors
while options are parsed), asserting exit status 1 (IgH's tool returns 1
for every failure), exactly one line on stderr naming the problem, and no
traceback. A few run in a real child process too.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.link.udp import UdpLink
from pyethercat.sim.server import SimServer
from pyethercat.sim.topology import load_topology

REPO = Path(__file__).resolve().parents[2]
DEMO = str(REPO / "examples" / "demo.toml")
COE = str(REPO / "examples" / "coe.toml")
CORPUS_SII = REPO.parent / "shared" / "corpus" / "sii"


@pytest.fixture(scope="module")
def bad(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Broken inputs: topologies with corrupt SII images, a cut master cable, files."""
    d = tmp_path_factory.mktemp("bad")
    ek = (CORPUS_SII / "ethercrab_ek1100.bin").read_bytes()
    images = {
        "trunc": ek[:100],
        "badcrc": ek[:14] + bytes([ek[14] ^ 0xFF]) + ek[15:],
        # The STRINGS category claims 0x7FFF words.
        "badcat": ek[:0x80] + b"\x0a\x00\xff\x7f" + ek[0x84:],
        # The receive mailbox at 0xFF00, far past the ET1100's 8 KiB.
        "badmbx": ek[:0x30] + b"\x00\xff\x80\x00" + ek[0x34:],
    }
    out: dict[str, str] = {}
    for name, image in images.items():
        if name == "badmbx":
            from pyethercat.master.sii_write import with_checksum

            image = with_checksum(image)
        (d / f"{name}.bin").write_bytes(image)
        topo = d / f"{name}.toml"
        topo.write_text(f'[[slave]]\nname = "a"\nsii = "{name}.bin"\n')
        out[name] = str(topo)
    cut = d / "cut.toml"
    cut.write_text('[[slave]]\nname = "a"\ndevice = "builtin:coupler"\n'
                   '[[slave]]\nname = "b"\ndevice = "builtin:di8"\n'
                   '[[fault]]\nkind = "break_link"\nslave = "a"\nport = 0\n')
    out["cut"] = str(cut)
    (d / "odd.bin").write_bytes(b"\x01\x02\x03")
    out["odd"] = str(d / "odd.bin")
    out["el2004"] = str(CORPUS_SII / "ethercrab_el2004.bin")
    plain = d / "plain-file"
    plain.write_text("x")
    out["plain"] = str(plain)
    return out


@pytest.fixture(scope="module")
def busy_control(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The control socket of a running simulator."""
    path = tmp_path_factory.mktemp("ctl") / "ctl.sock"
    seg = load_topology(DEMO).build()
    link = UdpLink(bind=("127.0.0.1", 0))
    srv = SimServer(seg, link, control=path)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    try:
        yield str(path)
    finally:
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()


def _case(args: list[str], fragment: str) -> tuple[list[str], str]:
    return args, fragment


# (arguments, a fragment of the one error line). "{x}" takes a path from `bad`.
CASES = [
    # usage: unknown, ambiguous, missing, malformed
    (["nosuch"], "No such command 'nosuch'"),
    (["s"], "ambiguous command 's': it matches sdos, sii_read, sii_write, sim, slaves, soe_read, soe_write, states"),
    (["--sim", DEMO, "reg_read", "-p", "0"], "Missing argument 'ADDRESS'"),
    (["--sim", DEMO, "reg_read", "-p", "zz", "0x130", "2"], "invalid character 'z'"),
    (["decode"], "Missing argument 'CAPTURE'"),
    (["decode", "/nonexistent/c.pcap"], "cannot read /nonexistent/c.pcap"),
    (["--sim", DEMO, "states", "FOO"], "unknown AL state 'FOO'"),
    (["--sim", "/nonexistent.toml", "slaves"], "/nonexistent.toml"),
    (["slaves"], "say where the segment is"),
    (["--sim", DEMO, "--udp", "127.0.0.1:1", "slaves"], "say where the segment is"),
    (["--iface", "pyecat-nonexist0", "slaves"], "pyecat-nonexist0"),
    # output files under a missing directory
    (["--sim", DEMO, "run", "--seconds", "1", "--pcap", "/nonexistent/dir/x.pcapng"],
     "cannot write the capture /nonexistent/dir/x.pcapng"),
    (["sim", DEMO, "--udp", "127.0.0.1:0", "--control", "/nonexistent/dir/ctl"],
     "--control /nonexistent/dir/ctl: directory /nonexistent/dir does not exist"),
    (["sim", DEMO, "--udp", "127.0.0.1:0", "--control", "{plain}"], "exists and is not a socket"),
    (["sim", DEMO, "--udp", "127.0.0.1:0", "--control", "{busy}"],
     "in use by a running simulator"),
    # zero and negative cycles, durations, timeouts
    (["demo", "--cycle", "0"], "--cycle must be a positive number"),
    (["demo", "--cycle", "-5"], "--cycle must be a positive number"),
    (["demo", "--seconds", "0"], "--seconds must be positive"),
    (["demo", "--seconds", "-1"], "--seconds must be positive"),
    (["--sim", DEMO, "run", "--cycle", "0"], "cycle time must be positive"),
    (["--sim", DEMO, "run", "--cycle", "-3"], "cycle time must be positive"),
    (["--sim", DEMO, "run", "--seconds", "0"], "--seconds must be positive"),
    (["--sim", DEMO, "run", "--seconds", "-2"], "--seconds must be positive"),
    (["--sim", DEMO, "states", "PREOP", "--wait", "--timeout", "0"], "--timeout must be positive"),
    (["--sim", DEMO, "states", "PREOP", "--wait", "--timeout", "-1"],
     "--timeout must be positive"),
    (["--sim", DEMO, "--frame-timeout", "0", "slaves"], "PYETHERCAT_FRAME_TIMEOUT'): 0.0 is not in the range x>0"),
    (["--sim", DEMO, "slaves", "--retries", "-1"], "PYETHERCAT_RETRIES'): -1 is not in the range x>=0"),
    # broken topology files: rejected at load, saying what is wrong
    (["--sim", "{trunc}", "slaves"], "100 bytes end inside the fixed area"),
    (["--sim", "{badcrc}", "slaves"], "header checksum (word 0x07) is 0xB9"),
    (["--sim", "{badcat}", "slaves"], "category STRINGS at word 0x0040: 32767 words run past"),
    (["--sim", "{badmbx}", "slaves"], "receive mailbox at 0xFF00 with 128 bytes lies outside"),
    (["--sim", "{cut}", "slaves"], "port 0 of the first slave 'a' is the master's cable"),
    (["sim", "{cut}", "--check"], "port 0 of the first slave 'a' is the master's cable"),
    # option combinations and ranges
    (["esi", "sii", "builtin:", "-o", "{plain}.bin", "--serial", "0x1FFFFFFFF"],
     "--serial 0x1FFFFFFFF out of range 0..0xFFFFFFFF"),
    (["esi", "show", "builtin:", "--revision", "3"], "--revision needs --product"),
    (["--sim", DEMO, "demo", "--topology", DEMO], "--sim TOPOLOGY (before the command) or "
                                                  "--topology, not both"),
    # slave selection and values
    (["--sim", DEMO, "-p", "1,2", "reg_read", "0", "2"],
     "the slave selection matches 2 slaves; 'reg_read' needs exactly one"),
    (["--sim", DEMO, "upload", "-p", "9", "0x1000", "0"], "no slave at position 9"),
    (["--sim", DEMO, "reg_read", "-p", "0", "-t", "nosuch", "0"], "unknown data type 'nosuch'"),
    (["--sim", DEMO, "reg_write", "-p", "0", "-t", "uint8", "0xf80", "300"],
     "value 300 out of range 0..255"),
    (["--sim", DEMO, "reg_read", "-p", "0", "0xFFFF", "4"], "cannot read 4 bytes at 0xFFFF"),
    (["--sim", COE, "download", "-p", "0", "0x8000", "5", "nan", "-t", "float"],
     "SDO abort 0x06090030"),
    (["--sim", COE, "download", "-p", "0", "0x8000", "1", "nan", "-t", "uint16"],
     "'nan' is not a valid UNSIGNED16 value"),
    (["--sim", DEMO, "upload", "-p", "1", "0x1000", "0"], "has no mailbox: no CoE"),
    (["--sim", DEMO, "alias", "-p", "0", "70000"], "alias 70000 out of range 0..0xFFFF"),
    (["--sim", DEMO, "alias", "7"], "this writes the alias of 6 slaves to 7; give --force"),
    (["--sim", DEMO, "sii_write", "-p", "0", "{odd}"], "3 bytes of SII data"),
    (["--sim", DEMO, "sii_write", "-p", "0", "/nonexistent.bin"], "cannot read /nonexistent.bin"),
    (["--sim", DEMO, "sii_write", "-p", "1", "{el2004}"],
     "the image is for another device (vendor 0x00504543 -> 0x00000002"),
    (["--sim", DEMO, "crc", "nonsense"], "takes no argument or 'reset'"),
    (["--sim", DEMO, "graph", "nonsense"], "unknown argument 'nonsense'"),
    (["--sim", DEMO, "run", "--eni", "/nonexistent.xml"], "/nonexistent.xml"),
    (["--sim", DEMO, "--eni", "/nonexistent.xml", "run"], "/nonexistent.xml"),
    (["--sim", DEMO, "run", "--seconds", "1", "--cycle", "0.5"],
     "--cycle '0.5': give the cycle time in whole microseconds"),
    # distributed clocks: times in microseconds, the shift within the cycle
    (["--sim", DEMO, "dc", "--sync0", "abc"], "--sync0 'abc': not a number of microseconds"),
    (["--sim", DEMO, "dc", "--sync0", "1000", "--sync1", "y"],
     "--sync1 'y': not a number of microseconds"),
    (["--sim", DEMO, "dc", "--shift", "nan"], "--shift 'nan': not a number of microseconds"),
    (["--sim", DEMO, "run", "--seconds", "1", "--dc", "--sync0", "abc"], "--sync0 'abc': not a number of microseconds"),
    (["--sim", DEMO, "run", "--seconds", "1", "--dc", "--shift", "x"], "--shift 'x': not a number of microseconds"),
    (["--sim", DEMO, "run", "--seconds", "1", "--dc", "--sync0", "-500"], "the SYNC0 cycle must be positive"),
    (["--sim", DEMO, "dc", "--sync0", "500", "--shift", "500"],
     "--shift 500 us: the shift must lie within the SYNC0 cycle (0 up to below 500 us)"),
    (["--sim", DEMO, "run", "--seconds", "1", "--cycle", "1000", "--shift", "1500"],
     "--shift 1500 us: the shift must lie within the SYNC0 cycle (0 up to below 1000 us)"),
    (["--sim", DEMO, "run", "--seconds", "1", "--shift", "-1"], "--shift -1 us: the shift must lie within"),
    # a plot under a missing directory is refused before the run, as --pcap is
    (["--sim", DEMO, "run", "--seconds", "1", "--plot", "/nonexistent/d/p.png"],
     "cannot write the plot /nonexistent/d/p.png: directory /nonexistent/d does not exist"),
    (["--sim", DEMO, "dc", "--plot", "/nonexistent/d/p.png"],
     "cannot write the plot /nonexistent/d/p.png: directory /nonexistent/d does not exist"),
    (["--sim", DEMO, "run", "--dc", "--seconds", "1", "--plot", "{plain}/p.png"],
     "plain-file is not a directory"),
    # selections checked before the segment or the running master is reached
    (["--sim", DEMO, "data", "-d", "x"], "invalid character 'x' at position 0 of 'x'"),
    (["--sim", DEMO, "domains", "-d", "1;2"], "invalid character ';'"),
    (["--sim", DEMO, "-a", "0x10000", "slaves"], "alias 0x10000 out of range 0..0xFFFF"),
    (["--sim", DEMO, "config", "-a", "70000"], "alias 70000 out of range 0..0xFFFF"),
    (["--sim", DEMO, "config", "-p", "q"], "invalid character 'q'"),
]


@pytest.mark.parametrize("args, fragment", CASES, ids=[" ".join(c[0][:4]) for c in CASES])
def test_bad_invocation_is_one_line_and_exit_1(args: list[str], fragment: str,
                                               bad: dict[str, str], busy_control: str) -> None:
    paths = dict(bad, busy=busy_control)
    argv = [a.format(**paths) for a in args]
    result = CliRunner().invoke(cli, argv, prog_name="pyethercat")
    err = result.stderr
    assert result.exit_code == 1, (result.exit_code, err, result.exception)
    # A SystemExit is how the program ends; anything else escaping is a traceback.
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception)
    assert "Traceback" not in err and "Traceback" not in result.stdout
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("pyethercat: error: "), lines[0]
    assert fragment in lines[0], lines[0]


def test_frame_timeout_and_retries_reach_the_commands_master(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A peer that never answers: the error names the attempts and the timeout asked for."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        addr = "{}:{}".format(*silent.getsockname())
        result = CliRunner().invoke(cli, ["--udp", addr, "--frame-timeout", "0.02", "--retries",
                                          "1", "slaves"])
        assert result.exit_code == 1
        assert "no reply to BRD" in result.stderr and "after 2 attempts (0.02 s each)" in \
            result.stderr
        monkeypatch.setenv("PYETHERCAT_FRAME_TIMEOUT", "0.03")
        monkeypatch.setenv("PYETHERCAT_RETRIES", "0")
        result = CliRunner().invoke(cli, ["--udp", addr, "slaves"])
        assert "after 1 attempt (0.03 s each)" in result.stderr


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pyethercat", *args],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("args, fragment", [
    (("nosuch",), "No such command"),
    (("--sim", DEMO, "run", "--pcap", "/nonexistent/dir/x.pcapng"), "cannot write the capture"),
    (("demo", "--cycle", "0"), "--cycle must be a positive number"),
])
def test_in_a_child_process_too(args: tuple[str, ...], fragment: str) -> None:
    result = run(*args)
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in result.stderr


def test_help_still_prints_usage_and_exits_zero() -> None:
    result = run("--help")
    assert result.returncode == 0 and result.stdout.startswith("Usage: pyethercat")


def test_a_stale_control_socket_is_taken_over(tmp_path: Path) -> None:
    path = tmp_path / "stale.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(path))
    sock.close()  # the file stays, nobody listens: a simulator that died
    from pyethercat.cli.sim import check_control_path

    check_control_path(str(path))  # no error
