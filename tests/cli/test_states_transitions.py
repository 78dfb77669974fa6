"""`pyethercat states STATE` configures process data before SAFEOP, as IgH's tool does."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def states(topology: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pyethercat", "--sim", str(EXAMPLES / topology),
                           "states", *args], capture_output=True, text=True, timeout=120)


def test_safeop_is_reached_by_every_slave_with_process_data_configured() -> None:
    for topology, count in (("demo.toml", 6), ("coe.toml", 2)):
        result = states(topology, "SAFEOP", "--wait")
        assert result.returncode == 0, result.stderr
        lines = result.stdout.strip().splitlines()
        assert len(lines) == count
        # A slave lacking its process-data SMs would be refused (PREOP+ERR 0x001D/0x001E).
        assert all(line.split()[2] == "SAFEOP" for line in lines), result.stdout


def test_op_without_cyclic_data_names_the_waiting_slaves_and_says_what_to_do() -> None:
    result = states("demo.toml", "OP", "--wait", "-t", "0.5")
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert "did not reach OP" in line and "PEC-DO8" in line and "pyethercat run" in line


def test_a_request_without_wait_returns_after_the_last_request() -> None:
    # IgH's `ethercat states OP` only requests: the steps before (INIT -> PREOP ->
    # SAFEOP, with the set-up) are walked, OP is requested, nothing is printed.
    result = states("demo.toml", "OP")
    assert result.returncode == 0, result.stderr
    assert result.stdout == ""
    assert "stays in SAFEOP without process data" in result.stderr
