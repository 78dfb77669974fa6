"""A link wrapper that records every frame it sends and receives to a capture file.

``CaptureLink(inner, "run.pcapng")`` behaves like ``inner`` and tees each sent
frame (before it is sent) and each received frame (as returned by ``recv``),
with a wall-clock time stamp in nanoseconds, into a pcapng file (direction in
the packet flags: outbound/inbound) or a classic nanosecond pcap file. The
format follows the file suffix (``.pcap`` or else pcapng) unless given.
Wireshark, tshark and ``pyethercat decode`` read the result.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import BinaryIO

from pyethercat.link.base import Link
from pyethercat.wire.pcap import (
    CaptureFormat,
    PacketDirection,
    PcapngWriter,
    PcapWriter,
)

__all__ = ["CaptureLink"]


class CaptureLink(Link):
    """Tees the frames of ``inner`` into a pcap or pcapng file or stream."""

    def __init__(
        self,
        inner: Link,
        target: str | os.PathLike[str] | BinaryIO,
        fmt: CaptureFormat | None = None,
        clock: Callable[[], int] = time.time_ns,
        flush: bool = False,
    ) -> None:
        super().__init__(f"capture({inner.name})")
        self.inner = inner
        self.sees_own_frames = inner.sees_own_frames
        self._clock = clock
        self._flush = flush
        self._lock = threading.Lock()
        if isinstance(target, str | os.PathLike):
            path = os.fspath(target)
            if fmt is None:
                fmt = (CaptureFormat.PCAP if path.lower().endswith(".pcap")
                       else CaptureFormat.PCAPNG)
            self._stream: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()
            self._owns_stream = True
        else:
            self._stream = target
            self._owns_stream = False
        self.format = fmt or CaptureFormat.PCAPNG
        self._writer: PcapWriter | PcapngWriter
        if self.format is CaptureFormat.PCAP:
            self._writer = PcapWriter(self._stream)
        else:
            self._writer = PcapngWriter(self._stream, interfaces=[inner.name])
        #: Frames recorded so far.
        self.count = 0

    def _record(self, frame: bytes, direction: PacketDirection) -> None:
        with self._lock:
            if self._stream.closed:
                return
            self._writer.write(self._clock(), frame, 0, direction)
            self.count += 1
            if self._flush:
                self._stream.flush()

    def fileno(self) -> int | None:
        return self.inner.fileno()

    def carrier(self) -> bool | None:
        return self.inner.carrier()

    def send(self, frame: bytes) -> None:
        self._check_open()
        self._record(bytes(frame), PacketDirection.OUTBOUND)
        self.inner.send(frame)

    def recv(self, timeout: float | None = None) -> bytes | None:
        self._check_open()
        frame = self.inner.recv(timeout)
        if frame is not None:
            self._record(frame, PacketDirection.INBOUND)
        return frame

    def flush(self) -> None:
        """Push buffered records to the file."""
        with self._lock:
            if not self._stream.closed:
                self._stream.flush()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.inner.close()
        finally:
            with self._lock:
                if self._owns_stream:
                    self._stream.close()
                elif not self._stream.closed:
                    self._stream.flush()
