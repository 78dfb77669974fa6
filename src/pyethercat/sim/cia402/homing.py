"""Homing methods of the simulated drive as table-driven programs (IEC 61800-7-201 numbering).

A method is a short program of search steps, each "move in direction d at
the switch-search or zero-search speed (0x6099:01/02) until signal s has
level l", followed by a rule that gives the home position: the edge of the
switch last searched, the next index pulse beyond it, or the current
position. Methods 19 and 20 have a second program for a home switch that is
already active at the start (the initial direction depends on it).

The switches are exact in the simulation (a limit switch is active at and
beyond its position, the home switch at and above its position, an index
pulse comes at every multiple of the encoder resolution), so the home
position a method finds does not depend on the speed, as on a drive that
latches the edge in hardware.

All of it is array work: the programs are numpy tables indexed by method,
variant and step, evaluated for every homing axis at once.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt

from pyethercat.wire.cia402 import HOMING_METHODS

__all__ = ["Phase", "Rule", "Signal", "HomingTable", "HOMING"]


class Signal(IntEnum):
    """Inputs a search step watches (columns of the signal matrix)."""

    NONE = 0
    NEGATIVE_LIMIT = 1
    POSITIVE_LIMIT = 2
    HOME = 3


class Rule(IntEnum):
    """Where the home position is once the steps are done."""

    NONE = 0
    EDGE = 1
    INDEX = 2
    CURRENT = 3


class Phase(IntEnum):
    """Homing phases beyond the search steps (0 .. steps-1)."""

    IDLE = -1
    APPROACH = 10
    """Moving on at zero-search speed until the index pulse is passed."""
    STOP = 11
    """Decelerating with the homing acceleration 0x609A."""
    DONE = 12
    ERROR = 13


_MAX_METHOD = 40
_MAX_STEPS = 3
N, P, H = Signal.NEGATIVE_LIMIT, Signal.POSITIVE_LIMIT, Signal.HOME
FAST, SLOW = 1, 2

# method: (rule, index direction, programs for (home switch inactive, active) at start);
# a step is (direction, speed, signal, level the signal must reach).
_PROGRAMS: dict[int, tuple[Rule, int, tuple[list[tuple[int, int, int, int]], ...]]] = {
    17: (Rule.EDGE, 0, ([(-1, FAST, N, 1), (+1, SLOW, N, 0)],)),
    18: (Rule.EDGE, 0, ([(+1, FAST, P, 1), (-1, SLOW, P, 0)],)),
    1: (Rule.INDEX, +1, ([(-1, FAST, N, 1), (+1, SLOW, N, 0)],)),
    2: (Rule.INDEX, -1, ([(+1, FAST, P, 1), (-1, SLOW, P, 0)],)),
    19: (Rule.EDGE, 0, ([(+1, FAST, H, 1), (-1, SLOW, H, 0)], [(-1, SLOW, H, 0)])),
    20: (Rule.EDGE, 0, ([(+1, FAST, H, 1), (-1, SLOW, H, 0), (+1, SLOW, H, 1)],
                        [(-1, FAST, H, 0), (+1, SLOW, H, 1)])),
    33: (Rule.INDEX, -1, ([],)),
    34: (Rule.INDEX, +1, ([],)),
    35: (Rule.CURRENT, 0, ([],)),
    37: (Rule.CURRENT, 0, ([],)),
}
assert set(_PROGRAMS) == set(HOMING_METHODS)


class HomingTable:
    """The programs as arrays: ``steps[m, v]``, ``step[m, v, k]`` = (dir, speed, signal, level)."""

    def __init__(self) -> None:
        self.valid = np.zeros(_MAX_METHOD, bool)
        self.rule = np.zeros(_MAX_METHOD, np.int8)
        self.index_dir = np.zeros(_MAX_METHOD, np.int8)
        self.steps = np.zeros((_MAX_METHOD, 2), np.int8)
        self.step = np.zeros((_MAX_METHOD, 2, _MAX_STEPS, 4), np.int8)
        #: The signal of the last search step (its position is the edge for Rule.EDGE).
        self.edge_signal = np.zeros((_MAX_METHOD, 2), np.int8)
        for m, (rule, idir, programs) in _PROGRAMS.items():
            self.valid[m] = True
            self.rule[m] = rule
            self.index_dir[m] = idir
            for v in range(2):
                prog = programs[min(v, len(programs) - 1)]
                self.steps[m, v] = len(prog)
                for k, st in enumerate(prog):
                    self.step[m, v, k] = st
                if prog:
                    self.edge_signal[m, v] = prog[-1][2]
        #: Limit switches that end a method with an error (the ones it does not search).
        self.forbidden = np.ones((_MAX_METHOD, 3), bool)
        self.forbidden[:, 0] = False
        for m in (17, 1):
            self.forbidden[m, N] = False
        for m in (18, 2):
            self.forbidden[m, P] = False

    def method_index(self, method: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Methods as table rows (unknown methods map to row 0, which is not valid)."""
        m = np.asarray(method, np.int64)
        out: npt.NDArray[np.int64] = np.where((m > 0) & (m < _MAX_METHOD), m, 0)
        return out


HOMING = HomingTable()
