"""The plan of the cyclic loop: each group's runtime state and the prepared frames.

A group's datagrams are packed into as few frames as fit (a group larger than
a frame gets one frame per datagram); each frame is a scheduler template
encoded once. Per frame the plan knows where every group's bytes go
(``fills``), which working counters to check (``checks``) and where the
input bytes come back from (``copies``), so a cycle does no per-slave work.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from pyethercat.errors import ConfigError
from pyethercat.master.config import CyclicDatagram, GroupConfig, ProcessDataConfig
from pyethercat.master.image import ProcessImage
from pyethercat.master.scheduler import CyclicTemplate, Scheduler
from pyethercat.wire.datagram import MAX_PAYLOAD, OVERHEAD, Datagram

__all__ = ["GroupRuntime", "FramePlan", "Planned", "group_runtimes", "plan_frames"]


class GroupRuntime:
    """A group's image plus its precomputed datagram plan and counters."""

    def __init__(self, config: GroupConfig, image: ProcessImage, every: int = 1) -> None:
        self.config = config
        self.image = image
        self.name = config.name
        #: The group is sent every ``every`` loop ticks.
        self.every = every
        self.plan: list[CyclicDatagram] = list(config.datagrams)
        self.expected_wkc = config.expected_wkc
        #: Working counters of the last exchange, per datagram.
        self.last_wkc: list[int] = [0] * len(self.plan)
        self.wkc_ok = False
        #: The last exchange was complete for every slave not known to be gone.
        self.present_ok = False
        self.wkc_errors = 0
        self.incomplete = 0
        self.lost = 0
        self.exchanges = 0

    @property
    def total_wkc(self) -> int:
        return sum(self.last_wkc)

    @property
    def input_age(self) -> int:
        """Exchanges since the inputs were last refreshed (0: by the last one)."""
        return self.image.input_age


class FramePlan:
    """One prepared frame of a cycle: where each group's bytes go and come back from.

    ``fills``: (source view of a group buffer, frame offset) for the bytes sent;
    ``checks`` (also ``takes``): per datagram (group, datagram number, WKC offset,
    expected WKC, the share of absent slaves that may be missing from it);
    ``copies``: per datagram with inputs (group, group buffer, buffer start,
    buffer end, reply offset of the input bytes).
    """

    __slots__ = ("template", "fills", "checks", "copies", "groups", "dc_fill", "dc_read")

    def __init__(self, template: CyclicTemplate, fills: list[tuple[memoryview, int]],
                 checks: list[tuple[GroupRuntime, int, int, int, int]],
                 copies: list[tuple[GroupRuntime, bytearray | memoryview, int, int, int]],
                 groups: list[GroupRuntime]) -> None:
        self.template = template
        self.fills = fills
        self.checks = checks
        self.copies = copies
        self.groups = groups
        #: Frame offsets of the DC datagrams' data (master time written, FRMW read); -1: none.
        self.dc_fill = -1
        self.dc_read = -1

    @property
    def takes(self) -> list[tuple[GroupRuntime, int, int, int, int]]:
        """The checks by the name the ring watch reads them (group, datagram, WKC offset)."""
        return self.checks


Planned = tuple[list[FramePlan], tuple[str, ...], tuple[GroupRuntime, ...]]


def group_runtimes(config: ProcessDataConfig, images: dict[str, ProcessImage],
                   names: Sequence[str] | None, cycle: float
                   ) -> tuple[float, list[GroupRuntime]]:
    """The loop tick (the shortest group cycle) and the runtime of each named group.

    Several groups may run at different cycle times (ETG.1000.6 "cyclic
    mode"): the loop ticks at the shortest period and sends a group every
    ``period / tick`` ticks; a cycle that is no multiple of the tick is refused.
    """
    chosen = list(names) if names is not None else [g.name for g in config.groups]
    tick = min([cycle] + [config.group(n).cycle or cycle for n in chosen])
    out: list[GroupRuntime] = []
    for n in chosen:
        g = config.group(n)
        g_cycle = g.cycle or cycle
        every = max(1, int(round(g_cycle / tick)))
        if abs(every * tick - g_cycle) > 1e-9 + 1e-6 * g_cycle:
            raise ConfigError(f"group {n!r}: cycle {g_cycle} s is not a multiple of the "
                              f"loop tick {tick} s")
        out.append(GroupRuntime(g, images[n], every))
    return tick, out


def plan_frames(scheduler: Scheduler, due: list[GroupRuntime], safe: bool = False,
                dc_dgs: Sequence[Datagram] = (),
                absent_share: Callable[[CyclicDatagram], int] | None = None) -> Planned:
    """Pack the due groups' datagrams into prepared frames (once per set of groups).

    With ``safe`` the frames send each group's :attr:`ProcessImage.safe`
    instead of its outputs (an orderly stop). ``dc_dgs`` (distributed
    clocks: the master time write and the FRMW) lead the first frame.
    ``absent_share(datagram)`` is how much of its working counter slaves known
    to be gone would add (0 by default).
    """
    frames: list[list[tuple[GroupRuntime, int]]] = []
    cur: list[tuple[GroupRuntime, int]] = []
    used = 0
    for g in due:
        items = [(g, n) for n in range(len(g.plan))]
        size = sum(d.length + OVERHEAD for d in g.plan)
        if cur and used + size > MAX_PAYLOAD:
            frames.append(cur)
            cur, used = [], 0
        if size > MAX_PAYLOAD:
            # A split group: one frame per datagram (each fits by construction).
            frames += [[item] for item in items]
            continue
        cur += items
        used += size
    if cur:
        frames.append(cur)
    # The DC datagrams lead the first frame (they belong to no group); a frame of
    # their own when the first one is full.
    if dc_dgs and (not frames or sum(d.size for d in dc_dgs) + sum(
            g.plan[n].length + OVERHEAD for g, n in frames[0]) > MAX_PAYLOAD):
        frames.insert(0, [])
    plans: list[FramePlan] = []
    for fi, items in enumerate(frames):
        lead = list(dc_dgs) if fi == 0 else []
        dgs = list(lead)
        for g, n in items:
            d = g.plan[n]
            dgs.append(Datagram(d.command, 0, d.logical_address, bytes(d.length)))
        template = scheduler.prepare_cyclic(dgs)
        if any(g.config.cross for g, _ in items):
            template.ordered = True  # cross traffic: the slaves in bus order (a ring)
        fills: list[tuple[memoryview, int]] = []
        checks: list[tuple[GroupRuntime, int, int, int, int]] = []
        copies: list[tuple[GroupRuntime, bytearray | memoryview, int, int, int]] = []
        groups: list[GroupRuntime] = []
        for i, (g, n) in enumerate(items, start=len(lead)):
            d = g.plan[n]
            at = template.data_offsets[i]
            source = g.image.safe if safe else g.image.buffer
            fills.append((memoryview(source)[d.offset:d.offset + d.length], at))
            share = absent_share(d) if absent_share is not None else 0
            checks.append((g, n, template.wkc_offsets[i], d.expected_wkc, share))
            if d.copy_end > d.copy_start:
                copies.append((g, g.image.buffer, d.copy_start, d.copy_end,
                               at + d.copy_start - d.offset))
            if g not in groups:
                groups.append(g)
        plan = FramePlan(template, fills, checks, copies, groups)
        if lead:
            plan.dc_read = template.data_offsets[len(lead) - 1]
            plan.dc_fill = template.data_offsets[0] if len(lead) > 1 else -1
        plans.append(plan)
    return plans, tuple(g.name for g in due), tuple(due)
