"""``--iface`` takes a link name with a scheme: the command line reaches a segment over any
link the registry opens, not only a raw interface.

A simulated segment listens on a ``SOCK_SEQPACKET`` Unix socket path and answers
every frame the master sends there; ``pyethercat --iface unix:PATH slaves`` finds its
slaves. A name without a known scheme stays an interface name.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.link.registry import iface_link
from pyethercat.sim.topology import load_topology

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "examples" / "demo.toml"


def test_interface_names_and_link_names() -> None:
    assert iface_link("eth1") == "raw:eth1"
    assert iface_link("eth0:1") == "raw:eth0:1"  # an alias interface, not a scheme
    assert iface_link("unix:/run/seg.sock") == "unix:/run/seg.sock"
    assert iface_link("udp:10.0.0.2:34980") == "udp:10.0.0.2:34980"
    assert iface_link("ring:eth1,eth2") == "ring:eth1,eth2"
    assert iface_link("raw:eth1") == "raw:eth1"


@pytest.fixture
def unix_segment(tmp_path: Path) -> Iterator[str]:
    """The demo segment answering frames on a Unix SOCK_SEQPACKET socket; yields its path."""
    path = str(tmp_path / "seg.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    listener.bind(path)
    listener.listen(1)
    seg = load_topology(DEMO).build()
    stop = threading.Event()

    def serve() -> None:
        listener.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(0.2)
                while not stop.is_set():
                    try:
                        frame = conn.recv(2048)
                    except TimeoutError:
                        continue
                    if not frame:
                        break
                    reply = seg.process(frame)
                    if reply is not None:
                        conn.send(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield path
    finally:
        stop.set()
        thread.join(5)
        listener.close()


def test_iface_with_a_unix_link_name_reaches_the_segment(unix_segment: str) -> None:
    result = CliRunner().invoke(cli, ["--iface", f"unix:{unix_segment}", "slaves"])
    assert result.exit_code == 0, result.output
    # the same listing as the segment gives in process (--sim)
    same = CliRunner().invoke(cli, ["--sim", str(DEMO), "slaves"])
    assert result.stdout == same.stdout
    lines = result.stdout.splitlines()
    assert len(lines) == len(load_topology(DEMO).slaves) == 6
    assert lines[0].split()[:4] == ["0", "0:0", "INIT", "+"] and "PEC-CU4" in lines[0]


def test_an_unknown_interface_is_a_one_line_error() -> None:
    result = CliRunner().invoke(cli, ["--iface", "pyecat-nosuch0", "slaves"])
    assert result.exit_code != 0
    assert "Traceback" not in result.output
