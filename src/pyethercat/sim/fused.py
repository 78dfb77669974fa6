"""A logical datagram of the cyclic exchange compiled into one short program.

A cyclic LRW does, slave by slave, what ``sim.fmmu`` and ``sim.syncman``
describe: outputs into the memory, inputs into the frame, the read events of
the input SMs (status bit, AL event, ECAT event cleared), the outputs'
buffers published to the PDI with the next buffer index and the write event
in the SM status, the AL events of those SMs, the watchdogs retriggered.
Done step by step that is some thirty numpy calls per frame; each costs
more than the bytes it moves.

:func:`fuse` compiles the register updates of one datagram shape (the read
events and the publish of every slave whose buffers it completes) into one
byte transform: each register byte touched gets a row of a 256-entry table,
the composition of all its updates in their order, so that applying them is
one gather, one table lookup and one scatter, whatever the number of slaves.
The program lives as long as the datagram's logical plan: both are compiled
from the same SM and FMMU registers and dropped together when they change.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

__all__ = ["FusedLogical", "fuse"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]


class LogicalPlan(Protocol):
    """What :func:`fuse` reads of a datagram's plan (``sim.fmmu``)."""

    done: I64
    or_idx: I64 | None
    or_val: U8 | None
    and_idx: I64 | None
    and_val: U8 | None
    and_hit: U8 | None


class Publisher(Protocol):
    """What :func:`fuse` asks of the SM areas (``sim.syncman.SmAreas``)."""

    #: SM status byte after a completed buffered write, by the status before.
    status_after_write: U8

    def publish_plan(self, slaves: I64) -> tuple[I64, I64, I64, U8, I64]: ...


_IDENTITY = np.arange(256, dtype=np.uint8)
_EMPTY = np.zeros(0, np.int64)


class FusedLogical:
    """One datagram shape's register updates as one byte transform, and what follows them.

    ``update``: register bytes (flat memory indices, unique) with ``rows``,
    where their 256-entry rows start in ``table`` (the rows one after the
    other); ``and_pos``/``and_hit``: where in ``update`` the ECAT event bytes
    a read clears sit, and the bits (a cleared bit changes the IRQ field); ``shadow``: buffer bytes published to the PDI side;
    ``done``: slaves whose write buffers complete, ``wd_slaves``: those whose
    watchdog it triggers.
    """

    __slots__ = ("update", "rows", "table", "and_pos", "and_hit", "shadow", "done", "wd_slaves")

    def __init__(self, update: I64, rows: I64, table: U8, and_pos: I64 | None, and_hit: U8 | None,
                 shadow: I64 | slice | None, done: I64, wd_slaves: I64) -> None:
        self.update, self.rows, self.table = update, rows, table
        self.and_pos, self.and_hit = and_pos, and_hit
        self.shadow, self.done, self.wd_slaves = shadow, done, wd_slaves

    def registers(self, flat: U8, shadow: U8) -> bool:
        """Apply the register updates and the publish; whether an ECAT event bit was cleared."""
        update = self.update
        events = False
        if len(update):
            old = flat[update]
            # (a flat table and row offsets: a 2-D fancy index costs more than the add)
            flat[update] = self.table[self.rows + old]
            and_pos, and_hit = self.and_pos, self.and_hit
            if and_pos is not None and and_hit is not None:
                events = bool((old[and_pos] & and_hit).any())
        idx = self.shadow
        if idx is not None:
            shadow[idx] = flat[idx]
        return events


def _compose(steps: list[tuple[I64, U8, str]]) -> tuple[I64, I64, U8]:
    """(unique indices, their rows in the table, the distinct 256-entry rows) of byte
    updates applied in order.

    Each step is (indices, values, op): op "or" and "and" take one value per
    index, "map" one 256-entry table for all; a step names each index once
    (its producers combine the bits of one byte)."""
    if not steps:
        return _EMPTY, _EMPTY, np.zeros((0, 256), np.uint8)
    keys = np.unique(np.concatenate([idx for idx, _, _ in steps]))
    funcs = np.tile(_IDENTITY, (len(keys), 1))  # each byte's function, row by row
    for idx, val, op in steps:
        pos = np.searchsorted(keys, idx)
        assert len(np.unique(pos)) == len(pos), "a step names a byte twice"
        if op == "or":
            funcs[pos] |= val[:, None]
        elif op == "and":
            funcs[pos] &= val[:, None]
        else:
            funcs[pos] = val[funcs[pos]]
    table, rows = np.unique(funcs, axis=0, return_inverse=True)
    return keys, rows.reshape(-1).astype(np.int64), table


def _run_or_index(idx: I64) -> I64 | slice:
    """A slice where the indices are one ascending run (a copy is cheaper than a gather)."""
    if len(idx) and bool((np.diff(idx) == 1).all()):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def fuse(plan: LogicalPlan, sm: Publisher) -> FusedLogical:
    """The register updates of ``plan`` (read events) and of the publish of the slaves whose
    write buffers it completes (``sm``), as one :class:`FusedLogical`."""
    steps: list[tuple[I64, U8, str]] = []
    and_idx: I64 | None = None
    if plan.or_idx is not None and plan.or_val is not None:
        steps.append((plan.or_idx, plan.or_val, "or"))
        if plan.and_idx is not None and plan.and_val is not None:
            and_idx = plan.and_idx
            steps.append((plan.and_idx, plan.and_val, "and"))
    shadow: I64 | slice | None = None
    wd_slaves = _EMPTY
    if len(plan.done):
        buf_idx, st, al_idx, al_val, wd_slaves = sm.publish_plan(plan.done)
        if len(st):
            steps.append((st, sm.status_after_write, "map"))
        if len(al_idx):
            steps.append((al_idx, al_val, "or"))
        if len(buf_idx):
            shadow = _run_or_index(buf_idx)
    update, rows, table = _compose(steps)
    offsets = rows * 256
    and_pos = and_hit = None
    if and_idx is not None and plan.and_hit is not None:
        and_pos = np.searchsorted(update, and_idx)
        and_hit = plan.and_hit
    return FusedLogical(update, offsets, table.reshape(-1), and_pos, and_hit, shadow, plan.done, wd_slaves)
