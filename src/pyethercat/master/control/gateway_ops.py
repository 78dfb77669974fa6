"""The mailbox gateway beside a running master: requests forwarded through its control socket.

A master that cycles (``pyethercat run``, a program that started one) owns
the link, so a gateway in another process (``pyethercat gateway``) cannot
open a master of its own there. It attaches instead: it keeps the UDP side
(:class:`~pyethercat.master.gateway.MailboxGateway`: decoding, addresses,
the master's object dictionary from the running master's scan, statistics)
and hands every request for a slave to the running master as a
:class:`GatewayForward` request on its control socket. The running master
runs :func:`~pyethercat.master.gateway.forward_request` on its own mailbox
of that slave, holding its lock from request to answer, the cycle
undisturbed.

Importing this module registers its handler (``server.HANDLER_MODULES``
lists it). :class:`RemoteForward` is the gateway's side: one control
connection per gateway worker thread, so requests to different slaves run
at the same time there too (the control server serves each connection in a
thread of its own).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.master.control.client import ControlClient
from pyethercat.master.control.handlers import MasterContext, handler
from pyethercat.master.control.protocol import ControlRequest, request
from pyethercat.master.gateway import DEFAULT_REQUEST_TIMEOUT, Forwarded, forward_request
from pyethercat.master.slave import Slave

__all__ = ["GatewayForward", "RemoteForward"]

#: Seconds the gateway waits for the running master beyond the request's own time-out.
_SLACK = 5.0


@request("gateway_forward", Forwarded)
@dataclass(frozen=True)
class GatewayForward(ControlRequest):
    """One mailbox request for the slave at ``position`` (ETG.8200 gateway).

    ``station_address`` is the slave's address as the gateway knows it: a
    running master that rescanned since and holds another slave there
    refuses rather than talk to the wrong one.
    """

    position: int
    station_address: int
    type: int
    payload: bytes
    timeout: float = DEFAULT_REQUEST_TIMEOUT


@handler(GatewayForward)
def _forward(ctx: MasterContext, req: GatewayForward) -> Forwarded:
    slaves = ctx.slaves()
    if not 0 <= req.position < len(slaves) \
            or slaves[req.position].station_address != req.station_address:
        return Forwarded(failed=f"no slave 0x{req.station_address:04X} at position "
                                f"{req.position} any more (the master rescanned)")
    return forward_request(slaves[req.position], req.type, req.payload, req.timeout)


class RemoteForward:
    """Forward gateway requests to the master serving the control socket ``path``.

    A :data:`~pyethercat.master.gateway.Forward` for
    :class:`~pyethercat.master.gateway.MailboxGateway` (``forward=``). Each
    calling thread gets its own connection, made on first use; :meth:`close`
    closes them all.
    """

    def __init__(self, path: Path, timeout: float = DEFAULT_REQUEST_TIMEOUT) -> None:
        self.path = path
        #: How long a request may take on the running master (the gateway's time-out).
        self.timeout = timeout
        self._local = threading.local()
        self._lock = threading.Lock()
        self._clients: list[ControlClient] = []

    def _client(self) -> ControlClient:
        client: ControlClient | None = getattr(self._local, "client", None)
        if client is None:
            try:
                client = ControlClient(self.path, self.timeout + _SLACK)
            except OSError as exc:
                raise ConfigError(f"the running master's control socket {self.path}: "
                                  f"{exc.strerror or exc}") from None
            self._local.client = client
            with self._lock:
                self._clients.append(client)
        return client

    def __call__(self, slave: Slave, mtype: int, payload: bytes, timeout: float) -> Forwarded:
        """Send one request through the running master (a failure comes back as ``failed``)."""
        req = GatewayForward(slave.position, slave.station_address, mtype, payload,
                             min(timeout, self.timeout))
        try:
            got: Forwarded = self._client().call(req)
        except (EtherCATError, OSError) as exc:
            self._reset()
            return Forwarded(failed=f"through the running master: {exc}")
        return got

    def _reset(self) -> None:
        """Forget this thread's connection (the next request makes a new one)."""
        client: ControlClient | None = getattr(self._local, "client", None)
        if client is not None:
            self._local.client = None
            client.close()
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)

    def close(self) -> None:
        """Close every connection."""
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()
