"""EtherCAT datagram codec (IEC 61158-4-12, ETG.1000.4; Wireshark ``packet-ethercat-datagram.c``).

A datagram is ``cmd idx addr(4) len(2) irq(2) data wkc(2)``. The 32-bit
address is kept raw: ADP in the low 16 bits and ADO in the high 16 bits for
device commands, the logical address for LRD/LWR/LRW.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from pyethercat.errors import FrameError, FrameTooLargeError

__all__ = [
    "CIRCULATING_BIT",
    "HEADER",
    "HEADER_SIZE",
    "HEADER_TAIL",
    "LEN_MASK",
    "LEN_RESERVED_MASK",
    "LOGICAL_COMMANDS",
    "MAX_DATA",
    "MAX_PAYLOAD",
    "MORE_BIT",
    "OVERHEAD",
    "WKC",
    "WKC_SIZE",
    "Command",
    "Datagram",
    "command_name",
    "datagrams_size",
    "decode_datagrams",
    "encode_datagram_into",
    "encode_datagrams",
]

#: Datagram header: cmd, idx, address (u32), length word, irq.
HEADER = struct.Struct("<BBIHH")
HEADER_SIZE = HEADER.size  # 10
#: The header from byte 2 on: address, length word, IRQ (what a slave patches in passing).
HEADER_TAIL = struct.Struct("<IHH")
#: The working counter after the data.
WKC = struct.Struct("<H")
WKC_SIZE = 2
OVERHEAD = HEADER_SIZE + WKC_SIZE  # 12 bytes around the data
LEN_MASK = 0x07FF
LEN_RESERVED_MASK = 0x3800
CIRCULATING_BIT = 0x4000
MORE_BIT = 0x8000
#: Largest data size of one datagram alone in a standard frame (1500 - 2 - 12).
MAX_DATA = 1486
#: Bytes of datagrams that fit into one frame (1500 - 2-byte EtherCAT header).
MAX_PAYLOAD = 1498


class Command(enum.IntEnum):
    """The 15 standard EtherCAT commands."""

    NOP = 0
    APRD = 1
    APWR = 2
    APRW = 3
    FPRD = 4
    FPWR = 5
    FPRW = 6
    BRD = 7
    BWR = 8
    BRW = 9
    LRD = 10
    LWR = 11
    LRW = 12
    ARMW = 13
    FRMW = 14

    @property
    def is_logical(self) -> bool:
        """Logical addressing (LRD/LWR/LRW): a 32-bit address matched by FMMUs."""
        return self in LOGICAL_COMMANDS

    @property
    def is_positional(self) -> bool:
        """Auto-increment addressing: every slave increments ADP."""
        return self in _POSITIONAL

    @property
    def is_configured(self) -> bool:
        """Configured station address (or alias) addressing."""
        return self in _CONFIGURED

    @property
    def is_broadcast(self) -> bool:
        """Broadcast (BRD/BWR/BRW): every slave acts and increments ADP."""
        return self in _BROADCAST

    @property
    def reads(self) -> bool:
        """Whether the command moves slave memory into the frame."""
        return self in _READS

    @property
    def writes(self) -> bool:
        """Whether the command moves frame data into slave memory."""
        return self in _WRITES


#: The logically addressed commands (FMMU access).
LOGICAL_COMMANDS = frozenset({Command.LRD, Command.LWR, Command.LRW})
_POSITIONAL = frozenset({Command.APRD, Command.APWR, Command.APRW, Command.ARMW})
_CONFIGURED = frozenset({Command.FPRD, Command.FPWR, Command.FPRW, Command.FRMW})
_BROADCAST = frozenset({Command.BRD, Command.BWR, Command.BRW})
_READS = frozenset(
    {Command.APRD, Command.APRW, Command.FPRD, Command.FPRW, Command.BRD, Command.BRW,
     Command.LRD, Command.LRW, Command.ARMW, Command.FRMW}
)
_WRITES = frozenset(
    {Command.APWR, Command.APRW, Command.FPWR, Command.FPRW, Command.BWR, Command.BRW,
     Command.LWR, Command.LRW, Command.ARMW, Command.FRMW}
)


def command_name(code: int) -> str:
    """Name of a command code; unknown codes read as ``CMD<n>``."""
    try:
        return Command(code).name
    except ValueError:
        return f"CMD{code}"


@dataclass(slots=True)
class Datagram:
    """One EtherCAT datagram.

    ``address`` is the raw 32-bit address field: ``adp | ado << 16`` for
    device commands, the logical address for LRD/LWR/LRW. ``more`` is what was
    decoded; :func:`encode_datagrams` sets it from the datagram's position.
    ``command`` stays a plain ``int`` when the code is not a standard command.
    """

    command: Command | int
    index: int
    address: int
    data: bytes | bytearray = b""
    irq: int = 0
    wkc: int = 0
    circulating: bool = False
    more: bool = False
    #: Byte offset of this datagram inside the EtherCAT payload (set by decode).
    offset: int = field(default=0, compare=False)

    # -- constructors ------------------------------------------------------------

    @classmethod
    def device(cls, command: Command, adp: int, ado: int, data: bytes | bytearray | int,
               index: int = 0) -> Datagram:
        """A device-addressed datagram (position, configured or broadcast).

        ``data`` is either the payload or, for reads, the number of zero bytes
        to send (masters send zeros for reads: BRD ORs into them).
        """
        payload = bytes(data) if isinstance(data, int) else data
        return cls(command, index, (adp & 0xFFFF) | ((ado & 0xFFFF) << 16), payload)

    @classmethod
    def positional(cls, command: Command, position: int, ado: int,
                   data: bytes | bytearray | int, index: int = 0) -> Datagram:
        """Auto-increment addressing of the slave at ``position`` (0-based)."""
        return cls.device(command, (-position) & 0xFFFF, ado, data, index)

    @classmethod
    def logical(cls, command: Command, address: int, data: bytes | bytearray | int,
                index: int = 0) -> Datagram:
        """A logically addressed datagram (LRD/LWR/LRW) at the 32-bit ``address``.

        ``data`` is the payload or, as in :meth:`device`, a number of zero bytes.
        """
        payload = bytes(data) if isinstance(data, int) else data
        return cls(command, index, address & 0xFFFFFFFF, payload)

    # -- views ---------------------------------------------------------------------

    @property
    def adp(self) -> int:
        """Address position: low 16 bits of the address field."""
        return self.address & 0xFFFF

    @property
    def ado(self) -> int:
        """Address offset (the register or memory address): high 16 bits."""
        return (self.address >> 16) & 0xFFFF

    @property
    def logical_address(self) -> int:
        """The whole 32-bit address field, as LRD/LWR/LRW use it."""
        return self.address & 0xFFFFFFFF

    @property
    def is_logical(self) -> bool:
        """Whether the command is LRD, LWR or LRW."""
        return self.command in LOGICAL_COMMANDS

    @property
    def size(self) -> int:
        """Encoded size in bytes (header + data + WKC)."""
        return OVERHEAD + len(self.data)

    @property
    def command_name(self) -> str:
        """The command's name (``CMD<n>`` for codes outside the standard 15)."""
        return command_name(int(self.command))

    def __repr__(self) -> str:
        if self.is_logical:
            where = f"lad=0x{self.logical_address:08X}"
        else:
            where = f"adp=0x{self.adp:04X} ado=0x{self.ado:04X}"
        flags = "".join(("C" if self.circulating else "", "M" if self.more else ""))
        return (f"Datagram({self.command_name} idx={self.index} {where} len={len(self.data)}"
                f" irq=0x{self.irq:04X} wkc={self.wkc}{' ' + flags if flags else ''})")


def encode_datagram_into(buf: bytearray, offset: int, dgram: Datagram, more: bool) -> int:
    """Encode ``dgram`` into ``buf`` at ``offset``; return the offset after it."""
    length = len(dgram.data)
    if length > LEN_MASK:
        raise FrameTooLargeError(f"datagram data of {length} bytes exceeds the 11-bit length field")
    word = length | (CIRCULATING_BIT if dgram.circulating else 0) | (MORE_BIT if more else 0)
    start = offset + HEADER_SIZE
    try:
        # struct range-checks every field: a value that does not fit its field is
        # refused, never silently cut (an index of 256 would otherwise go out as 0).
        HEADER.pack_into(buf, offset, int(dgram.command), dgram.index, dgram.address, word,
                         dgram.irq)
        WKC.pack_into(buf, start + length, dgram.wkc)
    except struct.error:
        raise FrameError(f"{dgram!r}: a field does not fit its width (command and index "
                         "8 bits, address 32, IRQ and WKC 16)", offset) from None
    buf[start:start + length] = dgram.data
    return start + length + WKC_SIZE


def encode_datagrams(datagrams: Sequence[Datagram]) -> bytes:
    """Concatenate datagrams, setting the more-follows bit on all but the last."""
    total = sum(d.size for d in datagrams)
    buf = bytearray(total)
    offset = 0
    last = len(datagrams) - 1
    for i, dgram in enumerate(datagrams):
        offset = encode_datagram_into(buf, offset, dgram, i != last)
    return bytes(buf)


def decode_datagrams(payload: bytes | bytearray | memoryview, base_offset: int = 0,
                     strict: bool = True) -> list[Datagram]:
    """Decode the datagrams of an EtherCAT payload (the bytes the header length covers).

    Raises :class:`FrameError` when a datagram header or its data runs past
    the payload, or when bytes remain after the last datagram (M = 0) that are
    not accounted for (unless ``strict`` is false). ``base_offset`` only
    shifts the offsets in messages.
    """
    view = memoryview(payload)
    end = len(view)
    out: list[Datagram] = []
    offset = 0
    while True:
        if end - offset < OVERHEAD:
            raise FrameError(
                f"datagram {len(out)} truncated: {end - offset} bytes left, header and WKC need {OVERHEAD}",
                base_offset + offset)
        cmd, idx, address, word, irq = HEADER.unpack_from(view, offset)
        length = word & LEN_MASK
        data_start = offset + HEADER_SIZE
        data_end = data_start + length
        if data_end + WKC_SIZE > end:
            raise FrameError(
                f"datagram {len(out)} ({command_name(cmd)}) claims {length} data bytes but only "
                f"{max(0, end - data_start - WKC_SIZE)} remain", base_offset + offset)
        (wkc,) = struct.unpack_from("<H", view, data_end)
        try:
            command: Command | int = Command(cmd)
        except ValueError:
            command = cmd
        more = bool(word & MORE_BIT)
        out.append(Datagram(command, idx, address, bytes(view[data_start:data_end]), irq, wkc,
                            bool(word & CIRCULATING_BIT), more, base_offset + offset))
        offset = data_end + WKC_SIZE
        if not more:
            break
        if offset >= end:
            raise FrameError(f"datagram {len(out) - 1} says another follows but the frame ends",
                             base_offset + offset)
    if offset != end and strict:
        raise FrameError(f"{end - offset} bytes after the last datagram inside the EtherCAT length",
                         base_offset + offset)
    return out


def datagrams_size(datagrams: Iterable[Datagram]) -> int:
    """Total encoded size of ``datagrams`` in bytes."""
    return sum(d.size for d in datagrams)
