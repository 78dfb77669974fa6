"""tshark (Wireshark's EtherCAT dissector, written by Beckhoff) reads the frames we encode
exactly as we meant them, and `pyethercat decode --json` agrees with it field by field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from ecat_frames import (
    TSHARK_FIELDS,
    decoded,
    expected_tshark,
    json_to_tshark,
    sample_frames,
    tshark_rows,
    udp_frame,
    write_capture,
)

from pyethercat.cli.main import cli
from pyethercat.wire.datagram import Command

_COMPARED = [f for f in TSHARK_FIELDS if f.startswith("ecat.")]


@pytest.fixture(scope="module", params=["pcap", "pcapng"])
def capture(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("tshark") / f"frames.{request.param}"
    # One non-EtherCAT packet first: an IPv4/UDP frame on another port.
    other = bytearray(udp_frame(b"hello"))
    other[34:38] = b"\x00\x35\x00\x35"  # ports 53 -> 53
    write_capture(path, sample_frames(), pcapng=request.param == "pcapng", extra=bytes(other))
    return path


def test_every_command_is_in_the_set() -> None:
    seen = {int(d.command) for f in sample_frames() for d in f.datagrams}
    assert seen == {int(c) for c in Command}
    assert any(d.circulating for f in sample_frames() for d in f.datagrams)
    assert any(d.irq for f in sample_frames() for d in f.datagrams)
    assert any(len(f.datagrams) > 1 and f.udp for f in sample_frames())


def test_tshark_reads_our_fields(tshark: str, capture: Path) -> None:
    frames = sample_frames()
    rows = tshark_rows(tshark, capture)
    # Frame 1 is the non-EtherCAT packet; ours start at 2.
    assert sorted(rows) == list(range(2, len(frames) + 2))
    for number, frame in enumerate(frames, 2):
        datagrams = decoded(frame)
        assert [d.command for d in datagrams] == [d.command for d in frame.datagrams]
        got = {k: rows[number][k] for k in _COMPARED}
        assert got == expected_tshark(datagrams), f"frame {number}"
        assert rows[number]["_ws.expert"] == [], f"frame {number}: {rows[number]['_ws.expert']}"
        assert rows[number]["_ws.malformed"] == [], f"frame {number}"


def test_decode_json_matches_tshark(tshark: str, capture: Path) -> None:
    result = CliRunner().invoke(cli, ["decode", "--json", str(capture)])
    assert result.exit_code == 0, result.output
    objs = [json.loads(line) for line in result.stdout.splitlines()]
    by_frame: dict[int, list[dict[str, object]]] = {}
    for obj in objs:
        by_frame.setdefault(int(obj["frame"]), []).append(obj)
    rows = tshark_rows(tshark, capture)
    assert sorted(by_frame) == sorted(rows)
    for number, row in rows.items():
        assert json_to_tshark(by_frame[number]) == {k: row[k] for k in _COMPARED}, f"frame {number}"
    udp_frames = {o["frame"] for o in objs if o["udp"]}
    assert udp_frames == {n for n, f in enumerate(sample_frames(), 2) if f.udp}
