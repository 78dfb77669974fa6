"""The control server: a running master answers requests on its Unix socket.

One thread accepts connections (and samples the frame counters once a
second for the rates of ``master``); each connection gets a thread that
reads requests, runs them through :func:`~pyethercat.master.control.handlers.dispatch`
and writes the replies. Only the master's own user (or root) may connect
(``SO_PEERCRED``); the socket file has mode 0600 in a 0700 directory.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import threading
from pathlib import Path

from pyethercat.errors import ConfigError
from pyethercat.master.control import handlers
from pyethercat.master.control.endpoint import endpoint_path
from pyethercat.master.control.protocol import (
    Framer,
    ProtocolError,
    decode_request,
    encode_error,
    encode_reply,
)

__all__ = ["ControlServer", "MasterRunningError", "serve", "HANDLER_MODULES"]

#: Modules whose import registers more handlers (one per mailbox protocol, added as they come).
HANDLER_MODULES: tuple[str, ...] = ("pyethercat.master.control.ring_ops",
                                     "pyethercat.master.control.drive_ops",
                                     "pyethercat.master.control.telemetry_ops",
                                     "pyethercat.master.control.gateway_ops")
_CRED = struct.Struct("3i")


class MasterRunningError(ConfigError):
    """Another master already serves this link: one master per wire."""


class ControlServer:
    """Serves one master's control socket at ``path`` until :meth:`close`."""

    def __init__(self, context: handlers.MasterContext, path: Path) -> None:
        self.context = context
        self.path = path
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._inode: int | None = None

    def start(self) -> ControlServer:
        """Bind the socket (refusing when a live master serves it) and start serving."""
        import importlib

        for name in HANDLER_MODULES:
            importlib.import_module(name)
        self._claim()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            sock.bind(str(self.path))
        except OSError as exc:
            sock.close()
            raise ConfigError(f"cannot create the control socket {self.path}: "
                              f"{exc.strerror or exc}") from None
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        self._inode = os.stat(self.path).st_ino
        sock.listen(8)
        sock.settimeout(1.0)
        self._sock = sock
        self._thread = threading.Thread(target=self._accept_loop, name="ecat-control",
                                        daemon=True)
        self._thread.start()
        return self

    def _claim(self) -> None:
        """Remove a stale socket file; refuse when a master answers on it."""
        from pyethercat.master.control.client import probe

        if not self.path.exists() and not self.path.is_symlink():
            return
        hello = probe(self.path)
        if hello is not None:
            raise MasterRunningError(f"a master already runs on {hello.link} (pid {hello.pid}, "
                              f"control socket {self.path}): one master per wire; send "
                              "commands to it, or stop it first")
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def close(self) -> None:
        """Stop serving and remove the socket file (if it is still ours)."""
        self._stop.set()
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        with contextlib.suppress(OSError):
            if self._inode is not None and os.stat(self.path).st_ino == self._inode:
                self.path.unlink()

    def __enter__(self) -> ControlServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- serving ------------------------------------------------------------------------------

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            sock = self._sock
            if sock is None:
                return
            try:
                conn, _ = sock.accept()
            except TimeoutError:
                self.context.sample()
                continue
            except OSError:
                return
            if not self._allowed(conn):
                conn.close()
                continue
            with self._lock:
                self._conns.add(conn)
            threading.Thread(target=self._serve, args=(conn,), name="ecat-control-conn",
                             daemon=True).start()

    @staticmethod
    def _allowed(conn: socket.socket) -> bool:
        try:
            _pid, uid, _gid = _CRED.unpack(conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                           _CRED.size))
        except OSError:
            return False
        return uid in (os.geteuid(), 0)

    def _serve(self, conn: socket.socket) -> None:
        framer = Framer()
        try:
            while not self._stop.is_set():
                data = conn.recv(65536)
                if not data:
                    return
                for message in framer.feed(data):
                    ident = message.get("id")
                    try:
                        ident_, req = decode_request(message)
                        reply = encode_reply(ident_, handlers.dispatch(self.context, req))
                    except Exception as exc:  # noqa: BLE001 - every failure goes back as a reply
                        reply = encode_error(ident if isinstance(ident, int) else -1, exc)
                    conn.sendall(reply)
        except (OSError, ProtocolError):
            return
        finally:
            with self._lock:
                self._conns.discard(conn)
            conn.close()


def serve(master: handlers.ServedMaster, link: str, *, path: Path | None = None) -> ControlServer:
    """Start serving ``master`` (on link ``link``, e.g. ``raw:eth0``) on its control socket."""
    ctx = handlers.MasterContext(master, link)
    return ControlServer(ctx, path if path is not None else endpoint_path(link)).start()
