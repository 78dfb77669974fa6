"""Slow slaves and late replies: a request is executed once, a late reply is not an answer.

A slave may take longer than half the mailbox timeout to answer (under load,
or a real one writing flash for 0x1010 "store parameters"). Once the master
had one answer from the mailbox, the counters are in sync and such a request
must not be sent again: the slave would execute it twice and answer twice,
and the second answer would be taken by the next SDO. The simulated slave
here (builtin:coe-io) holds its replies back until the master's virtual clock
reaches a set time; it counts the requests it served.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.coe import DEFAULT_SDO_TIMEOUT
from pyethercat.master.master import Master
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.coe import SdoInitiateUploadRequest
from pyethercat.wire.mailbox.header import MailboxType

TOPOLOGY = '[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n'
VENDOR, PRODUCT = 0x00504543, 0x00050001


class SlowSlave:
    """The segment's responder; the slave's replies wait until ``ready_ns`` (virtual time).

    Stands in for the slave's PDI: ``post_mailbox`` refuses while the slave
    is "still working", so the reply stays queued in the slave; every frame
    gives the slave a chance to post it.
    """

    def __init__(self, segment: Any, clock: VirtualClock) -> None:
        self.segment = segment
        self.clock = clock
        self.engine = segment.slaves[0].spec.app.mailbox
        self.pdi = self.engine.pdi
        self.engine.pdi = self
        self.ready_ns = 0
        self.frames: list[bytes] = []

    def post_mailbox(self, data: bytes) -> bool:
        if self.clock.now_ns() < self.ready_ns:
            return False
        return bool(self.pdi.post_mailbox(data))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.pdi, name)

    def slow_for(self, seconds: float) -> None:
        self.ready_ns = self.clock.now_ns() + int(seconds * 1e9)

    def __call__(self, frame: bytes) -> bytes | None:
        self.frames.append(bytes(frame))
        reply = self.segment.process(frame)
        self.engine.flush()  # the slave's firmware loop
        return reply  # type: ignore[no-any-return]

    def sm0_writes(self, offset: int) -> int:
        return sum(1 for f in self.frames for d in decode_frame(f).datagrams
                   if d.command == Command.FPWR and d.ado == offset and d.wkc == 0)


@pytest.fixture
def segment(tmp_path: Path) -> Any:
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "io.toml"
    path.write_text(TOPOLOGY)
    return load_topology(path).build()


def master_on(segment: Any) -> tuple[Master, SlowSlave]:
    clock = VirtualClock()
    slow = SlowSlave(segment, clock)
    m = Master(PairLink.responder_link(slow), clock=clock)
    m.scan()
    m.set_state("PREOP")
    return m, slow


def test_a_slow_slave_in_sync_is_asked_once_and_its_late_reply_returned(segment: Any) -> None:
    m, slow = master_on(segment)
    s = m.slaves[0]
    box = s.mbx
    assert box is not None
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert box.synced
    served, writes = slow.engine.requests, slow.sm0_writes(box.rx_offset)
    # answers after 70 % of the timeout: later than the half at which a
    # take-over would send again, in time for the request itself
    slow.slow_for(0.7 * DEFAULT_SDO_TIMEOUT)
    assert s.sdo_read(0x1018, 2, "uint32") == PRODUCT  # type: ignore[attr-defined]
    assert slow.engine.requests - served == 1
    assert slow.sm0_writes(box.rx_offset) - writes == 1
    assert box.stats.resent == 0
    # nothing is left over for the next request
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert box.stats.stale == 0


def test_a_stray_reply_in_sm1_is_dropped_and_the_next_sdo_gets_its_own(segment: Any) -> None:
    m, slow = master_on(segment)
    s = m.slaves[0]
    box = s.mbx
    assert box is not None
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    # A request whose answer nobody reads: it waits in SM1.
    box.send(MailboxType.COE, SdoInitiateUploadRequest(0x1018, 2).encode(), fetch=False)
    slow.engine.flush()
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert box.stats.stale == 1
    assert s.sdo_read(0x1018, 2, "uint32") == PRODUCT  # type: ignore[attr-defined]


def test_a_slow_first_reply_after_take_over_does_not_answer_the_next_sdo(segment: Any) -> None:
    m, slow = master_on(segment)
    s = m.slaves[0]
    box = s.mbx
    assert box is not None and not box.synced
    served = slow.engine.requests
    # Before the first answer the counter may be another master's: sent again
    # at half the timeout, so the slow slave executes the read twice ...
    slow.slow_for(0.7 * DEFAULT_SDO_TIMEOUT)
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert box.stats.resent == 1 and slow.engine.requests - served == 2
    # ... and its second answer (0x1018:01) must not pass for the next one.
    assert s.sdo_read(0x1018, 2, "uint32") == PRODUCT  # type: ignore[attr-defined]
    assert box.stats.stale == 1
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]


# --- SDO information in fragments, each late --------------------------------------------------


class PacedSlave(SlowSlave):
    """Posts each message ``gap`` seconds (virtual time) after the one before."""

    def __init__(self, segment: Any, clock: VirtualClock, gap: float) -> None:
        super().__init__(segment, clock)
        self.gap_ns = int(gap * 1e9)

    def post_mailbox(self, data: bytes) -> bool:
        if not super().post_mailbox(data):
            return False
        self.ready_ns = self.clock.now_ns() + self.gap_ns
        return True


def paced_drive(gap: float) -> tuple[Master, PacedSlave]:
    """The seed 002 drive (73 objects: its OD list takes two 128-byte fragments)."""
    from pyethercat.sim.topology import parse_topology

    segment = parse_topology('[[slave]]\nname = "drive"\ndevice = "builtin:seed002-drive"\n'
                             ).build()
    clock = VirtualClock()
    paced = PacedSlave(segment, clock, 0.0)
    m = Master(PairLink.responder_link(paced), clock=clock)
    m.scan()
    m.set_state("PREOP")
    paced.gap_ns = int(gap * 1e9)
    return m, paced


def test_each_sdo_information_fragment_gets_the_whole_timeout() -> None:
    # Each fragment comes 70 % of the timeout after the one before: the whole answer
    # takes longer than one timeout, each fragment is in time.
    m, paced = paced_drive(0.7 * DEFAULT_SDO_TIMEOUT)
    coe = m.slaves[0].coe
    assert coe is not None
    paced.slow_for(0.7 * DEFAULT_SDO_TIMEOUT)
    received = m.slaves[0].mbx.stats.received  # type: ignore[union-attr]
    indices = coe.od_list()
    assert len(indices) == 73 and 0x6040 in indices
    assert m.slaves[0].mbx.stats.received - received == 2  # type: ignore[union-attr]


def test_a_missing_sdo_information_fragment_says_which() -> None:
    from pyethercat.errors import TimeoutError as EcTimeoutError

    m, paced = paced_drive(1.5 * DEFAULT_SDO_TIMEOUT)
    coe = m.slaves[0].coe
    assert coe is not None
    with pytest.raises(EcTimeoutError) as info:
        coe.od_list()
    text = str(info.value)
    assert "SDO info OD list" in text and "fragment 2" in text
    assert f"within {DEFAULT_SDO_TIMEOUT:g} s" in text and "within 0 s" not in text


# --- a dictionary browse with an entry that never comes -----------------------------------------


def _deaf_to(segment: Any, slow: SlowSlave, deaf: Any) -> None:
    """The slave's CoE server leaves the requests ``deaf(message)`` takes unanswered."""
    from pyethercat.wire.mailbox.coe import decode_coe

    handlers = slow.engine.handlers
    serve = handlers[MailboxType.COE]

    def handle(header: Any, payload: bytes) -> None:
        if not deaf(decode_coe(payload)):
            serve(header, payload)

    handlers[MailboxType.COE] = handle


def _browse(m: Master) -> dict[int, Any]:
    from pyethercat.master.control import messages as msg
    from pyethercat.master.control.handlers import MasterContext, dispatch

    reply = dispatch(MasterContext(m, "test"), msg.SdoList(0))
    return {o.index: o for o in reply.objects}


def test_the_dictionary_browse_reports_an_entry_that_timed_out_and_goes_on(segment: Any
                                                                           ) -> None:
    from pyethercat.wire.mailbox.coe import SdoInfoGetEntryDescriptionRequest

    m, slow = master_on(segment)
    _deaf_to(segment, slow, lambda q: isinstance(q, SdoInfoGetEntryDescriptionRequest)
             and (q.index, q.subindex) == (0x1018, 2))
    objects = _browse(m)
    ident = objects[0x1018]
    assert ident.name == "Identity" and [e.subindex for e in ident.entries] == [0, 1, 3, 4]
    assert ident.error is not None and "0x1018:02 not described" in ident.error
    assert "within" in ident.error
    # the objects after it are described as usual
    later = [o for i, o in objects.items() if i > 0x1018]
    assert later and all(o.error is None and o.name and o.entries for o in later)
    # pyethercat sdos lists the object with the entries it has, and says which one is missing
    from pyethercat.cli.coe_cmds import format_sdos

    lines = format_sdos([ident])
    assert lines[0] == 'SDO 0x1018, "Identity"' and lines[1].startswith("  (0x1018:02 not")
    assert [line[:13] for line in lines[2:]] == [f"  0x1018:0{k}, " for k in (0, 1, 3, 4)]


def test_the_dictionary_browse_of_a_slave_that_went_silent_ends(segment: Any) -> None:
    from pyethercat.wire.mailbox.coe import (
        SdoInfoGetEntryDescriptionRequest,
        SdoInfoGetObjectDescriptionRequest,
    )

    m, slow = master_on(segment)
    box = m.slaves[0].mbx
    assert box is not None
    _deaf_to(segment, slow, lambda q: isinstance(
        q, SdoInfoGetEntryDescriptionRequest | SdoInfoGetObjectDescriptionRequest)
        and q.index >= 0x1018)
    objects = _browse(m)
    assert objects[0x1000].error is None and objects[0x1000].entries
    silent = [o for i, o in objects.items() if i >= 0x1018]
    assert len(silent) > 10
    # three requests went unanswered (each its own time-out), then the browse stopped
    # asking: every later object is listed as not described
    assert all(o.error and "within" in o.error for o in silent[:3])
    assert all(o.error == "not described: the slave stopped answering" for o in silent[3:])
