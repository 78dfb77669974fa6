"""Real captures (shared corpus): every mailbox Wireshark finds decodes, and agrees with it.

Wireshark's EtherCAT mailbox dissector (written by Beckhoff) is the independent
oracle: for each frame it flags, our decoder must find the same mailboxes with
the same header fields, CoE service, SDO index/subindex and EoE frame type.
"""

from __future__ import annotations

import subprocess
from collections import Counter
from pathlib import Path

import pytest

from pyethercat.errors import EtherCATError
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox import MAILBOX_HEADER_SIZE, MailboxType, decode_message
from pyethercat.wire.mailbox.coe import (
    CoeHeader,
    SdoAbortTransfer,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
)
from pyethercat.wire.mailbox.eoe import EoeFragment, EoeSetIpRequest
from pyethercat.wire.mailbox.header import MailboxHeader
from pyethercat.wire.pcap import parse_capture

CAPTURES = [
    "ethercrab_replay-ek1914-el3004-configure.pcapng",
    "ethercrab_replay-ek1914-el3004-mailbox.pcapng",
    "ethercrab_replay-ek1914-no-complete-access.pcapng",
    "ethercrab_replay-ek1914-segmented-upload.pcapng",
    "ethercrab_soem-dual-lan9252.pcapng",
    "ethercrab_soem-sdinfo-akd.pcapng",
    "ethercrab_soem-single-lan9252.pcapng",
    "ethercrab_twincat-akd-nc-mode.pcapng",
]
FIELDS = [
    "frame.number",
    "ecat_mailbox.length",
    "ecat_mailbox.type",
    "ecat_mailbox.counter",
    "ecat_mailbox.coe.type",
    "ecat_mailbox.coe.sdoidx",
    "ecat_mailbox.coe.sdosub",
    "ecat_mailbox.eoe.type",
]
_ADDRESSED = {0x01, 0x02, 0x04, 0x05}  # APRD, APWR, FPRD, FPWR

Key = tuple[int, int, int, int | None, int | None, int | None, int | None]


def _num(text: str) -> int | None:
    return int(text, 0) if text else None


def _tshark_mailboxes(tshark: str, path: Path) -> dict[int, Counter[Key]]:
    cmd = [
        tshark,
        "-r",
        str(path),
        "-Y",
        "ecat_mailbox",
        "-T",
        "fields",
        "-E",
        "separator=|",
        "-E",
        "occurrence=a",
        "-E",
        "aggregator=,",
    ]
    for f in FIELDS:
        cmd += ["-e", f]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    result: dict[int, Counter[Key]] = {}
    for line in out.splitlines():
        cols = line.split("|")
        frame = int(cols[0])
        lengths = cols[1].split(",")
        per: list[list[str]] = [c.split(",") if c else [] for c in cols[1:]]
        counter: Counter[Key] = Counter()
        for i in range(len(lengths)):
            vals = [p[i] if i < len(p) else "" for p in per]
            # CoE/EoE sub-fields only exist for their own type: keep them aligned by type
            counter[
                (
                    int(vals[0]),
                    int(vals[1]),
                    int(vals[2]),
                    _num(vals[3]),
                    _num(vals[4]),
                    _num(vals[5]),
                    _num(vals[6]),
                )
            ] += 1
        result[frame] = counter
    return result


def _our_key(data: bytes) -> Key | None:
    header = MailboxHeader.decode(data)
    if header.length == 0 or MAILBOX_HEADER_SIZE + header.length > len(data):
        return None
    _, msg = decode_message(data)  # must not raise on a real mailbox
    coe_type = index = sub = eoe_type = None
    payload = data[MAILBOX_HEADER_SIZE : MAILBOX_HEADER_SIZE + header.length]
    # re-encoding gives the captured bytes; Beckhoff slaves echo the written data in
    # the reserved bytes 4-7 of an initiate download response, which we send as zero
    again = msg.encode() if not isinstance(msg, (bytes, EtherCATError)) else payload
    if isinstance(msg, SdoInitiateDownloadResponse):
        assert again[:6] == payload[:6]
    else:
        assert again == payload, f"re-encoded {type(msg).__name__} differs"
    if header.type == MailboxType.COE:
        coe_type = int(CoeHeader.decode(payload).service)
        if isinstance(
            msg,
            (
                SdoInitiateUploadRequest,
                SdoInitiateUploadResponse,
                SdoInitiateDownloadRequest,
                SdoInitiateDownloadResponse,
                SdoAbortTransfer,
            ),
        ):
            index, sub = msg.index, msg.subindex
    if header.type == MailboxType.EOE:
        eoe_type = payload[0] & 0x0F
    return (header.length, int(header.type), header.counter, coe_type, index, sub, eoe_type)


@pytest.mark.parametrize("name", CAPTURES)
def test_capture_mailboxes_match_wireshark(name: str, corpus_dir: Path, tshark: str) -> None:
    path = corpus_dir / "pcap" / name
    oracle = _tshark_mailboxes(tshark, path)
    assert oracle, f"tshark found no mailboxes in {name}"
    records = parse_capture(path.read_bytes())
    checked = 0
    for frame_no, expected in oracle.items():
        frame = decode_frame(records[frame_no - 1].data)
        ours: Counter[Key] = Counter()
        for dg in frame.datagrams:
            if int(dg.command) not in _ADDRESSED or len(dg.data) < MAILBOX_HEADER_SIZE:
                continue
            try:
                key = _our_key(bytes(dg.data))
            except EtherCATError:
                continue  # not every addressed datagram is a mailbox
            if key is not None:
                ours[key] += 1
        # compare only fields Wireshark fills for that mailbox
        for key, count in expected.items():
            match = [
                k for k in ours if all(e is None or e == o for e, o in zip(key, k, strict=True))
            ]
            assert match, f"{name} frame {frame_no}: Wireshark {key}, ours {dict(ours)}"
            checked += count
    assert checked > 0


def test_twincat_eoe_set_ip_is_fixed_layout(corpus_dir: Path) -> None:
    """TwinCAT's set-IP request uses the 58-byte fixed layout (facts 9.3)."""
    path = corpus_dir / "pcap" / "ethercrab_twincat-akd-nc-mode.pcapng"
    found_ip = found_frag = False
    for rec in parse_capture(path.read_bytes()):
        try:
            frame = decode_frame(rec.data)
        except EtherCATError:
            continue
        for dg in frame.datagrams:
            data = bytes(dg.data)
            if int(dg.command) not in _ADDRESSED or len(data) < 10:
                continue
            try:
                header, msg = decode_message(data)
            except EtherCATError:
                continue
            if header.type != MailboxType.EOE or header.length == 0:
                continue
            if isinstance(msg, EoeSetIpRequest):
                assert header.length == 4 + 58 and not msg.packed
                # its addresses are little-endian words: the mask reads as a mask
                assert str(msg.params.subnet) == "255.255.255.0"
                assert str(msg.params.gateway) == "192.168.0.139"
                assert msg.encode() == data[6 : 6 + header.length]
                found_ip = True
            if isinstance(msg, EoeFragment):
                assert msg.encode() == data[6 : 6 + header.length]
                found_frag = True
    assert found_ip and found_frag
