"""Cyclic frames answered before their writes, and the fused register program, change nothing.

``sim.reply_first`` sends a logical datagram's reply before it applies the
datagram's writes, and ``sim.fused`` applies the read events and the
buffer publish of a datagram as one byte transform. The reference is a
twin segment that runs the step-by-step path of before, written out here
from the plan's own arrays: the data moved, then the SM read events (status
bit, AL event, ECAT event cleared), then ``OutputArrival.completed`` (the
publish, the status and AL event updates one after the other). The same frames go to
both, with process data, reconfigurations and input changes in between, on
random SM and FMMU layouts (bit-level FMMUs, slaves whose windows overlap,
watchdog and event bits); the replies, both memories, the watchdogs, the
output flags and the IRQ field must be identical after every frame.
"""

from __future__ import annotations

import struct
import types

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from simhelp import IN_SM, OUT_SM, address_all, fmmu_bytes, fpwr, sm_bytes, spec

from pyethercat.clock import VirtualClock
from pyethercat.sim.reply_first import serve_reply_first
from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame

READ, WRITE = int(R.FmmuType.READ), int(R.FmmuType.WRITE)
ST = 0x1000


def _unfused_logical(self: Segment, cmd: int, address: int, data: np.ndarray, n: int) -> int:
    """The logical datagram step by step (the path before ``sim.fused``)."""
    plan = self.logical_plan(cmd, address, n)
    if plan is None or not plan.wkc:
        return 0
    flat = self.memory.flat
    for stage in plan.stages:
        stage.apply(flat, data)
    if plan.or_idx is not None:  # input buffers read to their last byte
        flat[plan.or_idx] |= plan.or_val
        if plan.and_idx is not None:
            old = flat[plan.and_idx]
            if (old & plan.and_hit).any():
                flat[plan.and_idx] = old & plan.and_val
                self.state.irq_changed()
    if len(plan.done):
        self.arrival.completed(plan.done)
    return plan.wkc


_SLAVE = st.fixed_dictionaries({
    "out_len": st.integers(1, 4), "in_len": st.integers(1, 4),
    "out_control": st.sampled_from([R.SM_CONTROL_OUTPUTS, R.SM_CONTROL_OUTPUTS | R.SM_CONTROL_WATCHDOG,
                                    R.SM_CONTROL_OUTPUTS | R.SM_CONTROL_WATCHDOG | R.SM_CONTROL_ECAT_EVENT
                                    | R.SM_CONTROL_AL_EVENT]),
    "in_control": st.sampled_from([R.SM_CONTROL_INPUTS, R.SM_CONTROL_INPUTS | R.SM_CONTROL_ECAT_EVENT,
                                   R.SM_CONTROL_INPUTS | R.SM_CONTROL_ECAT_EVENT | R.SM_CONTROL_AL_EVENT]),
    "out_at": st.integers(0, 12), "in_at": st.integers(0, 12),
    "out_bits": st.sampled_from([(0, 7), (0, 7), (2, 5), (4, 3)]),
    "in_bits": st.sampled_from([(0, 7), (0, 7), (1, 6)]),
    "ecat_mask": st.integers(0, 0xFFFF),
    # Plain memory read and written through two FMMUs: an LRW reads it before it writes it.
    "ram_at": st.one_of(st.none(), st.integers(0, 12)),
})

_OP = st.one_of(
    st.tuples(st.just("lrw"), st.integers(0, 8), st.integers(1, 24), st.sampled_from(["LRW", "LRW", "LRD", "LWR"]),
              st.binary(min_size=24, max_size=24), st.integers(1, 3)),
    st.tuples(st.just("inputs"), st.integers(0, 3), st.binary(min_size=4, max_size=4)),
    st.tuples(st.just("event"), st.integers(0, 3), st.integers(0, 0xFFFF)),
    st.tuples(st.just("resize"), st.integers(0, 3), st.integers(1, 4)),
)


def _configure(seg: Segment, slaves: list[dict]) -> None:
    address_all(seg)
    for i, s in enumerate(slaves):
        fpwr(seg, ST + i, R.sm_address(2), sm_bytes(OUT_SM, s["out_len"], s["out_control"]))
        fpwr(seg, ST + i, R.sm_address(3), sm_bytes(IN_SM, s["in_len"], s["in_control"]))
        sb, eb = s["out_bits"]
        fpwr(seg, ST + i, R.fmmu_address(0), fmmu_bytes(s["out_at"], s["out_len"], sb, eb, OUT_SM, sb, WRITE))
        sb, eb = s["in_bits"]
        fpwr(seg, ST + i, R.fmmu_address(1), fmmu_bytes(8 + s["in_at"], s["in_len"], sb, eb, IN_SM, sb, READ))
        fpwr(seg, ST + i, R.ECAT_EVENT_MASK, struct.pack("<H", s["ecat_mask"]))
        if s.get("ram_at") is not None:
            fpwr(seg, ST + i, R.fmmu_address(2), fmmu_bytes(s["ram_at"], 2, 0, 7, R.USER_RAM, 0, READ))
            fpwr(seg, ST + i, R.fmmu_address(3), fmmu_bytes(s["ram_at"], 2, 0, 7, R.USER_RAM, 0, WRITE))
        fpwr(seg, ST + i, R.WATCHDOG_TIME_PROCESS_DATA, struct.pack("<H", 1000))


def _twins(slaves: list[dict]) -> tuple[Segment, Segment]:
    segs = []
    for _ in range(2):
        seg = Segment(VirtualClock(1_000_000))
        for i in range(len(slaves)):
            seg.add_slave(spec(f"io{i}", out_bits=32, in_bits=32))
        _configure(seg, slaves)
        segs.append(seg)
    segs[1]._logical = types.MethodType(_unfused_logical, segs[1])  # type: ignore[method-assign]
    return segs[0], segs[1]


def _same(a: Segment, b: Segment) -> None:
    assert np.array_equal(a.memory.mem, b.memory.mem)
    assert np.array_equal(a.memory.shadow_flat, b.memory.shadow_flat)
    assert np.array_equal(a.arrival.received, b.arrival.received)
    assert np.array_equal(a.watchdogs.last, b.watchdogs.last)
    assert a.state.irq == b.state.irq or a.state.irq_stale or b.state.irq_stale


@settings(max_examples=80, deadline=None)
@given(st.lists(_SLAVE, min_size=1, max_size=4), st.lists(_OP, min_size=1, max_size=30))
def test_reply_first_and_fused_registers_match_the_step_by_step_path(slaves: list[dict], ops: list[tuple]) -> None:
    fast, ref = _twins(slaves)
    for op in ops:
        if op[0] == "lrw":
            _, lo, n, cmd, data, repeat = op
            for k in range(repeat):
                # (the same datagram with new outputs each cycle, as a master sends it)
                payload = bytes((b + 37 * k) & 0xFF for b in data[:n])
                frame = encode_frame([Datagram.logical(getattr(Command, cmd), lo,
                                                       payload if cmd != "LRD" else n)])
                got: list[bytes] = []
                if not serve_reply_first(fast, frame, lambda r, got=got: got.append(bytes(r))):
                    r = fast.process(frame)
                    if r is not None:
                        got.append(r)
                want = ref.process(frame)
                assert got == ([] if want is None else [want])
                _same(fast, ref)
        elif op[0] == "inputs":
            _, i, data = op
            for seg in (fast, ref):
                if i < len(seg.slaves):
                    seg.slaves[i].esc.pdi.set_inputs(data)
        elif op[0] == "event":
            _, i, bits = op
            for seg in (fast, ref):
                if i < len(seg.slaves):
                    seg.slaves[i].esc.set_ecat_event(bits)
        else:
            _, i, n = op
            for seg in (fast, ref):
                if i < len(seg.slaves):
                    fpwr(seg, ST + i, R.sm_address(3), sm_bytes(IN_SM, n, R.SM_CONTROL_INPUTS | R.SM_CONTROL_ECAT_EVENT))
        _same(fast, ref)


def test_a_repeated_lrw_is_answered_first_and_others_are_not() -> None:
    slaves = [dict(out_len=2, in_len=2, out_control=R.SM_CONTROL_OUTPUTS | R.SM_CONTROL_WATCHDOG,
                   in_control=R.SM_CONTROL_INPUTS, out_at=2 * i, in_at=2 * i, out_bits=(0, 7),
                   in_bits=(0, 7), ecat_mask=0) for i in range(3)]
    fast, ref = _twins(slaves)
    lrw = encode_frame([Datagram.logical(Command.LRW, 0, bytes(range(1, 15)))])
    sent: list[bytes] = []
    fast.process(lrw)  # (the first frame compiles what the state changes left stale)
    ref.process(lrw)
    for k in range(5):
        for seg in (fast, ref):
            seg.slaves[k % 3].esc.pdi.set_inputs(bytes([k, k + 1]))
        assert serve_reply_first(fast, lrw, lambda r: sent.append(bytes(r)))
        assert sent[-1] == ref.process(lrw)
        _same(fast, ref)
    (d,) = decode_frame(sent[-1]).datagrams
    assert d.wkc == 3 * 3  # LRW: 3 slaves read and write
    assert d.data[8:14] == bytes([3, 4, 4, 5, 2, 3])  # the inputs of k = 3, 4, 2 (slaves 0, 1, 2)
    # Two datagrams, a BRD, a dropped frame: the general path answers them.
    two = encode_frame([Datagram.logical(Command.LRW, 0, b"abcd"),
                        Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)])
    assert not serve_reply_first(fast, two, sent.append)
    assert not serve_reply_first(fast, encode_frame([Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)]),
                                 sent.append)
    fast.faults.drop_p = 1.0
    assert not serve_reply_first(fast, lrw, sent.append)
