"""FoE transfers as state machines: read and write, client (master) and server (slave).

In the h11 manner: messages and the current time in, the next message out; no
I/O, no clock of their own. Time-outs are deadlines the driver compares with
its clock (:meth:`_FoeClient.check_deadline`).

The rules (IgH ``master/fsm_foe.c``, SOEM ``src/ec_foe.c``, SOES
``soes/esc_foe.c``):

- write: WRQ(password, name) -> ACK(0) -> DATA(1) -> ACK(1) -> ... ; read:
  RRQ -> DATA(1) -> ACK(1) -> ... Packets are numbered from 1.
- A DATA shorter than a full packet (mailbox size - 12 bytes) is the last one;
  a file whose length is a multiple of the full size ends with a 0-byte DATA.
- BUSY answers a DATA the slave cannot take yet: the sender sends the same
  packet again (SOEM ``ecx_FOEwrite``, IgH ``ec_fsm_foe_state_ack_read``);
  its done/entire words report progress. A BUSY in a read makes the master
  repeat its last message (IgH ``ec_fsm_foe_state_data_read_data``).
- ERR ends the transfer from either side, with an error code and text.
- Packet numbers travel as u32, but senders differ in width: some use the low
  16 bits only, and devices in the field wrap at 256 (ribalda/ethercat issue
  10, "received packet number 0, expected 256"). Received numbers therefore
  match modulo 2^32, 2^16 or 2^8 (:func:`~pyethercat.wire.mailbox.foe.foe_packet_matches`); a client writing to
  a slave that wraps can be told so (``wrap=256``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from pyethercat.errors import FoeAbort, FoeTimeoutError, MailboxError
from pyethercat.wire.mailbox.foe import (
    FoeAck,
    FoeBusy,
    FoeData,
    FoeError,
    FoeErrorCode,
    FoeMessage,
    FoeReadRequest,
    FoeWriteRequest,
    foe_data_size,
    foe_error_name,
    foe_packet_matches,
)

__all__ = [
    "DEFAULT_PACKET_TIMEOUT",
    "FoeFileStore",
    "FoeProgress",
    "FoeReadClient",
    "FoeServer",
    "FoeWriteClient",
    "abort",
]

#: Seconds a packet may wait for its answer (IgH's EC_FSM_FOE_TIMEOUT_JIFFIES is 3 s).
DEFAULT_PACKET_TIMEOUT = 3.0

def abort(code: int, text: str = "", *, by_master: bool = False) -> FoeAbort:
    """The typed error for FoE error ``code`` (the class of its code, its name, ``text``)."""
    return FoeAbort.for_code(code, foe_error_name(code), text, by_master=by_master)


@dataclass(frozen=True, slots=True)
class FoeProgress:
    """Where a transfer stands, for progress callbacks.

    ``done`` bytes acknowledged (write) or received (read); ``total`` the file
    size when known (writes); ``busy`` the slave's last BUSY while it is busy
    (its ``done``/``entire`` words are the slave's own progress figures).
    """

    done: int
    total: int | None
    packet: int
    busy: FoeBusy | None = None

    @property
    def fraction(self) -> float | None:
        """``done / total`` (None when the total is unknown)."""
        if not self.total:
            return None if self.total is None else 1.0
        return min(1.0, self.done / self.total)


class _FoeClient:
    """What the read and write clients share: deadline, outcome, the abort to send."""

    def __init__(self, name: str, password: int, packet_timeout: float) -> None:
        if not 0 <= password <= 0xFFFFFFFF:
            raise MailboxError(f"FoE password {password} out of range 0..0xFFFFFFFF")
        if packet_timeout <= 0:
            raise MailboxError("FoE packet time-out must be positive")
        self.name = name
        self.password = password
        self.packet_timeout = packet_timeout
        #: When the answer to the last message sent is due (None before start / after the end).
        self.deadline: float | None = None
        self.done = False
        #: The message to send the slave after we gave up (an FoE ERR), if any.
        self.abort_request: FoeError | None = None
        self.busy: FoeBusy | None = None
        #: BUSY answers received (each made us repeat a message).
        self.busy_count = 0
        self._last: FoeMessage | None = None

    def _sent(self, msg: FoeMessage, now: float) -> FoeMessage:
        self._last = msg
        self.deadline = now + self.packet_timeout
        return msg

    def _finish(self) -> None:
        self.done = True
        self.deadline = None

    def _fail(self, code: int, text: str) -> FoeAbort:
        """End the transfer from our side: the ERR to send, and the error to raise."""
        self._finish()
        self.abort_request = FoeError(code, text)
        return abort(code, text, by_master=True)

    def _common(self, msg: FoeMessage, now: float) -> FoeMessage | None:
        """Handle ERR and BUSY; None when ``msg`` is for the subclass."""
        if self.done:
            raise MailboxError("FoE transfer already finished")
        if self._last is None:
            raise MailboxError("FoE transfer not started")
        if isinstance(msg, FoeError):
            self._finish()
            raise abort(msg.code, msg.text)
        if isinstance(msg, FoeBusy):
            self.busy = msg
            self.busy_count += 1
            return self._sent(self._last, now)
        return None

    def check_deadline(self, now: float) -> None:
        """Raise :class:`FoeTimeoutError` (and arm ``abort_request``) once the deadline passed."""
        if self.done or self.deadline is None or now < self.deadline:
            return
        what = type(self._last).__name__ if self._last is not None else "request"
        self._finish()
        self.abort_request = FoeError(FoeErrorCode.NOT_DEFINED, "master time-out")
        raise FoeTimeoutError(f"FoE {self.name!r}: no answer to {what} within "
                              f"{self.packet_timeout:g} s")


class FoeWriteClient(_FoeClient):
    """Master side of writing a file to a slave.

    ``mailbox_size`` is the slave's receive mailbox (SM0) size: it fixes the
    full packet. ``start(now)`` gives the WRQ; ``receive(msg, now)`` the next
    DATA to send, or None once the last packet was acknowledged (``done``).
    ``wrap``: packet numbers go out modulo this (256 for slaves that wrap
    their counter at 256; the default is the u32 field).
    """

    def __init__(self, name: str, data: bytes, *, mailbox_size: int, password: int = 0,
                 packet_timeout: float = DEFAULT_PACKET_TIMEOUT, wrap: int = 1 << 32) -> None:
        super().__init__(name, password, packet_timeout)
        if not 2 <= wrap <= 1 << 32:
            raise MailboxError(f"FoE packet number wrap {wrap} out of range 2..2^32")
        self.packet_size = foe_data_size(mailbox_size)
        self.wrap = wrap
        self._data = memoryview(bytes(data))
        self.total = len(self._data)
        #: DATA packets in the transfer, the short (or empty) last one included.
        self.packets = self.total // self.packet_size + 1
        self._acked = 0  # the packet whose ACK we wait for: 0 = the WRQ's

    def start(self, now: float) -> FoeWriteRequest:
        """The write request (sent first)."""
        if self._last is not None:
            raise MailboxError("FoE write already started")
        msg = FoeWriteRequest(self.name, self.password)
        self._sent(msg, now)
        return msg

    def _data_packet(self, number: int) -> FoeData:
        start = (number - 1) * self.packet_size
        return FoeData(number % self.wrap, bytes(self._data[start:start + self.packet_size]))

    def receive(self, msg: FoeMessage, now: float) -> FoeMessage | None:
        """Process one answer of the slave; the next message to send, or None when done."""
        repeat = self._common(msg, now)
        if repeat is not None:
            if isinstance(repeat, FoeWriteRequest):
                # SOEM ignores a BUSY before the first DATA: keep waiting for the ACK.
                self._last = repeat
                return None
            return repeat
        if not isinstance(msg, FoeAck):
            raise self._fail(FoeErrorCode.ILLEGAL, f"unexpected {type(msg).__name__} in a write")
        if not foe_packet_matches(self._acked, msg.packet):
            raise self._fail(FoeErrorCode.PACKET_NUMBER_WRONG,
                             f"ACK {msg.packet}, expected {self._acked % self.wrap}")
        self.busy = None
        if self._acked == self.packets:
            self._finish()
            return None
        self._acked += 1
        return self._sent(self._data_packet(self._acked), now)

    @property
    def progress(self) -> FoeProgress:
        """Bytes the slave acknowledged so far."""
        done = min(self.total, max(0, self._acked - (0 if self.done else 1)) * self.packet_size)
        return FoeProgress(done, self.total, self._acked, self.busy)


class FoeReadClient(_FoeClient):
    """Master side of reading a file from a slave.

    ``mailbox_size`` is the slave's send mailbox (SM1) size: a DATA shorter
    than its full packet ends the file. ``max_size`` refuses a longer file
    (the slave gets ERR 0x8003 "disk full"). ``receive`` returns the ACK to
    send; after the last DATA it is still an ACK, and ``done`` is set.
    """

    def __init__(self, name: str, *, mailbox_size: int, password: int = 0,
                 packet_timeout: float = DEFAULT_PACKET_TIMEOUT,
                 max_size: int | None = None) -> None:
        super().__init__(name, password, packet_timeout)
        self.packet_size = foe_data_size(mailbox_size)
        self.max_size = max_size
        self._buffer = bytearray()
        self._next = 1

    def start(self, now: float) -> FoeReadRequest:
        """The read request (sent first)."""
        if self._last is not None:
            raise MailboxError("FoE read already started")
        msg = FoeReadRequest(self.name, self.password)
        self._sent(msg, now)
        return msg

    @property
    def data(self) -> bytes:
        """The file (complete once ``done``)."""
        return bytes(self._buffer)

    def receive(self, msg: FoeMessage, now: float) -> FoeMessage | None:
        """Process one message of the slave; the ACK (or repeat) to send."""
        repeat = self._common(msg, now)
        if repeat is not None:
            return repeat
        if not isinstance(msg, FoeData):
            raise self._fail(FoeErrorCode.ILLEGAL, f"unexpected {type(msg).__name__} in a read")
        if self._next > 1 and foe_packet_matches(self._next - 1, msg.packet):
            # The slave sent the previous packet again (our ACK was lost): ACK it again.
            return self._sent(FoeAck(msg.packet), now)
        if not foe_packet_matches(self._next, msg.packet):
            raise self._fail(FoeErrorCode.PACKET_NUMBER_WRONG,
                             f"DATA {msg.packet}, expected {self._next}")
        if len(msg.data) > self.packet_size:
            raise self._fail(FoeErrorCode.ILLEGAL,
                             f"DATA of {len(msg.data)} bytes, the mailbox carries "
                             f"{self.packet_size}")
        if self.max_size is not None and len(self._buffer) + len(msg.data) > self.max_size:
            raise self._fail(FoeErrorCode.DISK_FULL, f"file exceeds {self.max_size} bytes")
        self._buffer += msg.data
        self.busy = None
        ack = FoeAck(msg.packet)
        if len(msg.data) < self.packet_size:
            self._finish()
            self._last = ack
            return ack
        self._next += 1
        return self._sent(ack, now)

    @property
    def progress(self) -> FoeProgress:
        """Bytes received so far (the total is unknown until the end)."""
        return FoeProgress(len(self._buffer), len(self._buffer) if self.done else None,
                           self._next - (0 if self.done else 1), self.busy)


# --- server (slave side) ------------------------------------------------------------------


class FoeFileStore(Protocol):
    """Where a slave's FoE server finds and stores files; refuses by raising :class:`FoeAbort`.

    ``open_write`` returns the largest size it takes (None: no limit);
    ``close_write`` gets the whole file and may still refuse it (a firmware
    image with a wrong checksum).
    """

    def open_read(self, name: str, password: int) -> bytes: ...
    def open_write(self, name: str, password: int) -> int | None: ...
    def close_write(self, name: str, data: bytes) -> None: ...


class FoeServer:
    """Slave side of FoE: one transfer at a time, as SOES ``esc_foe.c`` serves them.

    ``receive(msg, rx_size, tx_size)`` takes a request and the current
    receive (SM0) and send (SM1) mailbox sizes and returns the reply, or None
    when none is due (the master's ERR, its final ACK). ``wrap`` numbers the
    DATA packets this server sends modulo that value (256 imitates devices
    that wrap).
    """

    def __init__(self, files: FoeFileStore, *, wrap: int = 1 << 32) -> None:
        self.files = files
        self.wrap = wrap
        self._mode = ""  # "", "write" or "read"
        self._name = ""
        self._buffer = bytearray()
        self._limit: int | None = None
        self._packet = 0  # write: last packet stored; read: last packet sent
        self._data = b""
        self._last_sent: FoeData | None = None
        #: Files written completely and accepted.
        self.completed = 0

    @property
    def busy_transfer(self) -> bool:
        """True while a transfer is in progress."""
        return bool(self._mode)

    @property
    def received(self) -> int:
        """Bytes of the file being written received so far."""
        return len(self._buffer)

    def reset(self) -> None:
        """Forget any transfer (the mailbox stopped, or the master aborted)."""
        self._mode = ""
        self._name = ""
        self._buffer = bytearray()
        self._limit = None
        self._packet = 0
        self._data = b""
        self._last_sent = None

    def _error(self, exc: FoeAbort) -> FoeError:
        self.reset()
        return FoeError(exc.code, exc.text)

    def _refuse(self, code: int, text: str) -> FoeError:
        self.reset()
        return FoeError(code, text)

    def receive(self, msg: FoeMessage, rx_size: int, tx_size: int) -> FoeMessage | None:
        """Serve one message of the master; the reply, if one is due."""
        if isinstance(msg, FoeError):
            self.reset()
            return None
        if isinstance(msg, FoeWriteRequest):
            self.reset()
            try:
                self._limit = self.files.open_write(msg.filename, msg.password)
            except FoeAbort as exc:
                return self._error(exc)
            self._mode, self._name = "write", msg.filename
            return FoeAck(0)
        if isinstance(msg, FoeReadRequest):
            self.reset()
            try:
                data = self.files.open_read(msg.filename, msg.password)
            except FoeAbort as exc:
                return self._error(exc)
            self._mode, self._name, self._data = "read", msg.filename, bytes(data)
            return self._next_data(tx_size)
        if isinstance(msg, FoeData):
            return self._on_data(msg, rx_size)
        if isinstance(msg, FoeAck):
            return self._on_ack(msg, tx_size)
        if isinstance(msg, FoeBusy):
            # The master is busy: send the last packet again (SOES FOE_busy).
            if self._mode == "read" and self._last_sent is not None:
                return self._last_sent
            return self._refuse(FoeErrorCode.ILLEGAL, "BUSY outside a read")
        return self._refuse(FoeErrorCode.ILLEGAL, f"unexpected {type(msg).__name__}")

    def _on_data(self, msg: FoeData, rx_size: int) -> FoeMessage:
        if self._mode != "write":
            return self._refuse(FoeErrorCode.ILLEGAL, "DATA without a write request")
        if self._packet and foe_packet_matches(self._packet, msg.packet):
            return FoeAck(msg.packet)  # repeated after a lost ACK: already stored
        if not foe_packet_matches(self._packet + 1, msg.packet):
            return self._refuse(FoeErrorCode.PACKET_NUMBER_WRONG,
                                f"packet {msg.packet}, expected {self._packet + 1}")
        full = foe_data_size(rx_size)
        if len(msg.data) > full:
            return self._refuse(FoeErrorCode.ILLEGAL, f"packet of {len(msg.data)} bytes")
        if self._limit is not None and len(self._buffer) + len(msg.data) > self._limit:
            return self._refuse(FoeErrorCode.DISK_FULL, f"file exceeds {self._limit} bytes")
        self._buffer += msg.data
        self._packet += 1
        if len(msg.data) == full:
            return FoeAck(msg.packet)
        name, data = self._name, bytes(self._buffer)
        try:
            self.files.close_write(name, data)
        except FoeAbort as exc:
            return self._error(exc)
        self.reset()
        self.completed += 1
        return FoeAck(msg.packet)

    def _next_data(self, tx_size: int) -> FoeData:
        full = foe_data_size(tx_size)
        start = self._packet * full
        self._packet += 1
        packet = FoeData(self._packet % self.wrap, self._data[start:start + full])
        self._last_sent = packet
        return packet

    def _on_ack(self, msg: FoeAck, tx_size: int) -> FoeMessage | None:
        if self._mode != "read" or self._last_sent is None:
            return None  # an ACK after the end (SOEM acknowledges the last packet too)
        if not foe_packet_matches(self._packet, msg.packet):
            return self._refuse(FoeErrorCode.PACKET_NUMBER_WRONG,
                                f"ACK {msg.packet}, expected {self._packet}")
        if len(self._last_sent.data) < foe_data_size(tx_size):
            self.reset()
            return None
        return self._next_data(tx_size)
