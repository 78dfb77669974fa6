"""Per-slave mailbox engine of a simulated device (the firmware side of SM0/SM1).

:class:`MailboxEngine` takes what the master wrote into SM0 (the ESC hands the
whole SM buffer to ``DeviceApp.on_mailbox``), checks the header, drops a
request whose counter repeats the previous one (SOES ``soes/esc.c``
``ESC_mbxprocess``: a frame the master
sent twice is not executed twice), and dispatches by mailbox type to the
protocol handlers registered with it. What cannot be served is answered with
a mailbox error reply (type 0; SOES ``soes/esc.h`` ``MBXERR_*``):

===========================  ======================================================
0x0002 unsupported protocol  no handler for the type (AoE, EoE, FoE, SoE, VoE ...)
0x0003 invalid channel       channel field not 0
0x0004 service not supported the handler does not know the service (raised by it)
0x0005 invalid header        type 0 (an error reply) sent to the slave
0x0006 size too short        length 0, or shorter than the protocol header
0x0007 no more memory        the reply queue is full
0x0008 invalid size          length beyond the SM0 buffer
===========================  ======================================================

Replies go out through ``Pdi.post_mailbox`` numbered with the engine's own
counter (1..7, then 1). When SM1 is still full they wait in a queue and are
posted, in order, as soon as the master has read SM1 (the ESC calls
``on_mailbox_read``). The ESC keeps the mailbox the master read last and
re-posts it on a repeat request (``sim.esc_mailbox``); a newer reply already in SM1 is
taken back and posted again after it (SOES's order), so a reply whose frame
was lost, or which the master gave up on, comes back once and nothing is
skipped, without the engine's help. :attr:`MailboxEngine.last_reply` is the
last reply posted.

:class:`MailboxDevice` is a :class:`~pyethercat.sim.device.DeviceApp` with an
engine wired to the ESC events, built from protocol servers: each is an
object with a mailbox ``type``, ``handle(header, payload)``, ``reset()`` and
``on_state_change(old, new)`` (:class:`ProtocolServer`: ``sim.coe.CoeServer``,
the FoE, SoE and EoE servers). Adding a protocol to a device is
:meth:`MailboxDevice.add_protocol`; nothing is subclassed.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from typing import Protocol

from pyethercat.errors import MailboxError, MailboxErrorReply
from pyethercat.sim.device import DeviceApp, Pdi
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.mailbox.header import (
    MAILBOX_HEADER_SIZE,
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
    encode_mailbox_error,
    is_repeated_counter,
    mailbox_error_name,
    next_counter,
)
from pyethercat.wire.mailbox.objects import StandardObject, SyncMode, SyncSub

__all__ = ["MailboxDevice", "MailboxEngine", "MailboxHandler", "ProcessDataLayout", "ProtocolServer",
           "service_error"]

MailboxHandler = Callable[[MailboxHeader, bytes], None]
"""``handler(header, payload)``: serve one request; raise :func:`service_error` to refuse it."""


class ProtocolServer(Protocol):
    """A mailbox protocol a simulated device serves (CoE, FoE, SoE, EoE ...).

    ``type`` is the mailbox type it takes, ``handle`` serves one request
    (raising :func:`service_error` refuses it), ``reset`` forgets any
    transfer when the mailbox stops (INIT, power-on), ``on_state_change``
    sees AL state changes (a bootloader applies new firmware on BOOT -> INIT).
    """

    @property
    def type(self) -> int: ...

    def handle(self, header: MailboxHeader, payload: bytes) -> None: ...
    def reset(self) -> None: ...
    def on_state_change(self, old: AlState, new: AlState) -> None: ...


class ProcessDataLayout(Protocol):
    """What decides a device's process-data sizes (a CoE device's PDO mapping)."""

    def sizes(self) -> tuple[int, int]:
        """(output bytes, input bytes) the SM2/SM3 buffers must have."""
        ...

#: Replies the engine holds while SM1 is full before it answers "no more memory".
QUEUE_LIMIT = 256


def service_error(code: int) -> MailboxErrorReply:
    """The exception a handler raises to have the engine send mailbox error ``code``."""
    return MailboxErrorReply(code, mailbox_error_name(code))


class MailboxEngine:
    """Header checks, duplicate detection, dispatch and the reply queue of one slave."""

    def __init__(self, pdi: Pdi | None = None) -> None:
        self.pdi = pdi
        self.handlers: dict[int, MailboxHandler] = {}
        #: Called when SM1 is free and nothing is queued: streaming protocols (EoE)
        #: post their next message then, one at a time.
        self.idle: list[Callable[[], None]] = []
        self._in_idle = False
        self.queue: deque[bytes] = deque()
        self.last_reply = b""
        self._last_in = 0
        self._out_counter = 0
        #: Requests dropped because their counter repeated the previous one.
        self.duplicates = 0
        #: Requests served (handed to a handler or answered with an error reply).
        self.requests = 0

    def register(self, mtype: int, handler: MailboxHandler) -> None:
        """Serve mailbox type ``mtype`` with ``handler``."""
        self.handlers[int(mtype)] = handler

    def reset(self) -> None:
        """Forget counters and queued replies (the mailbox was stopped, back in INIT)."""
        self.queue.clear()
        self._last_in = 0
        self._out_counter = 0

    # --- receive -------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """One mailbox the master wrote into SM0 (padded to the SM length)."""
        if len(data) < MAILBOX_HEADER_SIZE:
            self.send_error(MailboxErrorCode.SYNTAX)
            return
        try:
            header = MailboxHeader.decode(data)
        except MailboxError:
            self.send_error(MailboxErrorCode.SYNTAX)
            return
        if is_repeated_counter(self._last_in, header.counter):
            self.duplicates += 1
            return
        self._last_in = header.counter
        self.requests += 1
        if len(self.queue) >= QUEUE_LIMIT:
            self.send_error(MailboxErrorCode.NO_MORE_MEMORY, header.address, force=True)
            return
        code = self._header_problem(header, len(data))
        if code:
            self.send_error(code, header.address)
            return
        handler = self.handlers.get(int(header.type))
        if handler is None:
            self.send_error(MailboxErrorCode.UNSUPPORTED_PROTOCOL, header.address)
            return
        payload = bytes(data[MAILBOX_HEADER_SIZE: MAILBOX_HEADER_SIZE + header.length])
        try:
            handler(header, payload)
        except MailboxErrorReply as exc:
            self.send_error(exc.code, header.address)
        except MailboxError:
            # A request the handler's codecs could not serve must not stop the
            # segment: the master gets "service not supported".
            self.send_error(MailboxErrorCode.SERVICE_NOT_SUPPORTED, header.address)

    @staticmethod
    def _header_problem(header: MailboxHeader, size: int) -> int:
        if header.length > size - MAILBOX_HEADER_SIZE:
            return MailboxErrorCode.INVALID_SIZE
        if header.length == 0:
            return MailboxErrorCode.SIZE_TOO_SHORT
        if header.channel != 0:
            return MailboxErrorCode.INVALID_CHANNEL
        if header.type == MailboxType.ERR:
            return MailboxErrorCode.INVALID_HEADER
        return 0

    # --- send ------------------------------------------------------------------------

    def send(self, mtype: int, payload: bytes, *, address: int = 0, priority: int = 0) -> None:
        """Queue one reply (or unsolicited message) for SM1 with the next counter."""
        self._out_counter = next_counter(self._out_counter)
        frame = encode_mailbox(mtype, payload, counter=self._out_counter, address=address,
                               priority=priority)
        self.queue.append(frame)
        self.flush()

    def send_error(self, code: int, address: int = 0, force: bool = False) -> None:
        """Queue a mailbox error reply carrying ``code``."""
        if force and len(self.queue) >= QUEUE_LIMIT:
            self.queue.pop()  # make room: the error must get through
        self.send(MailboxType.ERR, encode_mailbox_error(code), address=address)

    def flush(self) -> None:
        """Post queued replies while SM1 takes them (one at a time: the ESC holds one)."""
        pdi = self.pdi
        if pdi is None:
            return
        while self.queue:
            frame = self.queue[0]
            if not pdi.post_mailbox(frame):
                return
            self.queue.popleft()
            self.last_reply = frame
        if self.idle and not self._in_idle:
            self._in_idle = True
            try:
                for more in self.idle:
                    more()
            finally:
                self._in_idle = False


class MailboxDevice(DeviceApp):
    """A device application with a mailbox engine and the protocol servers it serves.

    Types without a server get "protocol not supported". ``layout`` (a CoE
    device's PDO mapping) gives the process-data sizes the ESC checks on
    PREOP -> SAFEOP; without it the SII's PDOs count.
    """

    def __init__(self, servers: Iterable[ProtocolServer] = (), *,
                 layout: ProcessDataLayout | None = None) -> None:
        super().__init__()
        self.mailbox = MailboxEngine()
        #: Protocol servers by mailbox type.
        self.protocols: dict[int, ProtocolServer] = {}
        self.layout = layout
        for server in servers:
            self.add_protocol(server)

    def attach(self, pdi: Pdi) -> None:
        super().attach(pdi)
        self.mailbox.pdi = pdi

    def add_protocol(self, server: ProtocolServer) -> None:
        """Serve ``server.type`` with ``server`` (state changes and resets reach it too)."""
        self.protocols[int(server.type)] = server
        self.mailbox.register(server.type, server.handle)

    def sender(self, mtype: int) -> Callable[[bytes], None]:
        """A function that queues a reply of mailbox type ``mtype``."""
        return lambda payload: self.mailbox.send(mtype, payload)

    def al_state(self) -> AlState:
        """The current AL state (PREOP before the slave is attached)."""
        return self.pdi.al_state() if self.pdi is not None else AlState.PREOP

    def mailbox_sizes(self) -> tuple[int, int]:
        """Lengths of SM0 (receive) and SM1 (send) as configured now (128 when unset)."""
        if self.pdi is None:
            return 128, 128
        sizes = []
        for sm in (0, 1):
            raw = self.pdi.read(R.sm_address(sm) + R.SM_LENGTH, 2)
            sizes.append(int.from_bytes(raw, "little") or 128)
        return sizes[0], sizes[1]

    def process_data_sizes(self) -> tuple[int, int] | None:
        return self.layout.sizes() if self.layout is not None else None

    def check_transition(self, current: AlState, requested: AlState) -> int:
        """PREOP -> SAFEOP of a CoE device set to a DC sync mode needs its SYNC0.

        0x1C32 sub 1 = 2 or 3 (DC SYNC0/SYNC1) with the cyclic unit not
        running SYNC0 (0x0981) is "invalid DC SYNC configuration" (0x0030, as
        drives answer a master that did not start DC); a SYNC0 cycle below
        0x1C32 sub 5 (minimum cycle time) is 0x0036.
        """
        if not (current == AlState.PREOP and requested == AlState.SAFEOP) or self.pdi is None:
            return 0
        coe = self.protocols.get(int(MailboxType.COE))
        od = getattr(coe, "od", None)
        if od is None or od.find(StandardObject.SM_OUTPUT_SYNC) is None:
            return 0
        mode = int(od.value(StandardObject.SM_OUTPUT_SYNC, SyncSub.SYNC_MODE))
        if mode not in (SyncMode.DC_SYNC0, SyncMode.DC_SYNC1):
            return 0
        act = self.pdi.read(R.DC_ACTIVATION, 1)[0]
        if not (act & R.DcActivation.CYCLIC and act & R.DcActivation.SYNC0):
            return int(AlStatusCode.INVALID_DC_SYNC_CONFIG)
        cycle = int.from_bytes(self.pdi.read(R.DC_SYNC0_CYCLE, 4), "little")
        minimum = int(od.value(StandardObject.SM_OUTPUT_SYNC, SyncSub.MIN_CYCLE_TIME))
        if cycle and cycle < minimum:
            return int(AlStatusCode.DC_INVALID_SYNC0_CYCLE_TIME)
        return 0

    def on_mailbox(self, data: bytes) -> None:
        self.mailbox.receive(data)

    def on_mailbox_read(self) -> None:
        """The master read SM1 (called by the ESC): post the next queued reply."""
        self.mailbox.flush()

    def on_state_change(self, old: AlState, new: AlState) -> None:
        for server in self.protocols.values():
            server.on_state_change(old, new)
        if new == AlState.INIT:
            self._reset()
        elif old == AlState.INIT:
            # The mailbox starts: a new master session numbers from 1 again, so the
            # duplicate check must not remember the last session's counter (the slave
            # may have been left in INIT, when no INIT transition resets it).
            self.mailbox._last_in = 0
            self.mailbox.flush()

    def on_power_on(self) -> None:
        self._reset()

    def _reset(self) -> None:
        self.mailbox.reset()
        for server in self.protocols.values():
            server.reset()
