"""The isolated engine's real-time settings: what it got, and what it says it could not get.

Over a veth pair against ``pyethercat sim`` (root). With the privileges the
engine process runs under SCHED_FIFO on the CPU asked for with its memory
locked, as the kernel reports it from outside. Without them (the user's
program started without CAP_SYS_NICE and CAP_IPC_LOCK, RLIMIT_RTPRIO 0, a
64 KiB RLIMIT_MEMLOCK, and a CPU it may not use) the engine runs at normal
priority all the same, and says, in ``realtime_missing`` and in its log, what
was refused and what would allow it.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from pyethercat.master import Master
from pyethercat.master.engine.runner import IsolatedRunner

pytest.importorskip("pyethercat.sim.server")
from pyethercat.sim.server import SimProcess, start_sim_process  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
# A CPU no machine running this has: pinning to it is refused.
NO_SUCH_CPU = 4095

# The user's program: an isolated master asking for everything; it reports what it got,
# as its runner and the kernel tell, after a few hundred cycles.
USER = textwrap.dedent("""
    import json, os, sys
    from pyethercat.master import Master
    m = Master.open(iface=sys.argv[1], control=False, timeout=0.5)
    m.scan()
    m.configure()
    r = m.start(cycle=0.001, isolated=True, realtime=40, cpu=int(sys.argv[2]),
                lock_memory=True)
    try:
        r.run(cycles=300)
        st = r.status()
        print(json.dumps({
            "text": r.realtime_text, "missing": r.realtime_missing,
            "events": [e.text for e in r.events], "line": r.engine_line(),
            "policy": os.sched_getscheduler(r.engine_pid),
            "status": {k: st[k] for k in ("priority", "cpu", "locked", "cycles",
                                          "g0.exchanges", "wkc_errors")}}), flush=True)
    finally:
        r.stop()
""")


@pytest.fixture
def demo_sim(veth_pair: tuple[str, str]) -> Iterator[tuple[SimProcess, str]]:
    a, b = veth_pair
    with start_sim_process(DEMO, link=f"iface:{b}", realtime=10) as sim:
        yield sim, a


def _locked_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    return 0


def test_engine_gets_sched_fifo_its_cpu_and_locked_memory(
        demo_sim: tuple[SimProcess, str]) -> None:
    _sim, iface = demo_sim
    cpu = max(os.sched_getaffinity(0))
    with Master.open(iface=iface, control=False, timeout=0.5) as m:
        m.scan()
        m.configure()
        r = m.start(cycle=0.001, isolated=True, realtime=40, cpu=cpu, lock_memory=True)
        try:
            assert isinstance(r, IsolatedRunner) and r.engine_pid is not None
            pid = r.engine_pid
            assert r.realtime_missing == []
            assert r.realtime_text == f"SCHED_FIFO 40, CPU {cpu}, memory locked"
            # What the kernel says of the engine's process, not what it says of itself.
            assert os.sched_getscheduler(pid) == os.SCHED_FIFO
            assert os.sched_getparam(pid).sched_priority == 40
            assert os.sched_getaffinity(pid) == {cpu}
            assert _locked_kib(pid) > 0
            # This process is left as it was.
            assert os.sched_getscheduler(0) == os.SCHED_OTHER
            assert f"SCHED_FIFO 40, CPU {cpu}, memory locked" in r.engine_line()
        finally:
            r.stop()


def test_engine_without_privileges_says_what_was_refused_and_runs_anyway(
        demo_sim: tuple[SimProcess, str]) -> None:
    setpriv, prlimit = shutil.which("setpriv"), shutil.which("prlimit")
    if setpriv is None or prlimit is None:
        pytest.skip("needs setpriv and prlimit (util-linux)")
    _sim, iface = demo_sim
    # The user's program (and so its engine) without CAP_SYS_NICE and CAP_IPC_LOCK, even
    # as root: out of the bounding set, no real-time priority and 64 KiB of locked
    # memory allowed by the limits. CAP_NET_RAW stays: the raw socket opens.
    drop = "-sys_nice,-ipc_lock"
    cmd = [setpriv, f"--inh-caps={drop}", f"--bounding-set={drop}",
           prlimit, "--rtprio=0", "--memlock=65536",
           sys.executable, "-c", USER, iface, str(NO_SUCH_CPU)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["text"] == "normal scheduling, any CPU, memory not locked"
    missing = got["missing"]
    # One line per refusal, each naming what would allow it.
    assert len(missing) == 3, missing
    fifo = next(w for w in missing if w.startswith("SCHED_FIFO 40 refused"))
    assert re.search(r"RLIMIT_RTPRIO 0\b", fifo) and "root" in fifo
    assert "CAP_SYS_NICE" in fifo and "'ulimit -r' to 40" in fifo
    lock = next(w for w in missing if w.startswith("mlockall refused"))
    assert "RLIMIT_MEMLOCK 64 KiB" in lock and "CAP_IPC_LOCK" in lock and "'ulimit -l'" in lock
    cpu = next(w for w in missing if w.startswith(f"CPU {NO_SUCH_CPU} "))
    assert f"is not among the CPUs this process may use ({sorted(os.sched_getaffinity(0))})" in cpu
    # The engine's log says the same...
    for why in missing:
        assert f"real time: {why}" in got["events"]
    # ...and it ran at normal priority, on any CPU, and exchanged all the same.
    assert got["policy"] == os.SCHED_OTHER
    assert got["status"]["priority"] == 0 and got["status"]["cpu"] == -1
    assert got["status"]["locked"] == 0
    # (a frame may be lost to a loaded machine; a wrong working counter is a fault)
    assert got["status"]["cycles"] >= 300 and got["status"]["g0.exchanges"] > 0
    assert got["status"]["wkc_errors"] == 0
    assert "normal priority, any CPU" in got["line"]
