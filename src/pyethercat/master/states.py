"""The EtherCAT state machine from the master's side (ETG.1000.6 section 5.3).

Requests go out as one AL control write per slave, all in the same frames;
polling reads AL status and AL status code (0x0130-0x0135) of every slave
still on its way with one multiple read per round. A slave that raises its
error flag instead of reaching the state fails the wait with
:class:`~pyethercat.errors.AlStatusError` (the AL status code and its name,
the state it stays in); slaves that are still on their way when the time is
up fail it with :class:`~pyethercat.errors.StateTimeoutError` naming each
stuck slave and where it is.

``set_state`` walks the standard path (INIT -> PREOP -> SAFEOP -> OP up;
straight down; BOOT only from INIT), each step for all slaves at once.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from pyethercat.errors import AlStatusError, StateTimeoutError, WorkingCounterError
from pyethercat.master.diag import multiple_read, multiple_write
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.wire.al import AlState, al_status_code_name, state_name, state_path
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.registers import (
    AL_CONTROL,
    AL_ERROR_FLAG,
    AL_STATE_MASK,
    AL_STATUS,
    SM_ACTIVATE_ENABLE,
    SM_CONTROL_MAILBOX_IN,
    SM_CONTROL_MAILBOX_OUT,
    SM_STRUCT,
    sm_address,
)
from pyethercat.wire.sii.model import SyncManagerType

__all__ = [
    "AlStatusReading",
    "read_al_status",
    "request_state",
    "acknowledge_errors",
    "wait_for_state",
    "request_and_read",
    "set_state",
    "state_path",
    "mailbox_sm_writes",
    "setup_mailboxes",
    "DEFAULT_STATE_TIMEOUT",
]

S = TypeVar("S", bound=SlaveInfo)

#: Seconds one transition may take before the wait gives up.
DEFAULT_STATE_TIMEOUT = 5.0
#: Longest pause between two polls (in the scheduler's time: virtual time does not wait).
DEFAULT_POLL_INTERVAL = 0.001
#: First pause between polls; it doubles up to the poll interval (most slaves, and the
#: simulator, answer a request within the frame that carries it or soon after).
FIRST_POLL_PAUSE = 50e-6
# AL status (2 bytes), reserved (2), AL status code (2): one read covers all.
_AL_READ_SIZE = 6


@dataclass(frozen=True, slots=True)
class AlStatusReading:
    """AL status of one slave as read: state bits, error flag, status code."""

    station_address: int
    state: int
    error: bool
    code: int
    answered: bool = True

    @property
    def state_name(self) -> str:
        return state_name(self.state | (AL_ERROR_FLAG if self.error else 0))

    @property
    def code_name(self) -> str:
        return al_status_code_name(self.code)


def _apply(slave: SlaveInfo, r: AlStatusReading) -> None:
    if not r.answered:
        return
    try:
        slave.al_state = AlState(r.state)
    except ValueError:
        slave.al_state = AlState.NONE
    slave.al_error = r.error
    slave.al_status_code = r.code if r.error else 0


def read_al_status(scheduler: Scheduler, slaves: Sequence[SlaveInfo]) -> list[AlStatusReading]:
    """AL status and code of every slave in one multiple read; updates the slaves."""
    results = multiple_read(scheduler, [s.station_address for s in slaves], AL_STATUS,
                            _AL_READ_SIZE)
    out: list[AlStatusReading] = []
    for slave, res in zip(slaves, results, strict=True):
        status, _reserved, code = struct.unpack("<HHH", res.data)
        reading = AlStatusReading(res.station_address, status & AL_STATE_MASK,
                                  bool(status & AL_ERROR_FLAG), code, res.ok)
        _apply(slave, reading)
        out.append(reading)
    return out


def request_state(scheduler: Scheduler, slaves: Sequence[SlaveInfo], state: AlState | int,
                  ack: bool = False) -> None:
    """Write the requested state (with the error-acknowledge bit if ``ack``) to every slave."""
    value = int(state) | (AL_ERROR_FLAG if ack else 0)
    wkcs = multiple_write(scheduler, [s.station_address for s in slaves], AL_CONTROL,
                          struct.pack("<H", value))
    missing = [s for s, w in zip(slaves, wkcs, strict=True) if w != 1]
    if missing:
        names = ", ".join(s.describe() for s in missing[:5])
        more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
        raise WorkingCounterError(
            f"AL control write ({state_name(int(state))}) not taken by {names}{more}", 1, 0)


def acknowledge_errors(scheduler: Scheduler, slaves: Sequence[S]) -> list[S]:
    """Acknowledge the error flag of every slave that shows one; returns those slaves.

    The acknowledge writes the state the slave is in with the error bit
    (what IgH does), so the slave stays where it is and clears the flag.
    A slave in device emulation (no firmware, :attr:`SlaveInfo.device_emulation`)
    copies the acknowledge bit into AL status and shows the flag until the
    state is written again without it: those slaves, and only those, get that
    second, plain write (a firmware slave could read AL control after it and
    see a request without acknowledge while still in error).
    """
    readings = read_al_status(scheduler, slaves)
    flagged = [(s, r) for s, r in zip(slaves, readings, strict=True) if r.answered and r.error]
    if not flagged:
        return []
    _write_acks(scheduler, flagged)
    echo = [(s, r) for s, r in flagged if s.device_emulation]
    if echo:
        # A transaction of its own: the plain write must not overtake the acknowledge
        # (a lost frame is sent again, so two writes in one transaction may swap).
        multiple_write(scheduler, [s.station_address for s, _ in echo], AL_CONTROL,
                       [struct.pack("<H", r.state or int(AlState.INIT)) for _, r in echo])
    return [s for s, _ in flagged]


def _write_acks(scheduler: Scheduler, flagged: Sequence[tuple[SlaveInfo, AlStatusReading]]) -> None:
    """Write each flagged slave's current state with the acknowledge bit."""
    multiple_write(scheduler, [s.station_address for s, _ in flagged], AL_CONTROL,
                   [struct.pack("<H", (r.state or int(AlState.INIT)) | AL_ERROR_FLAG)
                    for _, r in flagged])


def _stuck_message(target: AlState | int, stuck: list[tuple[SlaveInfo, AlStatusReading | None]],
                   timeout: float) -> str:
    parts = []
    for slave, r in stuck[:8]:
        where = "no answer" if r is None or not r.answered else f"in {r.state_name}"
        parts.append(f"{slave.describe()} {where}")
    more = f" and {len(stuck) - 8} more" if len(stuck) > 8 else ""
    return (f"{len(stuck)} slave{'s' if len(stuck) != 1 else ''} did not reach "
            f"{state_name(int(target))} within {timeout:g} s: {'; '.join(parts)}{more}")


def wait_for_state(scheduler: Scheduler, slaves: Sequence[SlaveInfo], state: AlState | int,
                   timeout: float = DEFAULT_STATE_TIMEOUT,
                   poll_interval: float = DEFAULT_POLL_INTERVAL,
                   clock: Callable[[], float] | None = None,
                   sleep: Callable[[float], None] | None = None,
                   first: Sequence[AlStatusReading] | None = None) -> None:
    """Poll until every slave is in ``state``.

    Polls back off from ``FIRST_POLL_PAUSE`` to ``poll_interval``. ``first``
    are readings of ``slaves`` taken already (the poll that rode along with
    the request). Raises :class:`AlStatusError` for the first slave that sets
    its error flag while not in ``state`` (the message names every such
    slave), and :class:`StateTimeoutError` naming the slaves still on their way.
    ``clock``/``sleep`` default to the scheduler's time (virtual time polls
    without sleeping for real).
    """
    clock = scheduler.now if clock is None else clock
    sleep = scheduler.sleep if sleep is None else sleep
    target = int(state)
    pending = list(slaves)
    last: dict[int, AlStatusReading] = {}
    deadline = clock() + timeout
    pause = min(FIRST_POLL_PAUSE, poll_interval)
    while pending:
        if first is not None:
            readings, first = list(first), None
        else:
            readings = read_al_status(scheduler, pending)
        refused: list[tuple[SlaveInfo, AlStatusReading]] = []
        still: list[SlaveInfo] = []
        for slave, r in zip(pending, readings, strict=True):
            last[slave.position] = r
            if r.answered and r.state == target and not r.error:
                continue
            if r.answered and r.error and r.state != target:
                refused.append((slave, r))
            else:
                still.append(slave)
        if refused:
            slave, r = refused[0]
            text = (f"{slave.describe()} refused {state_name(target)}, "
                    f"stays in {r.state_name}")
            if len(refused) > 1:
                others = ", ".join(f"slave {s.position} 0x{x.code:04X}" for s, x in refused[1:6])
                more = ", ..." if len(refused) > 6 else ""
                text += (f" ({len(refused) - 1} more refused: {others}{more})")
            raise AlStatusError.for_code(text, r.code, r.code_name)
        pending = still
        if not pending:
            return
        if clock() >= deadline:
            raise StateTimeoutError(_stuck_message(
                state, [(s, last.get(s.position)) for s in pending], timeout))
        if poll_interval > 0:
            sleep(pause)
            pause = min(2 * pause, poll_interval)


def request_and_read(scheduler: Scheduler, slaves: Sequence[SlaveInfo], state: AlState | int
                     ) -> list[AlStatusReading]:
    """Request ``state`` and read AL status back in the same frame(s); checks the writes.

    A slave that changes state at once (most do within microseconds of the
    frame passing, the simulator does in it) is seen there already, so a
    transition often costs one round trip.
    """
    value = struct.pack("<H", int(state))
    writes = scheduler.submit([Datagram.device(Command.FPWR, s.station_address, AL_CONTROL, value)
                               for s in slaves], flush=False)
    readings = read_al_status(scheduler, slaves)  # sends the queued writes first
    scheduler.wait(writes)
    missing = [s for s, w in zip(slaves, writes, strict=True)
               if w.error is not None or w.reply is None or w.reply.wkc != 1]
    if missing:
        for w in writes:
            if w.error is not None:
                raise w.error
        names = ", ".join(s.describe() for s in missing[:5])
        more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
        raise WorkingCounterError(
            f"AL control write ({state_name(int(state))}) not taken by {names}{more}", 1, 0)
    return readings


def mailbox_sm_writes(slave: SlaveInfo, boot: bool = False) -> list[tuple[int, bytes]]:
    """(register address, bytes) of SM0/SM1 for the slave's standard (or bootstrap) mailbox.

    Sizes and offsets come from the SII fixed area (words 0x14-0x1B), control
    bytes from the SII SyncM category when it describes SM0/SM1 as mailboxes
    (the usual 0x26/0x22 otherwise). Empty for slaves without a mailbox.
    """
    sii = slave.sii
    if sii is None:
        return []
    rx, tx = sii.mailbox_layout(boot)
    if not rx[1] or not tx[1]:
        return []
    controls = [SM_CONTROL_MAILBOX_OUT, SM_CONTROL_MAILBOX_IN]
    sms = sii.sync_managers
    for n, kind in enumerate((SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN)):
        if n < len(sms) and sms[n].sm_type == kind and sms[n].control:
            controls[n] = sms[n].control
    return [(sm_address(n), SM_STRUCT.pack(start, size, controls[n], 0, SM_ACTIVATE_ENABLE, 0))
            for n, (start, size) in enumerate((rx, tx))]


def setup_mailboxes(scheduler: Scheduler, step: AlState, slaves: Sequence[SlaveInfo]) -> None:
    """Before INIT -> PREOP/BOOT: write the mailbox sync managers of slaves still in INIT."""
    if step not in (AlState.PREOP, AlState.BOOT):
        return
    wanted = [(s, w) for s in slaves if (w := mailbox_sm_writes(s, boot=step == AlState.BOOT))]
    if not wanted:
        return  # no mailbox among them: nothing to write, nothing to read
    readings = read_al_status(scheduler, [s for s, _ in wanted])
    datagrams = []
    for (s, writes), r in zip(wanted, readings, strict=True):
        if r.answered and r.state == AlState.INIT:
            for address, data in writes:
                datagrams.append(Datagram.device(Command.FPWR, s.station_address, address, data))
    replies = scheduler.transact(datagrams)
    for d, reply in zip(datagrams, replies, strict=True):
        if reply.wkc != 1:
            raise WorkingCounterError(
                f"mailbox sync manager write to station 0x{d.adp:04X} at 0x{d.ado:04X}", 1,
                reply.wkc)


#: Called before each step with the state about to be requested and the slaves concerned.
PrepareStep = Callable[[Scheduler, AlState, Sequence[SlaveInfo]], None]


def set_state(scheduler: Scheduler, slaves: Sequence[SlaveInfo], state: AlState | int,
              timeout: float = DEFAULT_STATE_TIMEOUT, *, ack_errors: bool = True,
              poll_interval: float = DEFAULT_POLL_INTERVAL,
              clock: Callable[[], float] | None = None,
              sleep: Callable[[float], None] | None = None,
              prepare: PrepareStep | None = setup_mailboxes,
              finish: PrepareStep | None = None, wait: bool = True) -> None:
    """Bring every slave to ``state`` step by step (all slaves per step at once).

    ``timeout`` applies to each step. With ``ack_errors`` pending error
    flags are acknowledged first (a slave ignores requests while flagged).
    ``prepare`` runs before each request (default: mailbox sync managers
    for INIT -> PREOP/BOOT; pass None when the configuration does that);
    ``finish`` after the slaves of a step reached it (CoE start-up commands
    of INIT -> PREOP run there: the mailbox works only from PRE-OP on).
    Without ``wait`` the last step is requested and not waited for (nor
    finished): what IgH's ``ethercat states`` does.
    """
    target = AlState(int(state))
    if not slaves:
        return
    readings = read_al_status(scheduler, slaves)
    if ack_errors:
        # What acknowledge_errors does, without reading the states a second time. A
        # slave in device emulation needs no plain write after it here: every flagged
        # slave gets a plain request below (flagged ones do not count as there).
        flagged = [(s, r) for s, r in zip(slaves, readings, strict=True) if r.answered and r.error]
        if flagged:
            _write_acks(scheduler, flagged)
    # Group slaves by the path they need; run the steps in lockstep.
    paths = {s.position: state_path(r.state if r.answered else AlState.INIT, target)
             for s, r in zip(slaves, readings, strict=True)}
    # Slaves already there without an error flag need no request (hooks still run).
    there = {s.position for s, r in zip(slaves, readings, strict=True)
             if r.answered and r.state == target and not r.error}
    steps = max(len(p) for p in paths.values())
    for n in range(steps):
        # Slaves with shorter paths sit at their target while others catch up.
        by_state: dict[AlState, list[SlaveInfo]] = {}
        for s in slaves:
            p = paths[s.position]
            step = p[n - (steps - len(p))] if n >= steps - len(p) else None
            if step is not None:
                by_state.setdefault(step, []).append(s)
        for step, group in by_state.items():
            if prepare is not None:
                prepare(scheduler, step, group)
        for step, group in by_state.items():
            todo = [s for s in group if s.position not in there]
            if todo and not wait and n == steps - 1:
                request_state(scheduler, todo, step)
            elif todo:
                first = request_and_read(scheduler, todo, step)
                wait_for_state(scheduler, todo, step, timeout, poll_interval, clock, sleep,
                               first=first)
        if not wait and n == steps - 1:
            break
        if finish is not None:
            for step, group in by_state.items():
                finish(scheduler, step, group)
