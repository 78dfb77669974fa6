"""The control channel between the user's process and its engine: one message per packet.

A Unix ``SOCK_SEQPACKET`` socketpair: each message is a small pickled dict
(``{"op": ..., ...}``) in one packet, so a reader never sees half a message
and the closing of the other end reads as end of file. Both sides trust
each other (the same user started both); nothing else can reach the pair.
"""

from __future__ import annotations

import pickle
import socket
from typing import Any

__all__ = ["MAX_MESSAGE", "recv_message", "send_message"]

#: Largest message (bytes of pickle).
MAX_MESSAGE = 1 << 16


def send_message(sock: socket.socket, message: dict[str, Any]) -> None:
    """Send one message (raises OSError when the other end has gone)."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) > MAX_MESSAGE:
        raise ValueError(f"control message of {len(data)} bytes is too long")
    sock.send(data)


def recv_message(sock: socket.socket) -> dict[str, Any]:
    """Receive one message; BlockingIOError when none waits (non-blocking socket),
    EOFError when the other end has closed."""
    data = sock.recv(MAX_MESSAGE)
    if not data:
        raise EOFError("the other end of the control channel has closed")
    message = pickle.loads(data)  # noqa: S301 - our own process pair
    if not isinstance(message, dict):
        raise EOFError("not a control message")
    return message
