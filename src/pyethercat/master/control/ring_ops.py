"""Control operations of the ring service: ``diag`` (ports, sides, located faults, events).

Importing this module registers its handler (``server.HANDLER_MODULES``
lists it; the command line imports it for its own short-lived master).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pyethercat.master.control.handlers import MasterContext, handler
from pyethercat.master.control.protocol import ControlRequest, Reply, request

__all__ = ["Diagnose", "DiagnosisReply", "FaultItem", "GroupItem", "GroupList", "HotConnectGroups"]


@dataclass(frozen=True)
class FaultItem:
    """One located fault: its kind, where it is, and what the registers said."""

    kind: str
    where: str
    detail: str = ""


@dataclass(frozen=True)
class DiagnosisReply(Reply):
    """The report of one diagnosis (``lines``) and its faults; ``events`` the recent fault events."""

    state: str
    lines: list[str]
    faults: list[FaultItem] = field(default_factory=list)
    events: list[str] = field(default_factory=list)


@request("diagnose", DiagnosisReply)
@dataclass(frozen=True)
class Diagnose(ControlRequest):
    """Read every slave once and locate faults (``events``: also the last N fault events)."""

    events: int = 0


@handler(Diagnose)
def _diagnose(ctx: MasterContext, req: Diagnose) -> DiagnosisReply:
    ctx.slaves()  # a direct master scans first
    ring = ctx.master.ring
    result = ring.diagnose()
    events = list(ring.events)[-req.events:] if req.events > 0 else []
    return DiagnosisReply(result.state, result.format(),
                          [FaultItem(f.kind, f.where, f.detail) for f in result.faults],
                          [e.text for e in events])


@dataclass(frozen=True)
class GroupItem:
    """One hot connect group: its name, alias, slaves and presence."""

    name: str
    alias: int
    positions: list[int]
    present: bool
    text: str


@dataclass(frozen=True)
class GroupList(Reply):
    """The hot connect groups the master knows (none for a master opened for one command)."""

    groups: list[GroupItem] = field(default_factory=list)


@request("hot_connect_groups", GroupList)
@dataclass(frozen=True)
class HotConnectGroups(ControlRequest):
    """Each hot connect group and whether it is present now."""


@handler(HotConnectGroups)
def _groups(ctx: MasterContext, req: HotConnectGroups) -> GroupList:
    m = ctx.master
    runner = m.pd.runner
    absent = runner.absent if runner is not None else frozenset()
    return GroupList([GroupItem(g.name, g.alias, list(g.positions), g.present, g.text)
                      for g in m.hotswap.groups(absent)])
