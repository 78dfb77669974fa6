"""``pdos``, ``run`` and ``demo`` from the command line (in-process and child-process simulator).

Output is taken off a terminal (CliRunner), as in ``make demo | tee`` or a CI
log: the summary must start on its own line after the live table, SII names
must not be cut, the loop-back check must have run.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("pyethercat.sim.topology")

from pyethercat.cli.main import cli  # noqa: E402
from pyethercat.wire.pcap import read_capture  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
COUPLER = "PEC-CU4 EtherCAT coupler, 4 ports"


def run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def test_run_prints_live_table_then_summary_on_its_own_lines() -> None:
    code, out, _ = run("--sim", str(DEMO), "run", "--seconds", "0.3", "--cycle", "2000")
    assert code == 0, out
    lines = out.splitlines()
    # The summary starts a line of its own (it used to follow the table's last row).
    starts = [i for i, line in enumerate(lines) if line.startswith("cycles: ")]
    assert len(starts) == 1, out
    summary = lines[starts[0]:]
    assert re.match(r"cycles: \d+ at 2000 us \(mean period", summary[0])
    assert summary[-3:] == [
        "WKC errors: 0, lost frames: 0",
        "link: up at the end; down 0 times, 0.00 s, 0 cycles lost",
        summary[-1]]
    # every end is an orderly stop: safe outputs, then the slaves down to PREOP
    assert re.fullmatch(r"stopped: safe outputs for 3 cycles, slaves in PREOP \(\d+ ms\)",
                        summary[-1]), summary[-1]
    assert int(summary[0].split()[1]) > 10
    # The live table: whole names, every slave in OP and supervised "ok".
    assert COUPLER in out
    rows = [line for line in lines if re.match(r"^ \d+\s+│ 0x10", line)]
    assert len(rows) == 6
    for row in rows:
        cells = [c.strip() for c in row.split("│")]
        assert cells[3:] == ["OP", "ok"], row
    assert re.search(r"group main WKC\s+│ 7/7 ok", out)


def test_pdos_lists_mapping_and_group() -> None:
    code, out, _ = run("--sim", str(DEMO), "pdos", "-p", "4")
    assert code == 0
    assert out.startswith("=== slave 4 (0x1005, PEC-DI2")
    # the 2-bit terminal, packed: 2 bits of one logical byte
    assert "FMMU0: logical 0x00010003.0-1 (1 byte, 2 bit) <-> 0x1000.0 inputs" in out, out
    assert "group main:" in out and "LRW 0x00010000" in out


def test_demo_runs_checks_loop_back_and_writes_a_capture(tmp_path: Path) -> None:
    pcap = tmp_path / "demo.pcapng"
    # (1 s: a loaded host may stall the simulator past the do8s' 100 ms watchdog, and
    # checks are left out while they recover)
    code, out, err = run("demo", "--seconds", "1", "--pcap", str(pcap))
    assert code == 0, out + err
    assert "6 slaves" in out and COUPLER in out
    assert "port 3 -> 1: PEC-DO8" in out  # the branch in the topology tree
    m = re.search(r"loop-back checks: (\d+), mismatches: (\d+) \((\d+) wires\)", out)
    assert m is not None, out
    assert int(m.group(1)) > 0 and m.group(2) == "0" and m.group(3) == "2"
    assert re.search(r"^cycles: \d+ at 1000 us", out, re.M)
    assert f"capture written to {pcap}" in out
    with pcap.open("rb") as f:
        assert sum(1 for _ in read_capture(f)) > 100
