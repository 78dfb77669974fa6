"""AL states, the state machine and the AL status code table (ETG.1000.6 section 5.3)."""

from __future__ import annotations

import pytest

from pyethercat.errors import ConfigError
from pyethercat.wire.al import (
    AL_STATUS_CODE_NAMES,
    PENDING,
    TRANSITIONS,
    AlState,
    AlStatusCode,
    al_status_code_name,
    is_legal_transition,
    parse_transition,
    state_name,
    state_path,
    transition_name,
)


def test_state_codes() -> None:
    assert [(s.name, int(s)) for s in AlState if s] == [
        ("INIT", 1), ("PREOP", 2), ("BOOT", 3), ("SAFEOP", 4), ("OP", 8)]


@pytest.mark.parametrize(
    ("text", "state"),
    [("init", AlState.INIT), ("PRE-OP", AlState.PREOP), ("pre_op", AlState.PREOP),
     (" SafeOp ", AlState.SAFEOP), ("op", AlState.OP), ("bootstrap", AlState.BOOT)],
)
def test_parse(text: str, state: AlState) -> None:
    assert AlState.parse(text) is state


@pytest.mark.parametrize("text", ["none", "RUN", "", "0x08"])
def test_parse_refuses_what_is_not_a_requestable_state(text: str) -> None:
    with pytest.raises(ConfigError, match="unknown AL state"):
        AlState.parse(text)


def test_state_name() -> None:
    assert state_name(0x0008) == "OP"
    assert state_name(0x0014) == "SAFEOP+ERR"
    assert state_name(0x0021) == "INIT"  # ID flag is not part of the state
    assert state_name(0x0007) == "0x7"


def test_every_code_of_the_facts_sheet_has_its_name() -> None:
    # Facts 4.4, code by code.
    facts = {
        0x0000: "No error", 0x0001: "Unspecified error", 0x0002: "No memory",
        0x0003: "Invalid device setup", 0x0004: "Invalid revision",
        0x0006: "SII/EEPROM information does not match firmware",
        0x0007: "Firmware update not successful, old firmware still running",
        0x000E: "License error", 0x0011: "Invalid requested state change",
        0x0012: "Unknown requested state", 0x0013: "Bootstrap not supported",
        0x0014: "No valid firmware", 0x0015: "Invalid mailbox configuration (BOOT)",
        0x0016: "Invalid mailbox configuration (PRE-OP)",
        0x0017: "Invalid sync manager configuration", 0x0018: "No valid inputs available",
        0x0019: "No valid outputs", 0x001A: "Synchronization error",
        0x001B: "Sync manager watchdog", 0x001C: "Invalid sync manager types",
        0x001D: "Invalid output configuration", 0x001E: "Invalid input configuration",
        0x001F: "Invalid watchdog configuration", 0x0020: "Slave needs cold start",
        0x0021: "Slave needs INIT", 0x0022: "Slave needs PRE-OP", 0x0023: "Slave needs SAFE-OP",
        0x0024: "Invalid input mapping", 0x0025: "Invalid output mapping",
        0x0026: "Inconsistent settings", 0x0027: "Free-run not supported",
        0x0028: "Synchronization not supported", 0x0029: "Free-run needs 3-buffer mode",
        0x002A: "Background watchdog", 0x002B: "No valid inputs and outputs",
        0x002C: "Fatal sync error", 0x002D: "No sync error",
        0x002E: "Invalid input FMMU configuration", 0x0030: "Invalid DC SYNC configuration",
        0x0031: "Invalid DC latch configuration", 0x0032: "PLL error",
        0x0033: "DC sync I/O error", 0x0034: "DC sync timeout error",
        0x0035: "DC invalid sync cycle time", 0x0036: "DC invalid SYNC0 cycle time",
        0x0037: "DC invalid SYNC1 cycle time", 0x0041: "MBX_AOE", 0x0042: "MBX_EOE",
        0x0043: "MBX_COE", 0x0044: "MBX_FOE", 0x0045: "MBX_SOE", 0x004F: "MBX_VOE",
        0x0050: "EEPROM no access", 0x0051: "EEPROM error",
        0x0052: "External hardware not ready", 0x0060: "Slave restarted locally",
        0x0061: "Device identification value updated",
        0x0070: "Detected module ident list does not match",
        0x0080: "Supply voltage too low", 0x0081: "Supply voltage too high",
        0x0082: "Temperature too low", 0x0083: "Temperature too high",
        0x00F0: "Application controller available",
    }
    assert facts == AL_STATUS_CODE_NAMES
    assert {int(c) for c in AlStatusCode} == set(facts)
    assert al_status_code_name(AlStatusCode.SM_WATCHDOG) == "Sync manager watchdog"
    assert al_status_code_name(0x8001) == "Vendor specific (0x8001)"
    assert al_status_code_name(0x0005) == "Unknown AL status code 0x0005"


# --- the state machine ------------------------------------------------------------------

I, P, B, S, O = AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP  # noqa: E741 - the letters of the transition names


def test_legal_transitions_are_exactly_the_state_machine_table() -> None:
    states = [I, P, B, S, O]
    legal = {(a, b) for a in states for b in states if a != b and is_legal_transition(a, b)}
    # Up one step, down to any lower state, BOOT from and to INIT only (ETG.1000.6 5.3).
    assert legal == {(I, P), (P, I), (P, S), (S, P), (S, O), (O, S), (S, I), (O, I), (O, P),
                     (I, B), (B, I)}
    assert all(is_legal_transition(s, s) for s in states)
    assert not is_legal_transition(I, 0x05)  # no such state
    assert {TRANSITIONS[name] for name in TRANSITIONS} == legal
    assert all(transition_name(*TRANSITIONS[name]) == name for name in TRANSITIONS)
    assert transition_name(I, O) is None and transition_name(P, P) is None


def test_state_path_walks_up_step_by_step_and_down_at_once() -> None:
    assert state_path(I, O) == [P, S, O]
    assert state_path(O, I) == [I]
    assert state_path(O, P) == [P]
    assert state_path(S, B) == [I, B]
    assert state_path(B, S) == [I, P, S]
    assert state_path(0x0F, P) == [I, P]  # unknown: start from INIT
    assert state_path(S, S) == [S]
    for start in (I, P, B, S, O):
        for target in (I, P, B, S, O):
            steps = [start, *state_path(start, target)]
            assert all(is_legal_transition(a, b) for a, b in zip(steps, steps[1:], strict=False))


def test_transition_names_as_users_and_esi_files_write_them() -> None:
    assert parse_transition("ps") == "PS"
    assert parse_transition("P->S") == "PS"
    assert parse_transition("SAFEOP_OP") == "SO"
    assert parse_transition("OP") == "OP"  # the transition OP -> PREOP
    with pytest.raises(ConfigError, match="unknown state transition 'PO'"):
        parse_transition("PO")


def test_pending_is_no_status_code() -> None:
    assert PENDING < 0 and PENDING not in {int(c) for c in AlStatusCode}
