"""What an isolated cyclic engine is told at start: a picklable plan, sockets by descriptor.

:class:`EnginePlan` holds everything the engine's process needs to run the
exchange the user's master prepared: the process-data configuration (frames
are planned from it in the engine, as the in-process loop plans them), the
slaves to supervise, the distributed-clock plan (``master.dc_loop``
objects are plain data), timing and real-time settings, and where the
shared memory is. The link travels inside the plan as the object it is
(:func:`dumps` replaces every socket in it by its descriptor, which the
child inherits, and :func:`loads` puts a socket back), so the engine sends
and receives on the very socket the master scanned with.
"""

from __future__ import annotations

import io
import pickle
import socket
from dataclasses import dataclass, field
from typing import Any

from pyethercat.link.base import Link
from pyethercat.master.config import ProcessDataConfig
from pyethercat.master.dc_loop import DcCycle
from pyethercat.master.engine.shared import AreaLayout
from pyethercat.wire.al import AlState

__all__ = ["EnginePlan", "dumps", "loads"]


@dataclass
class EnginePlan:
    """Everything the engine's process starts from (see the module text)."""

    link: Link
    config: ProcessDataConfig
    groups: list[str] | None
    cycle: float
    #: (position, station address) of every slave the loop supervises.
    slaves: list[tuple[int, int]]
    area_path: str
    layout: AreaLayout
    #: Names of the status block's fields that hold the loop's statistics.
    stats_fields: tuple[str, ...]
    #: Descriptor of the control channel and of the user's datagram link (the child's).
    control_fd: int
    frames_fd: int
    #: The user's process: the engine takes the slaves to a safe state when it goes.
    parent_pid: int
    target: AlState = AlState.OP
    check_interval: float = 0.1
    late_fraction: float = 0.25
    frame_timeout: float | None = None
    link_timeout: float | None = None
    state_timeout: float | None = None
    dc: DcCycle | None = None
    supervising: bool = False
    recover: bool = True
    safe_cycles: int = 3
    #: Scheduler settings of the user's master.
    timeout: float = 0.05
    retries: int = 3
    max_in_flight: int = 8
    src: bytes = b""
    #: Real-time wishes: SCHED_FIFO priority (0: none), CPU, mlockall.
    priority: int = 0
    cpu: int | None = None
    lock_memory: bool = False
    #: Busy-wait slice before each deadline, ns (the rest of the wait sleeps).
    spin_ns: int = 100_000
    extra: dict[str, Any] = field(default_factory=dict)


class _Pickler(pickle.Pickler):
    def __init__(self, out: io.BytesIO) -> None:
        super().__init__(out, protocol=pickle.HIGHEST_PROTOCOL)
        self.fds: list[int] = []

    def persistent_id(self, obj: Any) -> Any:  # noqa: ANN401 - pickle's signature
        if isinstance(obj, socket.socket):
            fd = obj.fileno()
            self.fds.append(fd)
            return ("socket", fd, int(obj.family), int(obj.type), obj.proto)
        return None


class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid: Any) -> Any:  # noqa: ANN401 - pickle's signature
        kind, fd, family, kind_of_socket, proto = pid
        if kind != "socket":
            raise pickle.UnpicklingError(f"unknown persistent id {kind!r}")
        return socket.socket(family, kind_of_socket, proto, fileno=fd)


def dumps(plan: EnginePlan) -> tuple[bytes, list[int]]:
    """The plan's bytes and the descriptors the child must inherit (same numbers)."""
    out = io.BytesIO()
    p = _Pickler(out)
    p.dump(plan)
    return out.getvalue(), p.fds


def loads(data: bytes) -> EnginePlan:
    """The plan, with its sockets rebuilt on the inherited descriptors."""
    plan = _Unpickler(io.BytesIO(data)).load()
    if not isinstance(plan, EnginePlan):
        raise pickle.UnpicklingError("not an engine plan")
    return plan
