"""Fidelity against real hardware: replay corpus captures into simulated twins.

The corpus (../shared/corpus, MANIFEST.md) holds captures taken on real
Beckhoff slaves together with those slaves' SII dumps. Each master-sent frame
of a capture is fed, in order and with the capture's timing (the segment's
own wire-time clock advance is off: the capture's time stamps are the clock),
into a segment built from the same SII dumps; the simulated reply is compared
with the reply the real slaves gave in every field: the Ethernet destination
and source MACs, and per datagram the command, index, address, length word
(length, circulating and more-follows bits), IRQ field, data and working
counter.

The slaves get their ESC profile from their SII identity (sim.profiles
DEVICE_PROFILES: EK1100, EL2828, EL2889 board profiles with the identity,
DC, SII and DL-status behaviour of the real devices; the EL2004 has no board
profile, the generic ET1200). The segment starts in INIT as built, with one
piece of history: the captured slaves had been on the bus before, and the
master of an earlier session read their DL status after their links came up
(SOEM's slaveinfo does so at every start, as this corpus's captures show), so
no DL-status event is pending: one BRD of 0x0110 precedes the replay. (Where
a slave's event was pending in a capture, e.g. the EL1004 of
soem-sdinfo-ek1100-el1004, its link had changed since.)

Only time-dependent data may differ; ``TIME_DEPENDENT`` lists each class of
difference with its reason, and anything else is "unexplained" and fails.
An EEPROM-busy difference is excused only when the time since the slave's
SII command lies inside the busy window measured on that board
(``EEPROM_BUSY_WINDOWS``): there the real chip could have shown either.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame, is_ethercat
from pyethercat.wire.pcap import parse_capture
from pyethercat.wire.registers import (
    DC_SYSTEM_TIME,
    SII_COMMAND_MASK,
    SII_CONTROL,
)

# capture -> SII dumps of the slaves on its bus, in bus order
CAPTURES = {
    "ethercrab_replay-ek1100-el2828-el2889.pcapng": ("ek1100", "el2828", "el2889"),
    "ethercrab_replay-dc.pcapng": ("ek1100", "el2828", "el2889"),
    "ethercrab_replay-issue-255.pcapng": ("ek1100", "el2828", "el2889"),
    "ethercrab_replay-ek1100-alias-address.pcapng": ("ek1100", "el2828", "el2889"),
    "ethercrab_rs-example-sii-el2004.pcapng": ("ek1100", "el2004", "el2004"),
    "ethercrab_soem-sdinfo-ek1100-only.pcapng": ("ek1100",),
}

_DC_START, _DC_END = 0x0900, 0x0A00
_SII_BUSY = 0x8000
_SII_BUSY_AND_COMMAND = _SII_BUSY | SII_COMMAND_MASK


@dataclass
class Diff:
    """One datagram whose simulated reply differs from the real one."""

    frame: int
    position: int
    datagram: Datagram
    real: Datagram
    sim: Datagram | None
    reason: str

    def describe(self) -> str:
        d = self.datagram
        where = (
            f"0x{d.address:08X}"
            if Command(d.command).is_logical
            else f"adp 0x{d.address & 0xFFFF:04X} ado 0x{d.address >> 16:04X}"
        )
        sim = "no reply" if self.sim is None else f"wkc {self.sim.wkc} data {bytes(self.sim.data).hex()}"
        return (
            f"frame {self.frame} dg {self.position} {d.command_name} {where}: "
            f"real wkc {self.real.wkc} data {bytes(self.real.data).hex()} / sim {sim} "
            f"[{self.reason}]"
        )


# Each class of difference the replay may show, with its reason.
TIME_DEPENDENT = {
    "dc-time": (
        "distributed-clock times: receive-time latches of ports a frame passed "
        "(0x0900-0x0907; their port-1 minus port-0 difference must match within "
        f"{20} ns, it does not depend on the clock's origin), system time and processing-unit receive time (0x0910-0x091F), "
        "system time difference (0x092C), SYNC/latch times (0x0990-0x099F, 0x09B0-0x09CF), "
        "and ARMW/FRMW of the system time: a real chip's clock runs from its power-on "
        "(minutes before the capture), ours from the segment's creation; every other "
        "byte of such a datagram (ports that never latched: 'hoff', 0, 'Verl'; offsets "
        "and delays the master wrote) and the working counter must be equal"
    ),
    "eeprom-busy": (
        "SII control/status (0x0502) busy bit and running command (bits 15, 10:8) read "
        "at a time after the slave's SII command that lies inside the busy window measured "
        "on that board (EEPROM_BUSY_WINDOWS): the real chip could show either"
    ),
}

#: Read-command busy window of each board as the corpus captures show it: the
#: longest time after a read command at which 0x0502 still read busy, and the
#: shortest at which it read idle, over all the replayed captures (measured by
#: ``_eeprom_windows`` when first needed; e.g. EK1100 675.6-711.4 us).
EEPROM_BUSY_WINDOWS: dict[str, tuple[int, int]] = {}

# DC register bytes that hold times (see TIME_DEPENDENT["dc-time"]).
_TIME_BYTES = frozenset(
    [*range(0x0900, 0x0908), *range(0x0910, 0x0920), *range(0x092C, 0x0930),
     *range(0x0990, 0x09A0), *range(0x09B0, 0x09D0)]
)
# A receive-time word of a port that never latched keeps its power-on value
# on both sides (Beckhoff ASICs: port 1 "hoff"): then it must be equal.
_UNLATCHED = (bytes(4), b"hoff")
#: Largest allowed difference between the real and the simulated port-1 minus
#: port-0 receive time (the simulated clock has the real 10 ns tick).
PORT_DIFF_TOLERANCE_NS = 20


def _port_diff(data: bytes, ado: int) -> int | None:
    """Port-1 minus port-0 receive time of a read covering 0x0900-0x0907 (None: not both latched)."""
    at = 0x0900 - ado
    if at < 0 or at + 8 > len(data):
        return None
    t0, t1 = data[at: at + 4], data[at + 4: at + 8]
    if t0 in _UNLATCHED or t1 in _UNLATCHED:
        return None
    d = (int.from_bytes(t1, "little") - int.from_bytes(t0, "little")) & 0xFFFF_FFFF
    return d - (1 << 32) if d >= 1 << 31 else d


def _dc_time_only(ado: int, real: bytes, sim: bytes) -> bool:
    """Whether ``real`` and ``sim`` (read at ``ado``) differ only in DC time bytes.

    Latched receive times may differ in their origin, not in the time the
    frame spent behind port 1."""
    dr, ds = _port_diff(real, ado), _port_diff(sim, ado)
    if dr is not None and (ds is None or abs(dr - ds) > PORT_DIFF_TOLERANCE_NS):
        return False
    for i, (r, m) in enumerate(zip(real, sim, strict=True)):
        a = ado + i
        if r == m:
            continue
        if a not in _TIME_BYTES:
            return False
        if a < 0x0908:
            w = a - (a - 0x0900) % 4 - ado
            if w >= 0 and real[w: w + 4] in _UNLATCHED:
                return False
    return True


def _classify(sent: Datagram, real: Datagram, sim: Datagram | None,
              busy_window: bool = False) -> str:
    """The class of a data difference (``busy_window``: the read falls into the
    board's measured EEPROM busy window)."""
    cmd = Command(sent.command)
    if sim is None or cmd.is_logical or real.wkc != sim.wkc:
        return "unexplained"
    ado = sent.address >> 16
    end = ado + len(sent.data)
    r, m = bytes(real.data), bytes(sim.data)
    if ado < _DC_END and end > _DC_START and cmd.reads:
        if cmd in (Command.ARMW, Command.FRMW) and ado == DC_SYSTEM_TIME:
            return "dc-time"
        if _dc_time_only(ado, r, m):
            return "dc-time"
    if ado <= SII_CONTROL < end:
        # While busy, the chip shows the command bits (10:8) with bit 15.
        off = SII_CONTROL - ado
        rr, ss = bytearray(r), bytearray(m)
        if busy_window and len(rr) >= off + 2 and (rr[off + 1] | ss[off + 1]) & (_SII_BUSY >> 8):
            rr[off + 1] &= ~(_SII_BUSY_AND_COMMAND >> 8) & 0xFF
            ss[off + 1] &= ~(_SII_BUSY_AND_COMMAND >> 8) & 0xFF
            if rr == ss:
                return "eeprom-busy"
    return "unexplained"


def _pairs(path: Path) -> list[tuple[int, bytes, bytes]]:
    """(time ns, sent frame, returned frame) in capture order."""
    out: list[tuple[int, bytes, bytes]] = []
    pending: tuple[int, bytes] | None = None
    for rec in parse_capture(path.read_bytes()):
        data = bytes(rec.data)
        if not is_ethercat(data):
            continue
        returned = bool(data[6] & 0x02)
        if not returned:
            pending = (rec.timestamp_ns, data)
        elif pending is not None:
            out.append((pending[0], pending[1], data))
            pending = None
    return out


#: (capture, station, real port-1 minus port-0, simulated) of every latch read.
PORT_DIFFS: list[tuple[str, int, int, int | None]] = []

#: Datagram header fields compared besides data and working counter.
FIELDS = ("command", "index", "address", "circulating", "more", "irq")


@dataclass
class Replay:
    """What one capture's replay found."""

    total: int = 0
    frames: int = 0
    diffs: list[Diff] = field(default_factory=list)
    #: Differences per field (a datagram may differ in several).
    fields: Counter[str] = field(default_factory=Counter)
    #: Frames whose simulated reply was lost, or whose MACs differ.
    lost: int = 0
    macs: int = 0

    @property
    def identical(self) -> int:
        return self.total - len(self.diffs)

    @property
    def explained(self) -> int:
        return sum(d.reason in TIME_DEPENDENT for d in self.diffs)


def _sii_command_at(d: Datagram) -> int:
    """The SII command a write of 0x0502 starts (0: none)."""
    ado = d.address >> 16
    off = SII_CONTROL + 1 - ado
    if Command(d.command) not in (Command.FPWR, Command.APWR) or not 0 <= off < len(d.data):
        return 0
    return int(d.data[off]) & 0x07


def _replay(corpus: Path, capture: str, devices: tuple[str, ...]) -> Replay:
    toml = "".join(
        f'[[slave]]\nname = "s{i}"\nsii = "{corpus / "sii" / f"ethercrab_{dev}.bin"}"\n'
        for i, dev in enumerate(devices)
    )
    clock = VirtualClock(1_000_000_000)
    topo = parse_topology(toml, source=capture)
    segment = topo.build(clock=clock)
    # The capture's time stamps drive the clock; the segment must not add its own wire time.
    segment.advance_clock = False
    # History (see the module docstring): an earlier session read DL status.
    segment.process(encode_frame([Datagram.device(Command.BRD, 0, 0x0110, 2)]))
    pairs = _pairs(corpus / "pcap" / capture)
    assert pairs, f"{capture}: no sent/returned frame pairs"
    out = Replay(frames=len(pairs))
    commanded: dict[tuple[int, int], int] = {}  # (command kind, adp) -> time of the SII read command
    t_prev = pairs[0][0]
    for n, (t, sent_raw, real_raw) in enumerate(pairs):
        if t > t_prev:
            clock.advance(t - t_prev)
        t_prev = t
        sim_raw = segment.process(sent_raw)
        # strict=False: one early ethercrab capture pads inside the EtherCAT length.
        sent = decode_frame(sent_raw, strict=False).datagrams
        real = decode_frame(real_raw, strict=False).datagrams
        sim = decode_frame(sim_raw, strict=False).datagrams if sim_raw is not None else []
        if sim_raw is None:
            out.lost += 1
        elif sim_raw[0:12] != real_raw[0:12]:
            out.macs += 1
        for k, (s, r) in enumerate(zip(sent, real, strict=True)):
            out.total += 1
            m = sim[k] if k < len(sim) else None
            cmd = Command(s.command)
            if _sii_command_at(s) == 1 and r.wkc:
                commanded[(cmd in (Command.FPWR, Command.FPRD), s.address & 0xFFFF)] = t
            if cmd == Command.FPRD and r.wkc:
                dr = _port_diff(bytes(r.data), s.address >> 16)
                if dr is not None:
                    ds = _port_diff(bytes(m.data), s.address >> 16) if m is not None else None
                    PORT_DIFFS.append((capture, s.address & 0xFFFF, dr, ds))
            header = [f for f in FIELDS if m is None or getattr(m, f) != getattr(r, f)]
            out.fields.update(header)
            data_equal = m is not None and m.wkc == r.wkc and bytes(m.data) == bytes(r.data)
            if m is not None and m.wkc != r.wkc:
                out.fields["wkc"] += 1
            if data_equal and not header:
                continue
            if not data_equal:
                out.fields["data"] += 1
            reason = "unexplained"
            if not header:
                since = commanded.get((cmd == Command.FPRD, s.address & 0xFFFF))
                reason = _classify(s, r, m, since is not None and _in_busy_window(
                    segment, cmd, s.address & 0xFFFF, t - since))
            out.diffs.append(Diff(n, k, s, r, m, reason))
    return out


def _in_busy_window(segment: object, cmd: Command, adp: int, elapsed: int) -> bool:
    """Whether ``elapsed`` ns after its read command falls into the slave's measured busy window."""
    slaves = segment.slaves  # type: ignore[attr-defined]
    if cmd == Command.FPRD:
        found = [sl for sl in slaves if sl.u16(0x0010) == adp]
    else:
        found = [slaves[(-adp) & 0xFFFF]] if (-adp) & 0xFFFF < len(slaves) else []
    if not found:
        return False
    window = _busy_windows().get(found[0].esc.profile.name)
    return window is not None and window[0] <= elapsed <= window[1]


#: Buses of captures used for EEPROM timing only (a slave on them has no SII dump in the
#: corpus, so they are not replayed): capture -> boards in bus order.
TIMING_ONLY = {
    "ethercrab_soem-sdinfo-ek1100-el1004.pcapng": ("ek1100", "el1004"),
}


def _stations(capture: str, board: str) -> list[int]:
    """Station addresses of ``board`` in ``capture`` (SOEM numbers them from 0x1001)."""
    first = 0x1001 if "soem" in capture else 0x1000
    bus = CAPTURES[capture] if capture in CAPTURES else TIMING_ONLY[capture]
    return [first + i for i, dev in enumerate(bus) if dev.upper() == board]


def _busy_windows() -> dict[str, tuple[int, int]]:
    if not EEPROM_BUSY_WINDOWS:
        corpus = Path(__file__).resolve().parents[3] / "shared" / "corpus"
        for capture in CAPTURES:
            windows = _eeprom_windows(corpus / "pcap" / capture)
            for board in ("EK1100", "EL2828", "EL2889"):
                for st in _stations(capture, board):
                    if st in windows:
                        lo, hi = windows[st]
                        old = EEPROM_BUSY_WINDOWS.get(board, (0, 1 << 62))
                        EEPROM_BUSY_WINDOWS[board] = (max(old[0], lo), min(old[1], hi))
    return EEPROM_BUSY_WINDOWS


_RESULTS: dict[str, Replay] = {}


def _result(corpus: Path, capture: str) -> Replay:
    if capture not in _RESULTS:
        _RESULTS[capture] = _replay(corpus, capture, CAPTURES[capture])
    return _RESULTS[capture]


def _report(capture: str, r: Replay) -> str:
    reasons = Counter(d.reason for d in r.diffs)
    lines = [
        f"{capture}: {r.frames} frames ({r.lost} lost, {r.macs} with other MACs), "
        f"{r.identical}/{r.total} datagrams identical in every field "
        f"({100.0 * r.identical / r.total:.2f} %), {r.explained} more differ only as explained "
        f"({100.0 * (r.identical + r.explained) / r.total:.2f} % identical or explained)",
        "  differing fields: " + (", ".join(f"{f} {n}" for f, n in r.fields.most_common()) or "none"),
        *(f"  {n:5d} x {reason}" for reason, n in reasons.most_common()),
    ]
    for cls, why in TIME_DEPENDENT.items():
        if reasons.get(cls):
            lines.append(f"  {cls} (excused {reasons[cls]}): {why}")
    firsts: dict[str, Diff] = {}
    for d in r.diffs:
        firsts.setdefault(d.reason, d)
    lines += [f"  e.g. {d.describe()}" for d in firsts.values()]
    return "\n".join(lines)


@pytest.mark.parametrize("capture", sorted(CAPTURES))
def test_replay_every_field(corpus_dir: Path, capture: str) -> None:
    r = _result(corpus_dir, capture)
    print(_report(capture, r))
    assert r.lost == 0 and r.macs == 0, f"{r.lost} replies lost, {r.macs} with other MACs"
    for f in FIELDS:
        assert r.fields[f] == 0, f"{capture}: {r.fields[f]} datagrams differ in {f}\n{_report(capture, r)}"
    unexplained = [d for d in r.diffs if d.reason == "unexplained"]
    assert not unexplained, (
        f"{capture}: {len(unexplained)} unexplained differences:\n"
        + "\n".join(d.describe() for d in unexplained[:40])
    )


def _eeprom_windows(path: Path) -> dict[int, tuple[int, int]]:
    """Per station: (longest busy, shortest idle) time after an SII read command, in ns."""
    last: dict[int, int] = {}
    busy: dict[int, int] = {}
    idle: dict[int, int] = {}
    for t, sent_raw, real_raw in _pairs(path):
        for s, r in zip(decode_frame(sent_raw, strict=False).datagrams,
                        decode_frame(real_raw, strict=False).datagrams, strict=True):
            st = s.address & 0xFFFF
            if Command(s.command) == Command.FPWR and _sii_command_at(s) == 1 and r.wkc:
                last[st] = t
            elif (Command(s.command) == Command.FPRD and r.wkc and st in last
                  and (s.address >> 16) <= SII_CONTROL < (s.address >> 16) + len(r.data)):
                off = SII_CONTROL - (s.address >> 16)
                word = r.data[off] | (r.data[off + 1] << 8) if off + 1 < len(r.data) else 0
                if word & _SII_BUSY:
                    busy[st] = max(busy.get(st, 0), t - last[st])
                else:
                    idle[st] = min(idle.get(st, 1 << 62), t - last.pop(st))
    return {st: (busy.get(st, 0), idle[st]) for st in idle}


#: Board -> (captures the EEPROM read time was fitted on, captures held out). The
#: EL1004 takes the read time fitted on the other boards: no capture of its own was
#: used, the one it appears in (541-773 us) is the check.
EEPROM_FIT = {
    "EK1100": (("ethercrab_replay-ek1100-el2828-el2889.pcapng", "ethercrab_replay-ek1100-alias-address.pcapng"),
               ("ethercrab_replay-dc.pcapng", "ethercrab_replay-issue-255.pcapng",
                "ethercrab_soem-sdinfo-ek1100-only.pcapng", "ethercrab_soem-sdinfo-ek1100-el1004.pcapng")),
    "EL1004": ((), ("ethercrab_soem-sdinfo-ek1100-el1004.pcapng",)),
    "EL2828": (("ethercrab_replay-ek1100-el2828-el2889.pcapng", "ethercrab_replay-ek1100-alias-address.pcapng"),
               ("ethercrab_replay-dc.pcapng", "ethercrab_replay-issue-255.pcapng")),
    "EL2889": (("ethercrab_replay-ek1100-el2828-el2889.pcapng", "ethercrab_replay-ek1100-alias-address.pcapng"),
               ("ethercrab_replay-dc.pcapng", "ethercrab_replay-issue-255.pcapng")),
}


@pytest.mark.parametrize("board", sorted(EEPROM_FIT))
def test_board_eeprom_timing_holds_on_captures_it_was_not_fitted_on(corpus_dir: Path, board: str) -> None:
    """The board profile's read time lies in the busy window each held-out capture shows."""
    read_ns = PROFILES[board].sii_read_ns
    fitted, held_out = EEPROM_FIT[board]
    for role, captures in (("fitted", fitted), ("held out", held_out)):
        for capture in captures:
            windows = _eeprom_windows(corpus_dir / "pcap" / capture)
            for st in _stations(capture, board):
                lo, hi = windows[st]
                print(f"{board} {role} {capture} station 0x{st:04X}: busy up to {lo / 1000:.1f} us, "
                      f"idle from {hi / 1000:.1f} us; profile {read_ns / 1000:.1f} us")
                assert lo <= read_ns <= hi, (board, capture, lo, read_ns, hi)
    checked = [st for capture in held_out for st in _stations(capture, board)]
    assert checked, f"{board}: no held-out capture shows its EEPROM"
    if board in _busy_windows():
        lo, hi = _busy_windows()[board]
        print(f"{board}: busy window over all replayed captures {lo / 1000:.1f}-{hi / 1000:.1f} us")
        assert lo < hi


@pytest.mark.parametrize("capture", ["ethercrab_replay-dc.pcapng",
                                     "ethercrab_replay-ek1100-alias-address.pcapng",
                                     "ethercrab_replay-ek1100-el2828-el2889.pcapng"])
def test_replay_port_time_differences(corpus_dir: Path, capture: str) -> None:
    """The EK1100 (590-600 ns) and EL2828 (310 ns) round trips behind port 1, simulated within 20 ns."""
    _result(corpus_dir, capture)
    seen = [(st, dr, ds) for c, st, dr, ds in PORT_DIFFS if c == capture]
    print(capture, seen)
    assert {st for st, _, _ in seen} == {0x1000, 0x1001}  # EK1100 and EL2828; the EL2889 ends the line
    for st, dr, ds in seen:
        assert ds is not None and abs(dr - ds) <= PORT_DIFF_TOLERANCE_NS, (st, dr, ds)
    assert {dr for st, dr, _ in seen if st == 0x1001} == {310}


def test_dc_time_classification_is_strict() -> None:
    # Latched times may differ; a port that never latched ("hoff"), the unused
    # ports 2/3 and master-written offsets may not.
    real = bytes.fromhex("520f623caa11623c000000005665726c")  # port 1 600 ns after port 0
    sim = (0x04A3E151).to_bytes(4, "little") + (0x04A3E151 + 590).to_bytes(4, "little")
    assert _dc_time_only(0x0900, real, sim + bytes.fromhex("000000005665726c"))
    assert not _dc_time_only(0x0900, real, sim + bytes.fromhex("00000000" + "00000000"))
    # another clock origin is fine, another round trip behind port 1 is not
    slow = (0x04A3E151).to_bytes(4, "little") + (0x04A3E151 + 630).to_bytes(4, "little")
    assert not _dc_time_only(0x0900, real, slow + bytes.fromhex("000000005665726c"))
    unlatched = bytes.fromhex("ec65803c686f6666000000005665726c")
    assert not _dc_time_only(0x0900, unlatched, bytes.fromhex("b3e3a30412345678000000005665726c"))
    assert not _dc_time_only(0x0920, bytes(8), bytes([1]) + bytes(7))


# --- the AKD: a board profile read off one capture, checked on another ----------------------

AKD_CAPTURE = "ethercrab_soem-sdinfo-akd.pcapng"
AKD_HELD_OUT = "ethercrab_twincat-akd-nc-mode.pcapng"

#: What still differs in the AKD's replay (ado -> reason): the drive's firmware, which a
#: board profile does not model. The ESC itself (board profile ``AKD``) answers as the real one.
AKD_FIRMWARE = {
    0x080D: "SM1 status polled while the firmware prepares its mailbox answer: 0.65-2.9 ms after "
            "the request in this capture, longer for some requests (no fixed delay or task "
            "period fits every request)",
    0x1C00: "the mailbox answers: the AKD's CoE dictionary (the simulated AKD has the SII's "
            "mailbox only and answers 'unsupported protocol')",
    0x0130: "AL status: the firmware takes 4-6 ms from INIT to PRE-OP (3 polls)",
    0x0120: "AL control written again 0.56 ms after the first write, before the firmware read "
            "it: the ESC refuses the write (WKC 0) until the PDI has read AL control",
}


def test_akd_replay_differs_only_in_its_firmware(corpus_dir: Path) -> None:
    r = _replay(corpus_dir, AKD_CAPTURE, ("akd",))
    print(_report(AKD_CAPTURE, r))
    assert r.lost == 0 and r.macs == 0
    for f in FIELDS:
        assert r.fields[f] == 0, (f, r.fields[f])
    left = Counter(d.datagram.address >> 16 for d in r.diffs if d.reason == "unexplained")
    for ado, n in sorted(left.items()):
        print(f"  0x{ado:04X}: {n} x {AKD_FIRMWARE.get(ado, 'NOT FIRMWARE')}")
    assert set(left) <= set(AKD_FIRMWARE), {hex(a): n for a, n in left.items() if a not in AKD_FIRMWARE}
    print(f"{AKD_CAPTURE}: {100.0 * (r.identical + r.explained) / r.total:.2f} % identical or "
          f"explained; the rest is firmware ({sum(left.values())} datagrams)")


def test_akd_profile_holds_on_a_capture_it_was_not_read_off(corpus_dir: Path) -> None:
    """TwinCAT's reads of the AKD's identity registers and SII control (twincat-akd-nc-mode)
    equal the simulated AKD's, for every value read off soem-sdinfo-akd: type, revision,
    port descriptor, features (build, FMMU, SM and RAM counts came from this capture)."""
    sii = corpus_dir / "sii" / "ethercrab_akd.bin"
    seg = parse_topology(f'[[slave]]\nname = "akd"\nsii = "{sii}"\n').build()
    esc = seg.slaves[0]
    assert esc.spec.profile.name == "AKD"
    checked = {0x0000, 0x0001, 0x0007, 0x0008, 0x0009, SII_CONTROL}
    seen: Counter[int] = Counter()
    for rec in parse_capture((corpus_dir / "pcap" / AKD_HELD_OUT).read_bytes()):
        data = bytes(rec.data)
        if not is_ethercat(data) or not data[6] & 0x02:
            continue
        for d in decode_frame(data, strict=False).datagrams:
            if Command(d.command) not in (Command.APRD, Command.FPRD, Command.BRD) or d.wkc != 1:
                continue
            ado = d.address >> 16
            for i, real in enumerate(bytes(d.data)):
                if ado + i in checked:
                    sim = esc.read(ado + i, 1)[0]
                    assert real == sim, (f"0x{ado + i:04X}", hex(real), hex(sim))
                    seen[ado + i] += 1
    print({f"0x{a:04X}": n for a, n in sorted(seen.items())})
    assert set(seen) == checked
