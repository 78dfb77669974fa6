"""The control protocol: typed requests and replies, and their byte framing (sans-IO).

A running master answers other programs (the command line, later the web
dashboard) on a local socket. Every exchange is one request and one reply,
each a :func:`dataclasses.dataclass`:

* a request class is registered with :func:`request` under an operation
  name and names its reply class;
* values are turned into JSON by their type hints (``bytes`` as hex,
  enums by value, nested dataclasses as objects), and back the same way,
  so a reply arrives as the same typed object that was sent;
* on the wire every message is a 4-byte big-endian length and that many
  bytes of UTF-8 JSON. A request is ``{"v": 1, "id": N, "op": NAME,
  "args": {...}}``; a reply ``{"id": N, "ok": {...}}`` or ``{"id": N,
  "error": {"type": CLASS, "message": TEXT}}``.

This module does no I/O: :class:`Framer` turns received bytes into
messages, :func:`encode_request`/:func:`encode_reply` turn messages into
bytes. Adding an operation (FoE, SoE, EoE...) is a request and a reply
dataclass here or in the protocol's own module, and a handler registered
with :func:`pyethercat.master.control.handlers.handler`.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import struct
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

from pyethercat.errors import EtherCATError

__all__ = [
    "PROTOCOL_VERSION",
    "MAX_MESSAGE",
    "ControlRequest",
    "Reply",
    "RemoteError",
    "ProtocolError",
    "request",
    "request_types",
    "to_json",
    "from_json",
    "encode_message",
    "encode_request",
    "encode_reply",
    "encode_error",
    "decode_request",
    "decode_reply",
    "Framer",
]

#: Bumped when a message changes incompatibly; both ends must agree.
PROTOCOL_VERSION = 1
#: Largest message accepted (a full process image or SII fits many times over).
MAX_MESSAGE = 64 << 20

_LENGTH = struct.Struct(">I")
T = TypeVar("T")


class ProtocolError(EtherCATError):
    """A control message could not be framed, decoded or matched."""


class RemoteError(EtherCATError):
    """The running master answered a request with an error.

    ``remote_type`` is the name of the error class raised there (``SdoAbort``,
    ``SiiWriteError``...); the message is its text.
    """

    def __init__(self, remote_type: str, message: str) -> None:
        self.remote_type = remote_type
        super().__init__(message)


@dataclass(frozen=True)
class ControlRequest:
    """Base of every control-socket request; subclasses are registered with :func:`request`."""

    op: ClassVar[str] = ""
    reply: ClassVar[type[Any]] = type(None)


@dataclass(frozen=True)
class Reply:
    """Base of replies that carry nothing (an acknowledgement)."""


_REQUESTS: dict[str, type[ControlRequest]] = {}

R = TypeVar("R", bound=type[ControlRequest])


def request(op: str, reply: type[Any]) -> Callable[[R], R]:
    """Class decorator: register a request dataclass under ``op`` with its reply type."""

    def register(cls: R) -> R:
        if op in _REQUESTS and _REQUESTS[op] is not cls:
            raise ValueError(f"control operation {op!r} registered twice")
        cls.op = op
        cls.reply = reply
        _REQUESTS[op] = cls
        return cls

    return register


def request_types() -> dict[str, type[ControlRequest]]:
    """Every registered operation and its request class."""
    return dict(_REQUESTS)


# --- values <-> JSON by type hints ------------------------------------------------------


def to_json(value: Any) -> Any:
    """A JSON-able form of ``value`` (dataclasses, enums, bytes, containers)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, enum.Enum):
        return to_json(value.value)
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(to_json(k)): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [to_json(v) for v in value]
    raise ProtocolError(f"cannot send a value of type {type(value).__name__}")


_HINTS: dict[type[Any], dict[str, Any]] = {}


def _hints(cls: type[Any]) -> dict[str, Any]:
    hints = _HINTS.get(cls)
    if hints is None:
        hints = typing.get_type_hints(cls)
        _HINTS[cls] = hints
    return hints


def from_json(tp: Any, data: Any) -> Any:
    """Rebuild a value of type ``tp`` from :func:`to_json`'s form."""
    if tp is Any:
        return data
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if data is None and type(None) in args:
            return None
        last: Exception | None = None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return from_json(arg, data)
            except (ProtocolError, TypeError, ValueError, KeyError) as exc:
                last = exc
        raise ProtocolError(f"no member of {tp} fits {data!r}: {last}")
    if origin in (list, tuple, set, frozenset) or tp in (list, tuple):
        if not isinstance(data, list):
            raise ProtocolError(f"expected a list for {tp}, got {type(data).__name__}")
        args = typing.get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            return tuple(from_json(a, v) for a, v in zip(args, data, strict=True))
        item = args[0] if args else Any
        items = [from_json(item, v) for v in data]
        return items if origin in (list, None) else (origin or list)(items)
    if origin is dict or tp is dict:
        if not isinstance(data, dict):
            raise ProtocolError(f"expected an object for {tp}, got {type(data).__name__}")
        kt, vt = typing.get_args(tp) or (Any, Any)
        return {from_json(kt, int(k) if kt is int else k): from_json(vt, v)
                for k, v in data.items()}
    if origin is typing.Literal:
        return data
    if isinstance(tp, type):
        if issubclass(tp, enum.Enum):
            return tp(data)
        if tp is bytes:
            if not isinstance(data, str):
                raise ProtocolError(f"expected hex text for bytes, got {type(data).__name__}")
            return bytes.fromhex(data)
        if dataclasses.is_dataclass(tp):
            return _dataclass_from_json(tp, data)
        if tp is float and isinstance(data, (int, float)):
            return float(data)
        if tp is bool:
            if not isinstance(data, bool):
                raise ProtocolError(f"expected true/false, got {data!r}")
            return data
        if tp is int:
            if isinstance(data, bool) or not isinstance(data, int):
                raise ProtocolError(f"expected an integer, got {data!r}")
            return data
        if tp is str:
            if not isinstance(data, str):
                raise ProtocolError(f"expected text, got {data!r}")
            return data
        if isinstance(data, tp):
            return data
    raise ProtocolError(f"cannot rebuild a {tp} from {data!r}")


def _dataclass_from_json(cls: type[T], data: Any) -> T:
    if not isinstance(data, dict):
        raise ProtocolError(f"expected an object for {cls.__name__}, got {type(data).__name__}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    late: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in data:
            continue
        value = from_json(hints.get(f.name, Any), data[f.name])
        (kwargs if f.init else late)[f.name] = value
    try:
        obj = cls(**kwargs)
    except TypeError as exc:
        raise ProtocolError(f"{cls.__name__}: {exc}") from None
    for name, value in late.items():
        object.__setattr__(obj, name, value)
    return obj


# --- messages ------------------------------------------------------------------------------


def encode_message(message: dict[str, Any]) -> bytes:
    """Length prefix and UTF-8 JSON of one message."""
    body = json.dumps(message, separators=(",", ":"), allow_nan=True).encode()
    if len(body) > MAX_MESSAGE:
        raise ProtocolError(f"control message of {len(body)} bytes is too large")
    return _LENGTH.pack(len(body)) + body


def encode_request(req: ControlRequest, ident: int) -> bytes:
    """The bytes of a request."""
    if not req.op:
        raise ProtocolError(f"{type(req).__name__} is not a registered control request")
    return encode_message({"v": PROTOCOL_VERSION, "id": ident, "op": req.op,
                           "args": to_json(req)})


def encode_reply(ident: int, reply: Any) -> bytes:
    """The bytes of a successful reply."""
    return encode_message({"id": ident, "ok": to_json(reply)})


def encode_error(ident: int, exc: BaseException) -> bytes:
    """The bytes of a failed request (the error's class name and its one-line text)."""
    name = exc.remote_type if isinstance(exc, RemoteError) else type(exc).__name__
    return encode_message({"id": ident, "error": {"type": name, "message": str(exc)}})


def decode_request(message: dict[str, Any]) -> tuple[int, ControlRequest]:
    """(id, request) of a received request message."""
    ident = message.get("id")
    if not isinstance(ident, int):
        raise ProtocolError("control request without an id")
    if message.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"control protocol version {message.get('v')!r}, this master "
                            f"speaks {PROTOCOL_VERSION} (the two pyethercat installs differ)")
    cls = _REQUESTS.get(str(message.get("op")))
    if cls is None:
        raise ProtocolError(f"unknown control operation {message.get('op')!r} (the running "
                            "master's pyethercat is older than this one)")
    req: ControlRequest = _dataclass_from_json(cls, message.get("args") or {})
    return ident, req


def decode_reply(message: dict[str, Any], req: ControlRequest) -> Any:
    """The typed reply to ``req``, or raise :class:`RemoteError`."""
    if "error" in message:
        err = message["error"] or {}
        raise RemoteError(str(err.get("type", "Error")), str(err.get("message", "")))
    if "ok" not in message:
        raise ProtocolError("control reply without a result")
    return from_json(req.reply, message["ok"])


@dataclass
class Framer:
    """Splits a byte stream into messages (length-prefixed JSON objects)."""

    buffer: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[dict[str, Any]]:
        """Add received bytes; return the messages now complete."""
        self.buffer += data
        out: list[dict[str, Any]] = []
        while len(self.buffer) >= _LENGTH.size:
            (size,) = _LENGTH.unpack_from(self.buffer)
            if size > MAX_MESSAGE:
                raise ProtocolError(f"control message of {size} bytes announced (too large)")
            if len(self.buffer) < _LENGTH.size + size:
                break
            body = bytes(self.buffer[_LENGTH.size:_LENGTH.size + size])
            del self.buffer[:_LENGTH.size + size]
            try:
                message = json.loads(body)
            except ValueError as exc:
                raise ProtocolError(f"control message is not JSON: {exc}") from None
            if not isinstance(message, dict):
                raise ProtocolError("control message is not an object")
            out.append(message)
        return out
