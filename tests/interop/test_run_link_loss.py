"""``pyethercat run`` over a veth pair while the far end goes away (root).

The simulator (``pyethercat sim``, child process) serves the demo segment on
one end of a ``pyecat-`` veth pair; ``pyethercat --iface A run`` cycles on
the other end, as a user would start it. While it runs:

- the far end of the pair goes down for 200 ms, then for 10 s: the run
  survives both, counts the lost cycles, and the slaves whose process-data
  watchdog ran out are back in OP afterwards; at the end the slaves are
  taken to PREOP (orderly stop) and the exit status is 0;
- the master's own interface goes down for 1 s and comes back up: the run
  goes on (sends are refused meanwhile, the frames counted lost) and the
  slaves are back in OP;
- the simulator is killed and started again: the restarted segment (every
  station address 0, INIT) is found and brought back to OP;
- the simulator is killed for good: ``run`` gives up after ``--give-up``
  seconds with one line on stderr and exit status 1.

The 10 s drop makes the first the slowest test of the suite (about 25 s).

No timing is asserted: the counts only have to show that cycles were lost
and counted, and the states that the segment came back.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire.al import AlState

pytestmark = pytest.mark.root

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def wait_for(cond: Callable[[], bool], seconds: float = 30.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


def states(sim: SimProcess) -> list[int]:
    return [s["al_status"] for s in sim.control("slaves")["slaves"]]


def all_in(sim: SimProcess, state: AlState) -> bool:
    try:
        return all(st == state for st in states(sim))
    except OSError:
        return False


def start_run(iface: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pyethercat", "--iface", iface, "run", "--cycle", "1000", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})


def set_link(name: str, state: str) -> None:
    subprocess.run(["ip", "link", "set", name, state], check=True)


def summary_value(out: str, pattern: str) -> re.Match[str]:
    m = re.search(pattern, out, re.M)
    assert m is not None, out
    return m


@pytest.mark.slow
def test_run_survives_a_200ms_and_a_10s_drop_of_the_far_end(
        veth_pair: tuple[str, str]) -> None:
    master_end, sim_end = veth_pair
    with start_sim_process(DEMO, link=f"iface:{sim_end}", realtime=10) as sim:
        run = start_run(master_end, "--seconds", "22")
        try:
            assert wait_for(lambda: all_in(sim, AlState.OP)), "never in OP"
            for drop in (0.2, 10.0):
                time.sleep(1.0)
                set_link(sim_end, "down")
                time.sleep(drop)
                set_link(sim_end, "up")
                # back in OP after the drop (the do8s ran into their watchdog)
                assert wait_for(lambda: all_in(sim, AlState.OP), 15), states(sim)
            out, err = run.communicate(timeout=60)
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
        assert run.returncode == 0, err + out
        assert err == ""
        # both spells counted, with the cycles lost in them
        m = summary_value(out, r"^link: up at the end; down (\d+) times, ([\d.]+) s, "
                               r"(\d+) cycles lost$")
        assert int(m.group(1)) >= 2  # (a loaded host may add a short spell of its own)
        assert float(m.group(2)) >= 10.0
        assert int(m.group(3)) > 0
        lost = int(summary_value(out, r"^WKC errors: \d+, lost frames: (\d+)$").group(1))
        assert lost >= int(m.group(3))
        # the live view's last picture: every slave supervised ok in OP, link up
        rows = [line for line in out.splitlines() if re.match(r"^ \d+\s+│ 0x10", line)]
        assert rows and all(re.search(r"│ OP\s+│ ok", r) for r in rows[-6:]), out
        # the orderly stop took the slaves to PREOP
        assert re.search(r"^stopped: safe outputs for 3 cycles, slaves in PREOP", out, re.M)
        assert all_in(sim, AlState.PREOP), states(sim)


def test_run_survives_its_own_interface_going_down(veth_pair: tuple[str, str]) -> None:
    master_end, sim_end = veth_pair
    with start_sim_process(DEMO, link=f"iface:{sim_end}", realtime=10) as sim:
        run = start_run(master_end)
        try:
            assert wait_for(lambda: all_in(sim, AlState.OP)), "never in OP"
            set_link(master_end, "down")
            time.sleep(1.0)
            set_link(master_end, "up")
            back = wait_for(lambda: all_in(sim, AlState.OP), 30)
            run.send_signal(signal.SIGTERM)
            out, err = run.communicate(timeout=60)
            assert back, f"{states(sim)}\n{out}\n{err}"
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
        assert run.returncode == 0, err + out
        assert err == ""
        m = summary_value(out, r"^link: up at the end; down (\d+) times, ([\d.]+) s, "
                               r"(\d+) cycles lost$")
        assert int(m.group(1)) >= 1 and float(m.group(2)) >= 0.5 and int(m.group(3)) > 0
        assert re.search(r"^stopped: safe outputs for 3 cycles, slaves in PREOP", out, re.M), out
        assert all_in(sim, AlState.PREOP), states(sim)


@pytest.mark.slow
def test_run_finds_a_restarted_segment(veth_pair: tuple[str, str]) -> None:
    master_end, sim_end = veth_pair
    sim = start_sim_process(DEMO, link=f"iface:{sim_end}", realtime=10)
    # --give-up 0: a child process may take long to start on a busy host
    run = start_run(master_end, "--give-up", "0")
    try:
        assert wait_for(lambda: all_in(sim, AlState.OP)), "never in OP"
        # the segment disappears, and a fresh one (station addresses 0, INIT) comes
        sim.process.kill()
        sim.stop()
        time.sleep(0.5)
        sim = start_sim_process(DEMO, link=f"iface:{sim_end}", realtime=10)
        back = wait_for(lambda: all_in(sim, AlState.OP), 30)
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=60)
        assert back, f"{states(sim)}\n{out}\n{err}"
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        sim.stop()
    assert run.returncode == 0, err + out
    assert re.search(r"^link: up at the end; down [1-9]\d* times", out, re.M), out
    assert re.search(r"^stopped: safe outputs for 3 cycles, slaves in PREOP", out, re.M), out


def test_run_gives_up_on_a_dead_segment(veth_pair: tuple[str, str]) -> None:
    master_end, sim_end = veth_pair
    sim = start_sim_process(DEMO, link=f"iface:{sim_end}", realtime=10)
    run = start_run(master_end, "--seconds", "60", "--give-up", "2")
    try:
        assert wait_for(lambda: all_in(sim, AlState.OP)), "never in OP"
        sim.process.kill()  # gone for good: run gives up after 2 s without a frame
        out, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        sim.stop()
    assert run.returncode == 1, err + out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.fullmatch(rf"pyethercat: error: the segment on {master_end} did not come back: "
                        r"no frame returned for [\d.]+ s \(\d+ cycles lost\)", lines[0]), lines
    # the summary was printed all the same, and says the link is down
    assert re.search(r"^link: DOWN at the end; down [1-9]\d* times", out, re.M), out
    assert "slaves not taken to PREOP: the link is down" in out
