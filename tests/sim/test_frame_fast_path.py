"""The frame fast paths of Segment.process answer exactly as the general path.

A segment with the fast paths switched off (``commands.brd_fast = False``: every BRD
goes through the general broadcast path; ``commands.fprd_fast = False``: every
FPRD through the general addressed path; no memo of single-datagram frame
parses) is the reference; the same frames go to both and the replies and the
memories must be identical byte for byte. The fast segment ORs short columns
as Python ints or, with ``commands.brd_py_max = 0``, with one numpy reduce.
"""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from simhelp import line, one, spec

from pyethercat.clock import VirtualClock
from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame


class _NoMemo(dict):  # type: ignore[type-arg]
    """A parse memo that never remembers (every frame is parsed afresh)."""

    def __setitem__(self, key: object, value: object) -> None:
        pass


def _pair(profiles: list[str], python_ints: bool = True) -> tuple[Segment, Segment]:
    segs = []
    for fast in (True, False):
        seg = Segment(VirtualClock(1_000_000))
        if not python_ints:
            seg.commands.brd_py_max = 0
        if not fast:
            seg.commands.brd_fast = False
            seg.commands.fprd_fast = False
            seg._parsed = _NoMemo()
        for i, prof in enumerate(profiles):
            seg.add_slave(spec(f"s{i}", prof))
        segs.append(seg)
    return segs[0], segs[1]


_REGION = st.sampled_from([R.TYPE, R.STATION_ADDRESS, R.DL_STATUS, R.AL_STATUS, R.AL_STATUS_CODE,
                           R.ECAT_EVENT_REQUEST, R.FMMU_BASE + 0x30, R.SM_BASE + 0x40, R.DC_SYSTEM_TIME,
                           R.DC_RECEIVE_TIME_PORT0, R.USER_RAM, 0x0F80, 0xFFF8])

_OP = st.one_of(
    st.tuples(st.just("raw"), st.integers(0, 5), _REGION, st.integers(0, 7), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("brd"), _REGION, st.integers(-1, 9), st.integers(1, 8), st.binary(max_size=8)),
    st.tuples(st.just("al"), st.sampled_from([1, 2, 3, 4, 0x11])),
    st.tuples(st.just("mask"), st.integers(0, 0xFFFF)),
    # Station addresses 0x1000 + position (APWR), some slaves twice the same.
    st.tuples(st.just("addr"), st.lists(st.integers(0, 5), min_size=1, max_size=6)),
    # FPRDs of one station, two in a frame after a NOP, the second after a write
    # to the same station's address or event mask.
    st.tuples(st.just("fprd"), st.integers(0x0FFF, 0x1006), _REGION, st.integers(0, 9),
              st.integers(1, 8), st.sampled_from([None, R.STATION_ADDRESS, R.ECAT_EVENT_MASK])),
    # A BRD frame with some bytes changed and/or cut short (malformed, other type, C bit...).
    st.tuples(st.just("mangle"), _REGION, st.integers(1, 8),
              st.lists(st.tuples(st.integers(12, 40), st.integers(0, 255)), max_size=3),
              st.integers(0, 64)),
)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(["ET1100", "ET1200", "LAN9252"]), min_size=1, max_size=6),
       st.lists(_OP, min_size=1, max_size=25), st.booleans())
def test_fast_paths_match_general_path(profiles: list[str], ops: list[tuple], python_ints: bool) -> None:
    fast, ref = _pair(profiles, python_ints)
    for op in ops:
        frames: list[bytes] = []
        if op[0] == "raw":
            _, slave, base, delta, data = op
            for seg in (fast, ref):
                if slave < len(seg.slaves):
                    # (memory a chip lacks takes no raw writes: stay inside its row)
                    address = min(base + delta, len(seg.slaves[slave].esc.row) - len(data))
                    seg.slaves[slave].write(address, data)
            continue
        if op[0] == "brd":
            _, base, delta, n, incoming = op
            ado = max(0, min(base + delta, 0xFFFF))
            payload = (incoming + bytes(n))[:n]
            frames.append(encode_frame([Datagram.device(Command.BRD, 0x20, ado, payload)]))
            # Two BRDs in one frame, the second after a NOP (plan cached by the first).
            frames.append(encode_frame([Datagram.device(Command.BRD, 0, ado, n),
                                        Datagram.device(Command.NOP, 0, 0, 1),
                                        Datagram.device(Command.BRD, 0, ado, payload)]))
        elif op[0] == "addr":
            frames.append(encode_frame([
                Datagram.positional(Command.APWR, i, R.STATION_ADDRESS,
                                    struct.pack("<H", 0x1000 + (op[1][i] if i < len(op[1]) else i)))
                for i in range(6)]))
        elif op[0] == "fprd":
            _, station, base, delta, n, between = op
            ado = max(0, min(base + delta, 0xFFFF))
            read = Datagram.device(Command.FPRD, station, ado, n)
            frames.append(encode_frame([read]))
            middle = (Datagram.device(Command.NOP, 0, 0, 1) if between is None else
                      Datagram.device(Command.FPWR, station, between, struct.pack("<H", 0x1003)))
            frames.append(encode_frame([read, middle, read]))
        elif op[0] == "al":
            frames.append(encode_frame([Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", op[1]))]))
        elif op[0] == "mangle":
            _, ado, n, changes, cut = op
            raw = bytearray(encode_frame([Datagram.device(Command.BRD, 0, ado, n)]))
            for at, value in changes:
                if at < len(raw):
                    raw[at] = value
            raw = raw[: len(raw) - cut]
            frames += [bytes(raw), bytes(raw)]  # the second may find the first's parse
        else:
            frames.append(encode_frame([Datagram.device(Command.BWR, 0, R.ECAT_EVENT_MASK,
                                                        struct.pack("<H", op[1]))]))
        for frame in frames:
            assert fast.process(frame) == ref.process(frame)
            assert fast.process(bytearray(frame)) == ref.process(bytearray(frame))
            assert (fast.frames, fast.frames_lost) == (ref.frames, ref.frames_lost)
    assert np.array_equal(fast.memory.mem[: len(profiles)], ref.memory.mem[: len(profiles)])


def test_brd_fast_path_reads_current_memory_and_ors_incoming_data() -> None:
    seg = line(4)
    for _ in range(3):  # the plan is cached after the first frame
        seg.slaves[1].write(R.USER_RAM, b"\x01\x00\x00\x10")
        seg.slaves[3].write(R.USER_RAM, b"\x00\x02\x00\x00")
        d = one(seg, Datagram.device(Command.BRD, 0x0005, R.USER_RAM, b"\x00\x00\x40\x00"))
        assert d.data == b"\x01\x02\x40\x10" and d.wkc == 4 and d.adp == 0x0009
    seg.slaves[1].write(R.USER_RAM, b"\x00\x00\x00\x00")
    assert one(seg, Datagram.device(Command.BRD, 0, R.USER_RAM, 4)).data == b"\x00\x02\x00\x00"


def test_brd_of_al_status_clears_the_event_every_time_it_is_raised() -> None:
    seg = line(3)
    one(seg, Datagram.device(Command.BWR, 0, R.ECAT_EVENT_MASK, struct.pack("<H", R.EcatEvent.AL_STATUS)))
    for state in (2, 1, 2, 1):
        one(seg, Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", state)))
        assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.AL_STATUS
        d = one(seg, Datagram.device(Command.BRD, 0, R.AL_STATUS, 2))
        assert d.data == struct.pack("<H", state) and d.wkc == 3
        assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0


def test_memoised_parse_still_checks_the_frame_length() -> None:
    seg = line(2)
    frame = encode_frame([Datagram.device(Command.BRD, 0, R.USER_RAM, 64)])  # no padding
    assert seg.process(frame) is not None
    for _ in range(2):  # same bytes 12..25, but the datagram is cut: a processing error each time
        assert seg.process(frame[:-4]) is None
    assert seg.slaves[0].read(R.ECAT_PROCESSING_ERROR_COUNTER, 1) == b"\x02"
    assert seg.process(frame) is not None


def test_memoised_parse_keys_on_the_whole_datagram_header() -> None:
    seg = line(2)
    base = bytearray(encode_frame([Datagram.device(Command.BRD, 0, R.TYPE, 2)]))
    for irq, c_bit in ((0x0000, 0), (0x1234, 0), (0x0000, 0x40), (0x8001, 0)):
        frame = bytearray(base)
        frame[24:26] = struct.pack("<H", irq)
        frame[23] |= c_bit  # circulating bit of the length word
        reply = seg.process(bytes(frame))
        assert reply is not None
        assert struct.unpack_from("<H", reply, 24)[0] == irq  # IRQ field: ours OR the slaves' (0)
        assert reply[23] & 0x40 == c_bit


@settings(max_examples=40, deadline=None)
@given(st.lists(st.sampled_from(["ET1100", "ET1200", "LAN9252"]), min_size=1, max_size=5),
       st.lists(st.tuples(st.sampled_from([R.STATION_ADDRESS, R.ECAT_EVENT_MASK, R.FMMU_BASE, R.FMMU_BASE + 0x38,
                                           R.USER_RAM, 0x0F80, R.TYPE, R.DC_SYSTEM_TIME_OFFSET]),
                          st.integers(0, 6), st.binary(min_size=1, max_size=12)), min_size=1, max_size=12))
def test_array_bwr_matches_per_slave_writes(profiles: list[str], writes: list[tuple[int, int, bytes]]) -> None:
    """BWR as one array operation (with its cached per-chip masks) = every ESC writing for itself."""
    fast, ref = _pair(profiles)
    ref._fast_write_ok = lambda lo, hi: False  # type: ignore[method-assign]
    for base, delta, data in writes:
        frame = encode_frame([Datagram.device(Command.BWR, 0, base + delta, data)])
        assert fast.process(frame) == ref.process(frame)
    assert np.array_equal(fast.memory.mem[: len(profiles)], ref.memory.mem[: len(profiles)])


def test_brd_after_a_loop_control_write_in_the_same_frame_sees_the_new_dl_status() -> None:
    fast, ref = _pair(["ET1100", "ET1100", "ET1100"])
    brd = Datagram.device(Command.BRD, 0, R.DL_STATUS, 2)
    for seg in (fast, ref):
        seg.process(encode_frame([brd]))  # plan cached
    for loop in (0x00, 0x0C, 0x00, 0x0F, 0x04):  # ports 1/0 closed, opened...
        frame = encode_frame([Datagram.device(Command.FPWR, 0, R.DL_CONTROL_LOOP, bytes([loop])),
                              Datagram.positional(Command.APWR, 1, R.DL_CONTROL_LOOP, bytes([loop])),
                              brd])
        assert fast.process(frame) == ref.process(frame)


def _addressed(seg: Segment, count: int) -> None:
    for i in range(count):
        one(seg, Datagram.positional(Command.APWR, i, R.STATION_ADDRESS, struct.pack("<H", 0x1000 + i)))


def test_fprd_of_al_and_dl_status_clears_the_slaves_event_every_time_it_is_raised() -> None:
    fast, ref = _pair(["ET1100", "ET1200", "LAN9252"])
    for seg in (fast, ref):
        _addressed(seg, 3)
        mask = R.EcatEvent.AL_STATUS | R.EcatEvent.DL_STATUS
        one(seg, Datagram.device(Command.BWR, 0, R.ECAT_EVENT_MASK, struct.pack("<H", mask)))
        one(seg, Datagram.device(Command.BRD, 0, R.DL_STATUS, 2))  # DL events of the power-up
    al = Datagram.device(Command.FPRD, 0x1001, R.AL_STATUS, 6)
    for state in (2, 1, 2):
        for seg in (fast, ref):
            one(seg, Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", state)))
            assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.AL_STATUS
            # slave 1's read clears its event only; the others still raise it
            d = one(seg, al)
            assert d.data[:2] == struct.pack("<H", state) and d.wkc == 1
            assert d.irq & R.EcatEvent.AL_STATUS  # (the field shows the events before the read)
            one(seg, Datagram.device(Command.FPRD, 0x1000, R.AL_STATUS, 2))
            assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.AL_STATUS
            one(seg, Datagram.device(Command.FPRD, 0x1002, R.AL_STATUS, 2))
            assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0
            one(seg, al)  # nothing pending now: the plan answers
    assert any(fast.commands.fprd_plans.values()) and not any(ref.commands.fprd_plans.values())
    # a link change raises DL status events; one FPRD of 0x0110 per slave clears them
    for seg in (fast, ref):
        one(seg, Datagram.device(Command.FPWR, 0x1001, R.DL_CONTROL_LOOP, b"\x0c"))
        assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.DL_STATUS
        for station in (0x1000, 0x1001):
            one(seg, Datagram.device(Command.FPRD, station, R.DL_STATUS, 2))
        assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0
    assert np.array_equal(fast.memory.mem[:3], ref.memory.mem[:3])


def test_fprd_follows_a_new_station_address_and_loop_in_the_same_frame() -> None:
    fast, ref = _pair(["ET1100", "ET1100", "ET1100"])
    read = Datagram.device(Command.FPRD, 0x1002, R.TYPE, 8)
    for seg in (fast, ref):
        _addressed(seg, 3)
        one(seg, read)
        one(seg, read)  # plan cached
    assert any(fast.commands.fprd_plans.values())
    frames = [
        # slave 2 takes address 0x2002: the read of 0x1002 after it finds nobody
        encode_frame([Datagram.device(Command.FPWR, 0x1002, R.STATION_ADDRESS, b"\x02\x20"),
                      read, Datagram.device(Command.FPRD, 0x2002, R.STATION_ADDRESS, 2)]),
        # slave 1 closes its port 1: slave 2 is off the route from then on
        encode_frame([Datagram.device(Command.FPRD, 0x2002, R.STATION_ADDRESS, 2),
                      Datagram.device(Command.FPWR, 0x1001, R.DL_CONTROL_LOOP, b"\x0c"),
                      Datagram.device(Command.FPRD, 0x2002, R.STATION_ADDRESS, 2)]),
        encode_frame([Datagram.device(Command.FPRD, 0x2002, R.STATION_ADDRESS, 2)]),
        # the old address in a later frame: nobody has it (no plan left from before)
        encode_frame([read]),
    ]
    replies = [fast.process(f) for f in frames]
    assert replies == [ref.process(f) for f in frames]
    wkcs = [[d.wkc for d in decode_frame(r).datagrams] for r in replies if r is not None]
    assert wkcs == [[1, 0, 1], [1, 1, 1], [0], [0]]  # (a loop change holds from the next frame)
