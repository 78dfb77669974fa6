"""pcap / pcapng codec: round trips, both byte orders, resolutions, malformed input."""

from __future__ import annotations

import contextlib
import io
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import CaptureError
from pyethercat.wire.pcap import (
    LINKTYPE_ETHERNET,
    CaptureFormat,
    CaptureRecord,
    PacketDirection,
    PcapngWriter,
    PcapWriter,
    detect_format,
    encode_pcapng_epb,
    encode_pcapng_shb,
    parse_capture,
    read_capture,
)

FRAME = bytes.fromhex(
    "ffffffffffff010101010101 88a4 0e10 07000000000002000000 0000 0000".replace(" ", "")
) + bytes(30)

packets = st.lists(
    st.tuples(
        st.integers(min_value=0, max_value=(1 << 32) * 1_000_000_000 - 1),
        st.binary(min_size=0, max_size=200),
    ),
    max_size=8,
)


@given(packets, st.booleans())
def test_pcap_round_trip(pkts: list[tuple[int, bytes]], ns: bool) -> None:
    out = io.BytesIO()
    w = PcapWriter(out, nanosecond=ns)
    for ts, data in pkts:
        w.write(ts, data)
    recs = parse_capture(out.getvalue())
    assert detect_format(out.getvalue()) is CaptureFormat.PCAP
    assert [r.data for r in recs] == [d for _, d in pkts]
    expect = [ts if ns else ts // 1000 * 1000 for ts, _ in pkts]
    assert [r.timestamp_ns for r in recs] == expect
    assert all(r.linktype == LINKTYPE_ETHERNET and r.wire_len == len(r.data) for r in recs)


@given(
    st.lists(
        st.tuples(
            st.integers(min_value=0, max_value=(1 << 64) - 1),
            st.binary(max_size=200),
            st.integers(min_value=0, max_value=2),
            st.sampled_from(list(PacketDirection)),
        ),
        max_size=8,
    )
)
def test_pcapng_round_trip(pkts: list[tuple[int, bytes, int, PacketDirection]]) -> None:
    out = io.BytesIO()
    w = PcapngWriter(out, interfaces=["a", "b", "c"])
    for ts, data, iface, direction in pkts:
        w.write(ts, data, iface, direction)
    raw = out.getvalue()
    assert detect_format(raw) is CaptureFormat.PCAPNG
    recs = parse_capture(raw)
    assert recs == [
        CaptureRecord(ts, data, iface, LINKTYPE_ETHERNET, len(data), direction)
        for ts, data, iface, direction in pkts
    ]


def _be_pcapng(ts_units: int, data: bytes, tsresol: int | None, spb: bool = False) -> bytes:
    """A big-endian pcapng file built by hand (independent of our writer)."""

    def block(btype: int, body: bytes) -> bytes:
        return struct.pack(">II", btype, 12 + len(body)) + body + struct.pack(">I", 12 + len(body))

    shb = block(0x0A0D0D0A, struct.pack(">IHHq", 0x1A2B3C4D, 1, 0, -1))
    opts = b""
    if tsresol is not None:
        opts = struct.pack(">HH", 9, 1) + bytes([tsresol]) + b"\0\0\0" + struct.pack(">HH", 0, 0)
    idb = block(1, struct.pack(">HHI", 1, 0, 65535) + opts)
    # An unknown block type (name resolution) that must be skipped.
    nrb = block(4, struct.pack(">HH", 0, 0))
    pad = b"\0" * (-len(data) % 4)
    if spb:
        pkt = block(3, struct.pack(">I", len(data)) + data + pad)
    else:
        pkt = block(
            6,
            struct.pack(">IIIII", 0, ts_units >> 32, ts_units & 0xFFFFFFFF, len(data), len(data))
            + data
            + pad,
        )
    return shb + idb + nrb + pkt


@pytest.mark.parametrize(
    ("tsresol", "units", "ns"),
    [
        (None, 1_500_000, 1_500_000_000),  # default: microseconds
        (6, 1_500_000, 1_500_000_000),
        (9, 123, 123),
        (3, 7, 7_000_000),
        (0x80 | 10, 1024 * 3, 3_000_000_000),  # 2^-10 s units
    ],
)
def test_pcapng_big_endian_and_resolutions(tsresol: int | None, units: int, ns: int) -> None:
    (rec,) = parse_capture(_be_pcapng(units, FRAME, tsresol))
    assert rec.data == FRAME
    assert rec.timestamp_ns == ns


def test_pcapng_simple_packet_block() -> None:
    (rec,) = parse_capture(_be_pcapng(0, FRAME[:61], 9, spb=True))
    assert rec.data == FRAME[:61]
    assert rec.timestamp_ns == 0


@pytest.mark.parametrize("ns", [False, True])
def test_pcap_big_endian(ns: bool) -> None:
    magic = 0xA1B23C4D if ns else 0xA1B2C3D4
    raw = struct.pack(">IHHiIII", magic, 2, 4, 0, 0, 65535, 1)
    raw += struct.pack(">IIII", 10, 20, len(FRAME), 100) + FRAME
    (rec,) = parse_capture(raw)
    assert rec.data == FRAME
    assert rec.orig_len == 100
    assert rec.timestamp_ns == 10 * 10**9 + (20 if ns else 20_000)


def test_pcapng_several_sections_reset_interfaces() -> None:
    out = io.BytesIO()
    w = PcapngWriter(out, interfaces=["x"])
    w.write(1, b"one")
    w2 = PcapngWriter(out, interfaces=["y", "z"])
    w2.write(2, b"two", 1)
    recs = parse_capture(out.getvalue())
    assert [(r.data, r.interface_id) for r in recs] == [(b"one", 0), (b"two", 1)]


def test_writer_rejects_unknown_interface() -> None:
    w = PcapngWriter(io.BytesIO(), interfaces=["x"])
    with pytest.raises(CaptureError, match="interface id 3"):
        w.write(0, b"", 3)


def _good_files() -> list[bytes]:
    a = io.BytesIO()
    PcapWriter(a).write(5, FRAME)
    b = io.BytesIO()
    PcapngWriter(b).write(5, FRAME, 0, PacketDirection.INBOUND)
    return [a.getvalue(), b.getvalue()]


@pytest.mark.parametrize("which", [0, 1])
def test_every_truncation_is_a_capture_error(which: int) -> None:
    raw = _good_files()[which]
    for cut in range(len(raw)):
        part = raw[:cut]
        try:
            recs = parse_capture(part)
        except CaptureError:
            continue
        # A cut exactly at a record boundary is a valid, shorter file.
        assert len(recs) == 0


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        (b"", "too short"),
        (b"GIF89a....", "not a pcap or pcapng"),
        (encode_pcapng_epb(0, b"x"), "not a pcap or pcapng"),
        (encode_pcapng_shb() + encode_pcapng_epb(0, b"x"), "interface 0, only 0"),
        (encode_pcapng_shb()[:-4] + b"\xff\0\0\0", "trailing length"),
        (encode_pcapng_shb() + struct.pack("<II", 1, 13) + bytes(8), "block length 13"),
        (
            struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
            + struct.pack("<IIII", 0, 0, 1 << 30, 0),
            "not plausible",
        ),
        (struct.pack("<IHHiIII", 0xA1B2C3D4, 3, 4, 0, 0, 65535, 1), "version 3"),
    ],
)
def test_malformed_files(raw: bytes, match: str) -> None:
    with pytest.raises(CaptureError, match=match):
        parse_capture(raw)


@settings(max_examples=300)
@given(st.binary(max_size=64), st.integers(min_value=0, max_value=200), st.integers(0, 1))
def test_corrupted_files_raise_only_capture_error(junk: bytes, pos: int, which: int) -> None:
    raw = bytearray(_good_files()[which])
    pos = min(pos, len(raw))
    raw[pos : pos + len(junk)] = junk
    with contextlib.suppress(CaptureError):
        parse_capture(bytes(raw))


def test_read_capture_streams_incrementally() -> None:
    out = io.BytesIO()
    w = PcapngWriter(out)
    for i in range(100):
        w.write(i, FRAME)
    out.seek(0)
    it = read_capture(out)
    first = next(it)
    assert first.timestamp_ns == 0
    # Only the first packet has been read, not the whole file.
    assert out.tell() < len(out.getvalue()) // 10
    assert sum(1 for _ in it) == 99


def _blk(o: str, btype: int, body: bytes) -> bytes:
    return struct.pack(o + "II", btype, 12 + len(body)) + body + struct.pack(o + "I", 12 + len(body))


def _opt(o: str, code: int, value: bytes) -> bytes:
    return struct.pack(o + "HH", code, len(value)) + value + bytes(-len(value) % 4)


@st.composite
def _hand_made_pcapng(draw: st.DrawFn) -> tuple[bytes, list[tuple[int, bytes, int, PacketDirection]]]:
    """Several sections (each in its own byte order), several interfaces with their own
    time resolution and offset, packets with direction flags; plus what they must read as."""
    out, expect = b"", []
    for _section in range(draw(st.integers(1, 3))):
        o = draw(st.sampled_from("<>"))
        shb_opts = draw(st.sampled_from([b"", _opt(o, 4, b"hw") + _opt(o, 0, b"")]))
        out += _blk(o, 0x0A0D0D0A, struct.pack(o + "IHHq", 0x1A2B3C4D, 1, 0, -1) + shb_opts)
        units: list[tuple[int, int, int]] = []
        for _iface in range(draw(st.integers(1, 3))):
            res = draw(st.sampled_from([None, 6, 9, 3, 0x80 | 10]))
            offset_s = draw(st.integers(-5, 5))
            opts = b"" if res is None else _opt(o, 9, bytes([res]))
            opts += _opt(o, 14, struct.pack(o + "q", offset_s)) if offset_s else b""
            out += _blk(o, 1, struct.pack(o + "HHI", 1, 0, 0) + opts + (_opt(o, 0, b"") if opts else b""))
            num, den = ((1000, 1) if res is None else (10**9, 1 << 10) if res & 0x80
                        else (10 ** (9 - res), 1))
            units.append((num, den, offset_s))
        for _packet in range(draw(st.integers(0, 4))):
            iid = draw(st.integers(0, len(units) - 1))
            data = draw(st.binary(max_size=30))
            ts = draw(st.integers(0, 2**40))
            flags = draw(st.integers(0, 3))
            body = struct.pack(o + "IIIII", iid, ts >> 32, ts & 0xFFFFFFFF, len(data), len(data))
            body += data + bytes(-len(data) % 4)
            if flags:
                body += _opt(o, 2, struct.pack(o + "I", flags)) + _opt(o, 0, b"")
            out += _blk(o, 6, body)
            num, den, offset_s = units[iid]
            direction = PacketDirection(flags) if flags != 3 else PacketDirection.UNKNOWN
            expect.append((ts * num // den + offset_s * 10**9, data, iid, direction))
    return out, expect


@settings(max_examples=300)
@given(_hand_made_pcapng())
def test_pcapng_sections_interfaces_byte_orders(
        made: tuple[bytes, list[tuple[int, bytes, int, PacketDirection]]]) -> None:
    raw, expect = made
    got = [(r.timestamp_ns, r.data, r.interface_id, r.direction) for r in parse_capture(raw)]
    assert got == expect


@settings(max_examples=300)
@given(_hand_made_pcapng(), st.integers(0, 10**6), st.binary(min_size=1, max_size=8))
def test_corrupted_multi_section_pcapng_raises_only_capture_error(
        made: tuple[bytes, list[tuple[int, bytes, int, PacketDirection]]], pos: int, junk: bytes) -> None:
    raw = bytearray(made[0])
    pos %= len(raw)
    raw[pos : pos + len(junk)] = junk
    with contextlib.suppress(CaptureError):
        parse_capture(bytes(raw))
