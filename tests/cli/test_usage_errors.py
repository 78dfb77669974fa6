"""The CLI contract: every failure is one line on stderr and a non-zero exit."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pyethercat", *args],
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(
    "args, code, fragment",
    [
        (("nosuch",), 2, "No such command 'nosuch'"),
        (("--sim", str(DEMO), "reg_read", "-p", "0"), 2, "Missing argument 'ADDRESS'"),
        (("--sim", str(DEMO), "reg_read", "-p", "zz", "0x130", "2"), 1, "not a number"),
        (("decode",), 2, "Missing argument 'CAPTURE'"),
        (("--sim", str(DEMO), "states", "FOO"), 1, "unknown AL state 'FOO'"),
        (("--sim", "/nonexistent.toml", "slaves"), 1, "/nonexistent.toml"),
    ],
)
def test_failures_are_one_line_with_nonzero_exit(args: tuple[str, ...], code: int,
                                                 fragment: str) -> None:
    result = run(*args)
    assert result.returncode == code, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("pyethercat: error: ") and fragment in lines[0]
    assert "Traceback" not in result.stderr


def test_help_still_prints_usage_and_exits_zero() -> None:
    result = run("--help")
    assert result.returncode == 0 and result.stdout.startswith("Usage: pyethercat")
