"""The datagram headers of an EtherCAT frame, as the segment's frame path walks them.

A frame's datagrams follow each other (Wireshark
``plugins/epan/ethercat/packet-ethercat-datagram.c``): a 10-byte header
(command, index, address, length word with the circulating and more-follows
bits, IRQ), the data, a 2-byte working counter.
:func:`scan_headers` reads all headers before any datagram is executed,
because a slave does not process a frame whose datagrams run past its end.
"""

from __future__ import annotations

from pyethercat.wire.datagram import (
    CIRCULATING_BIT,
    HEADER,
    HEADER_SIZE,
    LEN_MASK,
    MORE_BIT,
    WKC_SIZE,
)
from pyethercat.wire.frame import ECAT_HEADER_SIZE, ECAT_LENGTH_MASK, ECAT_TYPE_SHIFT, FrameType

__all__ = ["MALFORMED", "NOT_DATAGRAMS", "Head", "scan_frame", "scan_headers"]

#: :func:`scan_frame`: an EtherCAT frame of another type (mailbox gateway), not for the slaves.
NOT_DATAGRAMS = 1
#: :func:`scan_frame`: datagrams running past the frame (not processed, a processing error).
MALFORMED = 2
_DATAGRAMS = int(FrameType.DATAGRAMS)

#: A parsed datagram header: offset, command, address, length word, IRQ, data length.
Head = tuple[int, int, int, int, int, int]


def scan_headers(buf: bytes | bytearray, body: int, end: int) -> tuple[list[Head], bool] | None:
    """The headers of the datagrams in ``buf[body:end]`` and whether any has the circulating bit;
    None when the datagrams do not fit (a malformed frame)."""
    heads: list[Head] = []
    off = body
    any_c = False
    while True:
        if off + HEADER_SIZE + WKC_SIZE > end:
            return None
        cmd, _idx, address, lw, irq = HEADER.unpack_from(buf, off)
        n = lw & LEN_MASK
        if off + HEADER_SIZE + n + WKC_SIZE > end:
            return None
        heads.append((off, cmd, address, lw, irq, n))
        if lw & CIRCULATING_BIT:
            any_c = True
        off += HEADER_SIZE + n + WKC_SIZE
        if not lw & MORE_BIT:
            return heads, any_c


def scan_frame(buf: bytes | bytearray, start: int) -> tuple[int, list[Head], bool] | int:
    """The datagrams after the EtherCAT header at ``start``: (end, headers, any circulating bit),
    or :data:`NOT_DATAGRAMS` / :data:`MALFORMED`."""
    word = buf[start] | (buf[start + 1] << 8)
    if word >> ECAT_TYPE_SHIFT != _DATAGRAMS:
        return NOT_DATAGRAMS
    body = start + ECAT_HEADER_SIZE
    end = body + (word & ECAT_LENGTH_MASK)
    scanned = scan_headers(buf, body, end) if end <= len(buf) else None
    if scanned is None:
        return MALFORMED
    return end, scanned[0], scanned[1]
