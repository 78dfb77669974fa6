"""The control client: send typed requests to a running master.

::

    client = find_master("raw:eth0")          # None: no master runs there
    if client is not None:
        with client:
            for s in client.call(ListSlaves()).slaves: ...
"""

from __future__ import annotations

import itertools
import socket
from pathlib import Path
from typing import Any

from pyethercat.errors import ConfigError
from pyethercat.master.control.endpoint import endpoint_path
from pyethercat.master.control.messages import Hello, HelloReply
from pyethercat.master.control.protocol import (
    ControlRequest,
    Framer,
    ProtocolError,
    decode_reply,
    encode_request,
)

__all__ = ["ControlClient", "find_master", "probe"]

#: How long a request may take (an SDO information listing or an SII write is slow).
DEFAULT_TIMEOUT = 300.0


class ControlClient:
    """A connection to one master's control socket."""

    def __init__(self, path: Path, timeout: float = DEFAULT_TIMEOUT) -> None:
        self.path = path
        self.timeout = timeout
        self.hello: HelloReply | None = None
        self._ids = itertools.count(1)
        self._framer = Framer()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(str(path))
        except OSError:
            sock.close()
            raise
        self._sock = sock

    def call(self, req: ControlRequest) -> Any:
        """Send ``req`` and return its typed reply (:class:`RemoteError` on failure)."""
        ident = next(self._ids)
        try:
            self._sock.sendall(encode_request(req, ident))
            while True:
                data = self._sock.recv(65536)
                if not data:
                    raise ConfigError(f"the running master closed its control socket "
                                      f"{self.path} while answering {req.op!r}")
                for message in self._framer.feed(data):
                    if message.get("id") in (ident, -1):
                        return decode_reply(message, req)
        except TimeoutError:
            raise ConfigError(f"the running master did not answer {req.op!r} within "
                              f"{self.timeout:g} s") from None
        except (BrokenPipeError, ConnectionResetError):
            raise ConfigError(f"the running master went away while answering {req.op!r}") from None

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def probe(path: Path, timeout: float = 2.0) -> HelloReply | None:
    """The hello of the master on ``path``, or None when nothing answers there."""
    try:
        client = ControlClient(path, timeout)
    except OSError:
        return None
    try:
        reply: HelloReply = client.call(Hello())
        return reply
    except (ConfigError, ProtocolError, OSError):
        return None
    finally:
        client.close()


def find_master(spec: str, *, timeout: float = DEFAULT_TIMEOUT) -> ControlClient | None:
    """A client of the master running on link ``spec`` (None: no master runs there)."""
    path = endpoint_path(spec)
    if not path.exists():
        return None
    try:
        client = ControlClient(path, timeout)
    except OSError:
        return None  # a stale socket file: its master is gone
    try:
        client.hello = client.call(Hello())
    except Exception:
        client.close()
        raise
    return client
