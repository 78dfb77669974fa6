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

from pyethercat.sim.cia402.arrays import DriveArrays
from pyethercat.sim.cia402.axis import Rows
from pyethercat.sim.cia402.keys import AX, F64, I64, OBJ, PH, B, Phase, ints
from pyethercat.sim.cia402.objects import AXIS_OBJECT
from pyethercat.sim.cia402.profile import ramp_velocity
from pyethercat.wire.cia402 import HOMING_METHODS

__all__ = ["HOMING", "PH", "HomingTable", "Phase", "Rule", "Signal", "home_found", "run_homing"]


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
RU = ints(Rule)
SG = ints(Signal)


# --- the homing mode of a drive's cycle ------------------------------------------------------


def run_homing(eng: DriveArrays, r: Rows, inst: I64, m: B, halt: B, cw: I64, prev: I64, p: F64,
               g_p: F64, g_v: F64, new_p: F64, new_v: F64, dt: F64,
               switches: tuple[B, B, B]) -> tuple[F64, F64, F64, F64]:
    """Homing: start on the rising edge of bit 4, run the method's program (``sim.cia402.homing``).

    Returns the demand at the start of the cycle (re-referenced where a method homed
    on the current position) and at its end: (g_p, g_v, new_p, new_v).
    """
    col = eng.col
    neg, posl, home = switches
    phase = eng.hm_phase[r].astype(np.int64)
    method = HOMING.method_index(col(OBJ.HOMING_METHOD, 0, r).astype(np.int64))
    start = m & ((cw & 0x10) != 0) & ((prev & 0x10) == 0) & ((phase < 0) | (phase >= PH.DONE))
    if start.any():
        sel = inst[start]
        eng.hm_method[sel] = method[start]
        eng.hm_var[sel] = home[start]
        eng.hm_attained[sel] = False
        eng.hm_error[sel] = ~HOMING.valid[method[start]]
        phase = np.where(start, np.where(HOMING.valid[method], 0, PH.ERROR), phase)
    meth = eng.hm_method[r]
    var = eng.hm_var[r].astype(np.int64)
    # bit 4 dropping interrupts the homing (as does halt): stop where it is
    aborted = m & (((cw & 0x10) == 0) | halt) & (phase >= 0) & (phase < PH.STOP)
    phase = np.where(aborted, PH.STOP, phase)
    steps = HOMING.steps[meth, var].astype(np.int64)
    searching = m & (phase >= 0) & (phase < steps)
    k = np.clip(phase, 0, 2)
    prog = HOMING.step[meth, var, k].astype(np.int64)
    direction, speed_sel, sig, level = prog[:, 0], prog[:, 1], prog[:, 2], prog[:, 3]
    signals = np.stack([np.ones_like(neg), neg, posl, home], axis=1)
    met = searching & (signals[np.arange(len(p)), sig] == (level == 1))
    # a limit switch the method does not search for ends it with an error
    bad = m & (phase >= 0) & (phase < PH.STOP) & (
        (neg & HOMING.forbidden[meth, SG.NEGATIVE_LIMIT])
        | (posl & HOMING.forbidden[meth, SG.POSITIVE_LIMIT]))
    phase = np.where(met, phase + 1, phase)
    # steps done: where is home?
    ready = m & (phase >= 0) & (phase == steps) & ~bad
    if ready.any():
        rule = HOMING.rule[meth]
        edge_sig = HOMING.edge_signal[meth, var]
        positions = np.stack([p, col(AXIS_OBJECT, AX.NEGATIVE_LIMIT_SWITCH, r),
                              col(AXIS_OBJECT, AX.POSITIVE_LIMIT_SWITCH, r),
                              col(AXIS_OBJECT, AX.HOME_SWITCH, r)], axis=1)
        edge = positions[np.arange(len(p)), edge_sig]
        # "current position": the encoder's count now, which the position actual value
        # shows (the drive knows no finer position than its encoder's)
        edge = np.where(rule == RU.EDGE, edge, np.where(rule == RU.INDEX, np.where(
            edge_sig > 0, edge, p), eng.enc_prev[r]))
        cpr = col(OBJ.POSITION_ENCODER_RESOLUTION, 1, r) / np.maximum(
            col(OBJ.POSITION_ENCODER_RESOLUTION, 2, r), 1.0)
        idir = HOMING.index_dir[meth]
        index = np.where(idir > 0, (np.floor(edge / cpr) + 1) * cpr,
                         (np.ceil(edge / cpr) - 1) * cpr)
        home_at = np.where(rule == RU.INDEX, index, edge)
        sel = inst[ready]
        eng.hm_home[sel] = home_at[ready]
        nxt = np.where(rule == RU.INDEX, PH.APPROACH,
                       np.where(rule == RU.CURRENT, PH.DONE, PH.STOP))
        phase = np.where(ready, nxt, phase)
        fin = ready & (rule == RU.CURRENT)
        if fin.any():
            home_found(eng, inst[fin], home_at[fin], r, fin)
            # Homing without motion: the drive holds the position it took as home. The
            # demand of the mode before (a profile move's target the axis may still be
            # settling onto, inside the position window) is dropped; kept, the axis
            # would come to rest that far from home.
            g_p = np.where(fin, home_at, g_p)
            g_v = np.where(fin, 0.0, g_v)
    hm_home = eng.hm_home[r]
    approach = m & (phase == PH.APPROACH)
    idir = HOMING.index_dir[meth].astype(np.float64)
    passed = approach & ((p - hm_home) * idir >= 0)
    phase = np.where(passed, PH.STOP, phase)
    phase = np.where(bad, PH.ERROR, phase)
    if bad.any():
        eng.hm_error[inst[bad]] = True
    speeds = np.stack([np.zeros_like(p), col(OBJ.HOMING_SPEEDS, 1, r), col(OBJ.HOMING_SPEEDS, 2, r)],
                      axis=1)
    goal_v = np.where(searching & (phase < steps),
                      direction * speeds[np.arange(len(p)), speed_sel], 0.0)
    goal_v = np.where(approach & ~passed, idir * col(OBJ.HOMING_SPEEDS, 2, r), goal_v)
    acc = np.maximum(col(OBJ.HOMING_ACCELERATION, 0, r), 1.0)
    moving = m & ~halt
    rv = ramp_velocity(g_v, goal_v, acc, acc, dt)
    new_v = np.where(moving, rv, new_v)
    new_p = np.where(moving, g_p + (g_v + rv) * 0.5 * dt, new_p)
    stopped = m & ((phase == PH.STOP) | (phase == PH.ERROR)) & (rv == 0)
    done = stopped & (phase == PH.STOP) & ~aborted
    if done.any():
        home_found(eng, inst[done], eng.hm_home[inst[done]], r, done)
    phase = np.where(done, PH.DONE, phase)
    phase = np.where(stopped & aborted, PH.IDLE, phase)
    eng.hm_phase[inst[m]] = phase[m]
    return g_p, g_v, new_p, new_v


def home_found(eng: DriveArrays, sel: I64, home_raw: F64, r: Rows, mask: B) -> None:
    """Homing attained: user position of the home position = -home offset (IEC 61800-7-201:
    "the zero position is offset from the home position by adding the home offset")."""
    offset = eng.col(OBJ.HOME_OFFSET, 0, r)[mask]
    eng.origin[sel] = home_raw + offset
    eng.hm_attained[sel] = True
    eng.hm_phase[sel] = int(PH.DONE)

