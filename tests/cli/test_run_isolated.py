"""``pyethercat run --isolated --plot`` over a veth pair against ``pyethercat sim`` (root).

The loop runs in its engine process: the live view names it (pid, priority,
share of a CPU) and shows the slaves' states as the engine sees them, the
run ends in order, and ``--plot`` writes the period and jitter distribution
as a PNG. ``--cpu`` without ``--isolated`` is refused in one line, before
the segment is touched.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from pyethercat.cli.main import cli

pytest.importorskip("pyethercat.sim.server")
from pyethercat.sim.server import start_sim_process  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_run_isolated_names_its_engine_and_plots_the_jitter(
        veth_pair: tuple[str, str], tmp_path: Path) -> None:
    a, b = veth_pair
    png = tmp_path / "jitter.png"
    with start_sim_process(DEMO, link=f"iface:{b}", realtime=10):
        result = CliRunner().invoke(cli, ["--iface", a, "run", "--isolated", "--seconds", "1",
                                          "--plot", str(png)], catch_exceptions=False)
    out = result.stdout
    assert result.exit_code == 0, out
    # The live view's loop row: the engine's own process, with what it got.
    assert re.search(r"loop\s+│ engine pid \d+ running: (SCHED_FIFO 40|normal priority)", out), out
    assert re.search(r"jitter histogram\s+│ <\d+us \d+", out), out
    # The slaves' states are the engine's supervision's (this process sees no frame).
    assert len(re.findall(r"│ PEC-\S+ .*│ OP\s+│ ok", out)) == 6, out
    assert re.search(r"stopped: safe outputs for 3 cycles, slaves in PREOP", out), out
    assert f"plot written to {png}" in out
    assert png.read_bytes()[:8] == PNG_MAGIC


def test_cpu_without_isolated_is_refused() -> None:
    result = CliRunner().invoke(cli, ["--sim", str(DEMO), "run", "--seconds", "0.1",
                                      "--cpu", "0"])
    assert result.exit_code != 0
    assert "--cpu pins the isolated loop's process: give --isolated" in result.output
    assert "Traceback" not in result.output
