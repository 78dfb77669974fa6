"""``pyethercat demo --motion``: simulated drives on DC follow S-curve moves and a plot is written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("matplotlib")

from pyethercat.cli.main import cli  # noqa: E402


def test_demo_motion_prints_following_error_and_writes_the_plot(tmp_path: Path) -> None:
    png = tmp_path / "motion.png"
    result = CliRunner().invoke(cli, ["demo", "--motion", "--drives", "2", "--cycle", "2000",
                                      "--plot", str(png)],
                                catch_exceptions=False)
    out = result.stdout
    assert result.exit_code == 0, out
    assert "2 drives in Operation enabled, CSP, SYNC0 every 2000 us" in out
    rows = [line for line in out.splitlines() if re.match(r"^│ axis\d", line)]
    assert len(rows) == 2, out
    for row in rows:
        cells = [c.strip() for c in row.split("│")[1:-1]]
        # max |e| well inside the following-error window (0x6065 = 10000), no missed SM events
        assert int(cells[1]) < 1000, row
        assert cells[4] == "0", row
    assert "target reached at the end: yes" in out
    assert "0 WKC errors, 0 lost frames" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 20_000


def test_demo_motion_refuses_a_topology() -> None:
    result = CliRunner().invoke(cli, ["demo", "--motion", "--topology", "x.toml"])
    assert result.exit_code != 0
