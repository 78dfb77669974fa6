"""AL (application layer) states and AL status codes.

States and the AL status code table as IEC 61158-6-12:2019 5.3 (ETG.1000.6) gives
them; the same codes in SOEM ``src/ec_print.c`` (``ec_ALstatuscodelist``), IgH
``master/fsm_change.c`` (``al_status_messages``) and SOES ``soes/esc.h`` (``ALERR_*``).
"""

from __future__ import annotations

import enum

from pyethercat.errors import ConfigError
from pyethercat.wire.registers import AL_ERROR_FLAG, AL_STATE_MASK

__all__ = [
    "AL_STATUS_CODE_NAMES",
    "PENDING",
    "STATE_LETTERS",
    "TRANSITIONS",
    "AlState",
    "AlStatusCode",
    "al_status_code_name",
    "is_legal_transition",
    "parse_transition",
    "state_name",
    "state_path",
    "transition_name",
]


class AlState(enum.IntEnum):
    """EtherCAT state machine states (AL control/status bits 3:0)."""

    NONE = 0x00
    INIT = 0x01
    PREOP = 0x02
    BOOT = 0x03
    SAFEOP = 0x04
    OP = 0x08

    @classmethod
    def parse(cls, text: str) -> AlState:
        """Parse a state name as users type it: INIT, PREOP, PRE-OP, SAFEOP, OP, BOOT.

        Raises :class:`~pyethercat.errors.ConfigError` (a ``ValueError``) for other text.
        """
        key = text.strip().upper().replace("-", "").replace("_", "")
        aliases = {"PREOP": cls.PREOP, "SAFEOP": cls.SAFEOP, "BOOTSTRAP": cls.BOOT}
        if key in aliases:
            return aliases[key]
        try:
            if key == "NONE":  # not a state anybody can request
                raise KeyError(key)
            return cls[key]
        except KeyError:
            raise ConfigError(
                f"unknown AL state {text!r}: use INIT, PREOP, BOOT, SAFEOP or OP") from None

    @property
    def label(self) -> str:
        """The name IgH's tool prints (PREOP, SAFEOP, ...)."""
        return self.name


_STATE_VALUES = frozenset(int(s) for s in AlState if s != AlState.NONE)


def state_name(value: int) -> str:
    """Name of an AL status value, with ``+ERR`` when the error flag is set."""
    base = value & AL_STATE_MASK
    try:
        name = AlState(base).name
    except ValueError:
        name = f"0x{base:X}"
    return name + ("+ERR" if value & AL_ERROR_FLAG else "")


#: One-letter state names of ESI/ENI transitions (ETG.2000 ``InitCmd/Transition``).
STATE_LETTERS: dict[AlState, str] = {AlState.INIT: "I", AlState.PREOP: "P", AlState.BOOT: "B",
                                     AlState.SAFEOP: "S", AlState.OP: "O"}

#: Every transition a slave carries out, by name -> (from state, to state)
#: (ETG.1000.6 section 5.3.1, figure "EtherCAT state machine"): up one step at a
#: time, down to any lower state, BOOT only from and back to INIT.
TRANSITIONS: dict[str, tuple[AlState, AlState]] = {
    "IP": (AlState.INIT, AlState.PREOP),
    "PI": (AlState.PREOP, AlState.INIT),
    "PS": (AlState.PREOP, AlState.SAFEOP),
    "SP": (AlState.SAFEOP, AlState.PREOP),
    "SO": (AlState.SAFEOP, AlState.OP),
    "OS": (AlState.OP, AlState.SAFEOP),
    "SI": (AlState.SAFEOP, AlState.INIT),
    "OI": (AlState.OP, AlState.INIT),
    "OP": (AlState.OP, AlState.PREOP),
    "IB": (AlState.INIT, AlState.BOOT),
    "BI": (AlState.BOOT, AlState.INIT),
}
_LEGAL = frozenset(TRANSITIONS.values())
_BY_LETTER = {letter: state for state, letter in STATE_LETTERS.items()}
_UP_ORDER = (AlState.INIT, AlState.PREOP, AlState.SAFEOP, AlState.OP)

#: A transition check that neither grants nor refuses the request yet: the
#: slave keeps the request pending (SAFEOP -> OP waiting for the first valid
#: outputs, ETG.1000.6 section 5.3.2). Not an AL status code (those are 0..0xFFFF).
PENDING = -1


def is_legal_transition(current: AlState | int, requested: AlState | int) -> bool:
    """Whether a slave in ``current`` carries out a request for ``requested``.

    Staying in the same state is legal; states outside :class:`AlState` are not.
    """
    cur, req = int(current) & AL_STATE_MASK, int(requested) & AL_STATE_MASK
    if cur == req:
        return cur in _STATE_VALUES
    return (cur, req) in _LEGAL


def transition_name(current: AlState | int, target: AlState | int) -> str | None:
    """``"PS"`` for PREOP -> SAFEOP; ``None`` for no change, an unknown state or an illegal step."""
    try:
        a, b = AlState(int(current) & AL_STATE_MASK), AlState(int(target) & AL_STATE_MASK)
    except ValueError:
        return None
    name = STATE_LETTERS.get(a, "") + STATE_LETTERS.get(b, "")
    return name if name in TRANSITIONS else None


def parse_transition(name: str) -> str:
    """Normalise a transition name (``"ps"``, ``"P->S"``, ``"PREOP_SAFEOP"``...) to ``"PS"``.

    Raises :class:`~pyethercat.errors.ConfigError` for names of no legal transition.
    """
    text = name.strip().upper().replace("->", "").replace("_", "").replace(" ", "")
    if text not in TRANSITIONS:
        for a, a_letter in _WORDS.items():
            if text.startswith(a) and text[len(a):] in _WORDS:
                text = a_letter + _WORDS[text[len(a):]]
                break
    if text not in TRANSITIONS:
        raise ConfigError(f"unknown state transition {name!r} "
                          f"(use one of {', '.join(TRANSITIONS)})")
    return text


_WORDS = {"INIT": "I", "PREOP": "P", "SAFEOP": "S", "OP": "O", "BOOT": "B"}


def state_path(current: AlState | int, target: AlState | int) -> list[AlState]:
    """The states to request one after the other to get from ``current`` to ``target``.

    Up one step at a time (INIT -> PREOP -> SAFEOP -> OP), down in one step;
    BOOT is reached from INIT only and left to INIT only; from an unknown
    state the path starts at INIT. ``[target]`` when already there.
    """
    cur, tgt = int(current) & AL_STATE_MASK, AlState(int(target))
    if cur == tgt:
        return [tgt]
    if tgt == AlState.BOOT:
        return [AlState.BOOT] if cur == AlState.INIT else [AlState.INIT, AlState.BOOT]
    if cur == AlState.BOOT or cur not in _UP_ORDER:
        start = AlState.INIT
        path = [AlState.INIT]
    else:
        start = AlState(cur)
        path = []
    i, j = _UP_ORDER.index(start), _UP_ORDER.index(tgt)
    if j > i:
        path += list(_UP_ORDER[i + 1:j + 1])
    elif j < i:
        path.append(tgt)  # going down may skip states
    return path or [tgt]


class AlStatusCode(enum.IntEnum):
    """AL status codes (register 0x0134)."""

    NO_ERROR = 0x0000
    UNSPECIFIED_ERROR = 0x0001
    NO_MEMORY = 0x0002
    INVALID_DEVICE_SETUP = 0x0003
    INVALID_REVISION = 0x0004
    SII_MISMATCH = 0x0006
    FIRMWARE_UPDATE_FAILED = 0x0007
    LICENSE_ERROR = 0x000E
    INVALID_STATE_CHANGE = 0x0011
    UNKNOWN_STATE = 0x0012
    BOOTSTRAP_NOT_SUPPORTED = 0x0013
    NO_VALID_FIRMWARE = 0x0014
    INVALID_MAILBOX_CONFIG_BOOT = 0x0015
    INVALID_MAILBOX_CONFIG = 0x0016
    INVALID_SM_CONFIG = 0x0017
    NO_VALID_INPUTS = 0x0018
    NO_VALID_OUTPUTS = 0x0019
    SYNCHRONIZATION_ERROR = 0x001A
    SM_WATCHDOG = 0x001B
    INVALID_SM_TYPES = 0x001C
    INVALID_OUTPUT_CONFIG = 0x001D
    INVALID_INPUT_CONFIG = 0x001E
    INVALID_WATCHDOG_CONFIG = 0x001F
    NEEDS_COLD_START = 0x0020
    NEEDS_INIT = 0x0021
    NEEDS_PREOP = 0x0022
    NEEDS_SAFEOP = 0x0023
    INVALID_INPUT_MAPPING = 0x0024
    INVALID_OUTPUT_MAPPING = 0x0025
    INCONSISTENT_SETTINGS = 0x0026
    FREERUN_NOT_SUPPORTED = 0x0027
    SYNC_NOT_SUPPORTED = 0x0028
    FREERUN_NEEDS_3BUFFER = 0x0029
    BACKGROUND_WATCHDOG = 0x002A
    NO_VALID_INPUTS_AND_OUTPUTS = 0x002B
    FATAL_SYNC_ERROR = 0x002C
    NO_SYNC_ERROR = 0x002D
    INVALID_INPUT_FMMU_CONFIG = 0x002E
    INVALID_DC_SYNC_CONFIG = 0x0030
    INVALID_DC_LATCH_CONFIG = 0x0031
    PLL_ERROR = 0x0032
    DC_SYNC_IO_ERROR = 0x0033
    DC_SYNC_TIMEOUT = 0x0034
    DC_INVALID_SYNC_CYCLE_TIME = 0x0035
    DC_INVALID_SYNC0_CYCLE_TIME = 0x0036
    DC_INVALID_SYNC1_CYCLE_TIME = 0x0037
    MBX_AOE = 0x0041
    MBX_EOE = 0x0042
    MBX_COE = 0x0043
    MBX_FOE = 0x0044
    MBX_SOE = 0x0045
    MBX_VOE = 0x004F
    EEPROM_NO_ACCESS = 0x0050
    EEPROM_ERROR = 0x0051
    EXTERNAL_HARDWARE_NOT_READY = 0x0052
    SLAVE_RESTARTED_LOCALLY = 0x0060
    DEVICE_ID_UPDATED = 0x0061
    MODULE_ID_LIST_MISMATCH = 0x0070
    SUPPLY_VOLTAGE_TOO_LOW = 0x0080
    SUPPLY_VOLTAGE_TOO_HIGH = 0x0081
    TEMPERATURE_TOO_LOW = 0x0082
    TEMPERATURE_TOO_HIGH = 0x0083
    APPLICATION_CONTROLLER_AVAILABLE = 0x00F0


AL_STATUS_CODE_NAMES: dict[int, str] = {
    AlStatusCode.NO_ERROR: "No error",
    AlStatusCode.UNSPECIFIED_ERROR: "Unspecified error",
    AlStatusCode.NO_MEMORY: "No memory",
    AlStatusCode.INVALID_DEVICE_SETUP: "Invalid device setup",
    AlStatusCode.INVALID_REVISION: "Invalid revision",
    AlStatusCode.SII_MISMATCH: "SII/EEPROM information does not match firmware",
    AlStatusCode.FIRMWARE_UPDATE_FAILED: "Firmware update not successful, old firmware still running",
    AlStatusCode.LICENSE_ERROR: "License error",
    AlStatusCode.INVALID_STATE_CHANGE: "Invalid requested state change",
    AlStatusCode.UNKNOWN_STATE: "Unknown requested state",
    AlStatusCode.BOOTSTRAP_NOT_SUPPORTED: "Bootstrap not supported",
    AlStatusCode.NO_VALID_FIRMWARE: "No valid firmware",
    AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT: "Invalid mailbox configuration (BOOT)",
    AlStatusCode.INVALID_MAILBOX_CONFIG: "Invalid mailbox configuration (PRE-OP)",
    AlStatusCode.INVALID_SM_CONFIG: "Invalid sync manager configuration",
    AlStatusCode.NO_VALID_INPUTS: "No valid inputs available",
    AlStatusCode.NO_VALID_OUTPUTS: "No valid outputs",
    AlStatusCode.SYNCHRONIZATION_ERROR: "Synchronization error",
    AlStatusCode.SM_WATCHDOG: "Sync manager watchdog",
    AlStatusCode.INVALID_SM_TYPES: "Invalid sync manager types",
    AlStatusCode.INVALID_OUTPUT_CONFIG: "Invalid output configuration",
    AlStatusCode.INVALID_INPUT_CONFIG: "Invalid input configuration",
    AlStatusCode.INVALID_WATCHDOG_CONFIG: "Invalid watchdog configuration",
    AlStatusCode.NEEDS_COLD_START: "Slave needs cold start",
    AlStatusCode.NEEDS_INIT: "Slave needs INIT",
    AlStatusCode.NEEDS_PREOP: "Slave needs PRE-OP",
    AlStatusCode.NEEDS_SAFEOP: "Slave needs SAFE-OP",
    AlStatusCode.INVALID_INPUT_MAPPING: "Invalid input mapping",
    AlStatusCode.INVALID_OUTPUT_MAPPING: "Invalid output mapping",
    AlStatusCode.INCONSISTENT_SETTINGS: "Inconsistent settings",
    AlStatusCode.FREERUN_NOT_SUPPORTED: "Free-run not supported",
    AlStatusCode.SYNC_NOT_SUPPORTED: "Synchronization not supported",
    AlStatusCode.FREERUN_NEEDS_3BUFFER: "Free-run needs 3-buffer mode",
    AlStatusCode.BACKGROUND_WATCHDOG: "Background watchdog",
    AlStatusCode.NO_VALID_INPUTS_AND_OUTPUTS: "No valid inputs and outputs",
    AlStatusCode.FATAL_SYNC_ERROR: "Fatal sync error",
    AlStatusCode.NO_SYNC_ERROR: "No sync error",
    AlStatusCode.INVALID_INPUT_FMMU_CONFIG: "Invalid input FMMU configuration",
    AlStatusCode.INVALID_DC_SYNC_CONFIG: "Invalid DC SYNC configuration",
    AlStatusCode.INVALID_DC_LATCH_CONFIG: "Invalid DC latch configuration",
    AlStatusCode.PLL_ERROR: "PLL error",
    AlStatusCode.DC_SYNC_IO_ERROR: "DC sync I/O error",
    AlStatusCode.DC_SYNC_TIMEOUT: "DC sync timeout error",
    AlStatusCode.DC_INVALID_SYNC_CYCLE_TIME: "DC invalid sync cycle time",
    AlStatusCode.DC_INVALID_SYNC0_CYCLE_TIME: "DC invalid SYNC0 cycle time",
    AlStatusCode.DC_INVALID_SYNC1_CYCLE_TIME: "DC invalid SYNC1 cycle time",
    AlStatusCode.MBX_AOE: "MBX_AOE",
    AlStatusCode.MBX_EOE: "MBX_EOE",
    AlStatusCode.MBX_COE: "MBX_COE",
    AlStatusCode.MBX_FOE: "MBX_FOE",
    AlStatusCode.MBX_SOE: "MBX_SOE",
    AlStatusCode.MBX_VOE: "MBX_VOE",
    AlStatusCode.EEPROM_NO_ACCESS: "EEPROM no access",
    AlStatusCode.EEPROM_ERROR: "EEPROM error",
    AlStatusCode.EXTERNAL_HARDWARE_NOT_READY: "External hardware not ready",
    AlStatusCode.SLAVE_RESTARTED_LOCALLY: "Slave restarted locally",
    AlStatusCode.DEVICE_ID_UPDATED: "Device identification value updated",
    AlStatusCode.MODULE_ID_LIST_MISMATCH: "Detected module ident list does not match",
    AlStatusCode.SUPPLY_VOLTAGE_TOO_LOW: "Supply voltage too low",
    AlStatusCode.SUPPLY_VOLTAGE_TOO_HIGH: "Supply voltage too high",
    AlStatusCode.TEMPERATURE_TOO_LOW: "Temperature too low",
    AlStatusCode.TEMPERATURE_TOO_HIGH: "Temperature too high",
    AlStatusCode.APPLICATION_CONTROLLER_AVAILABLE: "Application controller available",
}


def al_status_code_name(code: int) -> str:
    """Human-readable name of an AL status code."""
    if code in AL_STATUS_CODE_NAMES:
        return AL_STATUS_CODE_NAMES[code]
    if code >= 0x8000:
        return f"Vendor specific (0x{code:04X})"
    return f"Unknown AL status code 0x{code:04X}"
