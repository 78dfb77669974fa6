"""What the user's process reads of its isolated engine: statistics, groups, health, events.

:class:`EngineReadout` is the reading half of
:class:`~pyethercat.master.engine.runner.IsolatedRunner`: ``stats``,
``groups``, ``health`` and ``events`` are the engine's, loaded from the
shared status block when asked for (any rate; reading never slows the
engine), so everything that reads a ``CyclicRunner`` (the live view, the
control socket, the mailboxes) reads the engine's figures.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from pyethercat.errors import EngineDiedError
from pyethercat.master.cyclic import CycleStats, SlaveHealth
from pyethercat.master.engine.shared import HEALTH_STATUS, SharedArea
from pyethercat.master.engine.status import NONE, STATE_NAMES, load_stats, read_group
from pyethercat.master.ring import FaultBoard
from pyethercat.master.supervision import Supervisor

__all__ = ["EngineReadout", "Lifeline"]


class Lifeline:
    """Whether the engine is alive; ``why`` says how it died (None while it lives)."""

    def __init__(self) -> None:
        self.why: str | None = None

    def check(self) -> None:
        if self.why is not None:
            raise EngineDiedError(self.why)


class EngineReadout:
    """The engine's figures as a ``CyclicRunner`` shows its own (see the module text)."""

    area: SharedArea | None = None
    life: Lifeline
    slaves: list[object]
    supervisor: Supervisor
    _groups: list[Any]
    _events: deque[Any]
    fault_board: FaultBoard
    _stats_view: CycleStats
    _stats_names: tuple[str, ...]
    _event_serial: int

    # -- what readers see --------------------------------------------------------------------

    def status(self) -> dict[str, int]:
        """The engine's status block now (every field by name; empty before it started)."""
        area = self.area
        return {} if area is None else area.status.as_dict()

    @property
    def engine_state(self) -> str:
        """starting, running, stopping, stopped, failed (or "dead")."""
        if self.life.why is not None:
            return "dead"
        st = self.status()
        return STATE_NAMES.get(st.get("state", 0), "?")

    def refresh(self) -> dict[str, int]:
        """Load the engine's counters into ``stats`` and ``groups``; the status block."""
        st = self.status()
        if not st:
            return st
        load_stats(self._stats_view, self._stats_names, [st[k] for k in self._stats_names])
        for i, g in enumerate(self._groups_list()):
            c = read_group(st, i, len(g.plan))
            g.exchanges, g.wkc_ok, g.wkc_errors, g.lost = (c["exchanges"], bool(c["wkc_ok"]),
                                                          c["wkc_errors"], c["lost"])
            g.last_wkc = c["last_wkc"]
            if hasattr(g, "incomplete"):
                g.incomplete = c["incomplete"]
            if hasattr(g, "present_ok"):
                g.present_ok = bool(c["present_ok"])
        return st

    def dc_status(self) -> dict[str, Any] | None:
        """The engine's phase lock and sync monitor as it published them last (None before
        it started): ``phase_error_ns``, ``locked``, ``last_ns``, ``worst_ns``, ``unstable``
        (the ``dc`` plan of this process is the copy the engine started from)."""
        st = self.status()
        if not st:
            return None

        def value(name: str) -> int | None:
            v = st[name]
            return None if v == NONE else int(v)

        return {"phase_error_ns": value("dc_phase_ns"), "locked": bool(st["dc_locked"]),
                "last_ns": value("dc_last_ns"), "worst_ns": int(st["dc_worst_ns"]),
                "unstable": bool(st["dc_unstable"])}

    def _groups_list(self) -> list[Any]:
        return list(self._groups)

    # stats, groups, health and events are the engine's, read when asked for (any rate);
    # the base class's __init__ assigns them through the setters.

    @property
    def stats(self) -> CycleStats:
        if self.__dict__.get("area") is not None:
            self.refresh()
        return self._stats_view

    @stats.setter
    def stats(self, value: CycleStats) -> None:
        self.__dict__["_stats_view"] = value

    @property
    def groups(self) -> list[Any]:
        if self.__dict__.get("area") is not None:
            self.refresh()
        return self._groups

    @groups.setter
    def groups(self, value: list[Any]) -> None:
        self.__dict__["_groups"] = value

    @property
    def health(self) -> dict[int, SlaveHealth]:
        if self.__dict__.get("area") is not None:
            return self.health_table
        return self.supervisor.health

    @property
    def events(self) -> deque[Any]:
        if self.__dict__.get("area") is not None:
            self.poll_events()
        return self._events

    @events.setter
    def events(self, value: deque[Any]) -> None:
        self.__dict__["_events"] = value

    @property
    def health_table(self) -> dict[int, SlaveHealth]:
        """Supervision state per slave as the engine published it last."""
        area = self.area
        if area is None:
            return {}
        table = area.read_health()
        out: dict[int, SlaveHealth] = {}
        if table is None:
            return out
        for row in table[:len(self.slaves)].tolist():
            pos, station, state, error, code, present, status, recoveries, _now = row
            out[int(pos)] = SlaveHealth(int(pos), int(station), int(state), bool(error), int(code),
                                        bool(present), HEALTH_STATUS[int(status)],
                                        int(recoveries))
        return out

    def slave_state(self, position: int) -> int | None:
        """AL status (state, error flag) the engine's supervision confirmed lately; None
        when unknown (see :meth:`CyclicRunner.slave_state`), and when the engine is not
        running or has not published for longer than the state timeout (stopped, dead).

        The supervision of this process sees no frame while the engine cycles: the
        engine's health table carries its view (published after every change it logs
        and twice a second).
        """
        area = self.area
        if area is None or self.life.why is not None:
            return None
        st = self.status()
        if (STATE_NAMES.get(st.get("state", 0)) != "running"
                or time.perf_counter_ns() - st["heartbeat_ns"] > self.supervisor.state_timeout_ns):
            return None
        table = area.read_health()
        if table is None:
            return None
        rows = table[:len(self.slaves)]
        at = np.flatnonzero(rows["position"] == position)
        if not len(at):
            return None
        return int(rows["now"][at[0]]) or None

    def poll_events(self) -> None:
        """Take the engine's new log lines into ``events``."""
        area = self.area
        if area is None:
            return
        self._event_serial, got = area.events_since(self._event_serial)
        for t, text in got:
            self._events.append(_EventLine(t, text))
            self.fault_board.take(text)

    def engine_line(self) -> str:
        """The engine in one line: pid, state, priority, CPU, share of a CPU it uses."""
        st = self.status()
        if not st:
            return f"engine {self.engine_state}"
        cpu = st["cpu_ns"] / st["wall_ns"] * 100 if st["wall_ns"] else 0.0
        prio = f"SCHED_FIFO {st['priority']}" if st["priority"] else "normal priority"
        where = f"CPU {st['cpu']}" if st["cpu"] >= 0 else "any CPU"
        return (f"engine pid {st['pid']} {self.engine_state}: {prio}, {where}, "
                f"{'memory locked, ' if st['locked'] else ''}{cpu:.0f}% CPU; "
                f"carried {st['user_frames']} frames of requests")

    @staticmethod
    def _age_reader(area: SharedArea, index: int) -> Callable[[], tuple[int, bool]]:
        status = area.status
        at_age = status.index[f"g{index}.input_age"]
        at_valid = status.index[f"g{index}.inputs_valid"]
        last = [(0, False)]

        def age() -> tuple[int, bool]:
            values = status.read()
            if values is not None:
                last[0] = (values[at_age], bool(values[at_valid]))
            return last[0]

        return age


class _EventLine:
    __slots__ = ("t", "text")

    def __init__(self, t: float, text: str) -> None:
        self.t = t
        self.text = text
