"""DC arithmetic (wire.dc) against hand-computed values.

The expected delays below are worked out by hand from the formulas of the
ETG rule SOEM's ``ecx_configdc`` and IgH's ``ec_slave_calc_port_delays``
implement: the round trip through a branch, as measured by the slave in front
of it (its latch at the branch port minus its latch at the previous open port
in the order 0-3-1-2), less the round trip inside the next slave, halved.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import ConfigError
from pyethercat.wire import registers as R
from pyethercat.wire.dc import (
    DEFAULT_HOP_NS,
    AssignActivate,
    DcPorts,
    DcTopologyError,
    decode_time_difference,
    difference_bound,
    encode_time_difference,
    entry_port,
    next_port,
    port_sequence,
    prev_port,
    propagation_delays,
    sync1_cycle_register,
    sync1_period,
    sync_start_time,
    system_time_offset,
    time_diff32,
    unix_to_ethercat_ns,
)

HOFF = int.from_bytes(b"hoff", "little")  # an unlatched port of a Beckhoff ASIC


def ports(*p: int) -> frozenset[int]:
    return frozenset(p)


def delays(slaves: list[DcPorts], reference: int | None = None) -> list[int | None]:
    return [d.delay_ns for d in propagation_delays(slaves, reference)]


# --- ports ---------------------------------------------------------------------------------


def test_port_order_skips_closed_ports() -> None:
    assert next_port(0, {0, 1}) == 1
    assert next_port(0, {0, 3, 1}) == 3
    assert next_port(1, {0, 3, 1}) == 0
    assert prev_port(0, {0, 3, 1}) == 1
    assert prev_port(0, {0, 3, 1, 2}) == 2
    assert prev_port(1, {0, 1, 2}) == 0
    assert prev_port(0, {0}) == 0
    assert port_sequence(0, {0, 1, 2, 3}) == [3, 1, 2]
    assert port_sequence(1, {0, 1, 3}) == [0, 3]   # fed backwards on port 1


def test_entry_port_is_earliest_latch_across_a_32bit_wrap() -> None:
    # port 0 latched just before the clock wrapped, port 1 just after: port 0 came first
    times = (0xFFFF_FF00, 0x0000_0100, 0, 0)
    assert entry_port(times, {0, 1}) == 0
    assert time_diff32(times[1], times[0]) == 0x200
    # fed backwards: port 1 latched first
    assert entry_port((5000, 4000, 0, 0), {0, 1}) == 1


# --- lines --------------------------------------------------------------------------------


def test_corpus_line_ek1100_el2828_el2889() -> None:
    """The latches of the replay-dc capture: ethercrab wrote 145 and 300 ns."""
    slaves = [
        DcPorts(ports(0, 1), (0x3C620F52, 0x3C6211AA, 0, 0x6C726556)),  # EK1100: 600 ns behind port 1
        DcPorts(ports(0, 1), (0x3D0BD6AE, 0x3D0BD7E4, 0, 0)),           # EL2828: 310 ns
        DcPorts(ports(0), (0x3C8065EC, HOFF, 0, 0)),                    # EL2889: end of line
    ]
    # D1 = (600 - 310) / 2 = 145; D2 = 145 + (310 - 0) / 2 = 300
    assert delays(slaves) == [0, 145, 300]
    assert [d.round_trip_ns for d in propagation_delays(slaves)] == [600, 310, 0]


def test_line_of_four_with_wrapping_clocks() -> None:
    # round trips behind each slave: 900, 600, 280, 0 (last), clocks wrap at random places
    base = [0xFFFF_FE00, 0x1234_5678, 0xFFFF_FFF0, 7]
    rtt = [900, 600, 280, 0]
    slaves = [DcPorts(ports(0, 1) if r else ports(0), (b, (b + r) & 0xFFFF_FFFF, 0, 0))
              for b, r in zip(base, rtt, strict=True)]
    # D1 = 150, D2 = 150 + 160 = 310, D3 = 310 + 140 = 450
    assert delays(slaves) == [0, 150, 310, 450]


# --- trees --------------------------------------------------------------------------------


def test_fork_on_ports_3_and_1() -> None:
    """Coupler (ports 0, 3, 1): a line of two on port 3, one terminal on port 1.

    Coupler latches: port 0 = 0, port 3 = 700 (branch 3 back), port 1 = 1000.
    Branch-3 head: 0 / 300 (its own round trip through the second slave).
    Delays: branch-3 head (700 - 300)/2 = 200; its child 200 + 300/2 = 350;
    port-1 terminal: the whole branch 3 (700) + (1000 - 700 - 0)/2 = 850.
    """
    slaves = [
        DcPorts(ports(0, 3, 1), (10_000, 11_000, 0, 10_700)),
        DcPorts(ports(0, 1), (50, 350, 0, 0)),
        DcPorts(ports(0), (9, 0, 0, 0)),
        DcPorts(ports(0), (123, 0, 0, 0)),
    ]
    res = propagation_delays(slaves)
    assert [(d.parent, d.parent_port) for d in res] == [(None, None), (0, 3), (1, 1), (0, 1)]
    assert delays(slaves) == [0, 200, 350, 850]


def test_fork_on_port_2() -> None:
    """Ports 0, 1, 2: the port-1 branch comes back first (T1 = 400), then port 2 (T2 = 700).

    Port-1 child: 400/2 = 200; port-2 child: 400 + (700 - 400)/2 = 550.
    """
    slaves = [
        DcPorts(ports(0, 1, 2), (1000, 1400, 1700, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    res = propagation_delays(slaves)
    assert [d.parent_port for d in res] == [None, 1, 2]
    assert delays(slaves) == [0, 200, 550]


def test_cross_all_four_ports_with_branches() -> None:
    """A cross (ports 0, 3, 1, 2) whose port-1 branch is a line of two.

    Cross: T0 = 0, T3 = 300, T1 = 1100, T2 = 1400.
    Port-3 leaf: 300/2 = 150.
    Port-1 line head (own round trip 200): 300 + (800 - 200)/2 = 600; its child 600 + 100 = 700.
    Port-2 leaf: 1100 + 300/2 = 1250.
    """
    slaves = [
        DcPorts(ports(0, 3, 1, 2), (0, 1100, 1400, 300)),
        DcPorts(ports(0), (0, 0, 0, 0)),
        DcPorts(ports(0, 1), (40, 240, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    res = propagation_delays(slaves)
    assert [(d.parent, d.parent_port) for d in res] == [
        (None, None), (0, 3), (0, 1), (2, 1), (0, 2)]
    assert delays(slaves) == [0, 150, 600, 700, 1250]


# --- slaves without DC ----------------------------------------------------------------------


def test_non_dc_slave_between_two_dc_slaves() -> None:
    """DC A -> non-DC N -> DC B (end): A measures 800 through N and B, B nothing.

    Two links share the 800 ns: 200 each way; B's delay 400, as SOEM's
    (dt3 - dt1)/2 = 800/2 gives.
    """
    slaves = [
        DcPorts(ports(0, 1), (0, 800, 0, 0)),
        DcPorts(ports(0, 1)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    assert delays(slaves) == [0, None, 400]


def test_non_dc_fork_with_dc_children() -> None:
    """DC A -> non-DC fork N (ports 0, 3, 1) with a DC leaf on each branch.

    A measures 1200 for three links out and back: 200 per link.
    Leaf on N's port 3: 2 links = 400. Leaf on port 1: out to N (200), the
    port-3 branch there and back (400), the last link (200) = 800.
    """
    slaves = [
        DcPorts(ports(0, 1), (0, 1200, 0, 0)),
        DcPorts(ports(0, 3, 1)),
        DcPorts(ports(0), (0, 0, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    assert delays(slaves) == [0, None, 400, 800]


def test_non_dc_first_slave_uses_measured_hops_elsewhere() -> None:
    """Non-DC coupler first, DC terminals on its ports 3 and 1 (the second one a line of two).

    Nobody measures the coupler's links; the line on port 1 measures its own
    hop (300/2 = 150), which stands in for the unmeasured ones: the port-1
    head is out of the port-3 leaf (150 back), through the coupler (150), so
    2 * 150 = 300 behind the reference.
    """
    slaves = [
        DcPorts(ports(0, 3, 1)),
        DcPorts(ports(0), (0, 0, 0, 0)),          # reference (first DC slave)
        DcPorts(ports(0, 1), (0, 300, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    assert delays(slaves) == [None, 0, 300, 450]


def test_no_measured_hop_falls_back_to_default() -> None:
    slaves = [DcPorts(ports(0, 3, 1)), DcPorts(ports(0), (0, 0, 0, 0)), DcPorts(ports(0), (0, 0, 0, 0))]
    assert delays(slaves) == [None, 0, 2 * DEFAULT_HOP_NS]


# --- slaves fed backwards, reference choice ------------------------------------------------


def test_slave_fed_backwards_processes_after_its_branch() -> None:
    """A (ports 0, 1) -> B entered on port 1, with C behind B's port 0.

    B: T1 = 0 (entry), T0 = 400 (back from C): its processing unit sees the
    frame 400 ns after it arrived. A measures 1000: hop A-B = (1000 - 400)/2 = 300.
    C hangs on B's port 0: 300 + 400/2 = 500, before B (300 + 400 = 700).
    """
    slaves = [
        DcPorts(ports(0, 1), (0, 1000, 0, 0)),
        DcPorts(ports(0, 1), (400, 0, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    res = propagation_delays(slaves)
    assert [d.entry_port for d in res] == [0, 1, 0]
    assert [(d.parent, d.parent_port) for d in res] == [(None, None), (0, 1), (1, 0)]
    assert delays(slaves) == [0, 700, 500]


def test_named_reference_and_slaves_before_it() -> None:
    slaves = [
        DcPorts(ports(0, 1), (0, 1000, 0, 0)),
        DcPorts(ports(0, 1), (0, 600, 0, 0)),
        DcPorts(ports(0), (0, 0, 0, 0)),
    ]
    res = propagation_delays(slaves, reference=1)
    # slave 0 is passed before the reference: it cannot follow it in the same frame
    assert [d.delay_ns for d in res] == [None, 0, 300]
    assert [d.before_reference for d in res] == [True, False, False]
    with pytest.raises(ConfigError, match="no distributed clock"):
        propagation_delays([DcPorts(ports(0, 1)), DcPorts(ports(0), (0, 0, 0, 0))], reference=0)


def test_ports_that_do_not_explain_the_slaves() -> None:
    slaves = [DcPorts(ports(0), (0, 0, 0, 0)), DcPorts(ports(0), (0, 0, 0, 0))]
    with pytest.raises(DcTopologyError, match="explain 1 of 2"):
        propagation_delays(slaves)


# --- a physical model: latches from known link delays --------------------------------------


def _walk(tree: list[dict[str, object]], hops: list[int], clock0: list[int]
          ) -> tuple[list[DcPorts], list[int]]:
    """Latches of a tree whose links take ``hops[i]`` ns each way (the ESC itself: 0 ns)."""
    n = len(tree)
    times = [[0, 0, 0, 0] for _ in range(n)]
    epu = [0] * n

    def visit(i: int, t: int) -> int:
        node = tree[i]
        entry = int(node["entry"])  # type: ignore[call-overload]
        active: frozenset[int] = node["active"]  # type: ignore[assignment]
        times[i][entry] = t
        if entry == 0:
            epu[i] = t
        for p in port_sequence(entry, active):
            child = node["children"][p]  # type: ignore[index]
            back = visit(child, t + hops[child]) + hops[child]
            t = back
            times[i][p] = t
            if p == 0:
                epu[i] = t
        if 0 not in active:
            epu[i] = t  # port 0 closed: the frame loops back into the processing unit last
        return t

    visit(0, 0)
    slaves = [DcPorts(tree[i]["active"], tuple((v + clock0[i]) & 0xFFFF_FFFF for v in times[i]))  # type: ignore[arg-type, misc]
              for i in range(n)]
    return slaves, epu


@st.composite
def trees(draw: st.DrawFn) -> tuple[list[dict[str, object]], list[int], list[int]]:
    size = draw(st.integers(1, 24))
    tree: list[dict[str, object]] = []

    def grow(entry: int) -> int:
        i = len(tree)
        node: dict[str, object] = {"entry": entry, "children": {}}
        tree.append(node)
        free = [p for p in (0, 1, 2, 3) if p != entry]
        chosen = {p for p in free if len(tree) < size and draw(st.booleans())}
        node["active"] = frozenset(chosen | {entry})
        for p in port_sequence(entry, node["active"]):  # type: ignore[arg-type]
            if len(tree) >= size:
                node["active"] = frozenset(node["active"] - {p})  # type: ignore[operator]
                continue
            child_entry = draw(st.sampled_from([0, 0, 0, 1]))  # now and then fed backwards
            node["children"][p] = grow(child_entry)  # type: ignore[index]
        return i

    grow(0)
    n = len(tree)
    hops = [0] + [draw(st.integers(1, 2000)) for _ in range(n - 1)]
    clock0 = [draw(st.integers(0, 0xFFFF_FFFF)) for _ in range(n)]
    return tree, hops, clock0


@settings(max_examples=200, deadline=None)
@given(trees())
def test_delays_equal_the_model_for_any_tree(case: tuple[list[dict[str, object]], list[int], list[int]]) -> None:
    """Symmetric links, any tree, clocks anywhere in their 32-bit range: exact delays."""
    tree, hops, clock0 = case
    slaves, epu = _walk(tree, hops, clock0)
    res = propagation_delays(slaves)
    for i, d in enumerate(res):
        want = epu[i] - epu[0]
        if want < 0:
            assert d.before_reference and d.delay_ns is None
        else:
            assert d.delay_ns == want, (i, tree)
        assert d.entry_port == tree[i]["entry"]


# --- offsets, 0x092C, SYNC ----------------------------------------------------------------


def test_system_time_offset_64_and_32_bit() -> None:
    # master 10 s after 2000, slave's local time 3 s when the latch passed, 450 ns behind the reference
    assert system_time_offset(10_000_000_000, 3_000_000_000, 450) == 7_000_000_450
    # a slave whose local clock is ahead of the master: a negative offset, two's complement
    assert system_time_offset(1_000, 5_000) == (1 << 64) - 4_000
    assert system_time_offset(1_000, 5_000, bits=32) == (1 << 32) - 4_000
    assert unix_to_ethercat_ns(946_684_800_000_000_001) == 1


def test_time_difference_sign_magnitude() -> None:
    assert encode_time_difference(-25) == 25
    assert encode_time_difference(25) == 0x8000_0019
    assert encode_time_difference(-(1 << 40)) == 0x7FFF_FFFF
    assert decode_time_difference(0x8000_0019) == 25
    # BRD ORs the slaves' values: the bound covers the largest magnitude
    values = [encode_time_difference(v) for v in (-7, 30, 12)]
    or_ = 0
    for v in values:
        or_ |= v
    assert 30 <= difference_bound(or_) < 60


def test_sync_start_time_on_the_cycle_grid() -> None:
    # 1 ms cycle, shift 50 us: the first pulse after now + 100 ms, on the grid
    now = 12_345_678_901
    t = sync_start_time(now, 1_000_000, 50_000)
    assert t == 12_446_000_000 + 50_000
    assert (t - 50_000) % 1_000_000 == 0 and t > now + 100_000_000
    assert sync_start_time(now, 0, 7) == now + 100_000_000 + 7


def test_sync1_register_and_period() -> None:
    assert sync1_cycle_register(1_000_000, delay_ns=250_000) == 250_000
    assert sync1_period(1_000_000, 250_000) == 1_000_000
    # every 4th SYNC0 cycle, 10 us after that SYNC0
    reg = sync1_cycle_register(1_000_000, multiple=4, shift_ns=10_000)
    assert reg == 3_010_000
    assert sync1_period(1_000_000, reg) == 4_000_000
    with pytest.raises(ConfigError):
        sync1_cycle_register(1_000_000, delay_ns=1_000_000)
    with pytest.raises(ConfigError):
        sync1_cycle_register(1_000_000)


def test_assign_activate_decoding() -> None:
    a = AssignActivate(0x0300)
    assert a.sync0 and not a.sync1 and a.active
    assert a.describe() == "SYNC0 (0x0300)"
    b = AssignActivate(0x0700)
    assert b.sync0 and b.sync1 and b.activation & R.DcActivation.CYCLIC
    assert AssignActivate.for_sync(True, True) == b
    assert AssignActivate.for_sync(False, False).describe() == "off (0x0000)"
    assert AssignActivate(0x0301).describe() == "SYNC0+PDI (0x0301)"
    with pytest.raises(ConfigError):
        AssignActivate(0x1_0000)


@settings(max_examples=200, deadline=None)
@given(trees(), st.data())
def test_stretches_without_dc_share_their_measured_round_trip(
        case: tuple[list[dict[str, object]], list[int], list[int]], data: st.DataObject) -> None:
    """Slaves without DC anywhere below the first slave: exact when their links are equal.

    That is the one assumption the estimate makes (nothing inside such a
    stretch is measured); with equal links in each stretch the delays of all
    DC slaves come out exact.
    """
    tree, hops, clock0 = case
    n = len(tree)
    no_dc = {i for i in range(1, n) if tree[i]["entry"] == 0 and data.draw(st.booleans())}
    parent = {c: i for i, node in enumerate(tree) for c in node["children"].values()}  # type: ignore[attr-defined]
    hops = list(hops)
    for i in range(1, n):  # ring order: a stretch's top comes first
        if i in no_dc and parent[i] not in no_dc:
            todo = [i]
            while todo:
                j = todo.pop()
                hops[j] = hops[i]
                if j in no_dc:
                    todo.extend(tree[j]["children"].values())  # type: ignore[attr-defined]
    slaves, epu = _walk(tree, hops, clock0)
    slaves = [DcPorts(s.active, None) if i in no_dc else s for i, s in enumerate(slaves)]
    for i, d in enumerate(propagation_delays(slaves)):
        if i in no_dc:
            assert d.delay_ns is None
        elif epu[i] >= epu[0]:
            assert d.delay_ns == epu[i] - epu[0], (i, tree, sorted(no_dc))
