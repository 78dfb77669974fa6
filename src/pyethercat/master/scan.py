"""Finding the slaves: count, address, identify, read every SII, rebuild the topology.

Everything that is done per slave is done for all slaves in the same frames:
one APWR per position assigns the station addresses, one FPRD per slave reads
the ESC registers, and the SII of every slave is read in lockstep: each step
writes a read command to every slave's SII interface and reads the status,
address and data back (0x0502-0x050F) in the same frame, so a segment of 100
slaves needs about as many round trips as one slave does (8 bytes per step
where 0x0502 bit 6 offers 8-byte reads, else 4). Each slave stops at its
category end marker (``sii_bytes_needed``).

The topology is rebuilt from the DL status of every slave (frame processing
order from the ET1100 datasheet section I; the parent walk as SOEM's
``ecx_config_init`` does it):
a frame enters a slave at port 0 and leaves through its other open ports in
the order 3, 1, 2; auto-increment positions number the slaves in the order the
frame meets them. Walking that order depth first with each slave's open ports
gives every slave's parent and the parent's port.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar, overload

from pyethercat.errors import (
    EtherCATError,
    SiiError,
    TopologyMismatchError,
    WorkingCounterError,
)
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave_info import EscInfo, Identity, MailboxInfo, Port, SlaveInfo
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.registers import (
    AL_CONTROL,
    AL_ERROR_FLAG,
    AL_STATE_MASK,
    AL_STATUS,
    DL_CONTROL_ALIAS,
    DL_STATUS,
    ECAT_EVENT_MASK,
    ESC_CONFIG,
    SII_CONFIG,
    SII_CONFIG_FORCE_ECAT,
    SII_CONTROL,
    STATION_ADDRESS,
    STATION_ALIAS,
    TYPE,
    EcatEvent,
    SiiControl,
)
from pyethercat.wire.ring import walk_ring
from pyethercat.wire.sii import SII_DEFAULT_MAX_BYTES, SiiInfo, parse_sii, sii_bytes_needed
from pyethercat.wire.sii.model import (
    WORD_ALIAS,
    WORD_CHECKSUM,
)

S = TypeVar("S", bound=SlaveInfo)

__all__ = [
    "DEFAULT_STATION_BASE",
    "Progress",
    "ExpectedSlave",
    "count_slaves",
    "reset_slaves",
    "assign_addresses",
    "read_esc_info",
    "SiiAccess",
    "read_sii_batch",
    "build_topology",
    "check_expected",
    "scan",
    "describe_identity",
]

#: First configured station address the scan hands out (TwinCAT style 1001, 1002...).
DEFAULT_STATION_BASE = 0x1001

#: ``progress(stage, done, total)``; ``total`` may grow while a stage runs.
Progress = Callable[[str, int, int], None]

# 0x0502-0x050F: control/status (2), address (4), data (8).
_SII_WINDOW = 14
_SII_DATA_OFFSET = 6
# Plain ints: flag-enum arithmetic is slow in the per-slave loops below.
_SII_CMD_ERRORS = int(SiiControl.ACK_ERROR | SiiControl.WRITE_ENABLE_ERROR)
_SII_BUSY = int(SiiControl.BUSY)
_SII_ACK_ERROR = int(SiiControl.ACK_ERROR)
_SII_WE_ERROR = int(SiiControl.WRITE_ENABLE_ERROR)
_SII_CMD_READ = int(SiiControl.CMD_READ)
_SII_RETRIES = 3
# A missing acknowledge is the EEPROM's internal write cycle (I2C EEPROMs
# take up to 5-10 ms after a write; a real EK1100 refused commands 2.95 ms
# after one): retried at SOEM's pace (ecx_readeepromFP sleeps 1 ms after
# a NACK), for up to 10 ms.
_SII_NACK_RETRIES = 10
_SII_NACK_PAUSE = 0.001
# A busy read-back means the ESC is still clocking the EEPROM (ET1100/ET1200
# datasheets, section III, SII EEPROM interface: ~0.7 ms for a 4-word read).
# When every reader of the frame was busy, pause before polling again, as
# SOEM does (ecx_eeprom_waitnotbusyFP/AP in ethercatmain.c sleep EC_LOCALDELAY,
# 200 us, before each poll after the first): back-to-back polls of a busy
# EEPROM only fill the wire, and on a virtual clock each poll moves time by
# a few microseconds (a hundred polls per word).
_SII_BUSY_PAUSE = 200e-6
#: Most SII reads of one slave chained in one frame (each a command and its read-back).
_SII_CHAIN = 16
# ESC identification block 0x0000-0x0009.
_ESC_INFO = struct.Struct("<BBHBBBBH")


@dataclass(frozen=True, slots=True)
class ExpectedSlave:
    """One entry of an expected configuration: identity and, optionally, alias and name."""

    identity: Identity
    alias: int | None = None
    name: str | None = None


def describe_identity(identity: Identity, name: str | None = None) -> str:
    text = str(identity)
    return f"{text} ({name})" if name else text


def _check_wkc(what: str, replies: Sequence[Datagram], expected: int = 1) -> None:
    bad = [n for n, r in enumerate(replies) if r.wkc != expected]
    if bad:
        raise WorkingCounterError(f"{what}: position {bad[0]} did not answer", expected,
                                  replies[bad[0]].wkc)


# --- count, reset, address -------------------------------------------------------------


def count_slaves(scheduler: Scheduler) -> int:
    """Number of slaves on the segment: the working counter of a BRD of 0x0000."""
    reply = scheduler.transact_one(Datagram.device(Command.BRD, 0, TYPE, 2))
    return reply.wkc


def reset_slaves(scheduler: Scheduler) -> None:
    """Broadcast the start-up defaults: alias addressing off, INIT with acknowledge, SII to ECAT.

    Also sets the ECAT event mask to DL-status and AL-status changes, so the
    IRQ field of every datagram tells when a link or a slave's state changed
    (SOEM sets only the DL-status bit).
    """
    scheduler.transact([
        Datagram.device(Command.BWR, 0, DL_CONTROL_ALIAS, b"\x00"),
        Datagram.device(Command.BWR, 0, AL_CONTROL,
                        struct.pack("<H", AlState.INIT | AL_ERROR_FLAG)),
        Datagram.device(Command.BWR, 0, ECAT_EVENT_MASK,
                        struct.pack("<H", EcatEvent.DL_STATUS | EcatEvent.AL_STATUS)),
    ])
    take_sii_ownership(scheduler)


def take_sii_ownership(scheduler: Scheduler, station: int | None = None) -> None:
    """Give the SII interface to EtherCAT (force, then release the force bit), like SOEM."""
    if station is None:
        mk = [Datagram.device(Command.BWR, 0, SII_CONFIG, bytes([v]))
              for v in (SII_CONFIG_FORCE_ECAT, 0)]
    else:
        mk = [Datagram.device(Command.FPWR, station, SII_CONFIG, bytes([v]))
              for v in (SII_CONFIG_FORCE_ECAT, 0)]
    scheduler.transact(mk[:1])
    scheduler.transact(mk[1:])


def assign_addresses(scheduler: Scheduler, count: int, base: int = DEFAULT_STATION_BASE) -> list[int]:
    """Write station addresses ``base``, ``base + 1``... by position (one frame for all)."""
    if count and not (base > 0 and base + count - 1 <= 0xFFFF):
        raise ValueError(f"station addresses 0x{base:04X}+{count} do not fit 16 bits")
    stations = [base + n for n in range(count)]
    replies = scheduler.transact([
        Datagram.positional(Command.APWR, n, STATION_ADDRESS, struct.pack("<H", st))
        for n, st in enumerate(stations)])
    _check_wkc("station address assignment", replies)
    return stations


def read_esc_info(scheduler: Scheduler, slaves: Sequence[SlaveInfo]) -> None:
    """Read ESC identification, alias, DL status, AL status, SII control and ESC configuration."""
    reads = []
    for s in slaves:
        st = s.station_address
        reads += [Datagram.device(Command.FPRD, st, TYPE, _ESC_INFO.size),
                  Datagram.device(Command.FPRD, st, STATION_ALIAS, 2),
                  Datagram.device(Command.FPRD, st, DL_STATUS, 2),
                  Datagram.device(Command.FPRD, st, AL_STATUS, 6),
                  Datagram.device(Command.FPRD, st, SII_CONTROL, 2),
                  Datagram.device(Command.FPRD, st, ESC_CONFIG, 1)]
    replies = scheduler.transact(reads)
    for n, s in enumerate(slaves):
        esc, alias, dl, al, sii, config = replies[6 * n:6 * n + 6]
        _check_wkc(f"reading the registers of {s.describe()}", [esc, alias, dl, al, sii, config])
        s.esc = EscInfo(*_ESC_INFO.unpack(esc.data))
        (s.alias,) = struct.unpack("<H", alias.data)
        (s.dl_status,) = struct.unpack("<H", dl.data)
        status, _, code = struct.unpack("<HHH", al.data)
        try:
            s.al_state = AlState(status & AL_STATE_MASK)
        except ValueError:
            s.al_state = AlState.NONE
        s.al_error = bool(status & AL_ERROR_FLAG)
        s.al_status_code = code if s.al_error else 0
        (ctrl,) = struct.unpack("<H", sii.data)
        s.sii_read_8 = bool(ctrl & SiiControl.READ_8_BYTES)
        s.esc_config = config.data[0]
        s.ports = [Port.from_registers(p, s.esc.port_descriptor, s.dl_status) for p in range(4)]


# --- SII access ------------------------------------------------------------------------


@dataclass
class SiiAccess:
    """How to reach one slave's SII interface: configured address or ring position."""

    adp: int
    positional: bool = False
    read_8: bool = False
    label: str = ""

    @classmethod
    def of(cls, slave: SlaveInfo) -> SiiAccess:
        return cls(slave.station_address, False, slave.sii_read_8, slave.describe())

    @classmethod
    def at_position(cls, position: int, read_8: bool = False) -> SiiAccess:
        return cls((-position) & 0xFFFF, True, read_8, f"slave {position}")

    def rd(self, address: int, size: int) -> Datagram:
        return Datagram.device(Command.APRD if self.positional else Command.FPRD, self.adp,
                               address, size)

    def wr(self, address: int, data: bytes) -> Datagram:
        return Datagram.device(Command.APWR if self.positional else Command.FPWR, self.adp,
                               address, data)


@dataclass
class _Reader:
    access: SiiAccess
    data: bytearray = field(default_factory=bytearray)
    target: int = 0
    done: bool = False
    waiting: bool = False  # command issued, result not seen yet
    failures: int = 0
    polls: int = 0  # busy read-backs in a row
    error: str | None = None

    @property
    def word(self) -> int:
        return len(self.data) // 2

    @property
    def chunk(self) -> int:
        return 8 if self.access.read_8 else 4


def _sii_command(cmd: int, word: int) -> bytes:
    return struct.pack("<HI", cmd, word)


def _steps(r: _Reader, chain: bool) -> int:
    """How many reads of ``r`` to chain in the next frame: what is known to be needed."""
    if not chain or r.waiting:
        return 1
    left = max(r.target - len(r.data), r.chunk)
    return min(_SII_CHAIN, -(-left // r.chunk))


def read_sii_batch(scheduler: Scheduler, accesses: Sequence[SiiAccess], *,
                   max_bytes: int = SII_DEFAULT_MAX_BYTES, max_polls: int = 1000,
                   length: int | None = None, progress: Progress | None = None,
                   broadcast: bool = False) -> list[bytes | SiiError]:
    """Read the whole SII of every slave in lockstep; one result per access.

    Each result is the image from word 0 up to and including the category
    end marker (or what could be read, if the chain has none), or a
    :class:`SiiError` saying why that slave's SII could not be read. With
    ``length`` exactly that many bytes are read instead, whatever they hold.

    Every read is a command write and the read-back of status, address and
    data in the same frame. While every ESC has served its commands before
    the read-back (a fast EEPROM emulation, the simulator), the reads a
    slave is known to need (up to the next category header) are chained in
    one frame, ``_SII_CHAIN`` at most; the first busy status turns chaining
    off and the reader polls as usual. Each read-back is checked against
    the word it asked for, so a command an ESC ignored never yields wrong
    data. ``broadcast=True`` (only when ``accesses`` are every slave of the
    segment) sends one BWR command to all slaves instead of one FPWR each
    while they all read the same word.
    """
    def needed(data: bytes) -> int | None:
        if length is not None:
            return length if len(data) < length else None
        return sii_bytes_needed(data, max_bytes=max_bytes)

    readers = [_Reader(a, target=needed(b"") or 0) for a in accesses]
    chain = True
    window = _SII_WINDOW
    while True:
        active = [r for r in readers if not r.done]
        if progress is not None:
            have = sum(len(r.data) for r in readers)
            total = sum(len(r.data) if r.done else max(r.target, len(r.data)) for r in readers)
            progress("sii", have, total)
        if not active:
            break
        datagrams: list[Datagram] = []
        # Per datagram: (reader, step, is the read-back); None for a broadcast command.
        slots: list[tuple[_Reader, int, bool] | None] = []
        first = active[0]
        if (broadcast and chain and not any(r.waiting for r in active)
                and all(r.word == first.word and r.chunk == first.chunk for r in active)):
            steps = {id(r): _steps(r, chain) for r in active}
            for j in range(max(steps.values())):
                word = first.word + j * first.chunk // 2
                datagrams.append(Datagram.device(Command.BWR, 0, SII_CONTROL,
                                                 _sii_command(_SII_CMD_READ, word)))
                slots.append(None)
                for r in active:
                    if j < steps[id(r)]:
                        datagrams.append(r.access.rd(SII_CONTROL, window))
                        slots.append((r, j, True))
        else:
            for r in active:
                for j in range(_steps(r, chain)):
                    if j or not r.waiting:
                        # Command and read-back in one frame: an ESC that answers fast gives
                        # the data at once; a slow one shows busy and is polled again.
                        word = r.word + j * r.chunk // 2
                        datagrams.append(r.access.wr(SII_CONTROL,
                                                     _sii_command(_SII_CMD_READ, word)))
                        slots.append((r, j, False))
                    datagrams.append(r.access.rd(SII_CONTROL, window))
                    slots.append((r, j, True))
        replies = scheduler.transact(datagrams)
        nacked = False
        progressed = False
        # Readers whose remaining chained steps in this frame are void.
        skip: set[int] = set()
        for slot, reply in zip(slots, replies, strict=True):
            if slot is None:
                continue
            r, j, is_read = slot
            if id(r) in skip:
                continue
            if not is_read:
                if reply.wkc != 1:
                    skip.add(id(r))
                    r.waiting = False
                    if not j:
                        _fail(r, f"SII read command at word 0x{r.word:04X} not taken "
                                 f"(working counter {reply.wkc})")
                else:
                    r.waiting = True
                continue
            if reply.wkc != 1:
                skip.add(id(r))
                r.waiting = False
                if not j:
                    _fail(r, f"SII status read failed (working counter {reply.wkc})")
                continue
            ctrl, addr = struct.unpack_from("<HI", reply.data)
            if ctrl & _SII_BUSY:
                # A real EEPROM: its command runs now; poll it, chain no more.
                chain = False
                r.waiting = True
                skip.add(id(r))
                r.polls += 1
                if r.polls > max_polls:
                    # Counted per slave: slaves whose reads run staggered
                    # keep some slave busy in every frame for the whole scan.
                    r.done = True
                    r.error = f"SII interface stays busy at word 0x{r.word:04X}"
                continue
            r.waiting = False
            r.polls = 0
            if ctrl & _SII_CMD_ERRORS or (addr & 0xFFFF) != r.word:
                skip.add(id(r))
                if j:
                    # A chained command the ESC did not take: read on from here.
                    chain = chain and not ctrl & _SII_CMD_ERRORS
                    continue
                what = ("missing acknowledge" if ctrl & _SII_ACK_ERROR else
                        "write-enable error" if ctrl & _SII_WE_ERROR else
                        f"address register shows word 0x{addr:04X}")
                nacked = nacked or bool(ctrl & _SII_ACK_ERROR)
                _fail(r, f"SII read at word 0x{r.word:04X}: {what} (status 0x{ctrl:04X})",
                      _SII_NACK_RETRIES if ctrl & _SII_ACK_ERROR else _SII_RETRIES)
                continue
            r.failures = 0
            progressed = True
            r.data += reply.data[_SII_DATA_OFFSET:_SII_DATA_OFFSET + r.chunk]
            need = needed(bytes(r.data))
            if need is None or (length is None and len(r.data) >= max_bytes):
                r.done = True
                skip.add(id(r))
                if length is not None:
                    del r.data[length:]
            else:
                r.target = max(r.target, need)
        if not progressed and any(r.waiting and r.polls for r in active):
            scheduler.sleep(_SII_BUSY_PAUSE)
        # Clear error bits of slaves that will retry (the ESC refuses commands until then).
        clear = [r for r in readers if not r.done and r.failures and not r.waiting]
        if clear:
            if nacked:
                scheduler.sleep(_SII_NACK_PAUSE)
            scheduler.transact([r.access.wr(SII_CONTROL, b"\0\0") for r in clear])
    out: list[bytes | SiiError] = []
    for r in readers:
        if r.error is not None:
            out.append(SiiError(f"{r.access.label}: {r.error}"))
        else:
            out.append(bytes(r.data))
    return out


def _fail(r: _Reader, why: str, retries: int = _SII_RETRIES) -> None:
    r.failures += 1
    if r.failures > retries:
        r.done = True
        r.error = why


# --- slave objects from SII ------------------------------------------------------------


def apply_sii(slave: SlaveInfo, image: bytes) -> None:
    """Parse ``image`` and fill the slave's identity, name, mailbox and SII fields."""
    slave.sii_image = image
    try:
        info: SiiInfo = parse_sii(image)
    except SiiError as exc:
        slave.sii_error = str(exc)
        return
    slave.sii = info
    slave.identity = Identity(info.vendor_id, info.product_code, info.revision, info.serial)
    slave.name = (info.device_name or info.order_number
                  or f"0x{info.vendor_id:08X}:0x{info.product_code:08X}")
    (rx, tx), (boot_rx, boot_tx) = info.mailbox_layout(), info.mailbox_layout(boot=True)
    slave.mailbox = MailboxInfo(*rx, *tx, int(info.mailbox_protocols), *boot_rx, *boot_tx)
    if not slave.alias and info.station_alias not in (0, 0xFFFF):
        # The register wins; the SII word only fills in when the ESC did not load it.
        slave.alias = info.station_alias


# --- topology --------------------------------------------------------------------------


def build_topology(slaves: Sequence[SlaveInfo]) -> bool:
    """Set ``parent``, ``parent_port``, ``children`` and port peers from the open ports.

    Returns True when the walk accounts for exactly the slaves found; False
    when the ports do not explain the ring (then every slave that could not
    be placed hangs on the slave before it, as SOEM would guess).
    """
    for s in slaves:
        s.parent, s.parent_port, s.children = None, None, {}
        for p in s.ports:
            p.peer = None
    if not slaves:
        return True
    parents, explained = walk_ring([0] * len(slaves), [set(s.active_ports) for s in slaves])
    for pos, hang in enumerate(parents):
        if hang is not None:
            _attach(slaves[hang[0]], hang[1], slaves[pos])
    for pos in range(max(explained, 1), len(slaves)):
        prev, last = slaves[pos - 1], slaves[pos]
        free = [p for p in (1, 3, 2) if p not in prev.children]
        _attach(prev, free[0] if free else 1, last)
    return explained == len(slaves)


def _attach(parent: SlaveInfo, port: int, child: SlaveInfo) -> None:
    child.parent = parent
    child.parent_port = port
    parent.children[port] = child
    parent.ports[port].peer = child
    child.ports[0].peer = parent


# --- expected configuration ------------------------------------------------------------


def check_expected(slaves: Sequence[SlaveInfo],
                   expected: Sequence[Identity | ExpectedSlave]) -> None:
    """Raise :class:`TopologyMismatchError` unless the slaves match ``expected`` position by position."""
    for pos, item in enumerate(expected):
        exp = item if isinstance(item, ExpectedSlave) else ExpectedSlave(item)
        if pos >= len(slaves):
            raise TopologyMismatchError(
                f"position {pos}: expected {describe_identity(exp.identity, exp.name)}, "
                f"found no slave (segment has {len(slaves)} slaves, expected {len(expected)})")
        s = slaves[pos]
        if not exp.identity.matches(s.identity):
            raise TopologyMismatchError(
                f"position {pos}: expected {describe_identity(exp.identity, exp.name)}, "
                f"found {describe_identity(s.identity, s.name)}")
        if exp.alias is not None and exp.alias != s.alias:
            raise TopologyMismatchError(
                f"position {pos} ({s.name}): expected alias {exp.alias}, found {s.alias}")
    if len(slaves) > len(expected):
        s = slaves[len(expected)]
        raise TopologyMismatchError(
            f"position {len(expected)}: expected no slave, found "
            f"{describe_identity(s.identity, s.name)} (segment has {len(slaves)} slaves, "
            f"expected {len(expected)})")


# --- the whole scan --------------------------------------------------------------------


@overload
def scan(scheduler: Scheduler, *, make: Callable[[int, int], S], station_base: int = ...,
         reset: bool = ..., read_sii: bool = ...,
         expected: Sequence[Identity | ExpectedSlave] | None = ...,
         progress: Progress | None = ..., max_sii_bytes: int = ...) -> list[S]: ...


@overload
def scan(scheduler: Scheduler, *, make: None = ..., station_base: int = ...,
         reset: bool = ..., read_sii: bool = ...,
         expected: Sequence[Identity | ExpectedSlave] | None = ...,
         progress: Progress | None = ..., max_sii_bytes: int = ...) -> list[SlaveInfo]: ...


def scan(scheduler: Scheduler, *, make: Callable[[int, int], SlaveInfo] | None = None,
         station_base: int = DEFAULT_STATION_BASE, reset: bool = True,
         read_sii: bool = True, expected: Sequence[Identity | ExpectedSlave] | None = None,
         progress: Progress | None = None,
         max_sii_bytes: int = SII_DEFAULT_MAX_BYTES) -> list[Any]:
    """Find, address and identify every slave; returns them in ring order.

    ``make(position, station_address)`` makes each slave object (default
    :class:`SlaveInfo`; the master makes its :class:`Slave` handles).
    ``reset`` broadcasts INIT (with error acknowledge) and the start-up
    defaults first; without it the slaves keep their states (a listing tool).
    SII problems of one slave do not stop the scan: that slave gets
    ``sii_error`` and no identity; a given ``expected`` configuration then
    fails on it.
    """
    def report(stage: str, done: int, total: int) -> None:
        if progress is not None:
            progress(stage, done, total)

    report("count", 0, 1)
    count = count_slaves(scheduler)
    report("count", 1, 1)
    if reset:
        reset_slaves(scheduler)
    else:
        take_sii_ownership(scheduler)
    stations = assign_addresses(scheduler, count, station_base)
    factory = SlaveInfo if make is None else make
    slaves = [factory(pos, st) for pos, st in enumerate(stations)]
    report("registers", 0, 1)
    read_esc_info(scheduler, slaves)
    report("registers", 1, 1)
    if read_sii and slaves:
        # Every slave of the segment is read: one broadcast command serves them all.
        images = read_sii_batch(scheduler, [SiiAccess.of(s) for s in slaves],
                                max_bytes=max_sii_bytes, progress=progress,
                                broadcast=len(slaves) == count)
        for s, img in zip(slaves, images, strict=True):
            if isinstance(img, EtherCATError):
                s.sii_error = str(img)
            else:
                apply_sii(s, img)
    for s in slaves:
        if not s.name:
            s.name = "?"
    build_topology(slaves)
    if expected is not None:
        check_expected(slaves, expected)
    return slaves


# Re-exported for callers that patch SII words (alias, checksum) before writing.
SII_WORD_ALIAS = WORD_ALIAS
SII_WORD_CHECKSUM = WORD_CHECKSUM
