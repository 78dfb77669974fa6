"""The sync managers of all slaves of a segment, compiled for array work.

When any slave's SM registers change, :meth:`SmAreas.compile` turns the
enabled SMs of all slaves into flat index arrays over the memory:

- the byte span any SM covers (a multi-slave write outside it needs no SM
  rules at all);
- buffered write SMs (process-data outputs): their bytes, status bytes,
  AL event and watchdog trigger bits, so that completing the buffers of any
  set of slaves (:meth:`SmAreas.publish`) is a handful of fancy-index
  operations: copy into the shadow the PDI reads, next buffer index and
  write event in the status (ESC datasheet section I, "SyncManager",
  3-buffer mode), the SM's AL event;
- ECAT-read SMs, for logical access (``sim.fmmu.SmReads``).

:meth:`SmAreas.logical_map` compiles the FMMUs of the route into a
``sim.fmmu.LogicalMap`` with these SM rules.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.sim.access import buffer_written
from pyethercat.sim.cache import ArrayKeyCache
from pyethercat.sim.esc import Esc
from pyethercat.sim.fmmu import LogicalMap, SmReads, parse_fmmus
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.wire import registers as R

__all__ = ["SmAreas"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
_EMPTY = np.zeros(0, np.int64)
_MAILBOX = int(R.SmMode.MAILBOX)
_BUFFERED = int(R.SmMode.BUFFERED)
#: The buffer-publish work of one set of slaves: buffer bytes, status bytes,
#: AL event bytes and values, slaves whose watchdog the write triggers.
_Plan = tuple[I64, I64, I64, U8, I64]


def _status_after_write_table() -> U8:
    """SM status byte after an ECAT buffered write completed (read event cleared), by old status."""
    return np.array([buffer_written(old) & ~R.SM_STATUS_READ_EVENT & 0xFF for old in range(256)], np.uint8)


_STATUS_AFTER_WRITE = _status_after_write_table()


def _byte_and_mask(bit: int) -> tuple[int, int]:
    """Byte offset and in-byte mask of a one-bit register value (e.g. ``R.al_event_sm(n)``)."""
    pos = bit.bit_length() - 1
    return pos >> 3, 1 << (pos & 7)


class SmAreas:
    """Compiled SM state of a segment (see the module docstring)."""

    #: SM status byte after a completed buffered write, by the status before
    #: (what ``sim.fused`` composes into a datagram's register updates).
    status_after_write = _STATUS_AFTER_WRITE

    def __init__(self, memory: EscMemory) -> None:
        self.memory = memory
        #: [lo, hi) covered by any enabled SM of any slave ((0, 0): none).
        self.span = (0, 0)
        self.reads = SmReads.empty()
        #: Last bytes of each slave's enabled buffered write SMs.
        self.complete: dict[int, set[int]] = {}
        # buffered write SMs: byte indices and owning slave; one entry per SM
        self._idx = _EMPTY
        self._owner = _EMPTY
        self._slave = _EMPTY
        self._status = _EMPTY
        self._al: U8 = np.zeros(0, np.uint8)
        self._wd = np.zeros(0, bool)
        self._plans: ArrayKeyCache[_Plan] = ArrayKeyCache()

    def compile(self, escs: Sequence[Esc]) -> None:
        """Recompile from the SM registers of every powered slave."""
        stride = self.memory.stride
        idx_parts, owner_parts = [], []
        pair_slave, pair_status, pair_al, pair_wd = [], [], [], []
        lo, hi = R.ADDRESS_SPACE, 0
        complete: dict[int, set[int]] = {}
        # ECAT-read SMs, for logical access (sim.fmmu.SmReads): refused write
        # ranges, and per buffered one its last byte, status and event bytes.
        refused: dict[int, list[tuple[int, int]]] = {}
        last: dict[int, dict[int, int]] = {}
        rd: list[tuple[int, int, int, int, int]] = []
        for s, esc in enumerate(escs):
            if not esc.powered:
                continue
            base = s * stride
            for k in range(esc.profile.sm_count):
                sm = esc.sm(k)
                if not sm.enabled:
                    continue
                lo, hi = min(lo, sm.start), max(hi, sm.end)
                if not sm.ecat_writes:
                    refused.setdefault(s, []).append((sm.start, min(sm.end, R.ADDRESS_SPACE)))
                    if sm.mode != _MAILBOX and sm.end <= R.ADDRESS_SPACE:
                        # (the mailbox's read completion stays on the ESC's own path)
                        last.setdefault(s, {})[sm.end - 1] = len(rd)
                        al_off, al_mask = _byte_and_mask(R.al_event_sm(k))
                        ev_off, ev_mask = _byte_and_mask(R.ecat_event_sm(k))
                        rd.append((
                            base + R.sm_address(k) + R.SM_STATUS,
                            base + R.AL_EVENT_REQUEST + al_off,
                            al_mask if sm.control & R.SM_CONTROL_AL_EVENT else 0,
                            base + R.ECAT_EVENT_REQUEST + ev_off,
                            ev_mask if sm.control & R.SM_CONTROL_ECAT_EVENT and ev_off < 2 else 0))
                if sm.mode == _BUFFERED and sm.ecat_writes:
                    idx_parts.append(np.arange(sm.start, min(sm.end, R.ADDRESS_SPACE)) + base)
                    owner_parts.append(np.full(len(idx_parts[-1]), s, np.int64))
                    pair_slave.append(s)
                    pair_status.append(base + R.sm_address(k) + R.SM_STATUS)
                    pair_al.append(1 << k if sm.control & R.SM_CONTROL_AL_EVENT and k < 8 else 0)
                    pair_wd.append(bool(sm.control & R.SM_CONTROL_WATCHDOG))
                    complete.setdefault(s, set()).add(sm.end - 1)
        self._idx = np.concatenate(idx_parts).astype(np.int64) if idx_parts else _EMPTY
        self._owner = np.concatenate(owner_parts) if owner_parts else _EMPTY
        self._slave = np.array(pair_slave, np.int64)
        self._status = np.array(pair_status, np.int64)
        self._al = np.array(pair_al, np.uint8)
        self._wd = np.array(pair_wd, bool)
        self.complete = complete
        cols = list(zip(*rd, strict=True)) if rd else [(), (), (), (), ()]
        self.reads = SmReads(refused, last, np.array(cols[0], np.int64), np.array(cols[1], np.int64),
                             np.array(cols[2], np.uint8), np.array(cols[3], np.int64),
                             np.array(cols[4], np.uint8))
        self.span = (lo, hi) if hi > lo else (0, 0)
        self._plans.clear()

    def logical_map(self, route: Route, escs: Sequence[Esc]) -> LogicalMap:
        """The FMMUs of the slaves on ``route``, compiled with the SM rules."""
        configs = []
        mem = self.memory.mem
        for pos, s in enumerate(route.passes.tolist()):
            count = escs[s].profile.fmmu_count
            raw = mem[s, R.FMMU_BASE: R.FMMU_BASE + count * R.FMMU_SIZE].tobytes()
            configs.extend(parse_fmmus(raw, count, pos, s))
        writable = [e.writable for e in escs]
        impl = [e.impl for e in escs]
        return LogicalMap(configs, writable, self.complete, impl, self.reads, self.memory.stride, self)

    def publish_plan(self, slaves: I64) -> _Plan:
        """The index arrays of :meth:`publish` for ``slaves``: (buffer bytes, status bytes,
        AL event bytes, their bits, slaves whose watchdog the writes trigger)."""
        plan = self._plans.get(slaves)
        if plan is None:
            plan = self._plan(slaves)
            self._plans.put(slaves, plan)
        return plan

    def publish(self, slaves: I64) -> I64:
        """The write SMs of ``slaves`` got their last byte: publish their buffers.

        Copies the buffers into the shadow (what the PDI sees), advances the SM
        status (buffer index, write event) and raises the AL events. Returns
        the slaves whose watchdog these writes trigger. The index arrays for a
        given set of slaves are computed once and cached."""
        idx, st, al_idx, al_val, wd_slaves = self.publish_plan(slaves)
        flat = self.memory.flat
        self.memory.shadow_flat[idx] = flat[idx]
        if len(st):
            flat[st] = _STATUS_AFTER_WRITE[flat[st]]
        if len(al_idx):
            flat[al_idx] |= al_val
        return wd_slaves

    def _plan(self, slaves: I64) -> _Plan:
        count = int(slaves.max()) + 1 if len(slaves) else 0
        size = max(count, int(self._owner.max()) + 1 if len(self._owner) else 0)
        sel_mask = np.zeros(size, bool)
        sel_mask[slaves] = True
        idx = self._idx[sel_mask[self._owner]]
        psel = sel_mask[self._slave]
        st = self._status[psel]
        ps = self._slave[psel]
        al = self._al[psel]
        # One OR per slave: combine the SM event bits of slaves with several write SMs.
        al_bits: dict[int, int] = {}
        for s_, a in zip(ps.tolist(), al.tolist(), strict=True):
            if a:
                al_bits[s_] = al_bits.get(s_, 0) | a
        stride = self.memory.stride
        al_idx = np.array([s_ * stride + R.AL_EVENT_REQUEST + 1 for s_ in al_bits], np.int64)
        al_val = np.array(list(al_bits.values()), np.uint8)
        wd_slaves = np.unique(ps[self._wd[psel]]).astype(np.int64)
        return idx, st, al_idx, al_val, wd_slaves
