"""The AL state machine of a simulated slave (AL control 0x0120, AL status 0x0130/0x0134).

:class:`AlStateMachine` carries out what a slave's firmware does when the
master writes AL control (IEC 61158-6-12 6.4.1.4, the state machine, as
gatorcat ``src/module/sim/ESM.zig`` implements it; SOES ``soes/esc.c``
``ESC_state``, ``ESC_checkmbx``, ``ESC_checkSM23`` for the checks a real
stack makes):

- requests are checked: legal transition, mailbox SMs as the SII says for
  INIT -> PREOP (and the boot mailbox for INIT -> BOOT), process-data SMs
  matching the PDO layout for PREOP -> SAFEOP and SAFEOP -> OP, then the
  device application's own check; a failed request sets the error flag and
  the status code and stays in (or falls back to) the state the table gives;
- the error flag blocks further requests until acknowledged (bit 4), or an
  INIT request;
- SAFEOP -> OP before any outputs were received stays pending without an
  error (as KickCAT's emulator does) and completes with the first complete
  output buffer; the device application may keep it pending longer
  (``check_transition`` returning :data:`PENDING`: a DC drive waits for its
  SYNC0 events, as Beckhoff's slave stack does) and is asked again with
  every output buffer;
- SM changes while running drop the slave back (mailbox: INIT + 0x0016,
  process data: PREOP + 0x001D/0x001E), as SOES re-checks on SM activation;
- devices whose SII asks for device emulation (0x0141 bit 0) follow AL
  control without checks, as ESCs without a microcontroller do (ESC
  datasheet section II, register 0x0141; KickCAT ``EmulatedESC.cc``).
"""

from __future__ import annotations

from pyethercat.sim.access import EscRegisters
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.eeprom import SiiInterface
from pyethercat.sim.esc_mailbox import MailboxSms
from pyethercat.wire import registers as R
from pyethercat.wire.al import PENDING, AlState, AlStatusCode

__all__ = ["PENDING", "AlStateMachine"]

_VALID_STATES = {int(s) for s in (AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP)}
_BELOW_SAFEOP = (AlState.INIT, AlState.PREOP, AlState.BOOT)
# AL control bits a chip in device emulation copies into AL status (state + error ack).
_AL_EMULATION_COPY = R.AL_STATE_MASK | R.AL_ERROR_FLAG
_SM_MODE_MAILBOX = int(R.SmMode.MAILBOX)
_SM_MODE_BUFFERED = int(R.SmMode.BUFFERED)


class AlStateMachine:
    """AL control handling of one ESC (see the module docstring)."""

    def __init__(self, regs: EscRegisters, sii: SiiInterface, mailbox: MailboxSms,
                 app: DeviceApp | None) -> None:
        self.regs = regs
        self.sii = sii
        self.mailbox = mailbox
        self.app = app
        #: A SAFEOP -> OP request waits for the first complete outputs.
        self._pending_op = False

    @property
    def pending_op(self) -> bool:
        return self._pending_op

    @pending_op.setter
    def pending_op(self, value: bool) -> None:
        if value != self._pending_op:
            self._pending_op = value
            self.regs.host.wait_for_outputs(self.regs.index, value)

    def state(self) -> AlState:
        return self.regs.al_state()

    # --- process-data layout ----------------------------------------------------------

    def process_data_bytes(self) -> tuple[int, int]:
        """(output, input) bytes of process data (the app's PDO mapping, else the SII's PDOs)."""
        sizes = self.app.process_data_sizes() if self.app is not None else None
        if sizes is not None:
            return sizes
        info = self.sii.info
        if info is None:
            return 0, 0
        return (info.output_bits + 7) // 8, (info.input_bits + 7) // 8

    # --- status -----------------------------------------------------------------------

    def set_status(self, state: int, error: bool, code: int | None) -> None:
        regs = self.regs
        old_value = regs.u16(R.AL_STATUS)
        value = (state & R.AL_STATE_MASK) | (R.AL_ERROR_FLAG if error else 0)
        regs.set_u16(R.AL_STATUS, value)
        if code is not None:
            regs.set_u16(R.AL_STATUS_CODE, code)
        if value != old_value:
            regs.set_ecat_event(int(R.EcatEvent.AL_STATUS))
        old_state = old_value & R.AL_STATE_MASK
        if old_state != state & R.AL_STATE_MASK:
            self._state_changed(AlState(old_state) if old_state in _VALID_STATES else AlState.INIT,
                                AlState(state & R.AL_STATE_MASK))

    def _state_changed(self, old: AlState, new: AlState) -> None:
        self.sii.state_changed(old, new)
        self.regs.host.al_state_changed(self.regs.index, old, new)
        if new in _BELOW_SAFEOP:
            self.pending_op = False
        if new == AlState.INIT and not self.regs.device_emulation:
            self.mailbox.stop()
        if self.app is not None:
            self.app.on_state_change(old, new)

    def fail(self, state: AlState, code: int) -> None:
        self.pending_op = False
        self.set_status(int(state), True, code)
        if self.app is not None:
            self.app.on_al_error(state, code)

    def set_error(self, code: int, state: AlState | None = None) -> None:
        """Error from the application: error flag, code, optionally a new state."""
        self.fail(self.state() if state is None else state, code)

    # --- AL control -------------------------------------------------------------------

    def control_written(self) -> None:
        regs = self.regs
        control = regs.u16(R.AL_CONTROL)
        regs.set_al_event(int(R.AlEvent.AL_CONTROL))
        requested = control & R.AL_STATE_MASK
        ack = bool(control & R.AL_ERROR_FLAG)
        status = regs.u16(R.AL_STATUS)
        current = status & R.AL_STATE_MASK
        error = bool(status & R.AL_ERROR_FLAG)
        if current not in _VALID_STATES:
            # Only the PDI writes AL status: a value naming no state (a raw
            # poke of the register) is taken as INIT, the state after reset.
            current = AlState.INIT
            self.set_status(current, error, None)
        if regs.device_emulation:
            # No firmware: AL status is a copy of AL control bits 4:0, the
            # acknowledge bit included (real EK1100/EL1004/EL28xx read 0x0011
            # after AL control 0x0011). An error the ESC set itself (watchdog)
            # stays, with its code, until the master acknowledges it.
            if requested in _VALID_STATES:
                copied = control & _AL_EMULATION_COPY
                own_error = error and not ack and bool(regs.u16(R.AL_STATUS_CODE))
                self.set_status(requested, bool(copied & R.AL_ERROR_FLAG) or own_error,
                                None if own_error else 0)
            return
        if error and not ack and requested != AlState.INIT:
            return  # a request without acknowledge is ignored while the error flag is set
        if error:
            # Acknowledge (explicit, or implicit by an INIT request) clears the error.
            self.set_status(current, False, 0)
        if requested == current and requested in _VALID_STATES:
            self.pending_op = False
            return
        if requested not in _VALID_STATES:
            fallback = AlState.SAFEOP if current == AlState.OP else AlState(current)
            self.fail(fallback, AlStatusCode.UNKNOWN_STATE)
            return
        code, fail_state = self.transition_check(AlState(current), AlState(requested))
        if code == PENDING:
            self.pending_op = True
            return
        if code:
            self.fail(fail_state, code)
            return
        self.set_status(requested, False, 0)
        if control & R.AL_ID_FLAG:
            regs.set_u16(R.AL_STATUS_CODE, regs.u16(R.STATION_ALIAS))
            regs.set_u16(R.AL_STATUS, regs.u16(R.AL_STATUS) | R.AL_ID_FLAG)

    def transition_check(self, cur: AlState, req: AlState) -> tuple[int, AlState]:
        """AL status code (0 = allowed, :data:`PENDING`) and the state to stay in on failure."""
        I, P, B, S, O = AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP  # noqa: E741
        invalid = AlStatusCode.INVALID_STATE_CHANGE
        if cur == B:
            return (0, B) if req == I else (invalid, B)
        if req == B:
            if cur != I:
                return invalid, (S if cur in (S, O) else cur)
            info = self.sii.info
            if info is None or not info.boot_rx_mailbox_size:
                return AlStatusCode.BOOTSTRAP_NOT_SUPPORTED, I
            if self.mailbox_mismatch(True):
                return AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT, I
            return self._app_check(cur, req, I)
        if cur == I:
            if req in (S, O):
                return invalid, I
            if self.mailbox_mismatch(False):
                return AlStatusCode.INVALID_MAILBOX_CONFIG, I
            return self._app_check(cur, req, I)
        if cur == P:
            if req == O:
                return invalid, P
            if req == S:
                code = self.process_data_mismatch()
                if code:
                    return code, P
            return self._app_check(cur, req, P)
        if cur == S and req == O:
            code = self.process_data_mismatch()
            if code:
                return code, S
            code, state = self._app_check(cur, req, S)
            if code:
                return code, state
            if self.process_data_bytes()[0] and not self.regs.host.has_outputs(self.regs.index):
                return PENDING, S
            return 0, S
        # Downward transitions are always allowed.
        return self._app_check(cur, req, cur)

    def _app_check(self, cur: AlState, req: AlState, stay: AlState) -> tuple[int, AlState]:
        if self.app is not None:
            code = self.app.check_transition(cur, req)
            if code:
                return code, stay
        return 0, stay

    def mailbox_mismatch(self, boot: bool) -> bool:
        """True when the mailbox SMs do not match the SII's (standard or boot) mailbox."""
        info = self.sii.info
        if info is None:
            return False
        (rx_off, rx_size), (tx_off, tx_size) = info.mailbox_layout(boot)
        if not rx_size and not tx_size:
            return False
        sm0, sm1 = self.regs.sm(0), self.regs.sm(1)
        ok0 = (sm0.enabled and sm0.start == rx_off and sm0.length == rx_size
               and sm0.mode == _SM_MODE_MAILBOX and sm0.ecat_writes)
        ok1 = (sm1.enabled and sm1.start == tx_off and sm1.length == tx_size
               and sm1.mode == _SM_MODE_MAILBOX and not sm1.ecat_writes)
        return not (ok0 and ok1)

    def process_data_mismatch(self) -> int:
        """0 when the process-data SMs match the PDO layout, else 0x001D/0x001E.

        With nothing assigned to a direction, its SM enabled with a length is
        a mismatch too: the slave stack compares the SM length with the size of
        the assigned PDOs whatever that size is (Beckhoff SSC ``CheckSmSettings``:
        an active SM2 needs ``SMLength == nPdOutputSize && nPdOutputSize != 0``;
        SOES ``ESC_checkSM23`` compares the lengths).
        """
        if self.sii.info is None:
            return 0
        regs = self.regs
        sm_count = regs.profile.sm_count
        out_len, in_len = self.process_data_bytes()
        out_sm, in_sm = self.sii.output_sm, self.sii.input_sm
        s = regs.sm(out_sm) if out_sm < sm_count else None
        if out_len:
            if s is None or not s.enabled or s.length != out_len or not s.ecat_writes or (
                    s.mode != _SM_MODE_BUFFERED):
                return AlStatusCode.INVALID_OUTPUT_CONFIG
        elif (s is not None and out_sm != in_sm and s.enabled and s.length and s.ecat_writes
              and s.mode == _SM_MODE_BUFFERED):
            return AlStatusCode.INVALID_OUTPUT_CONFIG
        s = regs.sm(in_sm) if in_sm < sm_count else None
        if in_len:
            if s is None or not s.enabled or s.length != in_len or s.ecat_writes or (
                    s.mode != _SM_MODE_BUFFERED):
                return AlStatusCode.INVALID_INPUT_CONFIG
        elif (s is not None and out_sm != in_sm and s.enabled and s.length and not s.ecat_writes
              and s.mode == _SM_MODE_BUFFERED):
            return AlStatusCode.INVALID_INPUT_CONFIG
        return 0

    def recheck_running_state(self) -> None:
        """Continuous checks: SM changes while running drop the slave back."""
        if self.regs.device_emulation:
            return
        state = self.state()
        if state in (AlState.PREOP, AlState.SAFEOP, AlState.OP) and self.mailbox_mismatch(False):
            self.fail(AlState.INIT, AlStatusCode.INVALID_MAILBOX_CONFIG)
            return
        if state in (AlState.SAFEOP, AlState.OP):
            code = self.process_data_mismatch()
            if code:
                self.fail(AlState.PREOP, code)

    # --- events from the segment -----------------------------------------------------

    def outputs_arrived(self) -> None:
        """A pending SAFEOP -> OP request completes with the first complete outputs.

        The application is asked again first: it may keep the request pending
        (a DC drive waits for its SYNC0 events) or refuse it now.
        """
        if self._pending_op and self.state() == AlState.SAFEOP:
            code = self.app.check_transition(AlState.SAFEOP, AlState.OP) if self.app else 0
            if code == PENDING:
                return
            if code:
                self.fail(AlState.SAFEOP, code)
                return
            self.pending_op = False
            self.set_status(int(AlState.OP), False, 0)

    def watchdog_expired(self) -> None:
        """Process-data watchdog ran out: OP falls back to SAFEOP + 0x001B."""
        regs = self.regs
        regs.set_u16(R.WATCHDOG_STATUS_PROCESS_DATA, 0)
        count = regs.u8(R.WATCHDOG_COUNTER_PROCESS_DATA)
        regs.row[R.WATCHDOG_COUNTER_PROCESS_DATA] = min(255, count + 1)
        regs.set_al_event(int(R.AlEvent.WATCHDOG))
        if self.state() == AlState.OP:
            self.fail(AlState.SAFEOP, AlStatusCode.SM_WATCHDOG)

    def power_on(self) -> None:
        self.pending_op = False
