"""The frame's port order and the tree it gives a segment (shared by the scan and the DC set-up)."""

from __future__ import annotations

from pyethercat.wire.ring import PORT_CYCLE, next_port, port_sequence, prev_port, walk_ring


def test_port_cycle_and_neighbours() -> None:
    assert PORT_CYCLE == (0, 3, 1, 2)
    assert port_sequence(0, {0, 1, 2, 3}) == [3, 1, 2]
    assert port_sequence(1, {0, 1}) == [0]  # fed backwards: the frame goes on to port 0
    assert next_port(0, {0, 1}) == 1 and prev_port(0, {0, 1}) == 1
    assert next_port(2, {2}) == 2  # no other open port: the frame turns back


def test_walk_of_a_coupler_with_a_branch_on_port_3() -> None:
    # 0: coupler with ports 0, 3 and 1 open; 1: on its port 3 (end); 2, 3: a line on port 1.
    active = [{0, 1, 3}, {0}, {0, 1}, {0}]
    parents, explained = walk_ring([0] * 4, active)
    assert parents == [None, (0, 3), (0, 1), (2, 1)]
    assert explained == 4


def test_walk_of_a_cross_and_a_slave_fed_backwards() -> None:
    active = [{0, 1, 2, 3}, {1}, {0}, {0}]
    parents, explained = walk_ring([0, 1, 0, 0], active)
    assert parents == [None, (0, 3), (0, 1), (0, 2)]
    assert explained == 4


def test_ports_that_explain_too_few_slaves_and_an_open_port_with_nothing_behind() -> None:
    parents, explained = walk_ring([0] * 3, [{0}, {0, 1}, {0}])
    assert parents == [None, None, None] and explained == 1
    parents, explained = walk_ring([0] * 2, [{0, 1}, {0, 1}])  # a ring back to the master
    assert parents == [None, (0, 1)] and explained == 2
