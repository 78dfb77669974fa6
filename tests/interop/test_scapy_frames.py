"""scapy's EtherCAT layer (scapy.contrib.ethercat) reads our frames as we meant them.

scapy knows no NOP datagram (command 0), so the one frame holding a NOP is skipped.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from ecat_frames import decoded, encode_test_frame, sample_frames

from pyethercat.wire.datagram import Command, Datagram

ethercat = pytest.importorskip("scapy.contrib.ethercat")
scapy_layers = pytest.importorskip("scapy.layers.l2")
scapy_inet = pytest.importorskip("scapy.layers.inet")
scapy_config = pytest.importorskip("scapy.config")


@pytest.fixture(autouse=True)
def _long_lists() -> Iterator[None]:
    # scapy dissects list fields (datagram data) of at most 100 items by default.
    old = scapy_config.conf.max_list_count
    scapy_config.conf.max_list_count = 4096
    yield
    scapy_config.conf.max_list_count = old


def _scapy_datagrams(raw: bytes, udp: bool) -> list[Any]:
    pkt = scapy_layers.Ether(raw)
    if udp:
        assert pkt.haslayer(scapy_inet.UDP)
        ecat = ethercat.EtherCat(bytes(pkt[scapy_inet.UDP].payload))
    else:
        ecat = pkt[ethercat.EtherCat]
    assert ecat.type == 1
    out = []
    layer = ecat.payload
    while isinstance(layer, ethercat.EtherCatType12DLPDU):
        out.append(layer)
        layer = layer.payload
    return out


def _fields(d: Datagram) -> dict[str, Any]:
    common = {
        "cmd": int(d.command),
        "idx": d.index,
        "len": len(d.data),
        "c": int(d.circulating),
        "next": int(d.more),
        "irq": d.irq,
        "data": list(d.data),
        "wkc": d.wkc,
    }
    if d.is_logical:
        common["adr"] = d.logical_address
    else:
        common["adp"] = d.adp
        common["ado"] = d.ado
    return common


def _scapy_fields(layer: Any) -> dict[str, Any]:
    out = {
        "cmd": layer._cmd,
        "idx": layer.idx,
        "len": layer.len,
        "c": layer.c,
        "next": layer.next,
        "irq": layer.irq,
        "data": list(layer.data),
        "wkc": layer.wkc,
    }
    # Not hasattr(): scapy looks up unknown attributes in the following layers too.
    if "adr" in {f.name for f in layer.fields_desc}:
        out["adr"] = layer.adr
    else:
        out["adp"] = layer.adp
        out["ado"] = layer.ado
    return out


FRAMES = [f for f in sample_frames() if all(d.command != Command.NOP for d in f.datagrams)]


def test_only_the_nop_frame_is_skipped() -> None:
    assert len(sample_frames()) - len(FRAMES) == 1


@pytest.mark.parametrize("number", range(len(FRAMES)))
def test_scapy_reads_our_frames(number: int) -> None:
    frame = FRAMES[number]
    ours = decoded(frame)
    theirs = _scapy_datagrams(encode_test_frame(frame), frame.udp)
    assert [_scapy_fields(x) for x in theirs] == [_fields(d) for d in ours]
