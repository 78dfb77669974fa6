"""The PDI side of a simulated ESC and the device-application base class.

A device application (an IO terminal, a drive, an EoE endpoint) sees only its
own ESC through a :class:`Pdi`, as the firmware of a real slave sees its ESC
through the process data interface. It is called on ESC events: state
changes, completed output buffers (only when it asks for them), mailbox
writes, SYNC0 and power-on. It reports edges on the ESC's latch inputs
through :meth:`Pdi.latch_input` (a touch probe, a registration mark).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from pyethercat.wire.al import AlState

if TYPE_CHECKING:
    from pyethercat.sim.profiles import EscProfile

__all__ = [
    "DeviceApp",
    "Pdi",
    "PdiTarget",
]


class PdiTarget(Protocol):
    """What a :class:`Pdi` needs from the ESC model (implemented by ``sim.esc.Esc``)."""

    index: int
    profile: EscProfile

    def pdi_read(self, address: int, length: int) -> bytes: ...
    def pdi_write(self, address: int, data: bytes) -> None: ...
    def pdi_outputs(self) -> bytes: ...
    def pdi_set_inputs(self, data: bytes) -> None: ...
    def pdi_post_mailbox(self, data: bytes) -> bool: ...
    def pdi_sii_write(self, word: int, data: bytes) -> None: ...
    def pdi_latch_input(self, unit: int, rising: bool, t_ns: int | None = None) -> None: ...
    def al_state(self) -> AlState: ...
    def set_al_error(self, code: int, state: AlState | None = None) -> None: ...
    def now_ns(self) -> int: ...


class Pdi:
    """The PDI side of one ESC, handed to its device application.

    PDI accesses have no EtherCAT side effects (no working counter, no ECAT
    events); they do have the ESC-internal ones a real PDI access has
    (reading the last byte of a mailbox SM empties it, writing the last byte
    of SM1 posts a mailbox).
    """

    def __init__(self, target: PdiTarget) -> None:
        self._t = target

    @property
    def station(self) -> int:
        """Index of the slave in its segment."""
        return self._t.index

    @property
    def profile(self) -> EscProfile:
        return self._t.profile

    def read(self, address: int, length: int) -> bytes:
        """PDI read of ESC memory."""
        return self._t.pdi_read(address, length)

    def write(self, address: int, data: bytes) -> None:
        """PDI write of ESC memory."""
        self._t.pdi_write(address, data)

    def outputs(self) -> bytes:
        """Newest complete SM2 buffer (process data outputs); ``b""`` if none."""
        return self._t.pdi_outputs()

    def set_inputs(self, data: bytes) -> None:
        """Write the SM3 buffer (process data inputs); readable by EtherCAT at once."""
        self._t.pdi_set_inputs(data)

    def post_mailbox(self, data: bytes) -> bool:
        """Put a mailbox reply into SM1; False if SM1 is still full (or not enabled)."""
        return self._t.pdi_post_mailbox(data)

    def write_sii(self, word: int, data: bytes) -> None:
        """Rewrite SII EEPROM words, as firmware does after an update (PDI EEPROM access).

        The master sees the change when it next reads the EEPROM.
        """
        self._t.pdi_sii_write(word, data)

    def latch_input(self, unit: int, rising: bool, t_ns: int | None = None) -> None:
        """An edge on the ESC's latch input ``unit`` (0 or 1: the LATCH0/LATCH1 pin).

        The device's hardware saw a rising (``rising``) or falling edge, now
        or at segment time ``t_ns``: the DC unit stamps it with its system
        time in 0x09B0-0x09CF and sets the event in 0x09AE/0x09AF, in
        continuous or single-event mode as 0x09A8/0x09A9 say (ESC datasheet
        section I, "Latch Unit"). ValueError for another unit or an ESC
        without distributed clocks.
        """
        self._t.pdi_latch_input(unit, rising, t_ns)

    def al_state(self) -> AlState:
        """Current AL state (AL status bits 3:0)."""
        return self._t.al_state()

    def set_al_error(self, code: int, state: AlState | None = None) -> None:
        """Report an error: AL status code ``code``, error flag set, optionally a new state."""
        self._t.set_al_error(code, state)

    def now_ns(self) -> int:
        """Current time of the segment's clock."""
        return self._t.now_ns()


class DeviceApp:
    """Base class of device applications: every hook does nothing by default.

    ``wants_output_events`` stays False for plain IO terminals so that the
    cyclic path does no per-slave Python work; set it to have
    :meth:`on_outputs` called whenever the master completes an SM2 buffer.
    """

    wants_output_events: bool = False
    #: The firmware reads SM0 as soon as :meth:`on_mailbox` returns (the SM is
    #: empty again for the master). False: the application empties it itself
    #: by reading the last byte of SM0 through its PDI.
    mailbox_auto_read: bool = True

    def __init__(self) -> None:
        self.pdi: Pdi | None = None

    def attach(self, pdi: Pdi) -> None:
        """Called once when the slave is added to a segment."""
        self.pdi = pdi

    def check_transition(self, current: AlState, requested: AlState) -> int:
        """Extra checks of a requested state change: an AL status code, or 0 to allow it.

        Called after the ESC model's own checks (mailbox SMs, process-data SMs,
        outputs received) passed. For SAFEOP -> OP, -1 (``wire.al.PENDING``)
        keeps the request pending: the check runs again with every complete
        output buffer until it allows or refuses.
        """
        return 0

    def on_al_error(self, state: AlState, code: int) -> None:
        """The slave set the AL error flag with status ``code`` and stays in (or fell to) ``state``."""

    def process_data_sizes(self) -> tuple[int, int] | None:
        """(output bytes, input bytes) of the current PDO mapping, or None to use the SII's.

        A CoE device whose 0x1C12/0x1C13 mapping can change overrides this: the
        ESC compares SM2/SM3 lengths with it on PREOP -> SAFEOP (0x001D/0x001E).
        """
        return None

    def on_state_change(self, old: AlState, new: AlState) -> None:
        """The AL state changed (also on error fall-backs)."""

    def on_outputs(self) -> None:
        """An SM2 buffer was completed (only called if ``wants_output_events``)."""

    def on_mailbox(self, data: bytes) -> None:
        """The master wrote a complete mailbox into SM0 (the bytes of the whole SM)."""

    def on_mailbox_read(self) -> None:
        """The master read the mailbox in SM1: it is free for the next reply."""

    def on_sync0(self, time_ns: int) -> None:
        """A SYNC0 event at system time ``time_ns``."""

    def on_sync1(self, time_ns: int) -> None:
        """A SYNC1 event at system time ``time_ns``."""

    def on_power_on(self) -> None:
        """The slave was powered on (also the first time, after attach)."""
