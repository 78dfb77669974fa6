"""Cyclic operation over a veth pair against ``pyethercat sim`` (child process, raw sockets).

The demo topology: OP is reached, outputs come back as inputs bit-exactly
(the di8 byte and the 2 bits of the packed di2), and while the loop keeps
running a pulled cable and a power-cycled slave (through the simulator's
control channel) are detected and recovered without restarting the master;
the ``run`` live view shows the incident and the recovery.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT, SIM_REALTIME, wait_for
from rich.console import Console

from pyethercat.cli.run_cmds import live_view
from pyethercat.master import Master
from pyethercat.master.config import Layout
from pyethercat.wire.al import AlState

pytest.importorskip("pyethercat.sim.server")
from pyethercat.sim.server import start_sim_process  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def render(m: Master, r: object) -> str:
    console = Console(width=140, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    console.print(live_view(m, r))  # type: ignore[arg-type]
    text = console.export_text()
    console.file.close()
    return text


def test_op_loop_back_and_recovery_over_veth(veth_pair: tuple[str, str]) -> None:
    a, b = veth_pair
    with start_sim_process(DEMO, link=f"iface:{b}", realtime=SIM_REALTIME) as sim, \
            Master.open(iface=a, timeout=SIM_FRAME_TIMEOUT) as m:
        m.scan()
        cfg = m.configure(layout=Layout.PACKED)
        # the 2-bit terminal (position 4) is packed: 2 bits of a logical byte
        assert (cfg.slaves[4].fmmus[0].logical_start_bit, cfg.slaves[4].fmmus[0].logical_stop_bit) \
            == (0, 1)
        with m.start(cycle=0.002, check_interval=0.02) as r:
            assert all(s.al_state == AlState.OP for s in m.slaves)
            s = m.slaves
            for pattern in (0x01, 0x80, 0xA5, 0x5A, 0xFF, 0x00, 0x3C):
                for i in range(8):
                    s[3].outputs[f"Output {i + 1}"] = (pattern >> i) & 1
                s[1].outputs["Output 1"] = pattern & 1
                s[1].outputs["Output 2"] = (pattern >> 1) & 1

                def looped(p: int = pattern) -> bool:
                    got = sum(int(s[2].inputs[f"Input {i + 1}"]) << i for i in range(8))
                    return got == p and (s[4].inputs["Input 1"], s[4].inputs["Input 2"]) == \
                        (bool(p & 1), bool(p & 2))

                assert wait_for(looped), f"pattern 0x{pattern:02X} did not come back"
            assert r.stats.wkc_errors == 0

            def seen(text: str) -> bool:
                return any(text in e.text for e in r.events)

            def all_ok() -> bool:
                return all(h.status == "ok" for h in r.health.values()) and r.groups[0].wkc_ok

            # cable between di8 (2) and do8 (3) pulled: 3, 4, 5 vanish
            sim.control("break_link", slave="di8", port=1)
            assert wait_for(lambda: seen("slave 3 (0x1004) vanished")
                            and seen("slave 5 (0x1006) vanished"))
            # the table says who vanished, the event log where the segment was cut (the
            # fault is located a few cycles after the slaves are missed)
            cut = ("vanished", "slaves 3-5 silent", "cut between slave 2 port 1 and slave 3 port 0")
            assert wait_for(lambda: all(text in render(m, r) for text in cut)), render(m, r)
            sim.control("restore_link", slave="di8", port=1)
            assert wait_for(lambda: all_ok() and seen("slave 3 back in OP"))
            # the di2 (4) is power-cycled: address 0, INIT; it gets everything again
            before = r.health[4].recoveries
            sim.control("power_off", slave="di2")
            assert wait_for(lambda: r.health[4].status != "ok")
            sim.control("power_on", slave="di2")
            assert wait_for(lambda: r.health[4].recoveries > before and all_ok())
            assert wait_for(lambda: "slave 4 back in OP" in render(m, r)), render(m, r)
            # process data flows again through the recovered slaves
            s[1].outputs["Output 2"] = 1
            s[1].outputs["Output 1"] = 0
            assert wait_for(lambda: s[4].inputs["Input 2"] is True and s[4].inputs["Input 1"] is False)
            s[3].outputs["Output 5"] = 1
            assert wait_for(lambda: s[2].inputs["Input 5"] is True)
        # every cyclic frame that came back went through this simulator (how many there
        # were depends on how fast the steps above went, not on the feature)
        stats = sim.control("stats")
        assert r.stats.cycles > 0
        assert stats["frames"] >= r.stats.cycles - r.stats.lost_frames, (stats, r.stats)
