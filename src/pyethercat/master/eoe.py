"""EoE in the master: a client per slave and the service that moves its frames.

:class:`EoeClient` speaks Ethernet over EtherCAT (mailbox type 2) with one
slave through its :class:`~pyethercat.master.mailbox.Mailbox`:

- ``set_ip``/``get_ip`` (Set/Get IP parameter: MAC, IP address, subnet,
  gateway, DNS server and name) and ``set_address_filter``/``get_address_filter``
  are request/response transactions; a result code other than 0 raises
  :class:`EoeError` naming it. Set IP uses the fixed 58-byte layout IgH and
  TwinCAT send (``master/fsm_eoe.c``); slaves accept it and SOEM's packed one.
- ``send(frame)`` queues an Ethernet frame (``request_time``: the slave
  answers with a timestamp response; ``timestamp``: a 32-bit time appended to
  the last fragment with the time-appended flag); fragments go out one mailbox at a
  time (:class:`~pyethercat.wire.mailbox.eoe_stream.EoeSender`); frames the
  slave sends are rebuilt and checked
  (:class:`~pyethercat.wire.mailbox.eoe_stream.EoeReceiver`) and handed to
  ``on_frame``. Fragments can arrive through any read of SM1 (a CoE
  transfer's too): the client takes them as the mailbox's unsolicited handler.

:class:`EoeService` moves the fragments, as IgH's EoE handlers do
(``master/ethernet.c``: one mailbox datagram per handler and cycle, queued
into the next frame), without a thread of its own while cyclic exchange
runs: :meth:`EoeService.tick` is chained to the cyclic loop's callback. Each
tick it takes the replies of the previous tick's datagrams and queues the
next ones (``flush=False``): they ride in the next cycle's frame, in the
room the process data leave, or in a frame of their own right after it.

- SM0 write: the current fragment, for every client with something to send;
  working counter 0 (SM0 still full) or a lost reply sends the same bytes
  again (the same mailbox counter: a slave that had it drops the repeat).
- SM1 read: when the SM1 status byte that the cyclic frame maps into the
  image (FMMU on 0x080D) says "full", and again right after a read that
  found a fragment (while a frame streams, one fragment per cycle).
  Without a mapped status byte, a 1-byte read of 0x080D rides along instead.
- Idle slaves cost one numpy gather of their status bytes per tick, not a
  Python loop.

A slave's mailbox is left alone while a protocol client (CoE) holds its
lock; that transfer's own SM1 reads hand any EoE fragment to the client.
Without cyclic exchange the service runs a thread of its own
(:meth:`EoeService.start`) at ``period``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Self

import numpy as np

from pyethercat.errors import ConfigError, EtherCATError, MailboxError
from pyethercat.master.mailbox import ClientContext, Mailbox, ReceivedMessage
from pyethercat.master.scheduler import Request
from pyethercat.master.slave import Slave
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.mailbox.eoe import (
    EoeFrameType,
    EoeGetAddressFilterRequest,
    EoeGetAddressFilterResponse,
    EoeGetIpRequest,
    EoeGetIpResponse,
    EoeIpParameters,
    EoeResult,
    EoeSetAddressFilterRequest,
    EoeSetIpRequest,
    EoeTimestampResponse,
    decode_eoe,
    eoe_result_name,
)
from pyethercat.wire.mailbox.eoe_stream import (
    DEFAULT_EOE_TIMEOUT,
    EoeDirectionStats,
    EoeReceiver,
    EoeSender,
)
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox
from pyethercat.wire.sii.model import MailboxProtocol

if TYPE_CHECKING:
    from pyethercat.master.cyclic import Cycle, CyclicRunner
    from pyethercat.master.scheduler import Scheduler

__all__ = ["EoeClient", "EoeError", "EoeService", "EoeStats", "eoe_client", "eoe_clients",
           "eoe_frame_type"]

_log = logging.getLogger("pyethercat.eoe")
_MAX_FILTERS = 16
#: Set IP parameter flag bit 16: the slave appends its time to the frames it sends
#: (Wireshark's ``packet-ecatmb.c`` dissects it as "AppendTimeStamp").
_APPEND_TIMESTAMP = 0x0001_0000


class EoeError(MailboxError):
    """A slave answered an EoE request with a result code other than success."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def eoe_frame_type(msg: ReceivedMessage) -> int | None:
    """EoE frame type of a mailbox message (None: not EoE or too short)."""
    if msg.header.type != MailboxType.EOE or len(msg.payload) < 4:
        return None
    return int(msg.payload[0] & 0x0F)


@dataclass
class EoeStats:
    """Both directions of one slave's EoE link plus the mailbox work."""

    tx: EoeDirectionStats
    rx: EoeDirectionStats
    #: SM0 writes refused (working counter 0) and sent again.
    write_retries: int = 0
    #: SM1 reads that found a message / found nothing.
    reads: int = 0
    empty_reads: int = 0
    #: Timestamp responses received (answers to the time-request flag).
    timestamps: int = 0
    #: Ticks that found last tick's SM0 write or SM1 read still on its way (the
    #: slave then waits a cycle for its next mailbox datagram).
    late: int = 0


class EoeClient:
    """EoE with one slave (see the module text). ``position`` is its ring position.

    The master makes one for every mailbox slave (the client registry,
    ``master.clients``): ``slave.client(EoeClient)``, or :func:`eoe_client`,
    which also checks that the slave announces EoE.
    """

    #: The mailbox type this client speaks (the registry key, see ``master.clients``).
    mailbox_type: ClassVar[MailboxType] = MailboxType.EOE

    @classmethod
    def for_mailbox(cls, mailbox: Mailbox, context: ClientContext) -> Self:
        """The client a master makes for a slave's mailbox: it takes the slave's fragments
        as the mailbox's unsolicited handler from the start."""
        return cls(mailbox, position=context.position)

    def __init__(self, mailbox: Mailbox, *, position: int = -1,
                 timeout: float = DEFAULT_EOE_TIMEOUT, queue_limit: int = 64) -> None:
        self.mailbox = mailbox
        self.position = position
        self.label = mailbox.label
        self.sender = EoeSender(mailbox.rx_size, queue_limit=queue_limit, timeout=timeout)
        self.receiver = EoeReceiver(timeout=timeout)
        self.stats = EoeStats(self.sender.stats, self.receiver.stats)
        #: Called with every frame the slave sent (in the thread that read it).
        self.on_frame: Callable[[bytes], None] | None = None
        #: Last timestamp response (32-bit slave time) and appended timestamp seen.
        self.last_timestamp: int | None = None
        self._lock = threading.Lock()
        # the SM0 write in flight: its request and the padded mailbox it carries
        self._write: Request | None = None
        self._write_bytes = b""
        self._read: Request | None = None
        self.streaming = False
        #: Set by the service: called when a frame is queued (the client has work).
        self.wake: Callable[[EoeClient], None] | None = None
        mailbox.add_handler(self._unsolicited)

    # -- requests ----------------------------------------------------------------------

    def set_ip(self, params: EoeIpParameters, *, append_timestamp: bool = False,
               timeout: float | None = None) -> None:
        """Send Set IP parameter; raises :class:`EoeError` unless the slave reports success.

        ``append_timestamp`` sets the flag that asks the slave to append its time
        to every frame it sends from now on (the client keeps the last one in
        :attr:`last_timestamp`).
        """
        payload = bytearray(EoeSetIpRequest(params).encode())
        if append_timestamp:  # the flag word follows the 4-byte EoE header
            flags = int.from_bytes(payload[4:8], "little") | _APPEND_TIMESTAMP
            payload[4:8] = flags.to_bytes(4, "little")
        msg = self.mailbox.transact(MailboxType.EOE, bytes(payload),
                                    _is(EoeFrameType.SET_IP_RESPONSE), what="EoE set IP parameter",
                                    timeout=timeout)
        self._check(msg, "set IP parameter")

    def get_ip(self, *, timeout: float | None = None) -> EoeIpParameters:
        """The slave's IP parameters (Get IP parameter)."""
        msg = self.mailbox.transact(MailboxType.EOE, EoeGetIpRequest().encode(),
                                    _is(EoeFrameType.GET_IP_RESPONSE), what="EoE get IP parameter",
                                    timeout=timeout)
        self._check(msg, "get IP parameter")
        got = decode_eoe(msg.payload)
        assert isinstance(got, EoeGetIpResponse)
        return got.params

    def set_address_filter(self, macs: Sequence[bytes], *, no_broadcast: bool = False,
                           timeout: float | None = None) -> None:
        """Let only frames to ``macs`` (and broadcasts unless ``no_broadcast``) through."""
        if len(macs) > _MAX_FILTERS or any(len(m) != 6 for m in macs):
            raise ConfigError(f"an EoE address filter holds up to {_MAX_FILTERS} MAC addresses")
        opts = len(macs) | (0x80 if no_broadcast else 0)
        body = (opts.to_bytes(2, "little") + b"".join(macs).ljust(_MAX_FILTERS * 6, b"\x00")
                + bytes(24))
        msg = self.mailbox.transact(MailboxType.EOE, EoeSetAddressFilterRequest(body).encode(),
                                    _is(EoeFrameType.SET_ADDRESS_FILTER_RESPONSE),
                                    what="EoE set address filter", timeout=timeout)
        self._check(msg, "set address filter")

    def get_address_filter(self, *, timeout: float | None = None) -> tuple[list[bytes], bool]:
        """(MAC addresses, no-broadcast flag) the slave filters with."""
        msg = self.mailbox.transact(MailboxType.EOE, EoeGetAddressFilterRequest().encode(),
                                    _is(EoeFrameType.GET_ADDRESS_FILTER_RESPONSE),
                                    what="EoE get address filter", timeout=timeout)
        self._check(msg, "get address filter")
        got = decode_eoe(msg.payload)
        assert isinstance(got, EoeGetAddressFilterResponse)
        body = got.data
        opts = int.from_bytes(body[:2], "little") if len(body) >= 2 else 0
        count = min(opts & 0xF, max(0, (len(body) - 2) // 6))
        return [bytes(body[2 + 6 * i:8 + 6 * i]) for i in range(count)], bool(opts & 0x80)

    def _check(self, msg: ReceivedMessage, what: str) -> None:
        code = int.from_bytes(msg.payload[2:4], "little")
        if code != EoeResult.SUCCESS:
            raise EoeError(f"{self.label}: EoE {what}: result 0x{code:04X} "
                           f"({eoe_result_name(code)})", code)

    # -- frames ------------------------------------------------------------------------

    def send(self, frame: bytes, *, request_time: bool = False,
             timestamp: int | None = None) -> bool:
        """Queue an Ethernet frame for the slave; False when it was dropped (queue full).

        ``request_time`` sets the time-request flag: the slave answers with a
        timestamp response (:attr:`last_timestamp`). ``timestamp`` (0..2**32-1,
        e.g. the low 32 bits of the DC system time) is appended to the frame's
        last fragment with the time-appended flag; the slave's IP side gets the
        frame without it.
        """
        if timestamp is not None and not 0 <= timestamp <= 0xFFFF_FFFF:
            raise ConfigError(f"an EoE timestamp is 32 bits (0..4294967295), got {timestamp}")
        with self._lock:
            ok = self.sender.push(frame, time.monotonic(), request_time=request_time,
                                  timestamp=timestamp)
        wake = self.wake
        if ok and wake is not None:
            wake(self)
        return ok

    @property
    def has_room(self) -> bool:
        """Whether :meth:`send` would take another frame."""
        return self.sender.room

    def _unsolicited(self, mailbox: Mailbox, msg: ReceivedMessage) -> bool:
        ftype = eoe_frame_type(msg)
        if ftype == EoeFrameType.FRAGMENT:
            frame = self.receiver.feed_payload(msg.payload, time.monotonic())
            if self.receiver.timestamp is not None:
                self.last_timestamp = self.receiver.timestamp
            if frame is not None and self.on_frame is not None:
                try:
                    self.on_frame(frame)
                except Exception:  # noqa: BLE001 - a broken consumer must not stop the mailbox
                    _log.exception("%s: EoE frame consumer failed", self.label)
            return True
        if ftype == EoeFrameType.TIMESTAMP_RESPONSE:
            got = decode_eoe(msg.payload)
            assert isinstance(got, EoeTimestampResponse)
            if len(got.data) >= 4:
                self.last_timestamp = int.from_bytes(got.data[:4], "little")
            self.stats.timestamps += 1
            return True
        return False

    # -- one tick of the service ---------------------------------------------------------

    def _collect(self) -> None:
        """Take the replies of the datagrams queued last tick."""
        w = self._write
        r = self._read
        if (w is not None and not w.done()) or (r is not None and not r.done()):
            self.stats.late += 1
        if w is not None and w.done():
            self._write = None
            if w.error is None and w.reply is not None and w.reply.wkc == 1:
                with self._lock:
                    self.sender.taken()
                self.mailbox.stats.sent += 1
                self._write_bytes = b""
            else:
                self.stats.write_retries += 1  # the same bytes again next tick
        r = self._read
        if r is not None and r.done():
            self._read = None
            if r.error is None and r.reply is not None and r.reply.wkc == 1:
                self.stats.reads += 1
                self.streaming = True
                try:
                    self.mailbox.deliver(bytes(r.reply.data))
                except EtherCATError as exc:
                    _log.warning("%s: %s", self.label, exc)
            else:
                self.stats.empty_reads += 1
                self.streaming = False

    def _queue(self, scheduler: Scheduler, now: float, full: bool, room: int = -1) -> int:
        """Queue this tick's SM0 write and SM1 read (unless another client holds the mailbox).

        ``room``: datagram bytes the next cyclic frame has left for them (-1: not
        known, they wait for it anyway). What does not fit goes out now, in a
        frame of its own: its reply is back before the next tick (queued, it
        would leave right behind the next cyclic frame, and the tick that
        follows that frame would find it still on its way and skip the slave
        for a cycle). Returns the room left.
        """
        box = self.mailbox
        if not box.lock.acquire(blocking=False):
            return room  # a CoE transfer has it; its reads dispatch our fragments
        try:
            out: list[Datagram] = []
            want_write = False
            if self._write is None:
                if not self._write_bytes:
                    with self._lock:
                        payload = self.sender.current(now)
                    if payload is not None:
                        self._write_bytes = encode_mailbox(MailboxType.EOE, payload,
                                                           counter=box.next_counter(),
                                                           size=box.rx_size)
                if self._write_bytes:
                    out.append(Datagram.device(Command.FPWR, box.station, box.rx_offset,
                                               self._write_bytes))
                    want_write = True
            want_read = self._read is None and (full or self.streaming)
            if want_read:
                out.append(Datagram.device(Command.FPRD, box.station, box.tx_offset,
                                           box.tx_size))
            if not out:
                return room
            size = sum(d.size for d in out)
            now_frame = 0 <= room < size
            reqs = scheduler.submit(out, retries=0, flush=now_frame)
            if want_write:
                self._write = reqs[0]
            if want_read:
                self._read = reqs[-1]
            return room if now_frame or room < 0 else room - size
        finally:
            box.lock.release()

    @property
    def busy(self) -> bool:
        """Whether the client has work this tick regardless of the status byte."""
        return (self.streaming or self._write is not None or self._read is not None
                or bool(self._write_bytes) or self.sender.busy)


class EoeService:
    """Moves the EoE frames of every client (see the module text)."""

    def __init__(self, scheduler: Scheduler, clients: Sequence[EoeClient], *,
                 period: float = 0.001) -> None:
        if period <= 0:
            raise ConfigError(f"EoE period must be positive, got {period}")
        self.scheduler = scheduler
        self.clients = list(clients)
        self.period = period
        self.ticks = 0
        self._runner: CyclicRunner | None = None
        self._chained: Callable[[Cycle], None] | None = None
        self._status: list[tuple[bytearray | memoryview, np.ndarray, list[EoeClient]]] = []
        self._polled: list[EoeClient] = []
        self._polls: dict[EoeClient, Request] = {}
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._started = False
        # clients with work in flight or queued: the only ones a tick looks at besides
        # those whose status byte says "full"
        self._active: set[EoeClient] = set()
        self._active_lock = threading.Lock()
        for c in self.clients:
            c.wake = self._wake

    def _wake(self, client: EoeClient) -> None:
        with self._active_lock:
            self._active.add(client)

    # -- attaching -----------------------------------------------------------------------

    def attach(self, runner: CyclicRunner, offsets: dict[int, tuple[str, int]]) -> None:
        """Tick from ``runner``'s cycle callback; ``offsets``: position -> (group, status offset).

        Clients whose slave has no status byte in the image poll 0x080D instead.
        """
        self._runner = runner
        by_group: dict[str, list[tuple[int, EoeClient]]] = {}
        self._polled = []
        for c in self.clients:
            where = offsets.get(c.position)
            if where is None or where[1] < 0:
                self._polled.append(c)
            else:
                by_group.setdefault(where[0], []).append((where[1], c))
        self._status = []
        for g in runner.groups:
            items = by_group.get(g.name)
            if items:
                self._status.append((g.image.buffer, np.array([o for o, _ in items],
                                                              dtype=np.intp),
                                     [c for _, c in items]))
        self._drain()
        self._chained = runner.callback
        runner.callback = self._on_cycle

    def detach(self) -> None:
        """Stop ticking from the cyclic loop (restores its callback)."""
        runner = self._runner
        if runner is not None and runner.callback == self._on_cycle:
            runner.callback = self._chained
        self._runner = None

    def _on_cycle(self, cycle: Cycle) -> None:
        self.tick()
        chained = self._chained
        if chained is not None:
            chained(cycle)

    def start(self) -> EoeService:
        """Tick from a thread of its own every ``period`` (no cyclic exchange running)."""
        if self._thread is not None and self._thread.is_alive():
            return self
        self._polled = list(self.clients)
        self._status = []
        self._drain()
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="ecat-eoe", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread (:meth:`start`) or the cyclic ticking (:meth:`attach`)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join()
        self._thread = None
        self.detach()

    def _loop(self) -> None:
        nxt = time.monotonic()
        while not self._stop.is_set():
            try:
                self.tick()
                self.scheduler.flush()
                # No cyclic thread receives for us: wait for this tick's replies.
                pending = [r for c in self.clients for r in (c._write, c._read) if r is not None]
                pending += [r for r in self._polls.values()]
                if pending:
                    self.scheduler.wait(pending)
            except EtherCATError as exc:
                _log.warning("EoE service: %s", exc)
            nxt += self.period
            delay = nxt - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                nxt = time.monotonic()

    def _drain(self) -> None:
        """Empty SM1 of what an earlier session left (once, before the first tick)."""
        if self._started:
            return
        self._started = True
        for c in self.clients:
            try:
                c.mailbox.drain()
            except EtherCATError as exc:
                _log.info("%s: mailbox not drained (%s)", c.label, exc)

    # -- the tick ------------------------------------------------------------------------

    def _cyclic_room(self) -> int:
        """Datagram bytes the next cyclic frame leaves free (-1: no cyclic loop, not known)."""
        runner = self._runner
        plans = runner.last_plans if runner is not None else None
        if not plans:
            return -1
        # queued datagrams ride in the first frame the loop sends (PduCore.send_prepared)
        return max(0, self.scheduler.core.capacity - plans[0].template.size)

    def tick(self) -> None:
        """Take last tick's replies and queue this tick's datagrams (see the module text)."""
        self.ticks += 1
        now = time.monotonic()
        sched = self.scheduler
        runner = self._runner
        ok = runner is None or all(g.wkc_ok for g in runner.groups)
        with self._active_lock:
            work = set(self._active)
        full_set: set[EoeClient] = set()
        for buffer, offsets, clients in self._status:
            # one gather for every client of the group: only full ones get Python work
            view = np.frombuffer(buffer, dtype=np.uint8)
            full = np.flatnonzero(view[offsets] & reg.SM_STATUS_MAILBOX_FULL)
            if ok and len(full):
                full_set.update(clients[i] for i in full)
        polled = set(self._polled)
        room = self._cyclic_room()
        for c in work | full_set:
            if c in polled:
                continue
            c._collect()
            room = c._queue(sched, now, c in full_set, room)
            if not c.busy:
                with self._active_lock:
                    self._active.discard(c)
            else:
                with self._active_lock:
                    self._active.add(c)
        for c in self._polled:
            poll = self._polls.pop(c, None)
            is_full = (poll is not None and poll.done() and poll.error is None
                    and poll.reply is not None and poll.reply.wkc == 1
                    and bool(poll.reply.data[0] & reg.SM_STATUS_MAILBOX_FULL))
            c._collect()
            c._queue(sched, now, is_full)
            if poll is not None and not poll.done():
                self._polls[c] = poll
            elif c._read is None and not c.streaming:
                self._polls[c] = sched.submit(
                    [Datagram.device(Command.FPRD, c.mailbox.station,
                                     c.mailbox.status_address, 1)],
                    retries=0, flush=False)[0]


def speaks_eoe(slave: Slave) -> bool:
    """Whether a scanned slave announces EoE in its SII and has a mailbox."""
    info = slave.mailbox
    return (slave.mbx is not None and info is not None
            and bool(info.protocols & MailboxProtocol.EOE))


def eoe_client(slave: Slave) -> EoeClient:
    """The EoE client of a scanned slave (``slave.client(EoeClient)``); ConfigError without EoE."""
    if not speaks_eoe(slave):
        raise ConfigError(f"{slave.describe()} does not speak EoE (SII mailbox protocols)")
    return slave.client(EoeClient)


def eoe_clients(slaves: Sequence[Slave]) -> dict[int, EoeClient]:
    """EoE clients of every slave that speaks EoE, by ring position."""
    return {s.position: eoe_client(s) for s in slaves if speaks_eoe(s)}


def _is(ftype: EoeFrameType) -> Callable[[ReceivedMessage], bool]:
    return lambda m: eoe_frame_type(m) == ftype
