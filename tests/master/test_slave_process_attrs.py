"""``Slave.inputs/outputs/config`` are declared on ``Slave`` (typed for mypy users).

Before ``configure()`` reading them raises a typed error that says what to do;
afterwards they are the slave's views into its group image; a slave left out
of every group says so.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.master.config import GroupSpec
from pyethercat.master.image import SlaveIO
from pyethercat.master.master import Master

pytest.importorskip("pyethercat.sim.topology")
from pyethercat.sim.topology import load_topology  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def scanned() -> Master:
    seg = load_topology(DEMO).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    return m


def test_before_configure_a_typed_error_names_the_slave() -> None:
    m = scanned()
    s = m.slaves[2]
    assert s.config is None
    with pytest.raises(ConfigError, match=r"slave 2 \(0x1003\).*configure\(\) first"):
        _ = s.inputs
    with pytest.raises(ConfigError, match="configure"):
        _ = s.outputs


def test_after_configure_views_into_the_group_image() -> None:
    m = scanned()
    cfg = m.configure()
    do8 = m.slaves[3]
    assert do8.config is cfg.slaves[3]
    assert isinstance(do8.outputs, SlaveIO) and isinstance(do8.inputs, SlaveIO)
    do8.outputs["Output 8"] = 1
    img = m.images["main"]
    var = img.variable(3, "Output 8")
    assert var.get() == 1
    assert m.slaves[2].inputs["Input 1"] is False


def test_a_slave_in_no_group_says_so() -> None:
    m = scanned()
    # the coupler has no process data and may stay out of every group
    m.configure(groups=[GroupSpec("main", [1, 2, 3, 4, 5])])
    assert m.slaves[2].inputs["Input 1"] is False
    assert m.slaves[0].config is not None
    with pytest.raises(ConfigError, match=r"slave 0 \(0x1001\) is in no process-data group"):
        _ = m.slaves[0].inputs


def test_two_groups_with_different_cycle_times_exchange_at_their_own_rates() -> None:
    """Seed 004 'cyclic mode': the loop ticks at the fast cycle, the slow group every 5th tick."""
    from pyethercat.master.cyclic import CyclicRunner

    m = scanned()
    cfg = m.configure(groups=[GroupSpec("fast", [1, 2], cycle=0.001),
                              GroupSpec("slow", [3, 4, 5], cycle=0.005)])
    assert cfg.group("fast").logical_base != cfg.group("slow").logical_base
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, cycle=0.001, clock=VirtualClock(),
                     check_interval=0)
    assert r.period_ns == 1_000_000
    r.run(cycles=20)
    fast, slow = r.groups
    assert (fast.name, fast.exchanges, slow.name, slow.exchanges) == ("fast", 20, "slow", 4)
    assert fast.wkc_ok and slow.wkc_ok and r.stats.wkc_errors == 0
    # the slow group's outputs reach the di8 only on its own ticks: do8 (3) -> di8 (2)
    m.slaves[3].outputs["Output 3"] = 1
    r.run(cycles=1)  # a new run starts at tick 0, both groups due: the do8's write lands
    r.run(cycles=2)  # the fast group reads the di8 the wiring drove
    assert m.slaves[2].inputs["Input 3"] is True
