"""Distributed clocks against SOEM (pysoem) over a veth pair: delays, and SYNC0 from dc_sync().

``pyethercat sim`` serves the 20-slave tree of examples/dc-tree-20.toml (a
cross, forks on ports 1-3, +-100 ppm oscillators) on one end of a veth pair.
SOEM's ``config_dc()`` and our master's set-up each measure the delays and
write them to 0x0928; both sets must agree within 10 ns per slave and with
the simulator's own walk times within 10 ns.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT, SIM_REALTIME

from pyethercat.master.dc import DcSettings
from pyethercat.master.master import Master
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire import registers as R

pysoem = pytest.importorskip("pysoem")

TREE = Path(__file__).resolve().parents[2] / "examples" / "dc-tree-20.toml"


@pytest.fixture
def served(veth_pair: tuple[str, str]) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    handle = start_sim_process(TREE, link=f"iface:{sim_end}", realtime=SIM_REALTIME)
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def true_delays(handle: SimProcess) -> list[int]:
    """The simulator's delays, in ring order, behind the first slave (the reference)."""
    report = handle.control("dc")["slaves"]
    epu = sorted(s["epu_ns"] for s in report)  # ring order = order of the walk here
    return [t - epu[0] for t in epu]


@pytest.mark.root
def test_soem_and_our_master_write_the_same_delays(served: tuple[SimProcess, str]) -> None:
    handle, iface = served
    truth = true_delays(handle)
    master = pysoem.Master()
    master.open(iface)
    try:
        assert master.config_init() == 20
        assert master.config_dc()
        soem = [struct.unpack("<I", s._fprd(R.DC_SYSTEM_TIME_DELAY, 4, 2000))[0]
                for s in master.slaves]
    finally:
        master.close()
    with Master.open(iface, timeout=SIM_FRAME_TIMEOUT) as m:
        m.scan()
        report = m.dc.setup(DcSettings(static_sync=1000))
        ours = [struct.unpack("<I", r.data)[0] for r in m.read_many(R.DC_SYSTEM_TIME_DELAY, 4)]
    assert [s.delay_ns for s in report.slaves] == ours
    print("truth", truth, "\nsoem ", soem, "\nours ", ours)
    for k in range(1, 20):
        assert abs(ours[k] - soem[k]) <= 10, (k, ours[k], soem[k])
        assert abs(ours[k] - truth[k]) <= 10, (k, ours[k], truth[k])
        assert abs(soem[k] - truth[k]) <= 10, (k, soem[k], truth[k])


@pytest.mark.root
def test_soem_dc_sync_makes_sync0_at_its_cycle(served: tuple[SimProcess, str]) -> None:
    handle, iface = served
    master = pysoem.Master()
    master.open(iface)
    try:
        assert master.config_init() == 20
        assert master.config_dc()
        slave = master.slaves[5]  # a terminal
        cycle = 500_000
        before = time.monotonic()
        slave.dc_sync(1, cycle)
        after = time.monotonic()
        start = struct.unpack("<Q", slave._fprd(R.DC_START_TIME, 8, 2000))[0]
        # SOEM's first pulse: a whole multiple of the cycle, 100 ms ahead
        assert start % cycle == 0
        time.sleep(0.6)
        for _ in range(5):  # frames make the simulator tick (its own timer does too)
            master.read_state()
            time.sleep(0.05)
        asked = time.monotonic()
        report = handle.control("dc")["slaves"]
        answered = time.monotonic()
    finally:
        master.close()
    pulses = [s for s in report if s["sync0_pulses"]]
    assert len(pulses) == 1
    fired = pulses[0]
    last_sys, _true = fired["last_sync0"]
    assert (last_sys - start) % cycle == 0
    # one pulse per cycle since the start time, 100 ms after dc_sync() (the
    # simulator's clock is the host's: 20 ms of slack for its tick timer)
    n = fired["sync0_pulses"]
    assert n == (last_sys - start) // cycle + 1
    assert (asked - after - 0.1 - 0.02) / 1e-9 / cycle <= n <= (answered - before - 0.1 + 0.02) / 1e-9 / cycle


@pytest.mark.root
def test_dc_and_run_dc_commands_over_veth(served: tuple[SimProcess, str], tmp_path: Path,
                                          patient_cli: None) -> None:
    """``pyethercat dc`` and ``run --dc`` against ``pyethercat sim`` on the other end of the pair."""
    from click.testing import CliRunner

    from pyethercat.cli.main import cli

    handle, iface = served
    truth = true_delays(handle)
    result = CliRunner().invoke(cli, ["--iface", iface, "dc", "--static", "1500", "--sync0", "1000"],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.output.splitlines() if line[:1].isdigit()]
    assert len(rows) == 20 and rows[0][3] == "*"
    delays = [int(r[6]) for r in rows]
    assert all(abs(d - t) <= 10 for d, t in zip(delays, truth, strict=True)), (delays, truth)
    terminals = [r for r in rows if "SYNC0" in r]
    assert len(terminals) == 16  # every terminal; the four couplers have no DC op mode
    plot = tmp_path / "run.png"
    result = CliRunner().invoke(cli, ["--iface", iface, "run", "--dc", "--cycle", "1000",
                                      "--seconds", "2", "--plot", str(plot)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    dc_lines = [line for line in result.output.splitlines() if line.startswith("DC master: ")]
    assert dc_lines and "WKC errors: 0" in result.output
    assert plot.read_bytes()[:4] == b"\x89PNG"
    # the simulator's pulses came at the asked cycle on every terminal
    report = handle.control("dc")["slaves"]
    pulsing = [s for s in report if s["sync0_pulses"]]
    assert len(pulsing) == 16
    last = {s["last_sync0"][0] for s in pulsing}
    assert all((t - min(last)) % 1_000_000 == 0 for t in last)
