"""Mailbox status from the cyclic frame: SM1 status (0x080D) mapped by a read FMMU.

While cyclic exchange runs, a mailbox transaction waits for the status byte
the cyclic frame reads into the group image and sends no poll frames of its
own (FPRD 0x080D). Against the simulator's ESC (real FMMU reads of the SM1
status register) over the in-process pair link, wall clock, 1 ms cycles.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from mini_coe import coe_segment
from status_waits import assert_no_stale_status, count_status_waits, lost_frames

from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame, encode_frame

STATUS = reg.sm_address(1) + reg.SM_STATUS
PATTERN = bytes(range(256)) * 16


def _datagrams(frames: list[bytes], command: Command, ado: int) -> int:
    return sum(1 for f in frames for d in decode_frame(f).datagrams
               if d.command == command and d.ado == ado)


def test_sdo_with_late_replies_polls_through_the_cyclic_frame() -> None:
    _seg, apps, drop, link = coe_segment(2)
    m = Master(link)
    m.coe_pdo_config = False  # MiniCoe has no 0x1C12/0x1C13: the SII layout
    m.scan()
    cfg = m.configure()
    group = cfg.groups[0]
    assert group.status_bytes == 2
    assert [cfg.slaves[p].mailbox_status_offset for p in (0, 1)] == [
        group.status_offset, group.status_offset + 1]
    runner = m.start(cycle=0.001)
    try:
        assert all(s.al_state == AlState.OP for s in m.slaves)
        for app in apps:
            app.late = 3  # the reply shows up three frames after the request
        a, b = m.slaves
        assert a.mbx is not None and b.mbx is not None
        before = len(drop.frames)
        polls = a.mbx.stats.status_polls + b.mbx.stats.status_polls
        assert a.sdo_read(0x1018, 1, "uint32") == 0x00504543
        assert a.sdo_read(0x2001) == PATTERN  # segmented: every segment waits
        # two slaves' transfers interleave, still without poll frames
        got: dict[int, bytes] = {}
        t = threading.Thread(target=lambda: got.update({1: b.sdo_read(0x2001)}))
        t.start()
        got[0] = a.sdo_read(0x2001)
        t.join()
        assert got == {0: PATTERN, 1: PATTERN}
        a.sdo_write(0x2000, 0, 0x1234, "uint32")
        assert a.sdo_read(0x2000, 0, "uint32") == 0x1234
        assert runner.groups[0].wkc_ok
        during = drop.frames[before:]
        assert _datagrams(during, Command.FPRD, STATUS) == 0
        assert a.mbx.stats.status_polls + b.mbx.stats.status_polls == polls
        assert a.mbx.stats.cyclic_status > 0 and b.mbx.stats.cyclic_status > 0
        assert a.mbx.stats.early_replies < a.mbx.stats.received  # the replies were late
    finally:
        runner.stop()
    # without cyclic exchange the same transfer polls with frames again
    before = len(drop.frames)
    assert a.sdo_read(0x1018, 1, "uint32") == 0x00504543
    assert _datagrams(drop.frames[before:], Command.FPRD, STATUS) > 0


TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""


def test_coe_io_sdos_and_emergency_while_cyclic_runs(tmp_path: Path) -> None:
    from pyethercat.sim.coe import coe_server
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "coe.toml"
    path.write_text(TOPOLOGY)
    seg = load_topology(path).build()
    frames: list[bytes] = []
    # Work on the simulator runs between frames (the cycle thread drives it too).
    chores: list[Callable[[], None]] = []

    def respond(frame: bytes) -> bytes | None:
        while chores:
            chores.pop()()
        frames.append(frame)
        return seg.process(frame)

    m = Master(PairLink.responder_link(respond))
    m.scan()
    runner = m.start(cycle=0.001)
    try:
        io = m.slaves[0]
        img = m.images["main"]
        assert img.group.status_bytes == 2
        before = len(frames)
        assert io.sdo_read(0x2000) == bytes(i & 0xFF for i in range(4096))
        blob = bytes((7 * i) & 0xFF for i in range(4096))
        io.sdo_write(0x2000, 0, blob)
        assert io.sdo_read(0x2000) == blob
        assert io.sdo_read(0x1018, 0, complete_access=True)[2:6] == (0x00504543).to_bytes(4, "little")
        # an emergency: the status byte in the image says "full", the poll needs no frame
        coe = coe_server(seg.slaves[0].spec.app)
        chores.append(lambda: coe.emergency(0x8210, 0x10, b"\x01\x02\x03\x04\x05"))
        for _ in range(200):
            status = img.mailbox_status(0)
            if status is not None and status & reg.SM_STATUS_MAILBOX_FULL:
                break
            runner.join(0.005)
        assert m.poll_mailboxes() == 1
        event = m.emergencies.get_nowait()
        assert (event.position, event.error_code, event.error_register) == (0, 0x8210, 0x10)
        assert _datagrams(frames[before:], Command.FPRD, STATUS) == 0
        assert runner.groups[0].wkc_ok and runner.stats.wkc_errors == 0
    finally:
        runner.stop()


def test_runner_public_wait_and_group_status() -> None:
    """The API CyclicMailboxStatus uses: wait_exchanges and a read-only group status."""
    _seg, _apps, _drop, link = coe_segment(1)
    m = Master(link)
    m.coe_pdo_config = False
    m.scan()
    cfg = m.configure()
    name = cfg.groups[0].name
    at = cfg.slaves[0].mailbox_status_offset
    runner = m.start(cycle=0.001)
    try:
        before = runner.group_status(name)
        assert runner.wait_exchanges(name, 3, timeout=2.0)
        after = runner.group_status(name)
        assert after.exchanges >= before.exchanges + 3 and after.wkc_ok
        # the image view is read-only and holds SM1's status byte (mailbox empty: bit 3 clear)
        assert after.image.readonly
        assert not after.image[at] & reg.SM_STATUS_MAILBOX_FULL
        # from inside the loop thread the wait would wait for itself: refused at once
        seen: list[bool] = []
        runner.callback = lambda _c: seen.append(runner.wait_exchanges(name, 1, 1.0)) \
            if not seen else None
        assert runner.wait_exchanges(name, 2, timeout=2.0)
        assert seen == [False]
        runner.callback = None
        with pytest.raises(ConfigError, match="no such group"):
            runner.group_status("no such group")
    finally:
        m.stop()
    assert not runner.wait_exchanges(name, 1, timeout=0.5)  # stopped: no wait


def test_lost_cyclic_frames_cost_a_cycle_not_a_poll_frame() -> None:
    """A cyclic exchange gone wrong leaves the group's working counter off until the next one.

    A mailbox waiting for its status byte then waits one exchange more
    instead of polling with a frame of its own. Here, across segmented
    uploads with late replies, of every four cyclic frames one is lost and
    one comes back with working counter 0 (the slave did not answer it).
    """
    _seg, apps, drop, _link = coe_segment(1)
    cyclic = 0

    def lossy(frame: bytes) -> bytes | None:
        nonlocal cyclic
        reply = drop(frame)
        if reply is None or not any(d.command == Command.LRW
                                    for d in decode_frame(frame).datagrams):
            return reply
        cyclic += 1
        if cyclic % 4 == 0:
            return None
        if cyclic % 4 == 2:
            back = decode_frame(reply)
            return encode_frame([replace(d, wkc=0) if d.command == Command.LRW else d
                                 for d in back.datagrams], back.src, back.dst)
        return reply

    m = Master(PairLink.responder_link(lossy), timeout=0.002)
    m.coe_pdo_config = False
    m.scan()
    runner = m.start(cycle=0.001)
    try:
        apps[0].late = 3
        s = m.slaves[0]
        assert s.mbx is not None
        before = len(drop.frames)
        polls = s.mbx.stats.status_polls
        lost, bad = runner.stats.lost_frames, runner.stats.wkc_errors
        for _ in range(3):
            assert s.sdo_read(0x2001) == PATTERN
        # cyclic exchanges went wrong while it waited
        assert runner.stats.lost_frames - lost >= 10 and runner.stats.wkc_errors - bad >= 10
        assert s.mbx.stats.status_polls == polls
        assert _datagrams(drop.frames[before:], Command.FPRD, STATUS) == 0
    finally:
        runner.stop()


class _ScriptedRunner:
    """Just what CyclicMailboxStatus reads of a runner, with scripted verdicts."""

    def __init__(self, verdicts: list[bool]) -> None:
        from types import SimpleNamespace

        self.running = True
        self.config = SimpleNamespace(slaves={0: SimpleNamespace(group="g",
                                                                 mailbox_status_offset=1)})
        self.groups = [SimpleNamespace(name="g")]
        self.verdicts = verdicts
        self.exchanges = 0
        self.waits: list[int] = []
        self.under_way = True

    def exchanges_after_now(self) -> int:
        return 2 if self.under_way else 1

    def wait_exchanges(self, name: str, count: int, timeout: float) -> bool:
        self.waits.append(count)
        self.exchanges += count
        return True

    def group_status(self, name: str) -> object:
        from pyethercat.master.cyclic import GroupStatus

        ok = self.verdicts.pop(0)
        image = memoryview(bytes([0, reg.SM_STATUS_MAILBOX_FULL if ok else 0xFF]))
        return GroupStatus(name, self.exchanges, ok, image)


def test_cyclic_status_waits_out_a_bad_counter_then_gives_up() -> None:
    from pyethercat.master.mailboxes import CyclicMailboxStatus

    runner = _ScriptedRunner([False, False, True])
    source = CyclicMailboxStatus(lambda: runner, 0)  # type: ignore[arg-type, return-value]
    assert source(1.0) == reg.SM_STATUS_MAILBOX_FULL  # the byte of the good exchange
    assert runner.waits == [2, 1, 1]
    # a counter that stays off: a few more exchanges, then None (the mailbox polls)
    runner.verdicts = [False] * (CyclicMailboxStatus.RETRIES + 1)
    runner.waits.clear()
    assert source(1.0) is None
    assert runner.waits == [2] + [1] * CyclicMailboxStatus.RETRIES
    # between exchanges the next one began after the call: one is enough
    runner.under_way = False
    runner.verdicts = [True]
    runner.waits.clear()
    assert source(1.0) == reg.SM_STATUS_MAILBOX_FULL
    assert runner.waits == [1]


def _one_slave_cycling() -> tuple[Master, Any]:
    """One MiniCoe slave, cycling at 1 kHz (over the in-process pair link)."""
    _seg, _apps, _drop, link = coe_segment(1)
    m = Master(link)
    m.coe_pdo_config = False
    m.scan()
    m.configure()
    return m, m.start(cycle=0.001)


def test_an_exchange_is_under_way_from_its_first_send_to_its_end() -> None:
    """What ``exchanges_after_now`` reads: set while the loop's frames may be passing
    the slaves (seen from the in-flight hook, after the sends), clear between cycles."""
    _m, runner = _one_slave_cycling()
    try:
        seen: list[tuple[bool, int]] = []
        xchg = runner.xchg
        hook = xchg.in_flight

        def look() -> None:
            seen.append((xchg.under_way, runner.exchanges_after_now()))
            if hook is not None:
                hook()

        xchg.in_flight = look
        assert runner.wait_cycles(5, 5.0)
        xchg.in_flight = hook
        # while the frames are out, a waiter needs the exchange after this one
        assert seen and all(s == (True, 2) for s in seen), seen
    finally:
        runner.stop()
    assert not runner.xchg.under_way and runner.exchanges_after_now() == 1


def test_sdos_while_cycling_wait_one_exchange_and_read_no_stale_status() -> None:
    """Expedited and segmented uploads at 1 kHz: most status waits are for one
    exchange (the loop is between exchanges most of the time), and no status byte was
    stale: no fetch came back empty, no repeat request, no poll frame, no duplicate."""
    m, runner = _one_slave_cycling()
    waits = count_status_waits(runner)
    try:
        a = m.slaves[0]
        assert a.mbx is not None
        before, lost = replace(a.mbx.stats), lost_frames(m, runner)
        for _ in range(100):
            assert a.sdo_read(0x1018, 1, "uint32") == 0x00504543
        assert a.sdo_read(0x2001) == PATTERN
        assert_no_stale_status(before, a.mbx.stats, lost_frames(m, runner) - lost)
    finally:
        runner.stop()
    assert waits and waits.count(1) > waits.count(2), waits
