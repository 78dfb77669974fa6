"""``run`` and ``demo`` ended by real signals (SIGINT as Ctrl-C sends it, SIGTERM).

Each command runs in a child process, as a user starts it; once it says it
is cycling, the test sends the signal. The command must end in order: final
statistics and the stop report printed, exit status 0, and the capture file
closed and complete. The capture shows the orderly stop on the wire: the
last cyclic frames before the first state request carry the safe (zero)
outputs while earlier ones carried the demo's toggled outputs, then every
slave is requested to SAFEOP and then to PREOP (or ``--final-state``).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pyethercat.cli._connect import connect
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import MASTER_MAC, decode_frame
from pyethercat.wire.pcap import read_capture
from pyethercat.wire.registers import AL_CONTROL

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
_WRITES = (Command.FPWR, Command.APWR, Command.BWR)


def start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "pyethercat", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def signal_when(p: subprocess.Popen[str], marker: str, sig: signal.Signals) -> str:
    """Read stdout until a line holds ``marker``, let it cycle a moment, send ``sig``."""
    assert p.stdout is not None
    seen = []
    deadline = time.monotonic() + 60
    for line in p.stdout:
        seen.append(line)
        if marker in line:
            break
        assert time.monotonic() < deadline, "".join(seen)
    else:
        pytest.fail("the command ended before cycling: " + "".join(seen))
    time.sleep(0.5)
    p.send_signal(sig)
    return "".join(seen)


def outbound(pcap: Path) -> list[list]:
    """Datagrams of every frame the master sent, in order (the capture must be whole)."""
    with pcap.open("rb") as f:
        records = list(read_capture(f))
    return [decode_frame(r.data).datagrams for r in records if r.data[6:12] == MASTER_MAC]


def al_requests(frames: list[list]) -> list[tuple[int, int]]:
    """(frame number, requested state) of every AL control write."""
    out = []
    for n, dgs in enumerate(frames):
        for d in dgs:
            if d.command in _WRITES and not d.is_logical and d.ado == AL_CONTROL:
                out.append((n, d.data[0] & 0x0F))
    return out


def walk(requests: list[tuple[int, int]], since: int = 0) -> list[int]:
    """The requested states from frame ``since`` on, repeats (one per slave) collapsed."""
    out: list[int] = []
    for n, state in requests:
        if n >= since and (not out or out[-1] != state):
            out.append(state)
    return out


def output_bytes() -> int:
    with connect({"sim": str(DEMO)}) as conn:
        conn.master.scan()
        return conn.master.configure().groups[0].output_bytes


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_run_ends_in_order_on_a_signal(tmp_path: Path, sig: signal.Signals) -> None:
    pcap = tmp_path / "run.pcapng"
    p = start("--sim", str(DEMO), "run", "--cycle", "2000", "--pcap", str(pcap),
              "--final-state", "INIT")
    try:
        head = signal_when(p, "cycling every 2000 us", sig)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    out = head + out
    assert p.returncode == 0, err + out
    assert err == ""
    assert f"ended by {sig.name}" in out
    assert re.search(r"^cycles: \d+ at 2000 us", out, re.M), out
    assert re.search(r"^WKC errors: 0, lost frames: 0$", out, re.M), out
    assert re.search(r"^stopped: safe outputs for 3 cycles, slaves in INIT \(\d+ ms\)$", out,
                     re.M), out
    frames = outbound(pcap)
    requests = al_requests(frames)
    # the walk down at the end: SAFEOP while cycling, then INIT (SAFEOP -> INIT is a
    # transition of its own), nothing after
    assert walk(requests)[-3:] == [AlState.OP, AlState.SAFEOP, AlState.INIT]


def test_demo_prints_statistics_and_capture_on_ctrl_c(tmp_path: Path) -> None:
    pcap = tmp_path / "demo.pcapng"
    p = start("demo", "--seconds", "60", "--cycle", "2000", "--pcap", str(pcap))
    try:
        head = signal_when(p, "slaves in OP after", signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    out = head + out
    assert p.returncode == 0, err + out
    assert "ended early by SIGINT" in out
    assert re.search(r"^cycles: \d+ at 2000 us", out, re.M), out
    assert re.search(r"loop-back checks: \d+, mismatches: 0", out), out
    assert re.search(r"^stopped: safe outputs for 3 cycles, slaves in PREOP", out, re.M), out
    assert f"capture written to {pcap}" in out
    frames = outbound(pcap)
    requests = al_requests(frames)
    # the first SAFEOP request after OP is the stop's
    op_at = max(n for n, state in requests if state == AlState.OP)
    first_down = next(n for n, state in requests if n > op_at)
    assert walk(requests, first_down) == [AlState.SAFEOP, AlState.PREOP]
    # the cyclic frames: the demo's toggled outputs, then the safe (zero) outputs
    n_out = output_bytes()
    cyclic = [(n, d.data[:n_out]) for n, dgs in enumerate(frames) for d in dgs[:1]
              if d.command == Command.LRW]
    before = [data for n, data in cyclic if n < first_down]
    assert any(data != bytes(n_out) for data in before), "the demo never toggled outputs"
    assert before[-3:] == [bytes(n_out)] * 3
