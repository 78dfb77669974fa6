"""ETG.8200 mailbox gateway: mailbox requests over UDP, forwarded to slaves while the master runs.

:class:`MailboxGateway` listens on a UDP socket (127.0.0.1:34980 unless told
otherwise: the gateway gives whoever reaches it the run of every slave's
mailbox, IgH's README warns the same). Each datagram is one request in the
framing of :mod:`pyethercat.wire.gateway`:

- address 0 goes to the master's object dictionary
  (:class:`~pyethercat.master.master_od.MasterObjectDictionary`);
- a station address or 1000 + ring position goes to that slave: the mailbox
  is sent with the master's own mailbox counter (the requester's could repeat
  the master's last one, and the slave would drop it), the slave's answer goes
  back with the requester's address in its header. A mailbox error reply
  (type 0) is forwarded as such;
- requests are served by a pool of threads: requests to different slaves run
  at the same time, requests to one slave one after the other, each holding
  that slave's mailbox lock from its request to its answer, so nothing
  (another client, the master's own CoE) interleaves in between;
- a datagram that cannot be decoded, names no slave, or whose slave does not
  answer is dropped without reply (as IgH and KickCAT do) and counted in
  :attr:`MailboxGateway.stats`.

The gateway reaches the slaves through a :data:`Forward` function: by default
:func:`forward_request` on the master in this process; a gateway in another
process than a running master (``pyethercat gateway`` beside ``pyethercat
run``) forwards through that master's control socket
(:mod:`pyethercat.master.control.gateway_ops`), where the same function runs.
"""

from __future__ import annotations

import logging
import socket
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol

from pyethercat.errors import ConfigError, EtherCATError, MailboxErrorReply
from pyethercat.master.control.protocol import Reply
from pyethercat.master.mailbox import ReceivedMessage
from pyethercat.master.master_od import MasterObjectDictionary
from pyethercat.master.slave import Slave
from pyethercat.wire.gateway import (
    GATEWAY_PORT,
    GatewayError,
    GatewayRequest,
    decode_gateway_request,
    encode_gateway_reply,
    gateway_target,
)
from pyethercat.wire.mailbox.header import (
    MAILBOX_HEADER_SIZE,
    MailboxType,
    encode_mailbox,
    encode_mailbox_error,
)

__all__ = ["DEFAULT_BIND", "DEFAULT_REQUEST_TIMEOUT", "Forward", "Forwarded", "GatewayMaster",
           "GatewayStats", "MailboxGateway", "forward_request", "parse_bind"]

_log = logging.getLogger("pyethercat.gateway")

#: Where the gateway listens by default: loopback only.
DEFAULT_BIND = ("127.0.0.1", GATEWAY_PORT)
#: Seconds a forwarded request may take (IgH's mailbox gateway waits about as long).
DEFAULT_REQUEST_TIMEOUT = 2.0


class GatewayMaster(Protocol):
    """What the gateway needs of a master: its slaves (with their mailboxes)."""

    slaves: list[Slave]


def parse_bind(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``HOST`` / ``:PORT``) to an address; :class:`ConfigError` if bad."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(GATEWAY_PORT)
    try:
        number = int(port, 0)
    except ValueError:
        raise ConfigError(f"bind address {text!r}: port {port!r} is not a number") from None
    if not 0 <= number <= 0xFFFF:
        raise ConfigError(f"bind address {text!r}: port out of range")
    return (host or DEFAULT_BIND[0]), number


@dataclass
class GatewayStats:
    """What the gateway did (monotonic counters)."""

    received: int = 0
    answered: int = 0
    to_master: int = 0
    forwarded: int = 0
    #: Requests forwarded but not answered (the slave's failure, a time-out).
    failed: int = 0
    #: Datagrams dropped before forwarding, by reason ("short", "type", "length", "address",
    #: "no mailbox").
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())


def _same_type(mtype: int) -> Callable[[ReceivedMessage], bool]:
    return lambda msg: int(msg.header.type) == mtype


@dataclass(frozen=True)
class Forwarded(Reply):
    """What became of one request forwarded to a slave.

    ``mailbox``: the slave's answer, a whole mailbox (header with address 0,
    payload; a mailbox error reply is one too); empty when there is none.
    ``dropped``: why the request was not sent (the slave has no mailbox);
    ``failed``: why the slave's answer did not come (a time-out, the link).
    """

    mailbox: bytes = b""
    dropped: str | None = None
    failed: str | None = None


#: How a gateway reaches a slave: ``forward(slave, mailbox type, payload, timeout)``.
Forward = Callable[[Slave, int, bytes, float], Forwarded]


def forward_request(slave: Slave, mtype: int, payload: bytes, timeout: float) -> Forwarded:
    """Send one request to ``slave``'s mailbox and take its answer (the master's side).

    Holds the slave's mailbox lock from the request to its answer, so no other
    client, nor the master's own CoE, interleaves in between. The request
    goes with the master's counter through ``Mailbox.transact`` (the take-over
    rule included); the answer is the next message of the same mailbox type.
    """
    mbx = slave.mbx
    if mbx is None:
        return Forwarded(dropped="no mailbox")
    accept = _same_type(mtype)
    try:
        with mbx.lock:
            mbx.drop(accept)  # answers to requests that timed out earlier
            answer = mbx.transact(mtype, payload, accept, what="gateway request",
                                  timeout=timeout)
    except MailboxErrorReply as exc:
        return Forwarded(encode_mailbox(MailboxType.ERR, encode_mailbox_error(exc.code)))
    except EtherCATError as exc:
        return Forwarded(failed=str(exc))
    h = answer.header
    return Forwarded(encode_mailbox(h.type, answer.payload, counter=h.counter,
                                    channel=h.channel, priority=h.priority))


class MailboxGateway:
    """The gateway of one master (see the module text); a context manager."""

    def __init__(self, master: GatewayMaster, *, bind: tuple[str, int] = DEFAULT_BIND,
                 workers: int = 8, timeout: float = DEFAULT_REQUEST_TIMEOUT,
                 master_od: MasterObjectDictionary | None = None,
                 forward: Forward = forward_request) -> None:
        self.master = master
        self.timeout = timeout
        self._forward = forward
        self.od = master_od if master_od is not None else MasterObjectDictionary(
            lambda: master.slaves)
        self.stats = GatewayStats()
        self._lock = threading.Lock()
        try:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(bind)
        except OSError as exc:
            raise ConfigError(f"mailbox gateway cannot listen on {bind[0]}:{bind[1]}: "
                              f"{exc.strerror or exc}") from None
        self.sock.settimeout(0.2)
        self._pool = ThreadPoolExecutor(max_workers=workers,
                                        thread_name_prefix="pyethercat-gateway")
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def address(self) -> tuple[str, int]:
        """The address the gateway listens on (the port the OS chose for port 0)."""
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    # -- running ---------------------------------------------------------------------

    def start(self) -> MailboxGateway:
        """Serve in a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.serve_forever, daemon=True,
                                            name="pyethercat-gateway")
            self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Receive and dispatch datagrams until :meth:`stop`."""
        while not self._stop.is_set():
            try:
                data, peer = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                raise
            with self._lock:
                self.stats.received += 1
            self._pool.submit(self._serve_one, data, peer)

    def stop(self) -> None:
        """Stop listening, finish the requests in progress, close the socket."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._pool.shutdown(wait=True)
        self.sock.close()

    def __enter__(self) -> MailboxGateway:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- one request -----------------------------------------------------------------

    def _drop(self, reason: str) -> None:
        with self._lock:
            self.stats.dropped[reason] = self.stats.dropped.get(reason, 0) + 1

    def _serve_one(self, data: bytes, peer: tuple[str, int]) -> None:
        try:
            request = decode_gateway_request(data)
        except GatewayError as exc:
            _log.info("gateway: datagram from %s:%d dropped: %s", peer[0], peer[1], exc)
            self._drop(exc.reason)
            return
        slaves: Sequence[Slave] = self.master.slaves
        target = gateway_target(request.address, [s.station_address for s in slaves])
        if target is None:
            _log.info("gateway: address %d names no slave", request.address)
            self._drop("address")
            return
        if target < 0:
            reply = self.od.handle(request.mailbox, requester=peer)
            with self._lock:
                self.stats.to_master += 1
        else:
            got = self.forward(slaves[target], request)
            if got is None:
                return
            reply = got
        with self._lock:  # counted first: the requester may look as soon as it has the reply
            self.stats.answered += 1
        try:
            self.sock.sendto(encode_gateway_reply(reply), peer)
        except OSError as exc:
            _log.info("gateway: reply to %s:%d not sent: %s", peer[0], peer[1], exc)
            with self._lock:
                self.stats.answered -= 1
                self.stats.failed += 1

    def forward(self, slave: Slave, request: GatewayRequest) -> bytes | None:
        """Send ``request`` to ``slave`` and return its answer mailbox (None: failed)."""
        got = self._forward(slave, int(request.header.type), request.payload, self.timeout)
        if got.dropped is not None:
            self._drop(got.dropped)
            return None
        with self._lock:
            self.stats.forwarded += 1
        if got.failed is not None or len(got.mailbox) < MAILBOX_HEADER_SIZE:
            _log.info("gateway: %s: request failed: %s", slave.describe(), got.failed)
            with self._lock:
                self.stats.failed += 1
            return None
        # the requester's address goes back in the answer's header (ETG.8200)
        out = bytearray(got.mailbox)
        out[2:4] = (request.address & 0xFFFF).to_bytes(2, "little")
        return bytes(out)
