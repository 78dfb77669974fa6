"""Every capture of the shared corpus decodes with `pyethercat decode --json` without
error, and each datagram's fields equal what tshark reports for the same file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from ecat_frames import TSHARK_FIELDS, json_to_tshark, tshark_rows

from pyethercat.cli.main import cli

_COMPARED = [f for f in TSHARK_FIELDS if f.startswith("ecat.")]
CORPUS_PCAPS = sorted(
    (Path(__file__).resolve().parents[3] / "shared" / "corpus" / "pcap").glob("*.pcap*")
)


def _names() -> list[str]:
    return [p.name for p in CORPUS_PCAPS] or ["<no corpus>"]


@pytest.mark.parametrize("name", _names())
def test_corpus_capture_matches_tshark(name: str, corpus_dir: Path, tshark: str) -> None:
    path = corpus_dir / "pcap" / name
    if not path.is_file():
        pytest.fail(f"corpus capture {path} is missing")
    result = CliRunner().invoke(cli, ["decode", "--json", str(path)])
    assert result.exit_code == 0, result.stderr
    assert "0 malformed" in result.stderr
    by_frame: dict[int, list[dict[str, object]]] = {}
    for line in result.stdout.splitlines():
        obj = json.loads(line)
        by_frame.setdefault(int(obj["frame"]), []).append(obj)
    rows = tshark_rows(tshark, path)
    # tshark's "ecat" filter also matches frames without datagrams (mailbox gateway,
    # unknown frame types): those have no ecat.cmd and no line from us.
    tshark_frames = {n for n, row in rows.items() if row["ecat.cmd"]}
    # Every corpus capture holds datagrams: two empty sets would prove nothing.
    assert tshark_frames, f"tshark found no EtherCAT datagrams in {name}"
    assert set(by_frame) == tshark_frames
    for number in tshark_frames:
        expected = {k: rows[number][k] for k in _COMPARED}
        assert json_to_tshark(by_frame[number]) == expected, f"{name} frame {number}"


def test_corpus_is_there(corpus_dir: Path) -> None:
    assert len(list((corpus_dir / "pcap").glob("*.pcap*"))) >= 20
