"""Distributed-clock arithmetic shared by the master and the simulator (no I/O).

Everything here is a pure function of register values:

* port receive-time latches (0x0900-0x090C) and the active ports of every
  slave -> the tree the frame walked and each slave's propagation delay
  (0x0928) behind the reference clock, for lines and trees (forks on ports
  1-3, crosses), slaves without DC in between, and slaves fed backwards
  (entered on a port other than 0);
* system-time offsets (0x0920) for 32- and 64-bit clocks;
* the sign-magnitude system time difference (0x092C) and the bound a
  broadcast read of it gives;
* SYNC0/SYNC1 start times on a common cycle grid, the SYNC1 cycle register
  (a delay after SYNC0 or a multiple of the cycle) and AssignActivate.

The frame passes the ports of an ESC in the order 0 -> 3 -> 1 -> 2 -> 0
(ESC datasheet section I, "Frame processing order"; SOEM ``ec_dc.c``, IgH
``master/slave.c``): the processing unit sits behind port 0, and a frame
that enters on port n is forwarded, untouched, to the next open port of that
cycle. The latch of port p holds the local time at which the latching frame
arrived *at* port p from outside: the entry port when it came in, every other
open port when it came back from the branch behind it.

Delays follow the rule of the ETG specification quoted by KickCAT
(``lib/master/src/dc.cc``) and implemented by SOEM (``ecx_configdc``) and
IgH (``ec_slave_calc_port_delays``): the round trip through a branch is
measured by the slave in front of it, and a link's one-way delay is half of
what is left after subtracting the round trip measured inside the next
slave. Slaves without DC measure nothing; the links of such a stretch share
what their DC neighbours measured in equal parts (the only assumption that
needs no more data; SOEM and IgH assume the same for a single non-DC slave
and skip the harder cases).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field

from pyethercat.errors import ConfigError
from pyethercat.wire import registers as R
from pyethercat.wire.ring import PORT_CYCLE, next_port, port_sequence, prev_port, walk_ring

__all__ = [
    "DEFAULT_HOP_NS",
    "EPOCH_UNIX_OFFSET_NS",
    "PORT_CYCLE",
    "SYNC_START_MARGIN_NS",
    "TIME_DIFFERENCE_SIGN",
    "AssignActivate",
    "DcDelay",
    "DcPorts",
    "DcTopologyError",
    "Sync1Mode",
    "decode_time_difference",
    "difference_bound",
    "encode_time_difference",
    "entry_port",
    "next_port",
    "port_sequence",
    "prev_port",
    "propagation_delays",
    "sync1_cycle_register",
    "sync1_period",
    "sync_start_time",
    "system_time_offset",
    "time_diff32",
    "unix_to_ethercat_ns",
]

#: Nanoseconds from 1970-01-01 to 2000-01-01, the EtherCAT system-time epoch
#: (SOEM subtracts 946684800 s from the host clock; KickCAT ``protocol.cc``).
EPOCH_UNIX_OFFSET_NS = 946_684_800 * 1_000_000_000

#: One-way delay assumed for a link no DC slave measured (a stretch of slaves
#: without DC ahead of the first DC slave): about one ESC forwarding delay plus
#: a short cable. Only used where the latches say nothing.
DEFAULT_HOP_NS = 150

#: 0x092C bit 31. The sources disagree on its sense (Infineon's ESC register description
#: vs hpm_sdk and KickCAT's EmulatedESC); masters use the magnitude.
TIME_DIFFERENCE_SIGN = 0x8000_0000
_MAGNITUDE = 0x7FFF_FFFF

#: How far in the future the first SYNC pulse is placed: SOEM ``ec_dc.c``
#: (SyncDelay) and IgH ``fsm_slave_config.c`` (EC_DC_START_OFFSET) use 100 ms.
SYNC_START_MARGIN_NS = 100_000_000

_U32 = 1 << 32
_U64 = 1 << 64


class DcTopologyError(ConfigError):
    """The active ports and receive times do not describe the slaves found."""


def unix_to_ethercat_ns(unix_ns: int) -> int:
    """A host time in ns since 1970 as EtherCAT system time (ns since 2000)."""
    return unix_ns - EPOCH_UNIX_OFFSET_NS


def time_diff32(a: int, b: int) -> int:
    """``a - b`` for two 32-bit clock values, across a wrap (|result| < 2**31)."""
    d = (a - b) & (_U32 - 1)
    return d - _U32 if d >= 1 << 31 else d


# --- ports (the visiting order: pyethercat.wire.ring) --------------------------------


def entry_port(times: Sequence[int], active: frozenset[int] | set[int]) -> int:
    """The port a frame came in on: the active port with the earliest latch (wrap-safe)."""
    ports = sorted(active, key=PORT_CYCLE.index)
    if not ports:
        return 0
    base = times[ports[0]]
    return min(ports, key=lambda p: (time_diff32(times[p], base), PORT_CYCLE.index(p)))


# --- propagation delays -----------------------------------------------------------------


@dataclass(frozen=True)
class DcPorts:
    """What the master knows of one slave for the delay measurement.

    ``active`` are the ports with communication and an open loop (DL status
    0x0110); ``times`` the four receive-time latches 0x0900-0x090C as read
    after the latching write, or ``None`` for a slave without DC (0x0008
    bit 2 clear), which latches nothing.
    """

    active: frozenset[int]
    times: tuple[int, int, int, int] | None = None

    @property
    def dc(self) -> bool:
        return self.times is not None


@dataclass(frozen=True)
class DcDelay:
    """The result for one slave (by ring position).

    ``parent``/``parent_port``: where it hangs (``None`` for the first slave);
    ``entry_port``: the port the frame came in on (not 0: fed backwards);
    ``delay_ns``: when the frame passes its processing unit, after it passed
    the reference clock's (the value for 0x0928); ``None`` for slaves without
    DC and for slaves the frame passes before the reference.
    ``round_trip_ns``: the time the frame spends behind its entry port (the
    round trip through its own children), ``None`` without DC.
    """

    position: int
    parent: int | None
    parent_port: int | None
    entry_port: int
    delay_ns: int | None
    round_trip_ns: int | None
    #: Time the frame passes the processing unit, relative to the first slave's
    #: entry (ns, model estimate; also set for slaves without DC).
    arrival_ns: float = field(default=0.0, compare=False)
    #: The frame passes this slave's processing unit before the reference's.
    before_reference: bool = False


@dataclass
class _Node:
    pos: int
    info: DcPorts
    entry: int
    parent: int | None = None
    parent_port: int | None = None
    children: list[int] = field(default_factory=list)  # in visiting order
    child_ports: list[int] = field(default_factory=list)
    rtt: float | None = None        # round trip behind the entry port (measured or derived)
    hop: float | None = None        # one-way delay of the link from the parent
    arrival: float = 0.0            # frame at the entry port, ns after the first slave's entry
    epu: float = 0.0                # frame at the processing unit


def _build_tree(slaves: Sequence[DcPorts]) -> list[_Node]:
    """Depth-first walk in frame order: each open port after the entry leads to the next slave."""
    nodes = []
    for pos, s in enumerate(slaves):
        if s.times is not None:
            entry = entry_port(s.times, s.active)
        else:
            # Nothing to tell the entry port by: assume port 0, as IgH does.
            entry = 0 if 0 in s.active or not s.active else min(s.active, key=PORT_CYCLE.index)
        nodes.append(_Node(pos, s, entry))
    if not nodes:
        return nodes
    parents, nxt = walk_ring([n.entry for n in nodes], [n.info.active for n in nodes])
    for child, hang in enumerate(parents):
        if hang is not None:
            parent, port = hang
            nodes[child].parent, nodes[child].parent_port = parent, port
            nodes[parent].children.append(child)
            nodes[parent].child_ports.append(port)
    if nxt < len(nodes):
        raise DcTopologyError(
            f"the open ports explain {nxt} of {len(nodes)} slaves: slave {nxt} is behind no "
            "open port (DL status and slave count disagree)")
    return nodes


def _branch_rtt(node: _Node, port: int) -> float:
    """Round trip through the branch behind ``port`` as the DC slave ``node`` measured it."""
    times = node.info.times
    assert times is not None
    return float(time_diff32(times[port], times[prev_port(port, node.info.active)]))


def _own_rtt(node: _Node) -> float:
    times = node.info.times
    assert times is not None
    if len(node.info.active) < 2:
        return 0.0
    return float(time_diff32(times[prev_port(node.entry, node.info.active)], times[node.entry]))


def _region(nodes: list[_Node], top: int) -> tuple[list[int], list[int]]:
    """The stretch of non-DC slaves from ``top`` down, and the DC slaves that hang on it."""
    inside, border, todo = [], [], [top]
    while todo:
        i = todo.pop()
        if nodes[i].info.dc:
            border.append(i)
        else:
            inside.append(i)
            todo.extend(nodes[i].children)
    return inside, border


def _fill_rtts(nodes: list[_Node]) -> None:
    """Round trip behind every slave without DC, from the hops estimated below it.

    Children come after their parent in ring order, so one backward pass
    sees every child before its parent (no recursion: long lines are fine).
    """
    for n in reversed(nodes):
        if n.rtt is not None:
            continue
        total = 0.0
        for c in n.children:
            child = nodes[c]
            assert child.hop is not None and child.rtt is not None
            total += 2 * child.hop + child.rtt
        n.rtt = total


def _estimate_hops(nodes: list[_Node]) -> None:
    """One-way delay of every link: measured where a DC slave sits in front of it."""
    measured: list[float] = []
    for n in nodes:
        if n.info.dc:
            n.rtt = _own_rtt(n)
    # Links from a DC slave to a DC child: half of the branch round trip less the child's own.
    for n in nodes:
        if not n.info.dc:
            continue
        for c, port in zip(n.children, n.child_ports, strict=True):
            child = nodes[c]
            if child.info.dc:
                assert child.rtt is not None
                child.hop = max(0.0, (_branch_rtt(n, port) - child.rtt) / 2)
                measured.append(child.hop)
    default = sum(measured) / len(measured) if measured else float(DEFAULT_HOP_NS)
    if nodes and not nodes[0].info.dc:
        # A stretch without DC at the very start: nobody measured its links.
        inside, border = _region(nodes, 0)
        for i in inside + border:
            if i != 0:
                nodes[i].hop = default
    # Stretches without DC behind a DC slave: that slave measured the whole
    # stretch; its links share what is left after the round trips of the DC
    # slaves hanging on it.
    for n in nodes:
        if not n.info.dc:
            continue
        for c, port in zip(n.children, n.child_ports, strict=True):
            if nodes[c].info.dc:
                continue
            inside, border = _region(nodes, c)
            rest = _branch_rtt(n, port) - sum(nodes[b].rtt or 0.0 for b in border)
            hop = max(0.0, rest / (2 * (len(inside) + len(border))))
            for i in inside + border:
                nodes[i].hop = hop
    _fill_rtts(nodes)


def _arrivals(nodes: list[_Node]) -> None:
    """Entry and processing-unit times of every slave, walking the tree in frame order."""
    for n in nodes:  # positions are in frame order: parents come first
        t = n.arrival
        for c in n.children:
            child = nodes[c]
            assert child.hop is not None and child.rtt is not None
            child.arrival = t + child.hop
            t += 2 * child.hop + child.rtt
        times = n.info.times
        if times is not None and n.entry != 0 and 0 in n.info.active:
            # Fed backwards: the frame reaches the processing unit when it comes
            # back in on port 0, after the branches between the entry and port 0.
            n.epu = n.arrival + time_diff32(times[0], times[n.entry])
        elif n.entry != 0 and 0 not in n.info.active:
            n.epu = n.arrival + (n.rtt or 0.0)  # port 0 closed: looped back at the end
        else:
            n.epu = n.arrival


def propagation_delays(slaves: Sequence[DcPorts], reference: int | None = None) -> list[DcDelay]:
    """Tree, entry ports and the delay behind the reference clock of every slave.

    ``slaves`` are in ring order (as the scan numbered them); ``reference``
    is the position of the reference clock (default: the first DC slave).
    Raises :class:`DcTopologyError` if the ports cannot explain the slaves,
    and :class:`~pyethercat.errors.ConfigError` if ``reference`` is no DC slave.
    """
    nodes = _build_tree(slaves)
    if not nodes:
        return []
    if reference is None:
        reference = next((n.pos for n in nodes if n.info.dc), None)
    elif not (0 <= reference < len(nodes)) or not nodes[reference].info.dc:
        raise ConfigError(f"reference clock: slave {reference} has no distributed clock")
    _estimate_hops(nodes)
    _arrivals(nodes)
    ref_t = nodes[reference].epu if reference is not None else 0.0
    out = []
    for n in nodes:
        delay: int | None = None
        before = False
        if n.info.dc and reference is not None:
            d = n.epu - ref_t
            before = d < 0
            delay = None if before else int(round(d))
        out.append(DcDelay(n.pos, n.parent, n.parent_port, n.entry, delay,
                           int(round(n.rtt)) if n.info.dc and n.rtt is not None else None,
                           n.epu, before))
    return out


# --- offsets -----------------------------------------------------------------------------


def system_time_offset(master_time_ns: int, epu_time: int, delay_ns: int = 0,
                       bits: int = 64) -> int:
    """Value for 0x0920 so that the slave's system time equals the master's clock.

    ``master_time_ns`` is the master's time (ns since 2000) when the latching
    frame left, ``epu_time`` the slave's 0x0918 (its local time when that
    frame passed its processing unit), ``delay_ns`` its propagation delay:
    the frame passed it that much later, so its system time then was that
    much later too (SOEM and ethercrab leave the delay out and let the drift
    compensation remove it). Returned as the unsigned register value of
    ``bits`` (64, or 32 for a 32-bit clock: only the low double word exists).
    """
    mask = (_U64 if bits == 64 else _U32) - 1
    return (master_time_ns + delay_ns - epu_time) & mask


# --- system time difference 0x092C -----------------------------------------------------


def decode_time_difference(raw: int) -> int:
    """Magnitude in ns of a 0x092C value (bits 30:0); the sign bit is left out."""
    return raw & _MAGNITUDE


def encode_time_difference(diff_ns: int) -> int:
    """0x092C for a difference (local copy less delay, less received time).

    Bit 31 is set when the local copy is ahead or equal (KickCAT's emulator
    and hpm_sdk, citing the ESC datasheet II 2.15); the magnitude saturates.
    """
    mag = min(abs(int(diff_ns)), _MAGNITUDE)
    return mag | (TIME_DIFFERENCE_SIGN if diff_ns >= 0 else 0)


def difference_bound(or_of_raw: int) -> int:
    """Upper bound of every slave's |difference| from a BRD of 0x092C.

    A broadcast read ORs the slaves' values: the OR of the magnitudes is at
    least the largest one and less than twice it (IgH's sync monitor).
    """
    return or_of_raw & _MAGNITUDE


# --- SYNC0 / SYNC1 ------------------------------------------------------------------------


class Sync1Mode(enum.Enum):
    """How a SYNC1 time is meant: a delay after each SYNC0, or every n-th SYNC0 cycle."""

    DELAY = "delay"
    MULTIPLE = "multiple"


def sync1_cycle_register(cycle0_ns: int, *, delay_ns: int | None = None,
                         multiple: int | None = None, shift_ns: int = 0) -> int:
    """Value for 0x09A4.

    The ESC fires SYNC1 that long after a SYNC0 pulse and starts the next
    wait with the first SYNC0 pulse after it (SOEM ``ecx_dcsync01``, which
    derives its start grid from this). So a value below the SYNC0 cycle is a
    delay after every SYNC0; ``(n - 1) * cycle0 + shift`` fires SYNC1 on
    every n-th SYNC0 cycle, ``shift`` after it.
    """
    if (delay_ns is None) == (multiple is None):
        raise ConfigError("SYNC1: give either a delay after SYNC0 or a multiple of the cycle")
    if cycle0_ns <= 0:
        raise ConfigError("SYNC1 needs a SYNC0 cycle time")
    if delay_ns is not None:
        if not 0 <= delay_ns < cycle0_ns:
            raise ConfigError(f"SYNC1 delay {delay_ns} ns must lie within the SYNC0 cycle "
                              f"({cycle0_ns} ns); use a multiple for longer SYNC1 cycles")
        return delay_ns
    assert multiple is not None
    if multiple < 1 or not 0 <= shift_ns < cycle0_ns:
        raise ConfigError(f"SYNC1: multiple {multiple} must be >= 1 and its shift within a cycle")
    value = (multiple - 1) * cycle0_ns + shift_ns
    if value >= _U32:
        raise ConfigError(f"SYNC1 cycle {value} ns does not fit 0x09A4 (32 bits)")
    return value


def sync1_period(cycle0_ns: int, cycle1_register: int) -> int:
    """Time between SYNC1 pulses for a 0x09A4 value (see :func:`sync1_cycle_register`)."""
    if cycle0_ns <= 0:
        return 0
    return (cycle1_register // cycle0_ns + 1) * cycle0_ns


def sync_start_time(now_ns: int, cycle_ns: int, shift_ns: int = 0, *,
                    margin_ns: int = SYNC_START_MARGIN_NS) -> int:
    """The first SYNC0 time: on the system-time grid of ``cycle_ns``, ``margin_ns`` ahead.

    All slaves started with the same cycle get pulses on the same grid
    (multiples of the cycle since the epoch, plus ``shift_ns``), so they fire
    together and the master can phase-lock its own cycle to that grid.
    ``cycle_ns = 0`` (single shot) gives ``now + margin + shift``.
    """
    base = now_ns + margin_ns
    if cycle_ns <= 0:
        return base + shift_ns
    return (base // cycle_ns + 1) * cycle_ns + shift_ns


@dataclass(frozen=True)
class AssignActivate:
    """The 16-bit ESI/SII AssignActivate: 0x0980 in the low byte, 0x0981 in the high byte."""

    value: int

    def __post_init__(self) -> None:
        if not 0 <= self.value <= 0xFFFF:
            raise ConfigError(f"AssignActivate 0x{self.value:X} is not a 16-bit value")

    @classmethod
    def for_sync(cls, sync0: bool = True, sync1: bool = False) -> AssignActivate:
        """The usual values: 0x0300 (SYNC0), 0x0700 (SYNC0 + SYNC1), 0 (none)."""
        act = 0
        if sync0 or sync1:
            act = R.DcActivation.CYCLIC | (R.DcActivation.SYNC0 if sync0 else 0) | (
                R.DcActivation.SYNC1 if sync1 else 0)
        return cls(int(act) << 8)

    @property
    def cyclic_unit_control(self) -> R.DcCyclicUnitControl:
        """0x0980: which units the PDI controls."""
        return R.DcCyclicUnitControl(self.value & 0x31)

    @property
    def activation(self) -> R.DcActivation:
        """0x0981."""
        return R.DcActivation(self.value >> 8)

    @property
    def sync0(self) -> bool:
        return bool(self.activation & R.DcActivation.CYCLIC and self.activation & R.DcActivation.SYNC0)

    @property
    def sync1(self) -> bool:
        return bool(self.activation & R.DcActivation.CYCLIC and self.activation & R.DcActivation.SYNC1)

    @property
    def active(self) -> bool:
        """The cyclic unit is to be enabled at all."""
        return bool(self.activation & R.DcActivation.CYCLIC)

    def describe(self) -> str:
        """``SYNC0+SYNC1 (0x0700)``, ``off (0x0000)``."""
        parts = [n for n, on in (("SYNC0", self.sync0), ("SYNC1", self.sync1)) if on]
        if self.cyclic_unit_control & R.DcCyclicUnitControl.SYNC_UNIT_PDI:
            parts.append("PDI")
        return f"{'+'.join(parts) or 'off'} (0x{self.value:04X})"
