"""What keeps a polling loop from being stalled: the spin budget and the quiet collector.

A SCHED_FIFO loop that polls past the kernel's real-time share, or a vCPU
that spins through its host's time slice, is taken off the CPU for
milliseconds; a full garbage collection walks every long-lived object. Both
stalled the simulator for 10-36 ms and broke SOEM's segmented transfers
(its mailbox time-out is 20 ms).
"""

from __future__ import annotations

import gc
import time
from pathlib import Path

import pytest

from pyethercat.realtime import VM_SPIN_SHARE, SpinBudget, idle_halt_hint, quiet_collector, rt_share
from pyethercat.sim.server import SimServer


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_budget_allows_its_share_of_each_period_then_refuses_until_the_next() -> None:
    clock = _Clock()
    budget = SpinBudget(0.25, period=1.0, clock=clock)
    assert budget.allowed(clock.t)
    budget.spent(0.2)
    clock.t += 0.3
    assert budget.allowed(clock.t)  # 0.2 of 0.25 spent
    budget.spent(0.06)
    clock.t += 0.1
    assert not budget.allowed(clock.t)  # 0.26 spent: block for the rest of the period
    clock.t += 0.59
    assert not budget.allowed(clock.t)
    clock.t += 0.02  # a new period (1.01 s after the first)
    assert budget.allowed(clock.t)
    budget.spent(0.24)
    assert budget.allowed(clock.t)


def _machine(monkeypatch: pytest.MonkeyPatch, *, rt_limit: float | None = 0.95,
             realtime: bool = True, vm: bool = False) -> None:
    """What the budget sees of the kernel and the process: the real-time share
    (None: sched_rt_runtime_us = -1), the policy, and whether a hypervisor runs it."""
    import pyethercat.realtime as rt

    monkeypatch.setattr(rt, "rt_share", lambda: rt_limit)
    monkeypatch.setattr(rt, "running_realtime", lambda: realtime)
    monkeypatch.setattr(rt, "on_virtual_machine", lambda: vm)


def test_budget_for_this_process_keeps_below_the_kernel_and_the_vm_share(monkeypatch: pytest.MonkeyPatch) -> None:
    _machine(monkeypatch)
    budget = SpinBudget.for_this_process()
    assert budget is not None and budget.share == pytest.approx(0.75)
    _machine(monkeypatch, vm=True)
    budget = SpinBudget.for_this_process()
    assert budget is not None and budget.share == VM_SPIN_SHARE
    _machine(monkeypatch, realtime=False)
    assert SpinBudget.for_this_process() is None  # bare metal, normal policy: spin freely
    _machine(monkeypatch, rt_limit=None)  # sched_rt_runtime_us = -1
    assert SpinBudget.for_this_process() is None


def test_engine_budget_keeps_below_the_real_time_throttle_only(monkeypatch: pytest.MonkeyPatch) -> None:
    # the isolated engine: below the kernel's real-time share (a throttled SCHED_FIFO
    # loop stops for the rest of the second), but not held to the VM share
    _machine(monkeypatch, vm=True)
    budget = SpinBudget.below_rt_throttle()
    assert budget is not None and budget.share == pytest.approx(0.85)
    _machine(monkeypatch, rt_limit=None, vm=True)
    assert SpinBudget.below_rt_throttle() is None
    _machine(monkeypatch, realtime=False, vm=True)
    assert SpinBudget.below_rt_throttle() is None


@pytest.mark.parametrize("share", [1.0, 0.0])
def test_the_cyclic_reply_poll_keeps_to_its_budget(share: float) -> None:
    # with a budget the cyclic wait polls for its reply and counts the time; with the
    # budget spent it blocks at once, and the exchange goes on all the same
    from pyethercat.link.pair import PairLink
    from pyethercat.master.master import Master
    from pyethercat.sim.topology import parse_topology

    seg = parse_topology('[[slave]]\nname = "d"\ndevice = "builtin:do8"\n').build()
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    m.scheduler.reply_spin = 0.01
    budget = m.scheduler.spin_budget = SpinBudget(share)
    with m.start(cycle=0.001) as r:
        time.sleep(0.1)
        assert r.stats.cycles > 20 and r.stats.wkc_errors == 0
    assert (budget._spent > 0.0) == (share > 0.0)


@pytest.mark.parametrize("share", [1.0, 0.0])
def test_the_engine_clock_spins_before_a_deadline_only_within_its_budget(share: float) -> None:
    from pyethercat.master.engine.child import EngineClock

    budget = SpinBudget(share)
    clock = EngineClock([], lambda left: None, spin_ns=2_000_000, budget=budget)
    for _ in range(3):
        deadline = time.perf_counter_ns() + 5_000_000
        clock.sleep_until(deadline)
        assert time.perf_counter_ns() >= deadline
    # spinning: about the last 2 ms of each wait, counted; budget spent: slept through
    assert (budget._spent > 0.003) == (share > 0.0)


def test_rt_share_reads_the_kernel_setting() -> None:
    share = rt_share()
    assert share is None or 0.0 < share <= 1.0


def test_busy_poll_blocks_once_the_budget_is_spent() -> None:
    """The serve loop's poll returns at once (to block in select) when its budget is used up."""
    server = SimServer.__new__(SimServer)  # (only the poll's own state)
    budget = server._spin_budget = SpinBudget(0.1)  # (the loop's clock: time.monotonic)
    budget.spent(0.1)
    polled: list[int] = []
    server._poll_frames = lambda *a: polled.append(1)  # type: ignore[method-assign]
    server._busy_poll([], [])
    assert polled == []
    budget._since -= 1.0  # the next second: polling again, and its time is counted
    server._busy_poll([], [])
    assert polled == [1] and 0.0 <= budget._spent < 0.1


def test_quiet_collector_freezes_and_stops_automatic_full_collections() -> None:
    before = gc.get_threshold()
    try:
        garbage = [[] for _ in range(10)]
        quiet_collector()
        assert gc.get_freeze_count() > 0
        assert gc.get_threshold()[:2] == before[:2]
        assert gc.get_threshold()[2] >= 1 << 30
        del garbage
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)


def test_busy_poll_share_option_sets_the_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    import pyethercat.realtime as rt

    server = SimServer.__new__(SimServer)
    server.busy_poll_share = 0.05
    budget = server.spin_budget()
    assert budget is not None and budget.share == 0.05
    server.busy_poll_share = 1.0
    assert server.spin_budget() is None  # no limit asked for
    server.busy_poll_share = None
    monkeypatch.setattr(rt, "on_virtual_machine", lambda: True)
    budget = server.spin_budget()
    assert budget is not None and budget.share <= VM_SPIN_SHARE


@pytest.mark.parametrize("value", ["0", "1.5", "x"])
def test_busy_poll_share_out_of_range_is_a_one_line_error(value: str) -> None:
    from click.testing import CliRunner

    from pyethercat.cli.main import cli

    got = CliRunner().invoke(cli, ["sim", "examples/demo.toml", "--check", "--busy-poll-share", value])
    assert got.exit_code != 0
    assert got.output.startswith("pyethercat: error: ") and got.output.count("\n") == 1
    assert "--busy-poll-share" in got.output


def test_idle_halt_hint_names_the_knob_for_sub_millisecond_cycles_only(tmp_path: Path) -> None:
    # A fake /sys: a KVM guest with the haltpoll cpuidle driver whose idle vCPUs halt at once.
    driver = tmp_path / "devices/system/cpu/cpuidle/current_driver"
    poll = tmp_path / "module/haltpoll/parameters/guest_halt_poll_ns"
    driver.parent.mkdir(parents=True)
    poll.parent.mkdir(parents=True)
    driver.write_text("haltpoll\n")
    poll.write_text("0\n")
    hint = idle_halt_hint(250e-6, tmp_path)
    assert hint is not None and "guest_halt_poll_ns 0" in hint and "250 us cycles" in hint
    assert f"echo 200000 > {poll} (root)" in hint
    assert idle_halt_hint(1e-3, tmp_path) is None  # a 1 ms cycle has room for the wake-up
    poll.write_text("200000\n")
    assert idle_halt_hint(100e-6, tmp_path) is None  # they poll already
    poll.write_text("0\n")
    driver.write_text("acpi_idle\n")
    assert idle_halt_hint(100e-6, tmp_path) is None  # another idle driver: nothing to say
    assert idle_halt_hint(100e-6, tmp_path / "none") is None  # no such files (bare metal)
