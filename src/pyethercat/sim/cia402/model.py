"""A CiA 402 servo drive as a device model: when it computes, how it synchronises, how it fails.

:class:`Cia402Model` runs the drive cycle (``sim.cia402.engine``) for all
instances of a kind:

- **synchronisation** (0x1C32/0x1C33, ETG.1020 section 14): in *DC mode* the
  drive samples its outputs on SYNC0, so the cycle runs once per SYNC0 pulse
  on whatever output buffer arrived before it; a pulse with no new buffer
  since the previous one is an *SM event missed* (0x1C32:0B; an output frame
  that arrives after SYNC0 misses its cycle). In *SM mode* (or free run) the
  cycle runs on every complete output buffer. DC mode is chosen when the
  master sets 0x1C32:01 to 2 or 3, or - when it does not write it, as SOEM
  does not - when SYNC0 is running at PRE-OP -> SAFE-OP (Beckhoff's slave
  stack decides the same way);
- **EtherCAT errors as the C-series drive's EtherCAT manual names them
  (its table "Fehlermeldungen")**: SM2/SM3 length
  wrong (62-3/62-4, the ESC refuses SAFE-OP with 0x001D/0x001E), sync
  unstable (62-5: SYNC0 stopped, or SM events missed until the sync error
  counter reaches 0x10F1:02; OP falls back to SAFE-OP+ERR with 0x002C /
  0x001A), no DC found although set for DC (63-3: SAFE-OP refused with
  0x0030, OP with 0x002D); without DC settings and without SYNC0 the drive
  synchronises on the frames and only warns (statusword bit 7), as the
  manual's warning 63-3 says; EtherCAT leaving OP while the drive is enabled
  (62-0, 0x7500);
- each error sends an emergency with its code (``wire.cia402.DriveErrorCode``),
  sets 0x603F, the error register 0x1001 and the history 0x1003, and takes
  the drive to Fault (through Fault reaction active when it was enabled); a
  fault reset clears 0x603F/0x1001 and sends the "error reset" emergency
  (code 0).

Emergency data (5 bytes): the manual's error number as two bytes (62, 3 for
"62-3"; 0, 0 for profile errors it does not number), then three bytes of
detail (the SM and its expected length; the following error; the switch).
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cia402.engine import DriveEngine
from pyethercat.sim.cia402.keys import all_of, any_of
from pyethercat.sim.coe import coe_server
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire import registers as R
from pyethercat.wire.al import PENDING, AlState, AlStatusCode
from pyethercat.wire.cia402 import DriveErrorCode, DriveState
from pyethercat.wire.mailbox.coe import ErrorRegister
from pyethercat.wire.mailbox.objects import Cia402Object, StandardObject, SyncMode, SyncSub
from pyethercat.wire.sii import SiiInfo

__all__ = ["Cia402Model", "DriveApp"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
_O = Cia402Object
_STD = StandardObject
_ERROR_SETTINGS = int(StandardObject.ERROR_SETTINGS)
S = DriveState
#: How long a SAFE-OP -> OP request waits for the first SYNC0 pulse (ns).
SYNC_WAIT_NS = 1_000_000_000
#: SAFE-OP -> OP: SYNC0 counts as running when a pulse came within two cycles, at least 1 ms
#: (the watchdog time of Beckhoff's slave stack).
_WATCHDOG_MIN_NS = 1_000_000
_DC_MODES = (int(SyncMode.DC_SYNC0), int(SyncMode.DC_SYNC1))
_SAFEOP, _OP = int(AlState.SAFEOP), int(AlState.OP)
_SYNC0_ON = int(R.DcActivation.CYCLIC | R.DcActivation.SYNC0)
_PROFILE_ERRORS = (int(DriveErrorCode.FOLLOWING_ERROR), int(DriveErrorCode.REFERENCE_LIMIT))
#: Statusword bits 4 (voltage enabled) and 9 (remote): the drive has its DC link and
#: takes its commands from EtherCAT.
_VOLTAGE_REMOTE = 0x0210


class DriveApp(MailboxDevice):
    """The per-slave side of a drive: AL transition checks and AL errors go to its model."""

    def __init__(self, model: Cia402Model, instance: int) -> None:
        super().__init__()
        self.model = model
        self.instance = instance
        #: Segment time of the first SAFE-OP -> OP check still waiting for SYNC0 (-1: none).
        self.waiting_since = -1

    def check_transition(self, current: AlState, requested: AlState) -> int:
        # the drive's own sync checks first: they raise its errors (emergency, fault)
        code = self.model.check_sync(self.instance, self, current, requested)
        if code:
            return code
        return super().check_transition(current, requested)

    def on_al_error(self, state: AlState, code: int) -> None:
        self.model.al_error(self.instance, self, state, code)

    def sync0_running(self) -> tuple[bool, int]:
        """(cyclic unit with SYNC0 on in 0x0981, SYNC0 cycle 0x09A0 in ns)."""
        if self.pdi is None:
            return False, 0
        act = self.pdi.read(R.DC_ACTIVATION, 1)[0]
        cycle = int.from_bytes(self.pdi.read(R.DC_SYNC0_CYCLE, 4), "little")
        return bool(act & R.DcActivation.CYCLIC and act & R.DcActivation.SYNC0), cycle


class Cia402Model(DriveEngine):
    """A CiA 402 drive kind (see the module docstring)."""

    output_events = True
    sync_events = True

    def __init__(self, dictionary: Callable[[SiiInfo, MailboxDevice], SimObjectDictionary], *,
                 details: int, capacity_out: int = 128, capacity_in: int = 128) -> None:
        super().__init__(dictionary, details=details, capacity_out=capacity_out,
                         capacity_in=capacity_in)
        arr = self.array
        self.al_state = arr("al_state", np.int8, int(AlState.INIT))
        #: Samples its outputs on SYNC0 (decided at PRE-OP -> SAFE-OP).
        self.sync_dc = arr("sync_dc", bool, False)
        #: The master wrote 0x1C32:01 since INIT.
        self.user_sync = arr("user_sync", bool, False)
        #: A complete output buffer arrived since the last SYNC0 pulse.
        self.fresh = arr("fresh", bool, False)
        #: Outputs flow (a buffer arrived since SAFE-OP).
        self.started = arr("started", bool, False)
        self.sync_cycle = arr("sync_cycle", np.int64, 0)
        self.last_sync_ns = arr("last_sync_ns", np.int64, -1)
        self.last_sync_sys = arr("last_sync_sys", np.int64, -1)
        self.last_tick_ns = arr("last_tick_ns", np.int64, -1)
        self.missed = arr("missed", np.int64, 0)
        self.sync_errors = arr("sync_errors", np.int64, 0)

    # --- instances --------------------------------------------------------------------------

    def new_app(self, instance: int) -> MailboxDevice:
        return DriveApp(self, instance)

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        instance, app = super().instance_app(info)
        od = coe_server(app).od
        sync = od.get(_STD.SM_OUTPUT_SYNC)
        entries = sync.entries

        def user_wrote(raw: bytes) -> None:
            self.user_sync[instance] = True

        entries[SyncSub.SYNC_MODE].on_write = user_wrote
        entries[SyncSub.CYCLE_TIME].on_read = lambda: self._cycle_time_now(instance)
        if SyncSub.SM_EVENT_MISSED in entries:
            entries[SyncSub.SM_EVENT_MISSED].on_read = lambda: struct.pack(
                "<H", int(self.missed[instance]) & 0xFFFF)
        if SyncSub.SYNC_ERROR in entries:
            entries[SyncSub.SYNC_ERROR].on_read = lambda: bytes([int(self._sync_error(instance))])
        if SyncSub.SYNC0_CYCLE_TIME in entries:
            entries[SyncSub.SYNC0_CYCLE_TIME].on_read = lambda: struct.pack(
                "<I", int(self.sync_cycle[instance]) & 0xFFFFFFFF)
        inputs = od.find(_STD.SM_INPUT_SYNC)
        if inputs is not None:
            # 0x1C33:02/0A show the cycle 0x1C32 does (Beckhoff SSC StartInputHandler sets
            # the cycle time of both parameter records from the SYNC0 cycle)
            for sub in (SyncSub.CYCLE_TIME, SyncSub.SYNC0_CYCLE_TIME):
                if sub in inputs.entries and sub in entries:
                    inputs.entries[sub].on_read = entries[sub].on_read
        hist = od.find(_STD.ERROR_HISTORY)
        if hist is not None:
            def clear(raw: bytes) -> None:
                for n, e in hist.entries.items():
                    if n:
                        e.raw[:] = bytes(len(e.raw))
            hist.entries[0].on_write = clear
        return instance, app

    def _cycle_time_now(self, instance: int) -> bytes:
        if self.sync_dc[instance]:
            return struct.pack("<I", int(self.sync_cycle[instance]) & 0xFFFFFFFF)
        return self._cycle_time(instance)

    def _sync_error(self, instance: int) -> bool:
        limit = int(self.field(_STD.ERROR_SETTINGS, 2)[instance])
        return bool(self.sync_errors[instance] >= max(limit, 1))

    def on_power_on(self, instance: int) -> None:
        self.unquiet()
        for name, (_dtype, fill) in self._arrays.items():
            if name != "layout_id":
                getattr(self, name)[instance] = fill
        self.reset_axis(instance)
        f = self.field
        f(_O.STATUSWORD, 0)[instance] = 0x0040 | _VOLTAGE_REMOTE  # switch on disabled
        for key in ((_O.ERROR_CODE, 0), (_O.MODES_OF_OPERATION_DISPLAY, 0),
                    (_O.POSITION_ACTUAL_VALUE, 0), (_O.VELOCITY_ACTUAL_VALUE, 0),
                    (_O.TORQUE_ACTUAL_VALUE, 0), (_O.FOLLOWING_ERROR_ACTUAL_VALUE, 0)):
            f(*key)[instance] = 0

    # --- events --------------------------------------------------------------------------------

    def on_outputs(self, instances: I64) -> None:
        self._unpack(instances)
        io = self.io
        if io is None:
            return
        now = io.now_ns()
        r = self.rows(instances)
        self.prev_out_ns[r] = self.last_out_ns[r]
        self.last_out_ns[r] = now
        active = self.al_state[instances] >= _SAFEOP
        self.started[instances] |= active
        dc = self.sync_dc[instances]
        if any_of(dc):
            d = instances[dc]
            self.fresh[d] = True
            # The SYNC0 watchdog: the simulated cyclic unit fires every pulse it has planned
            # (the segment fires the ones due before it processes a frame), so SYNC0 is
            # missing exactly when the unit is off. (Wall time would see the simulator's own
            # scheduling stalls as missing pulses.)
            act = io.memory.mem[self.slaves[d], R.DC_ACTIVATION]
            lost = (self.al_state[d] == _OP) & ((act & _SYNC0_ON) != _SYNC0_ON)
            if any_of(lost):
                for i in d[lost].tolist():
                    self._sync_lost(i, 2)
        sm = instances[~dc & active]
        if len(sm):
            last_tick = self.last_tick_ns[sm]
            dt = np.where(last_tick >= 0, (now - last_tick) * 1e-9, 0.0)
            self.last_tick_ns[sm] = now
            self._cycle(sm, dt)

    def on_sync0(self, instances: I64, time_ns: int) -> None:
        io = self.io
        if io is None:
            return
        now = io.now_ns()
        run = self.sync_dc[instances] & (self.al_state[instances] >= _SAFEOP)
        inst = instances if all_of(run) else instances[run]
        if not len(inst):
            self.last_sync_ns[instances] = now
            return
        cycle = np.maximum(self.sync_cycle[inst], 1)
        last = self.last_sync_sys[inst]
        fresh = self.fresh[inst]
        # The usual pulse: one cycle after the last, a frame came in between, nothing
        # missed so far: no event missed, no sync error (the general case below gives
        # the same with three times the array operations).
        if (all_of(time_ns - last == cycle) and all_of(fresh) and all_of(self.started[inst])
                and not np.count_nonzero(self.sync_errors[inst])):
            self.last_sync_sys[inst] = time_ns
            self.fresh[inst] = False
            self.last_sync_ns[instances] = now
            self.warn[inst] = False
            self._cycle(inst, cycle * 1e-9)
            return
        dt_ns = np.where(last >= 0, time_ns - last, cycle)
        dt_ns = np.where((dt_ns <= 0) | (dt_ns > 64 * cycle), cycle, dt_ns)
        self.last_sync_sys[inst] = time_ns
        # Pulses handled together had no frame between them (the segment fires the pulses
        # due before it processes a frame): all but the first missed their SM event, the
        # first too unless a frame came since the last pulse. When the segment itself did
        # not run for longer than three cycles (a simulator held up by its host), the
        # frames were held up with it: those pulses count as one.
        pulses = np.maximum(np.rint(dt_ns / cycle), 1).astype(np.int64)
        held_up = now - self.last_sync_ns[inst] > 3 * cycle
        pulses = np.where(held_up, 1, pulses)
        started = self.started[inst]
        missed = (pulses - fresh) * started
        self.fresh[inst] = False
        self.last_sync_ns[instances] = now
        self.missed[inst] += missed
        # the sync error counter: +3 per missed event, -1 per good one (Beckhoff slave stack)
        errors = np.maximum(self.sync_errors[inst] - fresh, 0) + 3 * missed
        self.sync_errors[inst] = errors
        self.warn[inst] = errors > 0
        limit = np.maximum(self.field(_ERROR_SETTINGS, 2)[inst].astype(np.int64), 1)
        self._cycle(inst, dt_ns * 1e-9)
        over = (errors >= limit) & (self.al_state[inst] == _OP)
        for i in inst[over].tolist():
            self._sync_lost(i, 1)

    def _cycle(self, inst: I64, dt: F64) -> None:
        """One drive cycle, its rare events, then the inputs."""
        hit, codes, details, resets = self.step(inst, dt)
        for i, code, detail in zip(hit.tolist(), codes.tolist(), details.tolist(), strict=True):
            self._report(i, code, _profile_data(code, detail))
        for i in resets.tolist():
            self._reset_report(i)
        self.publish(inst)

    def on_state_change(self, instance: int, old: AlState, new: AlState) -> None:
        self.unquiet()
        self.al_state[instance] = int(new)
        self.al_op[instance] = new == AlState.OP
        one = np.array([instance], np.int64)
        if old == AlState.OP and new != AlState.OP and self.state[instance] in (
                S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):
            app = self.apps[instance]
            code = 0
            if app.pdi is not None:
                code = int.from_bytes(app.pdi.read(R.AL_STATUS_CODE, 2), "little")
            self.raise_fault(instance, int(DriveErrorCode.COMMUNICATION),
                             bytes([62, 0]) + struct.pack("<H", code) + b"\x00")
        if new in (AlState.INIT, AlState.PREOP, AlState.BOOT):
            self.sync_dc[instance] = self.started[instance] = self.fresh[instance] = False
            self.last_sync_sys[instance] = self.last_tick_ns[instance] = -1
            self.sync_errors[instance] = 0
            app = self.apps[instance]
            if isinstance(app, DriveApp):
                app.waiting_since = -1
            if new == AlState.INIT:
                self.user_sync[instance] = False
        if new in (AlState.SAFEOP, AlState.OP) and old not in (AlState.SAFEOP, AlState.OP):
            self.last_out_ns[instance] = self.prev_out_ns[instance] = -1
            self.publish(one)

    # --- AL checks and errors (rare: per instance) --------------------------------------------

    def check_sync(self, instance: int, app: DriveApp, current: AlState, requested: AlState) -> int:
        """Synchronisation checks of PRE-OP -> SAFE-OP and SAFE-OP -> OP (module docstring)."""
        od = coe_server(app).od
        running, cycle = app.sync0_running()
        if current == AlState.PREOP and requested == AlState.SAFEOP:
            mode = int(od.value(_STD.SM_OUTPUT_SYNC, SyncSub.SYNC_MODE))
            if self.user_sync[instance] and mode in _DC_MODES:
                if not running:
                    self.raise_fault(instance, int(DriveErrorCode.SYNC_CONTROLLER), bytes([63, 3, 0, 0, 0]))
                    return int(AlStatusCode.INVALID_DC_SYNC_CONFIG)
                minimum = int(od.value(_STD.SM_OUTPUT_SYNC, SyncSub.MIN_CYCLE_TIME))
                if cycle and cycle < minimum:
                    return int(AlStatusCode.DC_INVALID_SYNC0_CYCLE_TIME)
                dc = True
            elif self.user_sync[instance]:
                dc = False
            else:
                # not set by the master: DC when SYNC0 runs, else on the frames with a warning
                dc = running
            self._choose_sync(instance, od, dc, cycle)
            return 0
        if (current == AlState.SAFEOP and requested == AlState.OP and not self.sync_dc[instance]
                and not self.user_sync[instance] and running):
            # SOEM requests SAFE-OP at the end of config_map, before dc_sync(): SYNC0 that
            # runs by now still makes the drive take its outputs on SYNC0
            self._choose_sync(instance, od, True, cycle)
        if current == AlState.SAFEOP and requested == AlState.OP and self.sync_dc[instance]:
            io = self.io
            now = io.now_ns() if io is not None else 0
            if not running:
                self.raise_fault(instance, int(DriveErrorCode.SYNC_CONTROLLER), bytes([63, 3, 0, 0, 0]))
                return int(AlStatusCode.NO_SYNC_ERROR)
            self.sync_cycle[instance] = cycle
            last = int(self.last_sync_ns[instance])
            if last >= 0 and now - last <= max(2 * cycle, _WATCHDOG_MIN_NS):
                app.waiting_since = -1
                self.sync_errors[instance] = 0
                return 0
            if app.waiting_since < 0:
                app.waiting_since = now
            if now - app.waiting_since > SYNC_WAIT_NS:
                app.waiting_since = -1
                self.raise_fault(instance, int(DriveErrorCode.SYNC_CONTROLLER), bytes([63, 3, 0, 0, 0]))
                return int(AlStatusCode.NO_SYNC_ERROR)
            return PENDING
        return 0

    def _choose_sync(self, instance: int, od: SimObjectDictionary, dc: bool, cycle: int) -> None:
        """Take the outputs on SYNC0 (``dc``) or on the frames; 0x1C32/0x1C33:01 show it."""
        if not self.user_sync[instance]:
            od.set_value(_STD.SM_OUTPUT_SYNC, SyncSub.SYNC_MODE,
                         int(SyncMode.DC_SYNC0) if dc else int(SyncMode.SM_EVENT))
            self.warn[instance] = not dc  # the manual's warning 63-3: no hardware SYNC
        if _STD.SM_INPUT_SYNC in od:
            od.set_value(_STD.SM_INPUT_SYNC, SyncSub.SYNC_MODE,
                         int(SyncMode.DC_SYNC0) if dc else int(SyncMode.SM2_EVENT))
        self.sync_dc[instance] = dc
        self.sync_cycle[instance] = cycle if dc else 0

    def al_error(self, instance: int, app: DriveApp, state: AlState, code: int) -> None:
        """The ESC refused a transition or fell back: the drive's own error for SM lengths."""
        if code not in (AlStatusCode.INVALID_OUTPUT_CONFIG, AlStatusCode.INVALID_INPUT_CONFIG):
            return
        outputs = code == AlStatusCode.INVALID_OUTPUT_CONFIG
        sizes = app.process_data_sizes() or (0, 0)
        expected = sizes[0] if outputs else sizes[1]
        data = bytes([62, 3 if outputs else 4, 2 if outputs else 3]) + struct.pack("<H", expected & 0xFFFF)
        self.raise_fault(instance, int(DriveErrorCode.TRANSITION_PREOP_SAFEOP), data)

    def _sync_lost(self, instance: int, why: int) -> None:
        """Sync unstable (62-5): SYNC0 stopped (why 2) or SM events missed (why 1)."""
        missed = int(self.missed[instance]) & 0xFFFF
        self.raise_fault(instance, int(DriveErrorCode.SYNC_CONTROLLER),
                         bytes([62, 5, why]) + struct.pack("<H", missed))
        app = self.apps[instance]
        if app.pdi is not None:
            code = AlStatusCode.FATAL_SYNC_ERROR if why == 2 else AlStatusCode.SYNCHRONIZATION_ERROR
            app.pdi.set_al_error(int(code), AlState.SAFEOP)

    def raise_fault(self, instance: int, code: int, data: bytes) -> None:
        """An error outside the cycle: the drive goes to Fault (reaction first when enabled)."""
        self.unquiet()
        state = int(self.state[instance])
        if state not in (S.FAULT, S.FAULT_REACTION_ACTIVE):
            one = np.array([instance], np.int64)
            react = int(self.field(_O.FAULT_REACTION_OPTION_CODE, 0)[instance])
            powered = state in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE)
            if powered and react:
                self.state[instance] = int(S.FAULT_REACTION_ACTIVE)
                self.stop_opt[instance] = react
                self.stop_goal[instance] = int(S.FAULT)
            else:
                self.state[instance] = int(S.FAULT)
                self.stop_opt[instance] = -1
            bits = 0x0F if self.state[instance] == S.FAULT_REACTION_ACTIVE else 0x08
            self.field(_O.STATUSWORD, 0)[instance] = bits | _VOLTAGE_REMOTE | (
                0x80 if self.warn[instance] else 0)
            self._report(instance, code, data)
            self.publish(one)
            return
        self._report(instance, code, data)

    def _report(self, instance: int, code: int, data: bytes) -> None:
        """0x603F, 0x1001, 0x1003 and the emergency of one error."""
        self.field(_O.ERROR_CODE, 0)[instance] = code
        register = int(ErrorRegister.GENERIC) | (
            int(ErrorRegister.DEVICE_PROFILE) if code in _PROFILE_ERRORS
            else int(ErrorRegister.COMMUNICATION))
        server = coe_server(self.apps[instance])
        od = server.od
        hist = od.find(_STD.ERROR_HISTORY)
        if hist is not None:
            subs = sorted(n for n in hist.entries if n)
            for n in reversed(subs[1:]):
                hist.entries[n].raw[:] = hist.entries[n - 1].raw
            info = int.from_bytes(data[:2], "big")
            hist.entries[subs[0]].raw[:] = struct.pack("<I", code | info << 16)
            count = min(int(hist.entries[0].raw[0]) + 1, len(subs))
            hist.entries[0].raw[:] = bytes([count])
        server.emergency(code, register, data)

    def _reset_report(self, instance: int) -> None:
        """Fault reset: 0x1001 cleared, the "error reset" emergency (code 0)."""
        coe_server(self.apps[instance]).emergency(0, 0, bytes(5))


def _profile_data(code: int, detail: int) -> bytes:
    """Emergency data of an error the cycle found: no manual number, then the detail."""
    if code == DriveErrorCode.FOLLOWING_ERROR:
        value = max(-(1 << 23), min((1 << 23) - 1, detail))
        return bytes([0, 0]) + (value & 0xFFFFFF).to_bytes(3, "little")
    return bytes([0, 0, detail & 0xFF, 0, 0])
