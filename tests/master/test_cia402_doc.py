"""The two-axis CSP example of docs/cia402.md does what the page says, on two simulated drives.

The page's code runs as written except for the link: ``Master.open(iface=...)``
becomes a master on two in-process drives, and the master and the drives
share one virtual clock (``m.start(..., clock=clock)``), so each cycle is
exact on any host.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.sim.topology import parse_topology

REPO = Path(__file__).resolve().parents[2]
TWO_DRIVES = "".join(f'[[slave]]\nname = "axis{i}"\ndevice = "builtin:seed002-drive"\n'
                     for i in (1, 2))


def doc_example() -> str:
    text = (REPO / "docs" / "cia402.md").read_text()
    return text.split("## Two axes in CSP", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]


def test_the_example_is_short() -> None:
    code = doc_example()
    assert len(code.strip().splitlines()) < 25
    assert 'Master.open(iface="eth1")' in code and 'm.start(cycle=0.001, dc="master")' in code


def test_two_axis_csp_example_moves_both_axes_within_the_window() -> None:
    clock = VirtualClock(1_000_000_000)
    segment = parse_topology(TWO_DRIVES).build(clock=clock)

    def opened() -> Master:
        m = Master(PairLink.responder_link(segment.process), clock=clock)
        m.dc.master_time = lambda: clock.now_ns() + 800_000_000_000_000_000
        return m

    code = (doc_example().replace('Master.open(iface="eth1")', "opened()")
            .replace('dc="master")', 'dc="master", clock=clock)'))
    scope = {"opened": opened, "clock": clock}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "cia402.md", "exec"), scope)  # noqa: S102
    rec = scope["rec"]
    # both axes went the distances of the example and ended with "target reached"
    moved = rec.actual[-1] - rec.actual[0]
    assert np.abs(moved - np.array([100_000, -50_000])).max() <= 1, moved
    assert (rec.statusword[-1] & 0x0400).all()
    # the following error the drives reported stayed far inside the window 0x6065 (10000)
    peak = np.abs(rec.following_error).max(axis=0)
    assert (peak > 0).all() and (peak < 200).all(), peak
    assert out.getvalue().startswith("peak following error:")
    # the axes moved together (synchronized=True): their commanded positions stop changing
    # in the same cycle (give or take the rounding of the last sample to whole increments)
    steps = np.abs(np.diff(rec.commanded, axis=0)) > 0
    ends = [int(np.nonzero(steps[:, k])[0].max()) for k in (0, 1)]
    assert abs(ends[0] - ends[1]) <= 1 and not steps[-50:].any(), ends
