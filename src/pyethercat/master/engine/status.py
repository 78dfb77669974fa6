"""The fields of the engine's status block: loop statistics, groups, the engine itself.

Both sides derive the field names from the same objects: the counters of a
fresh :class:`~pyethercat.master.cyclic.CycleStats` (every public integer,
the histogram bins, the ring positions), each group's counters and the
engine's own (state, CPU time, priority...). The user's process builds the
list once and hands it to the engine in the plan, so a counter added to
``CycleStats`` later travels without a change here. Values are 64-bit
integers; ``None`` is stored as :data:`NONE`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pyethercat.master.cyclic import CycleStats

__all__ = [
    "ENGINE_FIELDS",
    "GROUP_FIELDS",
    "NONE",
    "STATE_NAMES",
    "EngineState",
    "group_fields",
    "read_group",
    "stats_fields",
    "stats_values",
    "load_stats",
]

#: How ``None`` is stored (an int64 no counter reaches).
NONE = -(1 << 63)

# Private counters a CycleStats needs to read its rings (how many samples are in them).
_RING_COUNTERS = ("_n_period", "_n_rtt")
_SKIP = frozenset({"period_ns", "capacity"})


class EngineState:
    """The engine's life, as published in the ``state`` field."""

    STARTING = 0
    RUNNING = 1
    STOPPING = 2
    STOPPED = 3
    FAILED = 4


STATE_NAMES = {EngineState.STARTING: "starting", EngineState.RUNNING: "running",
               EngineState.STOPPING: "stopping", EngineState.STOPPED: "stopped",
               EngineState.FAILED: "failed"}

#: The engine's own fields (``cpu_ns``: CPU time of its process; ``priority`` and
#: ``cpu``: what it got, 0 / -1 when it got none; ``heartbeat_ns``: clock of the last
#: cycle; ``user_*``: requests of the user's process it carried).
ENGINE_FIELDS = ("state", "pid", "heartbeat_ns", "cpu_ns", "wall_ns", "priority", "cpu",
                 "locked", "supervising", "safe", "events", "user_frames", "user_datagrams",
                 "user_dropped", "dc_phase_ns", "dc_locked", "dc_last_ns", "dc_worst_ns",
                 "dc_unstable", "dc_difference_ns")
#: Counters of a group (``g<i>.`` prefix), besides its working counters per datagram.
GROUP_FIELDS = ("exchanges", "wkc_ok", "wkc_errors", "lost", "incomplete", "present_ok",
                "input_age", "inputs_valid")


def stats_fields(stats: CycleStats) -> tuple[str, ...]:
    """The counters of ``stats`` to publish: public integers, ring positions, histogram bins."""
    names = [k for k, v in vars(stats).items()
             if not k.startswith("_") and k not in _SKIP
             and (isinstance(v, int) or v is None)]
    names += [k for k in _RING_COUNTERS if hasattr(stats, k)]
    names += [f"histogram.{i}" for i in range(len(stats.histogram))]
    return tuple(names)


def stats_values(stats: CycleStats, fields: Sequence[str], hist_at: int) -> list[int]:
    """The values of ``fields`` (as :func:`stats_fields` named them) in ``stats`` now."""
    d = vars(stats)
    out = [NONE if (v := d[k]) is None else int(v) for k in fields[:hist_at]]
    out += stats.histogram
    return out


def load_stats(stats: CycleStats, fields: Sequence[str], values: Sequence[int]) -> None:
    """Set ``stats``'s counters from published values (the reader's side)."""
    hist: list[int] = []
    for name, v in zip(fields, values, strict=True):
        if name.startswith("histogram."):
            hist.append(int(v))
            continue
        old = getattr(stats, name, None)
        if v == NONE:
            setattr(stats, name, None)
        elif isinstance(old, bool):
            setattr(stats, name, bool(v))
        else:
            setattr(stats, name, int(v))
    stats.histogram = hist


def group_fields(index: int, datagrams: int) -> tuple[str, ...]:
    """Field names of group ``index`` with ``datagrams`` cyclic datagrams."""
    return tuple(f"g{index}.{f}" for f in GROUP_FIELDS) + tuple(
        f"g{index}.wkc.{n}" for n in range(datagrams))


def group_values(group: Any, image: Any) -> list[int]:  # noqa: ANN401 - runtime objects
    """The published values of one group (:func:`group_fields` order)."""
    return [group.exchanges, int(group.wkc_ok), group.wkc_errors, group.lost,
            getattr(group, "incomplete", 0), int(getattr(group, "present_ok", group.wkc_ok)),
            getattr(image, "input_age", 0), int(getattr(image, "inputs_valid", True)),
            *group.last_wkc]


def read_group(values: dict[str, int], index: int, datagrams: int) -> dict[str, Any]:
    """One group's counters out of a status snapshot."""
    out: dict[str, Any] = {f: values[f"g{index}.{f}"] for f in GROUP_FIELDS}
    out["last_wkc"] = [values[f"g{index}.wkc.{n}"] for n in range(datagrams)]
    return out
