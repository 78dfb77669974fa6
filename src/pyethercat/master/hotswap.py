"""Hot swap: a slave that comes back (power-cycled, unplugged and plugged, replaced) is identified
and brought back to its place while the others keep exchanging.

:meth:`HotSwap.recover` is the cyclic runner's recovery (it runs in step
with the loop, ``master.stepping``: its requests ride in cyclic frames).
For each slave to bring back:

1. a slave that still answers at its station address only left its state:
   acknowledged and requested again;
2. otherwise the device at its ring position (auto-increment addressing:
   on a ring the frame passes the slaves in bus order, so positions hold
   when the ring is open too) is read: station address and alias
   (0x0010-0x0013, the alias as its EEPROM loaded it), then, with the slot's
   station address written, its identity from the SII (words 0x08-0x0F);
3. it is identified against the slot: by position, by alias when the slot
   has one (a device with another alias is not this slot's), by identity
   (vendor and product; another revision or serial number is another unit
   of the same device, ``"replaced"``). A device of another product is
   accepted only when its SII describes the same sync managers and process
   data as the slot's (``"another product"``), else it is refused and left
   in INIT (``"refused"``);
4. it is configured again as the slot was: station address, mailbox sync
   managers, CoE start-up commands (the transition hooks), process-data
   sync managers and FMMUs, distributed clocks (its system-time delay as
   measured at set-up, its offset from one reading of the reference's and
   its own system time, then the SYNC set-up), and walked up to the loop's
   target state.

Every outcome is a :class:`HotSwapEvent` (``events``, and ``log``).

Hot connect groups (:class:`HotConnectGroup`, ``Master.hot_connect``): a
named group of slaves that may be absent, identified as in ETG hot connect
by the alias of its first slave. A group present at the scan may go
(unplugged: its slaves are marked absent, their share of the working counter
not expected, ``present_ok``) and come back (its first slave must carry the
group's alias), when it is configured again as above.

A group absent at the scan waits. When a ring reading counts more slaves
than the scan found (``Diagnosis.present``), :meth:`HotSwap.update_groups`
connects it, in step with the loop like a recovery: the new devices must
sit behind every slave the scan found, in bus order (on a free port of the
last slave, or at the end of a line: the positions of the others do not
move), the first must carry a waiting group's alias and the group must be
complete; they get station addresses after the others', their SII is read,
their mailboxes made, and their process data becomes a process-data group
of its own named after the hot connect group, laid after the other groups
in the logical address space (the others' layout does not change); they
are brought up (mailbox, CoE start-up commands, sync managers, FMMUs), the
running loop exchanges the new group from the next cycle on, and they are
walked up to its target state. From then on the group goes and comes back
as one found at the scan. Devices that appear in front of configured slaves
are not taken (an event says so).

:meth:`HotSwap.groups` tells each group's presence (``pyethercat slaves``
prints it) and a change is an event too.
"""

from __future__ import annotations

import struct
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pyethercat.errors import ConfigError, EtherCATError, WorkingCounterError
from pyethercat.master import scan as scanning
from pyethercat.master import states
from pyethercat.master.slave_info import Identity
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.sii import SiiInfo, parse_sii
from pyethercat.wire.sii.model import WORD_VENDOR_ID

if TYPE_CHECKING:
    from pyethercat.master.clocks import DistributedClocks
    from pyethercat.master.mailboxes import MailboxService
    from pyethercat.master.process import ProcessData
    from pyethercat.master.ring import Diagnosis, RingService
    from pyethercat.master.scheduler import Scheduler
    from pyethercat.master.slave import Slave

__all__ = ["GroupPresence", "HotConnectGroup", "HotSwap", "HotSwapEvent", "HotSwapRefused"]


class HotSwapRefused(EtherCATError):
    """A device in a slave's place is not that slave's (another alias, other process data)."""

#: SII bytes read to identify a device: up to the end of the identity words (0x08-0x0F).
_IDENTITY_BYTES = 2 * (WORD_VENDOR_ID + 8)


@dataclass(frozen=True)
class HotSwapEvent:
    """A slave brought back (or refused).

    ``outcome``: ``"resumed"`` (it had only left its state), ``"same"`` (the
    same device came back), ``"replaced"`` (another unit of the same
    device), ``"another product"`` (with the same process data), or
    ``"refused"``; for hot connect groups ``"group absent"``, ``"group
    present"``, ``"group connected"`` (absent at the scan, configured when
    it appeared) or ``"group refused"``.
    """

    position: int
    name: str
    outcome: str
    found: Identity | None
    text: str
    time_ns: int


class HotSwap:
    """Brings slaves back to their place (see the module text)."""

    def __init__(self, scheduler: Scheduler, pd: ProcessData, dc: DistributedClocks,
                 slaves: Callable[[], list[Slave]], now_ns: Callable[[], int], *,
                 make_slave: Callable[[int, int], Slave] | None = None,
                 mailboxes: MailboxService | None = None,
                 ring: RingService | None = None) -> None:
        self.scheduler = scheduler
        self.pd = pd
        self.dc = dc
        self._slaves = slaves
        self.now_ns = now_ns
        #: What connecting a group absent at the scan needs: the master's slave handles,
        #: its mailboxes and its ring service (cabling learnt again).
        self._make_slave = make_slave
        self._mailboxes = mailboxes
        self._ring = ring
        self._connecting: threading.Thread | None = None
        self._group_refusal = ""
        self.events: deque[HotSwapEvent] = deque(maxlen=500)
        #: Where event texts go too (the cyclic loop's log while one runs).
        self.log: Callable[[str], None] = lambda _text: None
        self._lock = threading.Lock()
        self._groups: list[tuple[HotConnectGroup, tuple[int, ...]]] = []
        self._present: dict[str, bool] = {}
        #: What was refused last at each position (refused again: no new event).
        self._refused: dict[int, tuple[Identity | None, int]] = {}

    # -- hot connect groups ---------------------------------------------------------------

    def add_group(self, group: HotConnectGroup) -> GroupPresence:
        """Declare a hot connect group: learnt from the scanned slaves when its first slave
        (carrying the alias) is there, else waiting to be connected when it appears."""
        if group.size < 1:
            raise ConfigError(f"hot connect group {group.name!r}: size must be at least 1")
        if not 0 < group.alias <= 0xFFFF:
            raise ConfigError(f"hot connect group {group.name!r}: alias must be 1..0xFFFF, "
                              f"not {group.alias}")
        if any(g.name == group.name for g, _ in self._groups):
            raise ConfigError(f"hot connect group {group.name!r} is known already")
        if any(g.alias == group.alias for g, _ in self._groups):
            raise ConfigError(f"hot connect group {group.name!r}: another group has alias "
                              f"0x{group.alias:04X}")
        slaves = self._slaves()
        head = next((s for s in slaves if s.alias == group.alias), None)
        if head is None:
            cfg = self.pd.config
            if cfg is not None and any(g.name == group.name for g in cfg.groups):
                raise ConfigError(f"hot connect group {group.name!r}: a process-data group "
                                  "has that name (the group's data would go in one of its own)")
            # Absent at the scan: connected when it appears (see the module text).
            self._groups.append((group, ()))
            self._present[group.name] = False
            return GroupPresence(group.name, group.alias, (), False)
        positions = tuple(range(head.position, head.position + group.size))
        if positions[-1] >= len(slaves):
            raise ConfigError(f"hot connect group {group.name!r}: {group.size} slaves from "
                              f"position {head.position}, the segment has {len(slaves)}")
        taken = {p for _, ps in self._groups for p in ps}
        if taken & set(positions):
            raise ConfigError(f"hot connect group {group.name!r} overlaps another group")
        self._groups.append((group, positions))
        self._present[group.name] = True
        return GroupPresence(group.name, group.alias, positions, True)

    def groups(self, absent: frozenset[int] | set[int] = frozenset()) -> list[GroupPresence]:
        """Each hot connect group and whether it is present (none of its slaves gone; a group
        absent at the scan is absent until it was connected)."""
        return [GroupPresence(g.name, g.alias, ps, bool(ps) and not (set(ps) & set(absent)))
                for g, ps in self._groups]

    def update_groups(self, absent: frozenset[int] | set[int],
                      reading: Diagnosis | None = None) -> None:
        """Note groups that went or came (events), and connect a group absent at the scan
        when ``reading`` counts more slaves than the scan found; the ring watch calls this
        after each reading."""
        for presence in self.groups(absent):
            if presence.positions and self._present.get(presence.name) != presence.present:
                self._present[presence.name] = presence.present
                slaves = self._slaves()
                head = slaves[presence.positions[0]]
                self._event(head, "group present" if presence.present else "group absent",
                            None, presence.text)
        if reading is not None and reading.present is not None \
                and reading.present > len(self._slaves()):
            self._start_connect()

    def _waiting(self) -> list[HotConnectGroup]:
        return [g for g, ps in self._groups if not ps]

    def _start_connect(self) -> None:
        """Connect waiting groups in step with the loop (one worker at a time)."""
        if not self._waiting() or (self._connecting is not None and self._connecting.is_alive()):
            return
        runner = self.pd.runner
        if runner is None or not runner.takes_new_groups or self._make_slave is None:
            self._refuse_once("new slaves are not taken: a group absent at the scan is "
                              "connected by a cyclic loop running in this process only")
            return

        def work() -> None:
            try:
                self.connect_groups()
            except EtherCATError as exc:
                # Tried again at the next reading that counts more slaves.
                self.log(f"hot connect: not done yet: {exc}")

        self._connecting = self.scheduler.stepper.run(work, name="ecat-hot-connect")

    def connect_groups(self) -> list[GroupPresence]:
        """Configure the waiting groups whose slaves appeared behind the scanned ones and add
        them to the running loop (see the module text); the groups connected."""
        sched = self.scheduler
        slaves = self._slaves()
        known = len(slaves)
        count = scanning.count_slaves(sched)
        if count <= known:
            return []
        replies = sched.transact([Datagram.positional(Command.APRD, p, reg.STATION_ADDRESS, 4)
                                  for p in range(known, count)])
        found = [struct.unpack_from("<HH", r.data) if r.wkc == 1 else (0, 0) for r in replies]
        stations = {s.station_address for s in slaves}
        moved = next((known + i for i, (st, _) in enumerate(found) if st in stations), None)
        if moved is not None:
            self._refuse_once(f"slaves appeared in front of configured ones (position "
                              f"{moved} answers as station 0x{found[moved - known][0]:04X}): "
                              "the positions of the others would move; not taken")
            return []
        done: list[GroupPresence] = []
        at = known
        while at < count:
            alias = found[at - known][1]
            group = next((g for g in self._waiting() if g.alias == alias), None)
            if group is None:
                self._refuse_once(f"the device at position {at} carries alias "
                                  f"0x{alias:04X}: no hot connect group waits for it")
                break
            if at + group.size > count:
                break  # not all its slaves are there yet
            done.append(self._connect(group, at, max(stations) + 1 + (at - known)))
            at += group.size
        return done

    def _connect(self, group: HotConnectGroup, first: int, station: int) -> GroupPresence:
        """Address, read, configure and bring up ``group``'s slaves at ``first``..."""
        assert self._make_slave is not None
        sched = self.scheduler
        positions = tuple(range(first, first + group.size))
        new_stations = [station + i for i in range(group.size)]
        if new_stations[-1] > 0xFFFF:
            raise ConfigError(f"hot connect group {group.name!r}: no station addresses left")
        replies = sched.transact([
            Datagram.positional(Command.APWR, p, reg.STATION_ADDRESS, struct.pack("<H", st))
            for p, st in zip(positions, new_stations, strict=True)])
        if any(r.wkc != 1 for r in replies):
            raise WorkingCounterError(f"hot connect group {group.name!r}: station addresses "
                                      "not taken", 1, 0)
        # The scan's start-up defaults, for these slaves only (reset_slaves broadcasts them).
        sched.transact([d for st in new_stations for d in (
            Datagram.device(Command.FPWR, st, reg.DL_CONTROL_ALIAS, b"\x00"),
            Datagram.device(Command.FPWR, st, reg.AL_CONTROL,
                            struct.pack("<H", AlState.INIT | reg.AL_ERROR_FLAG)),
            Datagram.device(Command.FPWR, st, reg.ECAT_EVENT_MASK,
                            struct.pack("<H", reg.EcatEvent.DL_STATUS | reg.EcatEvent.AL_STATUS)))])
        for st in new_stations:
            scanning.take_sii_ownership(sched, st)
        new = [self._make_slave(p, st) for p, st in zip(positions, new_stations, strict=True)]
        scanning.read_esc_info(sched, new)
        images = scanning.read_sii_batch(sched, [scanning.SiiAccess.of(s) for s in new])
        for s, img in zip(new, images, strict=True):
            if isinstance(img, EtherCATError):
                raise img
            scanning.apply_sii(s, img)
            s.name = s.name or "?"
        slaves = self._slaves()
        slaves.extend(new)  # the master's list: every service sees them from now on
        scanning.build_topology(slaves)
        if self._ring is not None:
            self._ring.learn()
        if self._mailboxes is not None:
            self._mailboxes.add(new)
        self.pd.add_group(group.name, new)
        runner = self.pd.runner
        target = runner.target if runner is not None else AlState.OP
        self.pd.bring_up(new, 5.0)
        if runner is not None:
            runner.add_group(group.name, new)
        self.pd.transitions.set_state(new, target, 5.0)
        self._groups = [(g, positions if g is group else ps) for g, ps in self._groups]
        self._present[group.name] = True
        presence = GroupPresence(group.name, group.alias, positions, True)
        self._event(new[0], "group connected", None, presence.text + " (connected: "
                    + ", ".join(f"{s.position} {s.name}" for s in new) + ")")
        return presence

    def _refuse_once(self, why: str) -> None:
        """A group event that says why waiting groups are not connected (once per reason)."""
        if self._group_refusal == why:
            return
        self._group_refusal = why
        ev = HotSwapEvent(-1, "", "group refused", None, "hot connect: " + why, self.now_ns())
        with self._lock:
            self.events.append(ev)
        self.log(ev.text)

    def in_group(self, position: int) -> bool:
        """Whether ``position`` belongs to a hot connect group (it may be absent)."""
        return any(position in ps for _, ps in self._groups)

    # -- the runner's recovery --------------------------------------------------------------

    def recover(self, positions: list[int]) -> None:
        """Bring the slaves at ``positions`` back to the loop's target state."""
        runner = self.pd.runner
        target = runner.target if runner is not None else AlState.OP
        slaves = self._slaves()
        sched = self.scheduler
        # Positions name the right devices only when every slave is there.
        count = scanning.count_slaves(sched)
        if count < len(slaves):
            raise WorkingCounterError("segment still incomplete", len(slaves), count)
        full: list[Slave] = []
        resume: list[Slave] = []
        refused: list[Slave] = []
        for p in positions:
            s = slaves[p]
            reply = sched.transact_one(
                Datagram.device(Command.FPRD, s.station_address, reg.AL_STATUS, 2))
            if reply.wkc == 1:
                state = struct.unpack("<H", reply.data)[0] & reg.AL_STATE_MASK
                (resume if state >= AlState.SAFEOP else full).append(s)
                continue
            (full if self._bring_back(s) else refused).append(s)
        if full:
            self._restore_dc(full)
            self.pd.bring_up(full, 5.0)
            resume += full
        if resume:
            states.acknowledge_errors(sched, resume)
            self.pd.transitions.set_state(resume, target, 5.0)
        for s in resume:
            if s not in full:
                self._event(s, "resumed", None, f"slave {s.position} back in "
                                               f"{AlState(target).name}")
        if refused:
            # The loop tries again later (a device plugged in instead is looked at then).
            raise HotSwapRefused(f"slave{'s' if len(refused) > 1 else ''} "
                                 f"{', '.join(str(s.position) for s in refused)} refused: "
                                 "not the device of that place")

    def _bring_back(self, slave: Slave) -> bool:
        """Address, identify and accept the device at ``slave``'s position (False: refused)."""
        sched = self.scheduler
        p = slave.position
        got = sched.transact_one(Datagram.positional(Command.APRD, p, reg.STATION_ADDRESS, 4))
        if got.wkc != 1:
            raise WorkingCounterError(f"{slave.describe()}: no answer at its position", 1, got.wkc)
        # Station address and the alias its EEPROM loaded into 0x0012.
        station, alias = struct.unpack_from("<HH", got.data)
        others = {s.station_address for s in self._slaves() if s is not slave}
        if station in others:
            # Another configured slave answers at this position: the positions moved.
            raise WorkingCounterError(f"{slave.describe()}: slave 0x{station:04X} answers at "
                                      f"its position", 0, 1)
        w = sched.transact_one(Datagram.positional(
            Command.APWR, p, reg.STATION_ADDRESS, struct.pack("<H", slave.station_address)))
        if w.wkc != 1:
            raise WorkingCounterError(f"{slave.describe()}: station address not taken", 1, w.wkc)
        found = self._identity(slave)
        outcome = self._judge(slave, found, alias)
        text = f"slave {p} ({slave.name}): "
        if outcome == "refused":
            why = (f"alias 0x{alias:04X}, its place wants 0x{slave.alias:04X}"
                   if found is not None and self._same_kind(slave, found) else
                   f"{found} in the place of {slave.identity}")
            # Back to no address: it must not pass for the slot's device.
            sched.transact_one(Datagram.device(Command.FPWR, slave.station_address,
                                               reg.STATION_ADDRESS, b"\x00\x00"))
            if self._refused.get(p) != (found, alias):
                self._refused[p] = (found, alias)
                self._event(slave, outcome, found, text + f"not configured: {why}")
            return False
        self._refused.pop(p, None)
        words = {"same": "the same device is back", "replaced": "another unit took its place",
                 "another product": "another product with the same process data took its place"}
        self._event(slave, outcome, found, text + words[outcome] + f" ({found})")
        return True

    def _identity(self, slave: Slave) -> Identity | None:
        """The device's identity from its SII (None: unreadable)."""
        access = scanning.SiiAccess.of(slave)
        try:
            image = scanning.read_sii_batch(self.scheduler, [access], length=_IDENTITY_BYTES)[0]
        except EtherCATError:
            return None
        if isinstance(image, Exception) or len(image) < _IDENTITY_BYTES:
            return None
        vendor, product, revision, serial = struct.unpack_from("<IIII", image, 2 * WORD_VENDOR_ID)
        return Identity(vendor, product, revision, serial)

    @staticmethod
    def _same_kind(slave: Slave, found: Identity) -> bool:
        ident = slave.identity
        return (found.vendor_id, found.product_code) == (ident.vendor_id, ident.product_code)

    def _judge(self, slave: Slave, found: Identity | None, alias: int) -> str:
        if found is None:
            return "refused"
        if slave.alias and alias != slave.alias:
            return "refused"
        if self._same_kind(slave, found):
            ident = slave.identity
            same = (found.revision, found.serial) == (ident.revision, ident.serial)
            return "same" if same else "replaced"
        return "another product" if self._same_process_data(slave) else "refused"

    def _same_process_data(self, slave: Slave) -> bool:
        """Whether the device now at ``slave``'s place describes the slot's SMs and PDOs."""
        old = slave.sii
        if old is None:
            return False
        got = scanning.read_sii_batch(self.scheduler, [scanning.SiiAccess.of(slave)])[0]
        if isinstance(got, Exception):
            return False
        try:
            new = parse_sii(got)
        except (EtherCATError, ValueError):
            return False

        def layout(info: SiiInfo) -> tuple[object, ...]:
            sms = tuple((m.start, m.length, m.control, m.enable) for m in info.sync_managers)
            pdos = tuple((p.sync_manager, tuple((e.index, e.subindex, e.bit_length)
                                                for e in p.entries))
                         for p in (*info.rx_pdos, *info.tx_pdos))
            return sms, pdos

        return layout(new) == layout(old)

    # -- distributed clocks -------------------------------------------------------------------

    def _restore_dc(self, slaves: Sequence[Slave]) -> None:
        """Delay and offset of slaves that came back, as the set-up had them.

        The delay is the cabling's (the same place); the offset comes from one
        frame reading the reference's and the slave's system time (0x0910):
        the slave passes ``delay`` ns after the reference, so its system time
        is the reference's reading plus the delay.
        """
        report = self.dc.report
        ref = self.dc.reference
        if report is None or ref is None:
            return
        results = {r.position: r for r in report.slaves}
        todo = [(s, results[s.position]) for s in slaves
                if s.position in results and results[s.position].system_time
                and results[s.position].delay_ns is not None and s is not ref]
        if not todo:
            return
        dgs = [Datagram.device(Command.FPRD, ref.station_address, reg.DC_SYSTEM_TIME, 8)]
        dgs += [Datagram.device(Command.FPRD, s.station_address, reg.DC_SYSTEM_TIME, 8)
                for s, _ in todo]
        replies = self.scheduler.transact(dgs)
        if replies[0].wkc != 1:
            return
        ref_time = struct.unpack("<Q", replies[0].data)[0]
        writes = []
        for (s, r), rep in zip(todo, replies[1:], strict=True):
            if rep.wkc != 1 or r.delay_ns is None:
                continue
            bits = r.bits or 64
            mask = (1 << bits) - 1
            local = struct.unpack("<Q", rep.data)[0] & mask
            offset = (ref_time + r.delay_ns - local) & mask
            delay = struct.pack("<I", r.delay_ns & 0xFFFF_FFFF)
            if bits == 64:
                writes.append(Datagram.device(Command.FPWR, s.station_address,
                                              reg.DC_SYSTEM_TIME_OFFSET,
                                              struct.pack("<Q", offset) + delay))
            else:
                writes.append(Datagram.device(Command.FPWR, s.station_address,
                                              reg.DC_SYSTEM_TIME_OFFSET, struct.pack("<I", offset)))
                writes.append(Datagram.device(Command.FPWR, s.station_address,
                                              reg.DC_SYSTEM_TIME_DELAY, delay))
        if writes:
            self.scheduler.transact(writes)

    # -- events -------------------------------------------------------------------------------

    def _event(self, slave: Slave, outcome: str, found: Identity | None, text: str) -> None:
        ev = HotSwapEvent(slave.position, slave.name, outcome, found, text, self.now_ns())
        with self._lock:
            self.events.append(ev)
        self.log(text)



@dataclass(frozen=True)
class HotConnectGroup:
    """A named group of slaves that may be present or absent (ETG hot connect): the slave
    carrying ``alias`` and the ``size - 1`` slaves behind it in bus order."""

    name: str
    alias: int
    size: int = 1


@dataclass(frozen=True)
class GroupPresence:
    """Where a hot connect group is and whether all its slaves exchange now."""

    name: str
    alias: int
    positions: tuple[int, ...]
    present: bool

    @property
    def text(self) -> str:
        if not self.positions:
            return (f"hot connect group {self.name} (alias 0x{self.alias:04X}, not connected "
                    "yet): ABSENT")
        span = (f"{self.positions[0]}-{self.positions[-1]}" if len(self.positions) > 1
                else str(self.positions[0]))
        return (f"hot connect group {self.name} (alias 0x{self.alias:04X}, slaves {span}): "
                f"{'present' if self.present else 'ABSENT'}")
