"""The memory an isolated cyclic engine shares with its user: images, status, samples, events.

One file in ``/dev/shm`` (``pyecat-engine-<pid>-<n>``, mode 0600) mapped by
the user's process and the engine, and by any other reader that knows the
name (a dashboard, a test): nothing in it is a Python object. Its parts,
each 8-byte aligned:

- a **status block**: the engine's counters (cycles, late cycles, lost
  frames, each group's exchanges and working counters...) as 64-bit
  integers behind a sequence number, a *seqlock*: the engine (the only
  writer) makes the number odd, writes, makes it even; a reader copies the
  block and takes the copy when the number was the same even value before
  and after. The writer never waits for a reader, a reader retries. The
  engine publishes it every cycle up to 1 kHz and every millisecond above
  (at 4 kHz every fourth cycle: its cost would lengthen the cycles);
- a **tick**: the number of cycles the engine has done, one 64-bit store
  every cycle, before the cycle's acyclic replies go back to the user's
  process: what the user's side follows to run its callback once per
  cycle, with those replies at hand. Beside it the number of cycles begun,
  written before each cycle's frames go: a cycle is under way while the two
  differ;
- per group, the **process image** (``[outputs][inputs][mailbox status]``
  as the configuration lays it out) and its **safe outputs**, with two
  sequence numbers: ``in`` (the engine writes the input bytes) and ``out``
  (the user's process writes outputs). The engine never takes outputs
  that were being written (it keeps sending the last whole ones). With the
  inputs, under ``in``, the engine writes the group's exchange count and
  whether its working counters were whole;
- three **sample rings** (period, wake-up latency, round trip; int64 ns,
  written in place by the engine's :class:`~pyethercat.master.cyclic.CycleStats`);
- an **event ring** (the engine's log lines) and a **health table** (one
  record per slave, with a seqlock of its own).

The seqlocks rely on stores becoming visible in program order (x86-64 and
other total-store-order machines). Reading the status block costs a copy of
a few hundred bytes: any number of readers at any rate do not slow the
engine.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import mmap
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError

__all__ = [
    "EVENT_TEXT",
    "HEALTH_STATUS",
    "AreaLayout",
    "SeqBlock",
    "SharedArea",
    "engine_area_path",
]

_MAGIC = 0x50594543_454E4731  # "PYECENG1"
# magic, total size, layout version, creator's pid, offset and length of the layout (JSON)
_HEADER = struct.Struct("<QQQQQQ")
_U64 = struct.Struct("<Q")
_EXCHANGE = struct.Struct("<QQ")  # a group's exchanges and whether its counters were whole
# Version of the file's layout rules (2: the tick and the cycles begun after the status
# block, each group's exchange beside its sequence numbers).
_VERSION = 2
_EVENT_SLOT = 256
#: Longest event text kept (bytes of UTF-8).
EVENT_TEXT = _EVENT_SLOT - 24
_EVENT_HEAD = struct.Struct("<QdQ")  # serial, unix time, text length
#: Supervision status of a slave, as numbered in the health table.
HEALTH_STATUS = ("ok", "dropped", "vanished", "recovering", "lost", "absent")
# ``state``/``error``/``code``: what the last per-slave read found; ``now``: the AL status
# (state and error flag) supervision confirmed lately, 0 when it is not known now.
_HEALTH_DTYPE = np.dtype([("position", "<i4"), ("station", "<u2"), ("state", "u1"),
                          ("error", "u1"), ("code", "<u2"), ("present", "u1"),
                          ("status", "u1"), ("recoveries", "<u4"), ("now", "u1")])
_counter = itertools.count()


def _align(n: int) -> int:
    return (n + 7) & ~7


def engine_area_path() -> str:
    """A fresh name for an engine's shared file (``/dev/shm`` when it exists)."""
    base = "/dev/shm" if os.path.isdir("/dev/shm") else "/tmp"
    return f"{base}/pyecat-engine-{os.getpid()}-{next(_counter)}"


class SeqBlock:
    """Int64 fields behind a seqlock at ``offset`` of ``buf`` (see the module text)."""

    def __init__(self, buf: memoryview, offset: int, fields: Sequence[str]) -> None:
        self.fields = tuple(fields)
        self.index = {name: i for i, name in enumerate(self.fields)}
        self._buf = buf
        self._at = offset
        self._body = struct.Struct(f"<{len(self.fields)}q")
        self._seq = 0
        self.size = 8 + self._body.size

    def write(self, values: Sequence[int]) -> None:
        """Publish all fields (the writer's side; one writer only)."""
        buf, at = self._buf, self._at
        seq = self._seq + 1
        _U64.pack_into(buf, at, seq)
        self._body.pack_into(buf, at + 8, *values)
        self._seq = seq + 1
        _U64.pack_into(buf, at, seq + 1)

    def read(self, tries: int = 1000) -> tuple[int, ...] | None:
        """A consistent copy of the fields, or None when every try met a write."""
        buf, at = self._buf, self._at
        unpack_seq = _U64.unpack_from
        body = self._body
        for _ in range(tries):
            before = unpack_seq(buf, at)[0]
            if before & 1:
                continue
            values: tuple[int, ...] = body.unpack_from(buf, at + 8)
            if unpack_seq(buf, at)[0] == before:
                return values
        return None

    def as_dict(self) -> dict[str, int]:
        values = self.read()
        return {} if values is None else dict(zip(self.fields, values, strict=True))


@dataclass(frozen=True)
class AreaLayout:
    """Sizes that fix where everything lies in the shared file (picklable)."""

    status_fields: tuple[str, ...]
    #: (name, image size) per group, in order.
    groups: tuple[tuple[str, int], ...]
    capacity: int
    slaves: int
    events: int = 256

    def offsets(self) -> dict[str, int]:
        at = _HEADER.size
        out = {"status": at}
        at = _align(at + 8 + 8 * len(self.status_fields))
        out["tick"] = at
        out["begun"] = at + 8
        at += 16
        for name, size in self.groups:
            out[f"seq:{name}"] = at
            at += ImageSeq.SIZE
            out[f"image:{name}"] = at
            at = _align(at + size)
            out[f"safe:{name}"] = at
            at = _align(at + size)
        for ring in ("periods", "latency", "rtt"):
            out[ring] = at
            at += 8 * self.capacity
        out["events"] = at
        at += 8 + _EVENT_SLOT * self.events
        out["health"] = at
        at = _align(at + 8 + _HEALTH_DTYPE.itemsize * max(1, self.slaves))
        out["layout"] = at
        out["end"] = at + len(self.to_json())
        return out

    @property
    def size(self) -> int:
        return self.offsets()["end"]

    def to_json(self) -> bytes:
        return json.dumps({"status_fields": list(self.status_fields),
                           "groups": [list(g) for g in self.groups], "capacity": self.capacity,
                           "slaves": self.slaves, "events": self.events}).encode()

    @classmethod
    def from_json(cls, data: bytes) -> AreaLayout:
        d = json.loads(data)
        return cls(tuple(d["status_fields"]), tuple((str(n), int(z)) for n, z in d["groups"]),
                   int(d["capacity"]), int(d["slaves"]), int(d["events"]))


class ImageSeq:
    """The two sequence numbers of one group's image (inputs by the engine, outputs by the
    user), and the exchange the inputs came with: the group's exchange count and whether
    its working counters were whole, written by the engine with the inputs (under the
    input number, so that a reader gets them from the same cycle as the bytes)."""

    #: Bytes per group: input and output sequence numbers, exchanges, working counter ok.
    SIZE = 32

    def __init__(self, buf: memoryview, offset: int) -> None:
        self._buf = buf
        self._in = offset
        self._out = offset + 8
        self._exchange = offset + 16

    def input_seq(self) -> int:
        return int(_U64.unpack_from(self._buf, self._in)[0])

    def output_seq(self) -> int:
        return int(_U64.unpack_from(self._buf, self._out)[0])

    def set_input_seq(self, value: int) -> None:
        _U64.pack_into(self._buf, self._in, value)

    def set_output_seq(self, value: int) -> None:
        _U64.pack_into(self._buf, self._out, value)

    def set_exchange(self, exchanges: int, wkc_ok: bool) -> None:
        """The engine's side, between the two input-number writes of a publish."""
        _EXCHANGE.pack_into(self._buf, self._exchange, exchanges, int(wkc_ok))

    def exchange(self, tries: int = 1000) -> tuple[int, bool] | None:
        """(exchanges, working counters whole) of the inputs now in the image, or None when
        every try met a publish (the engine stopped in the middle of one)."""
        buf, at = self._buf, self._in
        for _ in range(tries):
            before = _U64.unpack_from(buf, at)[0]
            if before & 1:
                continue
            exchanges, ok = _EXCHANGE.unpack_from(buf, self._exchange)
            if _U64.unpack_from(buf, at)[0] == before:
                return int(exchanges), bool(ok)
        return None


class SharedArea:
    """The mapped file (see the module text); :meth:`create` by the user, :meth:`attach` elsewhere."""

    def __init__(self, path: str, fd: int, layout: AreaLayout, owner: bool) -> None:
        self.path = path
        self.layout = layout
        self.owner = owner
        self._map = mmap.mmap(fd, layout.size)
        os.close(fd)
        self.buf = memoryview(self._map)
        self.offsets = layout.offsets()
        self.status = SeqBlock(self.buf, self.offsets["status"], layout.status_fields)
        self._tick_at = self.offsets["tick"]
        self._begun_at = self.offsets["begun"]
        self.images: dict[str, memoryview] = {}
        self.safe: dict[str, memoryview] = {}
        self.seqs: dict[str, ImageSeq] = {}
        for name, size in layout.groups:
            at = self.offsets[f"image:{name}"]
            self.images[name] = self.buf[at:at + size]
            at = self.offsets[f"safe:{name}"]
            self.safe[name] = self.buf[at:at + size]
            self.seqs[name] = ImageSeq(self.buf, self.offsets[f"seq:{name}"])
        self.rings = {ring: np.frombuffer(self._map, np.int64, layout.capacity, self.offsets[ring])
                      for ring in ("periods", "latency", "rtt")}
        at = self.offsets["health"]
        self._health_seq = 0
        self.health: npt.NDArray[np.void] = np.frombuffer(
            self._map, _HEALTH_DTYPE, max(1, layout.slaves), at + 8)
        self._event_serial = 0

    @classmethod
    def create(cls, layout: AreaLayout, path: str | None = None) -> SharedArea:
        """Make the file (0600, fresh), map it, write the header."""
        where = path or engine_area_path()
        try:
            fd = os.open(where, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        except OSError as exc:
            raise ConfigError(f"cannot create the engine's shared memory {where}: "
                              f"{exc.strerror or exc}") from None
        try:
            os.ftruncate(fd, layout.size)
        except OSError as exc:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(where)
            raise ConfigError(f"cannot size the engine's shared memory {where}: "
                              f"{exc.strerror or exc}") from None
        area = cls(where, fd, layout, owner=True)
        text = layout.to_json()
        at = area.offsets["layout"]
        area.buf[at:at + len(text)] = text
        _HEADER.pack_into(area.buf, 0, _MAGIC, layout.size, _VERSION, os.getpid(), at, len(text))
        return area

    @classmethod
    def attach(cls, path: str, layout: AreaLayout | None = None) -> SharedArea:
        """Map an existing file: the engine (which knows the layout), or any reader (a
        dashboard, a test), which finds the layout in the file."""
        try:
            fd = os.open(path, os.O_RDWR)
        except OSError as exc:
            raise ConfigError(f"cannot open the engine's shared memory {path}: "
                              f"{exc.strerror or exc}") from None
        if layout is None:
            try:
                head = os.pread(fd, _HEADER.size, 0)
                magic, _size, version, _pid, at, n = _HEADER.unpack(head)
                if magic != _MAGIC:
                    raise ValueError("bad magic")
                if version != _VERSION:
                    raise ValueError(f"layout version {version}, this pyethercat reads "
                                     f"{_VERSION}: another pyethercat's engine")
                layout = AreaLayout.from_json(os.pread(fd, n, at))
            except (ValueError, KeyError, struct.error) as exc:
                os.close(fd)
                raise ConfigError(f"{path} is not a cyclic engine's shared memory ({exc})") from None
        area = cls(path, fd, layout, owner=False)
        magic, size = _HEADER.unpack_from(area.buf, 0)[:2]
        if magic != _MAGIC or size != layout.size:
            area.close()
            raise ConfigError(f"{path} is not an engine area of this layout")
        return area

    # -- the tick (one writer: the engine) ------------------------------------------------

    def write_tick(self, cycles: int) -> None:
        """The engine has done ``cycles`` cycles (one aligned 8-byte store: never torn)."""
        _U64.pack_into(self.buf, self._tick_at, cycles)

    def read_tick(self) -> int:
        """Cycles the engine has done, as of its last :meth:`write_tick`."""
        return int(_U64.unpack_from(self.buf, self._tick_at)[0])

    def write_begun(self, cycles: int) -> None:
        """The engine has begun ``cycles`` cycles (written before the cycle's frames go)."""
        _U64.pack_into(self.buf, self._begun_at, cycles)

    def under_way(self) -> bool:
        """Whether a cycle has begun that is not done (its frames may be passing the slaves)."""
        begun = _U64.unpack_from(self.buf, self._begun_at)[0]
        return bool(begun > _U64.unpack_from(self.buf, self._tick_at)[0])

    # -- events (one writer: the engine) --------------------------------------------------

    def post_event(self, t: float, text: str) -> None:
        """Append a log line to the ring (the engine's side)."""
        data = text.encode("utf-8", "replace")[:EVENT_TEXT]
        self._event_serial += 1
        serial = self._event_serial
        at = self.offsets["events"]
        slot = at + 8 + _EVENT_SLOT * ((serial - 1) % self.layout.events)
        # The slot's serial is written last: a reader takes a slot whose serial is
        # the one it expects.
        _U64.pack_into(self.buf, slot, 0)
        self.buf[slot + 24:slot + 24 + len(data)] = data
        _EVENT_HEAD.pack_into(self.buf, slot, serial, t, len(data))
        _U64.pack_into(self.buf, at, serial)

    def events_since(self, serial: int) -> tuple[int, list[tuple[float, str]]]:
        """Events after ``serial``: (last serial seen, [(unix time, text)])."""
        at = self.offsets["events"]
        last = int(_U64.unpack_from(self.buf, at)[0])
        first = max(serial + 1, last - self.layout.events + 1)
        out: list[tuple[float, str]] = []
        for k in range(first, last + 1):
            slot = at + 8 + _EVENT_SLOT * ((k - 1) % self.layout.events)
            got, t, n = _EVENT_HEAD.unpack_from(self.buf, slot)
            text = bytes(self.buf[slot + 24:slot + 24 + min(n, EVENT_TEXT)]).decode("utf-8", "replace")
            if _EVENT_HEAD.unpack_from(self.buf, slot)[0] == got == k:
                out.append((t, text))
        return last, out

    # -- health (one writer: the engine) ----------------------------------------------------

    def write_health(self, fill: Callable[[npt.NDArray[np.void]], None]) -> None:
        """Rewrite the health table with ``fill(table)`` under its seqlock."""
        buf, at = self.buf, self.offsets["health"]
        seq = self._health_seq + 1
        _U64.pack_into(buf, at, seq)
        fill(self.health)
        self._health_seq = seq + 1
        _U64.pack_into(buf, at, seq + 1)

    def read_health(self, tries: int = 1000) -> npt.NDArray[np.void] | None:
        """A consistent copy of the health table (None when every try met a write)."""
        buf, at = self.buf, self.offsets["health"]
        for _ in range(tries):
            before = _U64.unpack_from(buf, at)[0]
            if before & 1:
                continue
            copy = self.health.copy()
            if _U64.unpack_from(buf, at)[0] == before:
                return copy
        return None

    def close(self) -> None:
        """Unmap (the views made from the area must be gone); the owner removes the file."""
        self.rings.clear()
        self.images.clear()
        self.safe.clear()
        self.buf.release()
        with contextlib.suppress(BufferError):
            self._map.close()
        if self.owner:
            self.unlink()

    def unlink(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
