"""The isolated cyclic engine over a veth pair against ``pyethercat sim`` (root).

A user's process that is stopped (SIGSTOP) does not stop the exchange; a
user's process that is killed leaves the slaves in SAFEOP with their outputs
zero; an engine that is killed makes the next access raise
:class:`EngineDiedError`; SDOs and register reads ride in the engine's
frames while it cycles. The user's processes here are small scripts run by
the test; the test watches the engine through its shared memory, as any
outside reader may. No timed assertions: the checks wait for states with
generous limits.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from pyethercat.errors import EngineDiedError
from pyethercat.master import Master
from pyethercat.master.engine.runner import IsolatedRunner
from pyethercat.master.engine.shared import SharedArea
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import ETHERTYPE_ETHERCAT, decode_frame

pytest.importorskip("pyethercat.sim.server")
from pyethercat.sim.server import SimProcess, start_sim_process  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
_ETH_P_ALL = 0x0003
COE = Path(__file__).resolve().parents[2] / "examples" / "coe.toml"

# The user's program: an isolated master that sets outputs, says where its engine is,
# then does nothing but sleep (the test stops or kills it).
USER = textwrap.dedent("""
    import json, sys, time
    from pyethercat.master import Master
    m = Master.open(iface=sys.argv[1], control=False)
    m.scan()
    m.configure()
    r = m.start(cycle=0.001, isolated=True)
    for name in m.slaves[3].outputs:
        m.slaves[3].outputs[name] = 1
    # Where the do8's output byte travels: the LRW's logical address and the byte in it.
    sc = m.process_data.slaves[3]
    group = m.process_data.groups[0]
    byte = sc.output_bit_offset // 8
    d = next(d for d in group.datagrams if d.offset <= byte < d.offset + d.length)
    print(json.dumps({"area": r.area.path, "engine": r.engine_pid,
                      "lrw": d.logical_address, "at": byte - d.offset}), flush=True)
    while True:
        time.sleep(0.05)
""")


def wait_for(cond: Callable[[], bool], seconds: float = 20.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def demo_sim(veth_pair: tuple[str, str]) -> Iterator[tuple[SimProcess, str]]:
    a, b = veth_pair
    with start_sim_process(DEMO, link=f"iface:{b}", realtime=10) as sim:
        yield sim, a


@pytest.fixture
def user(demo_sim: tuple[SimProcess, str]) -> Iterator[tuple[subprocess.Popen[str], dict[str, object]]]:
    _sim, iface = demo_sim
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-c", USER, iface], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            pytest.fail(f"the user's program did not start: {proc.stderr.read() if proc.stderr else ''}")
        yield proc, json.loads(line)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
        proc.wait()


class OutgoingFrames:
    """Every EtherCAT frame sent out of ``iface`` (the engine's), kept by a thread."""

    def __init__(self, iface: str) -> None:
        # (only a socket for every protocol, ETH_P_ALL, is shown the frames sent)
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(_ETH_P_ALL))
        self.sock.bind((iface, _ETH_P_ALL))
        self.sock.settimeout(0.1)
        self.frames: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            if addr[2] == socket.PACKET_OUTGOING and addr[1] == ETHERTYPE_ETHERCAT:
                self.frames.append(data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def do8_outputs_then_safeop(frames: list[bytes], lrw: int, at: int) -> list[int | str]:
    """The do8's output byte in each LRW sent, and "SAFEOP" where AL control asks for it."""
    out: list[int | str] = []
    for raw in frames:
        for d in decode_frame(raw, strict=False).datagrams:
            if d.command == Command.LRW and d.address == lrw:
                out.append(d.data[at])
            elif (d.command == Command.BWR and d.address >> 16 == R.AL_CONTROL
                    and d.data[0] & 0x0F == int(AlState.SAFEOP)):
                out.append("SAFEOP")
    return out


def al_states(sim: SimProcess) -> set[int]:
    """Every slave's AL status (state and error flag), as the simulator holds it."""
    return {int(s["al_status"]) & 0x1F for s in sim.control("slaves")["slaves"]}


def test_exchange_goes_on_while_the_user_process_is_stopped(
        demo_sim: tuple[SimProcess, str],
        user: tuple[subprocess.Popen[str], dict[str, object]]) -> None:
    proc, where = user
    area = SharedArea.attach(str(where["area"]))
    try:
        def counters() -> dict[str, int]:
            return area.status.as_dict()

        assert wait_for(lambda: counters().get("cycles", 0) > 200)
        before = counters()
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            time.sleep(2.0)
            during = counters()
            health = area.read_health()
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        # The engine went on cycling the whole time and its frames came back whole (a
        # frame or two may be lost to a loaded machine; the slaves' watchdogs, 100 ms,
        # would show a stall)...
        assert during["cycles"] > before["cycles"] + 100
        assert during["g0.exchanges"] > before["g0.exchanges"] + 100
        assert during["wkc_errors"] == before["wkc_errors"]
        assert during["state"] == 1  # running
        # ...and no slave ran into its process-data watchdog meanwhile (supervision saw
        # every one in OP).
        assert health is not None
        assert {int(s) for s in health["status"][:6]} == {0}
        assert proc.poll() is None
    finally:
        area.close()


def test_killed_user_process_leaves_the_slaves_in_safeop_with_zero_outputs(
        demo_sim: tuple[SimProcess, str],
        user: tuple[subprocess.Popen[str], dict[str, object]]) -> None:
    sim, iface = demo_sim
    proc, where = user
    engine = int(str(where["engine"]))
    # The outputs the user set reach the slave.
    assert wait_for(lambda: sim.control("outputs", slave="do8")["data"] == "ff")
    assert al_states(sim) == {int(AlState.OP)}
    wire = OutgoingFrames(iface)
    try:
        assert wait_for(lambda: len(wire.frames) > 20)
        proc.kill()
        proc.wait()
        # The engine notices, sends the safe (zero) outputs, takes the slaves to SAFEOP, ends.
        assert wait_for(lambda: not Path(f"/proc/{engine}").exists())
    finally:
        wire.close()
    # Every slave in SAFEOP without an error flag (not a watchdog's SAFEOP+ERR)...
    assert al_states(sim) == {int(AlState.SAFEOP)}
    # ...and on the wire: the user's outputs, then at least three cycles of the safe
    # ones (zero), and only then the request for SAFEOP, while the outputs stay zero.
    seen = do8_outputs_then_safeop(wire.frames, int(str(where["lrw"])), int(str(where["at"])))
    assert "SAFEOP" in seen
    asked = seen.index("SAFEOP")
    before = seen[:asked]
    assert before[0] == 0xFF
    first_zero = len(before) - before[::-1].index(0xFF)
    assert set(before[first_zero:]) == {0} and len(before) - first_zero >= 3
    assert set(seen[asked:]) <= {0, "SAFEOP"}


def test_engine_exits_when_the_user_dies_while_the_link_refuses_frames(
        demo_sim: tuple[SimProcess, str],
        user: tuple[subprocess.Popen[str], dict[str, object]]) -> None:
    # The engine's interface is down (its frames are refused, no cycle comes back) when
    # the user's process is killed: no slave can be reached, yet the engine must notice
    # that its parent is gone and exit rather than spin on as an orphan.
    _sim, iface = demo_sim
    proc, where = user
    engine = int(str(where["engine"]))
    assert Path(f"/proc/{engine}").exists()
    area = SharedArea.attach(str(where["area"]))
    try:
        assert wait_for(lambda: area.status.as_dict().get("cycles", 0) > 50)
        subprocess.run(["ip", "link", "set", iface, "down"], check=True)
        assert wait_for(lambda: area.status.as_dict().get("send_errors", 0) > 20)
    finally:
        area.close()
    proc.kill()
    proc.wait()
    # (generous: the engine gives up the leave a few seconds after it noticed)
    assert wait_for(lambda: not _alive(engine), seconds=60.0)


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie awaiting its reaper is not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False


def test_dead_engine_raises_on_the_next_access(demo_sim: tuple[SimProcess, str]) -> None:
    _sim, iface = demo_sim
    with Master.open(iface=iface, control=False, timeout=0.5) as m:
        m.scan()
        m.configure()
        r = m.start(cycle=0.001, isolated=True)
        assert isinstance(r, IsolatedRunner)
        assert r.engine_pid is not None
        assert m.slaves[2].inputs["Input 1"] in (True, False)
        os.kill(r.engine_pid, signal.SIGKILL)

        def raises() -> bool:
            try:
                m.slaves[2].inputs["Input 1"]
            except EngineDiedError:
                return True
            return False

        assert wait_for(raises)
        with pytest.raises(EngineDiedError, match="killed by signal 9"):
            m.slaves[3].outputs["Output 1"] = 1
        with pytest.raises(EngineDiedError):
            r.join()
        r.stop()
        # Back to the master's own link: it reaches the slaves again.
        assert m.read(0, R.AL_STATUS, 2)


def test_sdos_ride_in_the_engine_frames(veth_pair: tuple[str, str]) -> None:
    a, b = veth_pair
    # (a generous mailbox timeout: a request unanswered within half of it is sent again,
    # and on a loaded machine the answer to the first copy could then meet the next SDO)
    with start_sim_process(COE, link=f"iface:{b}", realtime=10), \
            Master.open(iface=a, control=False, mailbox_timeout=5.0) as m:
        m.scan()
        m.configure()
        r = m.start(cycle=0.001, isolated=True)
        try:
            assert isinstance(r, IsolatedRunner)
            io = m.slaves[0]
            vendor = io.sdo_read(0x1018, 1, "uint32")
            assert vendor == m.slaves[0].identity.vendor_id
            for k in range(20):
                io.sdo_write(0x8000, 1, 100 + k, "uint16")
                assert io.sdo_read(0x8000, 1, "uint16") == 100 + k
            st = r.status()
            assert st["user_frames"] >= 40
            stats = r.stats
            # (a frame may be lost to a loaded machine; a wrong working counter is a fault)
            assert stats.wkc_errors == 0
            assert m.read(1, R.AL_STATUS, 2)[0] & 0x0F == int(AlState.OP)
        finally:
            r.stop()


def test_telemetry_of_an_isolated_loop(demo_sim: tuple[SimProcess, str]) -> None:
    """The dashboard's reader on a loop in the engine (``run --web``): no ring watch rides
    that loop, so telemetry diagnoses the segment itself (a cut shows, and goes again), and
    the DC figures are the engine's lock and monitor, not this process's unused copy."""
    from pyethercat.master.telemetry import Telemetry

    sim, iface = demo_sim
    with Master.open(iface=iface, control=False, timeout=0.5) as m:
        m.scan()
        m.configure()
        m.dc.setup()
        r = m.start(cycle=0.001, isolated=True, dc="master", realtime=0)
        try:
            assert isinstance(r, IsolatedRunner) and not r.riders
            tel = Telemetry(m, max_rate=0, register_rate=0)

            def answering(snap: object) -> list[bool]:
                return [s.answered for s in snap.slaves]  # type: ignore[attr-defined]

            assert wait_for(lambda: all(answering(tel.snapshot())))
            assert wait_for(lambda: r.status()["dc_last_ns"] != -(1 << 63))
            dc = tel.snapshot().dc
            assert dc.mode == "master" and r.dc_status() is not None
            assert dc.monitor_last_ns is not None  # this process's copy never reads 0x092C
            sim.control("break_link", slave="di8", port=1)
            try:
                assert wait_for(lambda: answering(tel.snapshot())[3:] == [False] * 3)
                snap = tel.snapshot()
                assert any(f.kind == "cut" and [2, 1] in f.ends for f in snap.faults)
            finally:
                sim.control("restore_link", slave="di8", port=1)
            assert wait_for(lambda: all(answering(tel.snapshot())), 60)
        finally:
            r.stop()
