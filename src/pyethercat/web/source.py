"""The dashboard's way to the master: its control socket, or a master of its own.

Both kinds answer :meth:`MasterConnection.call` with the typed reply of a
control request (:mod:`pyethercat.master.control`), from any thread:

- :class:`RemoteConnection` talks to a running master (``pyethercat run``,
  ``demo``, a program serving its master) over its Unix socket; a small pool
  of connections lets a long SDO listing run while telemetry keeps coming;
- :class:`DirectConnection` serves the requests in process, against a
  master the dashboard opened itself (no master was running).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any, Protocol

from pyethercat.errors import ConfigError
from pyethercat.master.control import telemetry_ops  # noqa: F401 - registers the handlers
from pyethercat.master.control.client import ControlClient
from pyethercat.master.control.handlers import MasterContext, dispatch
from pyethercat.master.control.protocol import ControlRequest

__all__ = ["MasterConnection", "RemoteConnection", "DirectConnection"]


class MasterConnection(Protocol):
    """What the dashboard needs of a master."""

    link: str
    remote: bool

    def call(self, req: ControlRequest) -> Any: ...

    def close(self) -> None: ...


class RemoteConnection:
    """Requests to a running master over its control socket (a pool of ``size`` connections)."""

    remote = True

    def __init__(self, path: Path, link: str, *, size: int = 4, timeout: float = 60.0) -> None:
        self.path = path
        self.link = link
        self.timeout = timeout
        self._idle: queue.LifoQueue[ControlClient] = queue.LifoQueue()
        self._slots = threading.Semaphore(size)
        self._closed = False
        self._lock = threading.Lock()
        self._all: list[ControlClient] = []

    def _client(self) -> ControlClient:
        try:
            return self._idle.get_nowait()
        except queue.Empty:
            pass
        try:
            client = ControlClient(self.path, self.timeout)
        except OSError as exc:
            raise ConfigError(f"the master on {self.link} is gone (control socket "
                              f"{self.path}: {exc.strerror or exc})") from None
        with self._lock:
            self._all.append(client)
        return client

    def call(self, req: ControlRequest) -> Any:
        if self._closed:
            raise ConfigError("the dashboard's connection to the master is closed")
        with self._slots:
            client = self._client()
            ok = False
            try:
                reply = client.call(req)
                ok = True
                return reply
            finally:
                if ok:
                    self._idle.put(client)
                else:
                    # A failed socket is not reused (the error may be the socket's).
                    client.close()
                    with self._lock:
                        if client in self._all:
                            self._all.remove(client)

    def close(self) -> None:
        self._closed = True
        with self._lock:
            clients, self._all = self._all, []
        for c in clients:
            c.close()


class DirectConnection:
    """Requests served in process by a master this program opened.

    One request at a time, under :attr:`lock`: a direct master's
    scan-on-first-use is not re-entrant. Code of the same program that works
    on the master (or on an in-process simulated segment) from another
    thread holds the same lock, so its frames never interleave with the
    dashboard's.
    """

    remote = False

    def __init__(self, context: MasterContext, lock: threading.Lock | None = None) -> None:
        self.context = context
        self.link = context.link
        self.lock = lock if lock is not None else threading.Lock()

    def call(self, req: ControlRequest) -> Any:
        with self.lock:
            return dispatch(self.context, req)

    def close(self) -> None:
        pass
