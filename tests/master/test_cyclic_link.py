"""The cyclic loop when things go wrong, and how it ends (register-level fake segment).

- Inputs come only from an exchange that came back whole: a cycle whose
  working counter is short (or whose frame is lost) keeps the last good
  inputs, and they age (per group and per slave).
- The link goes silent: the loop keeps ticking, counts the lost cycles,
  calls the link down, shows no state as current; when frames return,
  supervision brings the slaves that fell out of OP back.
- Every stop is orderly: safe outputs for a few cycles, SAFEOP while cycling,
  then the final state.
"""

from __future__ import annotations

import re
import threading
import time

import pytest
from fake_esc_segment import FakeSlave
from fake_logical import LogicalSegment
from master_sii_helpers import coupler, di, do
from rich.console import Console

from pyethercat.cli._lifecycle import segment_lost_error
from pyethercat.cli.run_cmds import live_view
from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError, LinkDownError
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import build_sii

OUT_RAM = 0x1100


class Switch:
    """A responder that answers through the fake segment unless switched off."""

    def __init__(self, seg: LogicalSegment) -> None:
        self.seg = seg
        self.off = False

    def __call__(self, frame: bytes):  # noqa: ANN204 - a PairLink responder
        return None if self.off else self.seg.process(frame)


def make() -> tuple[LogicalSegment, Switch, Master]:
    siis = [coupler(), do(2), di(2), do(2), di(2), do(8), di(8)]
    seg = LogicalSegment([FakeSlave(build_sii(s)) for s in siis])
    seg.wires = [(1, OUT_RAM, 2, 0x1180, 2), (3, OUT_RAM, 4, 0x1180, 2),
                 (5, OUT_RAM, 6, 0x1180, 8)]
    switch = Switch(seg)
    m = Master(PairLink.responder_link(switch), clock=VirtualClock())
    m.scan()
    m.configure()
    return seg, switch, m


def wait_for(cond, seconds: float = 10.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.005)
    return False


def test_inputs_kept_and_aged_when_the_working_counter_is_short() -> None:
    seg, _switch, m = make()
    m.pd.bring_up(m.slaves, 1.0)
    r = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                     clock=VirtualClock(), check_interval=0)
    s = m.slaves
    r.run(cycles=1)
    m.set_state("OP")
    s[1].outputs["Output 1"] = 1
    r.run(cycles=2)  # one cycle writes, the wire copies, the next one reads
    assert s[2].inputs["Input 1"] is True
    assert (s[2].inputs.age, s[2].inputs.stale) == (0, False)
    # Slaves 3.. stop answering; the do2 -> di2 wire in front of the break still works,
    # so the short frames carry the di2's new input 0: it must not be taken.
    seg.break_after = 2
    s[1].outputs["Output 1"] = 0
    r.run(cycles=3)
    assert seg.slaves[2].mem[0x1180] & 1 == 0  # the slave's input really changed
    assert s[2].inputs["Input 1"] is True  # the last good value
    assert (s[2].inputs.age, s[2].inputs.stale) == (3, True)
    st = r.group_status("main")
    assert (st.input_age, st.inputs_stale, st.wkc_ok) == (3, True, False)
    assert r.slave_input_age(2) == r.slave_input_age(6) == 3
    assert any("inputs 3 cycles old" in line for line in r.status_lines())
    # A lost frame ages them too.
    seg.faults[seg.frames] = "drop"
    r.run(cycles=1)
    assert s[2].inputs.age == 4 and r.stats.lost_frames == 1
    # The segment heals: the next whole exchange refreshes the inputs.
    seg.break_after = None
    r.run(cycles=1)
    assert s[2].inputs["Input 1"] is False
    assert (s[2].inputs.age, s[2].inputs.stale) == (0, False)
    assert not r.group_status("main").inputs_stale
    with pytest.raises(ConfigError):
        r.slave_input_age(99)


def test_inputs_never_refreshed_are_stale() -> None:
    _seg, switch, m = make()
    m.pd.bring_up(m.slaves, 1.0)
    r = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                     clock=VirtualClock(), check_interval=0)
    switch.off = True
    r.run(cycles=2)
    img = m.images["main"]
    assert img.inputs_stale and not img.inputs_valid and img.input_age == 2
    assert m.slaves[6].inputs.stale


def test_link_loss_keeps_the_loop_going_and_recovers_to_op() -> None:
    seg, switch, m = make()
    with m.start(cycle=0.001, check_interval=0.01, link_timeout=0.02) as r:
        assert wait_for(lambda: r.stats.cycles > 30 and r.slave_state(6) == AlState.OP)

        def seen(text: str) -> bool:
            return any(text in e.text for e in r.events)

        switch.off = True  # the cable is pulled
        assert wait_for(lambda: not r.stats.link_up)
        assert seen("link down: no frame came back for")
        # no state is shown as current while nothing comes back
        assert all(r.slave_state(p) is None for p in range(7))
        assert all(h.status == "lost" for h in r.health.values())
        assert not r.cycle.link_up
        # the loop keeps its deadlines and counts what it loses
        before = r.stats.down_cycles
        assert wait_for(lambda: r.stats.down_cycles > before + 20)
        assert r.stats.lost_frames >= r.stats.down_cycles
        assert r.down_for() > 0.02
        assert "link DOWN" in r.status_lines()[0]
        # the live view says so, and shows the last known states as such
        console = Console(record=True, width=160)
        console.print(live_view(m, r))
        view = console.export_text()
        assert re.search(r"link\s+│ DOWN for [\d.]+ s \(\d+ cycles lost\)", view), view
        assert len(re.findall(r"│ unknown\s+│ lost", view)) == 7, view
        assert re.search(r"group main WKC\s+│ 0/9 BAD inputs \d+ cycles old", view), view
        # meanwhile the slaves' process-data watchdogs ran out
        for i in range(1, 7):
            seg.drop_to(i, AlState.SAFEOP)
        switch.off = False  # plugged in again
        assert wait_for(lambda: r.stats.link_up)
        assert seen("link up again after")
        assert wait_for(lambda: all(h.status == "ok" for h in r.health.values())
                        and all(seg.slaves[i].al_status == AlState.OP for i in range(1, 7)))
        assert seen("left OP: now SAFEOP+ERR (AL code 0x001B)")
        assert r.slave_state(6) == AlState.OP
        st = r.stats
        assert st.link_downs == 1 and st.down_ns > 20_000_000 and st.down_cycles > 20
        assert st.summary()["link"]["downs"] == 1


def test_the_live_view_keeps_a_located_fault_until_it_is_cleared() -> None:
    # the event log shows its last 4 lines; a fault stands as "fault now" however many
    # lines came after it (under CI load "vanished" and recovery lines pushed it out)
    _seg, _switch, m = make()
    with m.start(cycle=0.001) as r:
        cut = "cut between slave 2 port 1 and slave 3 port 0 (or slave 3 failed) (slaves 3-5 silent)"

        def view() -> str:
            console = Console(record=True, width=200)
            console.print(live_view(m, r))
            return console.export_text()

        r.log("fault: " + cut)
        for k in range(10):
            r.log(f"recovery of slaves 3-5 not done yet ({k})")
        assert "fault now: " + cut in view()
        r.log("cleared: " + cut)
        assert "fault now" not in view() and cut in view()  # (the cleared line is recent)


def test_stop_sends_safe_outputs_then_takes_slaves_to_preop() -> None:
    seg, _switch, m = make()
    m.safe_outputs(5)["Output 3"] = 1  # the do8's safe value: only output 3 on
    with m.start(cycle=0.001) as r:
        m.slaves[5].outputs.update({f"Output {i}": 1 for i in (1, 2, 8)})
        m.slaves[1].outputs["Output 1"] = 1
        assert wait_for(lambda: seg.slaves[5].mem[OUT_RAM] == 0b1000_0011
                        and seg.slaves[1].mem[OUT_RAM] & 1)
    # what the slaves got last are the safe outputs, not the application's
    assert seg.slaves[5].mem[OUT_RAM] == 0b0000_0100
    assert seg.slaves[1].mem[OUT_RAM] & 1 == 0
    assert all(seg.slaves[i].al_status == AlState.PREOP for i in range(7))
    assert r.stop_report.startswith("stopped: safe outputs for 3 cycles, slaves in PREOP")
    assert not r.running
    # the application's outputs are untouched
    assert m.slaves[5].outputs["Output 8"] == 1


@pytest.mark.parametrize("how", ["stop", "close"])
def test_master_stop_and_close_are_orderly_too(how: str) -> None:
    seg, _switch, m = make()
    m.start(cycle=0.001, final_state="SAFEOP")
    assert all(seg.slaves[i].al_status == AlState.OP for i in range(7))
    if how == "stop":
        m.stop(final_state="INIT")
        assert all(seg.slaves[i].al_status == AlState.INIT for i in range(7))
        with pytest.raises(ConfigError, match="below OP"):
            m.start(cycle=0.001, final_state="OP")
        assert all(seg.slaves[i].al_status == AlState.INIT for i in range(7))  # untouched
    else:
        m.close()
        assert all(seg.slaves[i].al_status == AlState.SAFEOP for i in range(7))
    assert m.runner is not None and not m.runner.running


def test_stop_while_the_link_is_down_leaves_states_alone() -> None:
    seg, switch, m = make()
    r = m.start(cycle=0.001, link_timeout=0.01)
    switch.off = True
    assert wait_for(lambda: not r.stats.link_up)
    r.stop()
    assert not r.running
    assert "slaves not taken to PREOP: the link is down" in r.stop_report
    assert all(seg.slaves[i].al_status == AlState.OP for i in range(7))


def test_a_run_ending_during_a_spell_is_judged_once_it_is_over() -> None:
    """``run`` exits non-zero when the segment did not come back; a spell that is
    still on when the time is up gets its chance to end first."""
    _seg, switch, m = make()
    with m.start(cycle=0.001, check_interval=0.01, link_timeout=0.02) as r:
        assert wait_for(lambda: r.stats.cycles > 30 and r.slave_state(6) == AlState.OP)
        switch.off = True
        assert wait_for(lambda: not r.stats.link_up)
        err = segment_lost_error(r, m)
        assert isinstance(err, LinkDownError) and "did not come back" in str(err)
        threading.Timer(0.2, lambda: setattr(switch, "off", False)).start()
        assert segment_lost_error(r, m, settle=60.0) is None
        assert r.stats.link_up
