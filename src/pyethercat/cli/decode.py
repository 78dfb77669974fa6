"""``pyethercat decode CAPTURE [--json]``: the datagrams of a pcap / pcapng capture.

Output, one line per datagram on stdout (frame = packet number in the file,
counting every packet from 1 like Wireshark; time = seconds since the first
packet)::

    FRAME TIME CMD idx=0xII ADDRESS len=N irq=0xIIII wkc=N FLAGS [REGISTER NAME]

    ADDRESS  addr=0xADP:0xADO for device commands (position, station, broadcast,
             NOP, ARMW/FRMW), lad=0xLLLLLLLL for LRD/LWR/LRW
    FLAGS    three characters: M (more datagrams follow) or -, C (circulating) or -,
             U (frame came over UDP port 34980) or -
    REGISTER name of the register at ADO when it is a known ESC register (may
             contain spaces; the rest of the line)

``--json`` prints one JSON object per datagram and line instead, with keys
``frame time udp cmd cmd_name idx adp ado lad len irq wkc more circulating
register``. As in Wireshark's ``ecat`` fields, ``adp``/``ado`` are set (and
``lad`` is null) for device commands, and ``lad`` (32-bit) is set (and
``adp``/``ado`` are null) for LRD/LWR/LRW. All numbers are plain integers.

EtherCAT frames are recognised by EtherType 0x88A4 (also behind one VLAN
tag) and as the payload of IPv4/IPv6 UDP datagrams whose source or
destination port is 34980. Captures of Ethernet (link type 1) and of Linux
"cooked" captures (``tcpdump -i any``: SLL, link type 113, and SLL2, link
type 276) are decoded; packets of any other link type are counted and named
in the summary. A summary goes to stderr at the end: packets,
EtherCAT frames (how many over UDP), datagrams, non-EtherCAT packets skipped,
EtherCAT frames of other types than datagrams (e.g. mailbox gateway), and
malformed frames. A malformed EtherCAT frame is reported on stderr as
``frame N: malformed EtherCAT frame: REASON`` and decoding goes on.

Exit status: 0 all decoded; 1 the file cannot be read or is not a valid
pcap/pcapng file (one-line reason on stderr); 2 usage error; 3 some EtherCAT
frames were malformed (everything else was printed).
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import click

from pyethercat.errors import CaptureError, FrameError
from pyethercat.wire.datagram import Command, Datagram, command_name
from pyethercat.wire.frame import (
    ECAT_HEADER_SIZE,
    ECAT_TYPE_SHIFT,
    ETHERTYPE_ETHERCAT,
    ETHERTYPE_VLAN,
    UDP_PORT,
    FrameType,
    decode_ecat_payload,
)
from pyethercat.wire.pcap import LINKTYPE_ETHERNET, CaptureRecord, read_capture
from pyethercat.wire.registers import register_name

__all__ = ["DatagramRow", "DecodeStats", "decode_records", "format_row", "row_json", "register"]

EXIT_MALFORMED = 3

_ETHERTYPE_IPV4 = 0x0800
_ETHERTYPE_IPV6 = 0x86DD
_ETHERTYPE_QINQ = 0x88A8
_IPPROTO_UDP = 17


@dataclass(slots=True)
class DatagramRow:
    """One datagram of a capture with where it was found."""

    frame: int
    time: float
    udp: bool
    datagram: Datagram


@dataclass(slots=True)
class DecodeStats:
    """Counters for the summary line."""

    packets: int = 0
    ethercat: int = 0
    udp: int = 0
    datagrams: int = 0
    non_ethercat: int = 0
    other_types: int = 0
    #: Frames whose EtherCAT length covers bytes after the last datagram (tolerated).
    trailing: int = 0
    malformed: list[tuple[int, str]] = field(default_factory=list)
    #: Packets of link types this decoder does not read, by link type.
    other_links: dict[int, int] = field(default_factory=dict)


def _udp_payload(packet: bytes, ethertype: int, start: int) -> bytes | None:
    """The UDP payload of an IPv4/IPv6 packet to or from port 34980, else None."""
    if ethertype == _ETHERTYPE_IPV4:
        if len(packet) < start + 20:
            return None
        ihl = (packet[start] & 0x0F) * 4
        if packet[start] >> 4 != 4 or ihl < 20 or packet[start + 9] != _IPPROTO_UDP:
            return None
        (frag,) = struct.unpack_from(">H", packet, start + 6)
        if frag & 0x3FFF:  # a fragment: not a whole UDP datagram
            return None
        udp = start + ihl
    elif ethertype == _ETHERTYPE_IPV6:
        if len(packet) < start + 40 or packet[start + 6] != _IPPROTO_UDP:
            return None
        udp = start + 40
    else:
        return None
    if len(packet) < udp + 8:
        return None
    sport, dport, length = struct.unpack_from(">HHH", packet, udp)
    if UDP_PORT not in (sport, dport):
        return None
    end = udp + length if length >= 8 else len(packet)
    return packet[udp + 8 : min(end, len(packet))]


#: Linux cooked captures (tcpdump -i any): SLL v1 (16-byte header, protocol at
#: bytes 14-15) and SLL2 (20-byte header, protocol at bytes 0-1); see
#: tcpdump.org/linktypes/LINKTYPE_LINUX_SLL.html and LINKTYPE_LINUX_SLL2.html.
LINKTYPE_LINUX_SLL = 113
LINKTYPE_LINUX_SLL2 = 276
#: Names of common link types for the summary (tcpdump.org/linktypes.html).
_LINK_NAMES = {0: "NULL", 101: "RAW", 105: "IEEE802_11", 108: "LOOP", 127: "IEEE802_11_RADIOTAP",
               228: "IPV4", 229: "IPV6", 147: "USER0"}


def link_name(linktype: int) -> str:
    """``LINKTYPE_RAW (101)``: how the summary names a link type."""
    names = {LINKTYPE_ETHERNET: "ETHERNET", LINKTYPE_LINUX_SLL: "LINUX_SLL",
             LINKTYPE_LINUX_SLL2: "LINUX_SLL2", **_LINK_NAMES}
    return f"LINKTYPE_{names[linktype]} ({linktype})" if linktype in names else \
        f"link type {linktype}"


def _network_start(linktype: int, packet: bytes) -> tuple[int, int] | None:
    """(EtherType, offset of what follows) of a packet, or None for a link type we do not read."""
    if linktype == LINKTYPE_ETHERNET:
        if len(packet) < 14:
            return 0, len(packet)
        return (packet[12] << 8) | packet[13], 14
    if linktype == LINKTYPE_LINUX_SLL:
        if len(packet) < 16:
            return 0, len(packet)
        return (packet[14] << 8) | packet[15], 16
    if linktype == LINKTYPE_LINUX_SLL2:
        if len(packet) < 20:
            return 0, len(packet)
        return (packet[0] << 8) | packet[1], 20
    return None


def _frame_type(ecat: bytes) -> int:
    return (ecat[1] << 8 | ecat[0]) >> ECAT_TYPE_SHIFT if len(ecat) >= ECAT_HEADER_SIZE else -1


def decode_records(records: Iterable[CaptureRecord], stats: DecodeStats) -> Iterator[DatagramRow]:
    """Yield every datagram of every EtherCAT frame in ``records``, counting into ``stats``.

    Malformed EtherCAT frames are recorded in ``stats.malformed`` as
    (frame number, reason) and skipped.
    """
    first_ts: int | None = None
    for number, rec in enumerate(records, 1):
        stats.packets += 1
        if first_ts is None:
            first_ts = rec.timestamp_ns
        when = (rec.timestamp_ns - first_ts) / 1e9
        packet = rec.data
        network = _network_start(rec.linktype, packet)
        if network is None:
            stats.other_links[rec.linktype] = stats.other_links.get(rec.linktype, 0) + 1
            continue
        ethertype, start = network
        while ethertype in (ETHERTYPE_VLAN, _ETHERTYPE_QINQ) and len(packet) >= start + 4:
            ethertype = (packet[start + 2] << 8) | packet[start + 3]
            start += 4
        over_udp = False
        if ethertype == ETHERTYPE_ETHERCAT:
            ecat = packet[start:]
        else:
            payload = _udp_payload(packet, ethertype, start)
            if payload is None:
                stats.non_ethercat += 1
                continue
            ecat, over_udp = payload, True
        stats.ethercat += 1
        stats.udp += over_udp
        ftype = _frame_type(ecat)
        if ftype not in (-1, FrameType.DATAGRAMS):
            stats.other_types += 1
            continue
        try:
            # Not strict: some masters (TwinCAT) send an EtherCAT length a byte
            # longer than their datagrams; Wireshark shows such frames without
            # complaint, so we decode them too and count them.
            frame = decode_ecat_payload(ecat, base_offset=start if not over_udp else 0,
                                        strict=False)
        except FrameError as exc:
            stats.malformed.append((number, str(exc)))
            continue
        datagrams = frame.datagrams
        stats.trailing += frame.trailing > 0
        stats.datagrams += len(datagrams)
        for dgram in datagrams:
            yield DatagramRow(number, when, over_udp, dgram)


def _register_of(dgram: Datagram) -> str | None:
    if dgram.is_logical or dgram.command == Command.NOP:
        return None
    return register_name(dgram.ado)


def format_row(row: DatagramRow) -> str:
    """The text line of one datagram (see the module docstring)."""
    d = row.datagram
    addr = f"lad=0x{d.logical_address:08X}" if d.is_logical else f"addr=0x{d.adp:04X}:0x{d.ado:04X}"
    flags = ("M" if d.more else "-") + ("C" if d.circulating else "-") + ("U" if row.udp else "-")
    line = (
        f"{row.frame:>6} {row.time:>11.6f} {command_name(int(d.command)):<4} idx=0x{d.index:02X}"
        f" {addr:<20} len={len(d.data):<4} irq=0x{d.irq:04X} wkc={d.wkc:<5} {flags}"
    )
    reg = _register_of(d)
    return f"{line} {reg}" if reg else line


def row_json(row: DatagramRow) -> dict[str, Any]:
    """The JSON object of one datagram (see the module docstring)."""
    d = row.datagram
    logical = d.is_logical
    return {
        "frame": row.frame,
        "time": round(row.time, 9),
        "udp": row.udp,
        "cmd": int(d.command),
        "cmd_name": command_name(int(d.command)),
        "idx": d.index,
        "adp": None if logical else d.adp,
        "ado": None if logical else d.ado,
        "lad": d.logical_address if logical else None,
        "len": len(d.data),
        "irq": d.irq,
        "wkc": d.wkc,
        "more": d.more,
        "circulating": d.circulating,
        "register": _register_of(d),
    }


def summary(stats: DecodeStats) -> str:
    """The summary line printed on stderr."""
    return (
        f"{stats.packets} packets: {stats.ethercat} EtherCAT frames ({stats.udp} over UDP), "
        f"{stats.datagrams} datagrams, {stats.non_ethercat} non-EtherCAT packets skipped, "
        f"{stats.other_types} EtherCAT frames without datagrams, "
        f"{stats.trailing} with bytes after the last datagram, "
        f"{len(stats.malformed)} malformed"
        + "".join(f", {n} packets of {link_name(t)} not decoded (Ethernet and Linux cooked "
                  "captures are)" for t, n in sorted(stats.other_links.items()))
    )


@click.command("decode")
@click.argument("capture", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="One JSON object per datagram.")
def decode_cmd(capture: str, as_json: bool) -> None:
    """Print the datagrams of a pcap/pcapng CAPTURE, one per line."""
    stats = DecodeStats()
    try:
        stream = open(capture, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise CaptureError(f"cannot read {capture}: {exc.strerror or exc}") from None
    reported = 0
    out = sys.stdout
    try:
        for row in decode_records(read_capture(stream), stats):
            while reported < len(stats.malformed):
                _report(stats.malformed[reported])
                reported += 1
            if as_json:
                out.write(json.dumps(row_json(row), separators=(",", ":")) + "\n")
            else:
                out.write(format_row(row) + "\n")
    except CaptureError as exc:
        out.flush()
        raise CaptureError(f"{capture}: {exc}") from None
    except BrokenPipeError:
        # The reader went away (``| head``): stop quietly, without a traceback at exit.
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), out.fileno())
        sys.exit(0)
    finally:
        stream.close()
    out.flush()
    for item in stats.malformed[reported:]:
        _report(item)
    click.echo(f"pyethercat decode: {summary(stats)}", err=True)
    if stats.malformed:
        sys.exit(EXIT_MALFORMED)


def _report(item: tuple[int, str]) -> None:
    click.echo(f"pyethercat decode: frame {item[0]}: malformed EtherCAT frame: {item[1]}", err=True)


def register(cli: click.Group) -> None:
    """Attach ``decode`` to the ``pyethercat`` command group."""
    cli.add_command(decode_cmd)
