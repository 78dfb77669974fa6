"""The isolated cyclic engine over a veth pair against ``pyethercat sim`` (root).

A user's process that is stopped (SIGSTOP) does not stop the exchange, and
slaves cut off meanwhile come back once it continues; a user's process that
is killed leaves the slaves in SAFEOP with their outputs zero (those it can
reach, when some are cut off); an engine that is killed makes the next
access raise :class:`EngineDiedError`; SDOs, FoE, EoE and register reads
ride in the engine's frames while it cycles, the mailbox status bytes with
the process image. The user's processes here are small scripts run by
the test; the test watches the engine through its shared memory, as any
outside reader may. No timed assertions: the checks wait for states with
generous limits.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
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
from eoe_helpers import arp_request, ping

from pyethercat.errors import EngineDiedError, EtherCATError
from pyethercat.master import Master
from pyethercat.master.engine.runner import IsolatedRunner
from pyethercat.master.engine.shared import HEALTH_STATUS, SharedArea
from pyethercat.master.eoe import EoeService, eoe_clients
from pyethercat.master.foe import FoeClient
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import ETHERTYPE_ETHERCAT, decode_frame
from pyethercat.wire.pcap import read_pcap

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
        where = json.loads(line)
        yield proc, where
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
        proc.wait()
    # Its engine takes the slaves to SAFEOP and ends (not left for the run's clean-up).
    wait_for(lambda: not _alive(int(where["engine"])), seconds=60.0)


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


def test_slaves_cut_off_while_the_user_process_is_stopped_come_back_after_it_continues(
        demo_sim: tuple[SimProcess, str],
        user: tuple[subprocess.Popen[str], dict[str, object]]) -> None:
    # Bringing a slave back is the user's master's work (its configuration): while that
    # process is stopped the engine exchanges with the slaves it reaches and asks, and
    # the asking waits. The do8 behind the cut falls to SAFEOP with an error (its own
    # watchdog) and waits for the user's process; the input-only di2 and ai2 never left
    # OP and are back as soon as the cable is.
    sim, _iface = demo_sim
    proc, where = user
    area = SharedArea.attach(str(where["area"]))

    def states() -> dict[str, int]:
        return {s["name"]: int(s["al_status"]) & 0x1F for s in sim.control("slaves")["slaves"]}

    def health() -> list[str]:
        table = area.read_health()
        return [] if table is None else [HEALTH_STATUS[int(s)] for s in table["status"][:6]]

    try:
        assert wait_for(lambda: set(states().values()) == {int(AlState.OP)})
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            sim.control("break_link", slave="di8", port=1)
            assert wait_for(lambda: health()[3:] != ["ok"] * 3 and health()[:3] == ["ok"] * 3)
            assert wait_for(lambda: states()["do8"] == int(AlState.SAFEOP) | R.AL_ERROR_FLAG)
            before = area.status.as_dict()["cycles"]
            sim.control("restore_link", slave="di8", port=1)
            assert wait_for(lambda: health()[4:] == ["ok"] * 2)
            # (the engine went on cycling; the do8 waits for the stopped process)
            assert area.status.as_dict()["cycles"] > before
            assert health()[3] == "recovering"
            assert states()["do8"] == int(AlState.SAFEOP) | R.AL_ERROR_FLAG
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        assert wait_for(lambda: health() == ["ok"] * 6, seconds=60.0)
        assert set(states().values()) == {int(AlState.OP)}
        _serial, events = area.events_since(0)
    finally:
        area.close()
    assert any(text.startswith("slave 3 (0x1004) back in OP") or
               text.startswith("slave 3 back in OP") for _t, text in events), events


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
        # The states the live view shows are the engine's supervision's (this process's
        # sees no frame)...
        assert wait_for(lambda: [r.slave_state(p) for p in range(6)] == [int(AlState.OP)] * 6)
        os.kill(r.engine_pid, signal.SIGKILL)

        def raises() -> bool:
            try:
                m.slaves[2].inputs["Input 1"]
            except EngineDiedError:
                return True
            return False

        assert wait_for(raises)
        # ...and unknown once it is dead.
        assert r.slave_state(0) is None
        with pytest.raises(EngineDiedError, match="killed by signal 9"):
            m.slaves[3].outputs["Output 1"] = 1
        with pytest.raises(EngineDiedError):
            r.join()
        r.stop()
        # Back to the master's own link: it reaches the slaves again.
        assert m.read(0, R.AL_STATUS, 2)


@contextlib.contextmanager
def coe_engine(veth_pair: tuple[str, str]) -> Iterator[tuple[Master, IsolatedRunner]]:
    """The CoE example segment served on one end of ``veth_pair``, our master on the
    other with its loop in the engine at 1 kHz (stopped in order afterwards)."""
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
            yield m, r
        finally:
            r.stop()


def test_sdos_ride_in_the_engine_frames(veth_pair: tuple[str, str]) -> None:
    with coe_engine(veth_pair) as (m, r):
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


def test_engine_survives_its_interface_going_down_while_user_requests_are_out(
        veth_pair: tuple[str, str]) -> None:
    """The user's reads (two 1000-byte FPRDs a frame: one rides behind the cyclic frame
    in a frame of its own) go on while the engine's interface is taken down three times.
    The engine's sends and receives between cycles then fail: the requests fail with
    them (the user's scheduler times them out), the engine keeps cycling, and an SDO
    works afterwards. (An unguarded flush between cycles made the engine exit.)"""
    a, _b = veth_pair
    with coe_engine(veth_pair) as (m, r):
        station = m.slaves[0].station_address
        stop = threading.Event()
        done: list[int] = []
        failed: list[str] = []

        def reader() -> None:
            while not stop.is_set():
                try:
                    m.scheduler.transact(
                        [Datagram.device(Command.FPRD, station, 0x1000, 1000)] * 2)
                    done.append(1)
                except EtherCATError as exc:
                    failed.append(type(exc).__name__)

        t = threading.Thread(target=reader)
        t.start()
        try:
            assert wait_for(lambda: len(done) >= 20)
            for _ in range(3):
                subprocess.run(["ip", "link", "set", a, "down"], check=True)
                time.sleep(0.4)
                subprocess.run(["ip", "link", "set", a, "up"], check=True)
                time.sleep(0.6)
            before = len(done)
            assert wait_for(lambda: len(done) >= before + 20)
        finally:
            stop.set()
            t.join()
        assert r.running and r.engine_state == "running", r.engine_state
        assert set(failed) <= {"TimeoutError", "LinkDownError", "LinkError"}, failed
        assert m.slaves[0].sdo_read(0x1018, 1, "uint32") == m.slaves[0].identity.vendor_id


# A CoE I/O that serves FoE from a folder, and the seed 002 drive as an EoE endpoint
# (128-byte mailboxes: a full Ethernet frame is 16 fragments each way).
FOE_EOE = """
[[slave]]
name = "io"
device = "builtin:coe-io"
foe = true
foe_dir = "{folder}"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = {{ ip = "10.9.0.3/24" }}
"""


def test_foe_and_eoe_ride_in_the_engine_frames(tmp_path: Path) -> None:
    folder = tmp_path / "foe"
    folder.mkdir()
    down = random.Random(18).randbytes(3000)
    (folder / "down.bin").write_bytes(down)
    topo = tmp_path / "foe-eoe.toml"
    topo.write_text(FOE_EOE.format(folder=folder))
    pcap = tmp_path / "sim.pcap"
    # (the simulator on a Unix socketpair: the engine takes any link over one socket;
    # both under SCHED_FIFO and a generous frame timeout, as a loaded machine needs)
    with start_sim_process(topo, pcap=pcap, realtime=10) as sim, \
            Master(sim.link, owns_link=False, timeout=0.5, mailbox_timeout=5.0) as m:
        m.scan()
        m.configure()
        r = m.start(cycle=0.001, isolated=True)
        started_ns = time.time_ns()
        try:
            assert isinstance(r, IsolatedRunner)
            carried = r.status()["user_frames"]
            # FoE: a file written lands in the simulator's folder; one read comes back whole.
            foe = m.slaves[0].client(FoeClient)
            up = random.Random(19).randbytes(5000)
            foe.write("up.bin", up)
            assert (folder / "up.bin").read_bytes() == up
            assert foe.read("down.bin") == down
            assert r.status()["user_frames"] - carried >= foe.stats.packets
            # EoE as `run --eoe` moves it: ticking from the runner's callback, which here
            # runs in this process after the engine's cycles, with the drive's SM1 status
            # byte read from the shared image.
            clients = eoe_clients(m.slaves)
            assert set(clients) == {1}
            drive = clients[1]
            got: list[bytes] = []
            drive.on_frame = got.append
            offsets = {p: (r.config.slaves[p].group, r.config.slaves[p].mailbox_status_offset)
                       for p in clients}
            assert offsets[1][1] >= 0
            svc = EoeService(m.scheduler, [drive])
            svc.attach(r, offsets)
            try:
                drive.send(arp_request(bytes([10, 9, 0, 3])))
                assert wait_for(lambda: len(got) == 1)
                reply = got.pop()
                assert reply[12:14] == b"\x08\x06" and reply[20:22] == b"\x00\x02"
                frame = ping(reply[22:28], bytes([10, 9, 0, 3]), 1472, 1)
                drive.send(frame)
                assert wait_for(lambda: len(got) == 1), (drive.stats, m.scheduler.stats,
                                                         r.status())
                echo = got.pop()
                assert len(echo) == len(frame)
                assert echo[34] == 0 and echo[42:] == frame[42:]  # ICMP echo reply, same data
            finally:
                svc.stop()
            assert drive.stats.tx.fragments >= 16 and drive.stats.rx.fragments >= 16
            assert r.stats.wkc_errors == 0
            boxes = [m.mailboxes.mailbox_of(p) for p in (0, 1)]
        finally:
            r.stop()
    # On the wire, from the engine's start on: the EoE fragments reached the drive's SM0,
    # and no frame polled an SM1 status register (0x080D): every mailbox status came with
    # the process image.
    with pcap.open("rb") as f:
        sent = [decode_frame(rec.data, strict=False) for rec in read_pcap(f)
                if rec.timestamp_ns >= started_ns]
    dgs = [d for fr in sent for d in fr.datagrams]
    io_box, drive_box = boxes
    assert io_box is not None and drive_box is not None
    assert any(d.command == Command.FPWR and d.adp == drive_box.station
               and d.ado == drive_box.rx_offset for d in dgs)
    polls = {(b.station, b.status_address) for b in boxes if b is not None}
    assert not any(d.command == Command.FPRD and (d.adp, d.ado) in polls for d in dgs)


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


def test_killed_user_with_slaves_cut_off_leaves_the_reachable_ones_in_safeop(
        demo_sim: tuple[SimProcess, str],
        user: tuple[subprocess.Popen[str], dict[str, object]]) -> None:
    # The slaves behind the di8's port 1 (do8, di2, ai2) drop out while the user's process
    # lives, and it dies before they are back. The engine cannot bring them back (the
    # configuration is the dead process's): it takes the three it reaches to SAFEOP, says
    # that three did not answer, and exits. Of the three cut off, the do8 (outputs) was
    # taken to SAFEOP with an error by its own process-data watchdog (ETG.1000.6 AL status
    # code 0x001B); the input-only di2 and ai2 have none and are still in OP when the
    # cable is back.
    sim, _iface = demo_sim
    proc, where = user
    engine = int(str(where["engine"]))
    area = SharedArea.attach(str(where["area"]))

    def states() -> dict[str, int]:
        return {s["name"]: int(s["al_status"]) & 0x1F for s in sim.control("slaves")["slaves"]}

    reachable = ("coupler", "branch-do8", "di8")
    try:
        assert wait_for(lambda: set(states().values()) == {int(AlState.OP)})
        sim.control("break_link", slave="di8", port=1)

        def cut_off() -> bool:
            health = area.read_health()
            return health is not None and [bool(p) for p in health["present"][:6]] == [
                True, True, True, False, False, False]

        assert wait_for(cut_off)
        proc.kill()
        proc.wait()
        assert wait_for(lambda: not _alive(engine), seconds=60.0)
        _serial, events = area.events_since(0)
    finally:
        area.close()
    texts = [text for _t, text in events]
    assert any("safe outputs, then SAFEOP" in t for t in texts), texts
    # (the BRD's working counter: the slaves it reached, none of them in OP)
    assert "3 of 6 slaves in SAFEOP; 3 did not answer and stay as they were" in texts, texts
    assert {n: s for n, s in states().items() if n in reachable} == dict.fromkeys(
        reachable, int(AlState.SAFEOP))
    sim.control("restore_link", slave="di8", port=1)
    # (the engine may have ended within the do8's watchdog time, 100 ms)
    assert wait_for(lambda: states()["do8"] == int(AlState.SAFEOP) | R.AL_ERROR_FLAG)
    after = states()
    assert after["di2"] == after["ai2"] == int(AlState.OP)
