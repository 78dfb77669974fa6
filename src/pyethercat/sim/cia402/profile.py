"""Set-point generators of the simulated drive: ramps and the profile-position move.

Pure array functions (no state of their own): each takes the generator state
of the axes concerned (demand position ``p`` in raw increments, demand
velocity ``v`` in increments/s) and returns the next cycle's.

- :func:`ramp_velocity`: the velocity demand moves towards a goal with a
  bounded acceleration (speeding up) or deceleration (slowing down);
- :func:`profile_move`: a trapezoidal move to a goal position (profile
  velocity, acceleration, deceleration), braking so that it arrives with
  velocity 0; it lands exactly on the goal.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["profile_move", "ramp_velocity"]

F64 = npt.NDArray[np.float64]


def ramp_velocity(v: F64, goal: F64, acc: F64, dec: F64, dt: F64) -> F64:
    """Velocity demand after ``dt`` moving from ``v`` towards ``goal`` (acc up, dec down)."""
    dv = goal - v
    # speeding up when the change goes the way the axis already moves (or from rest)
    up = (v * dv > 0) | (v == 0)
    step = np.where(up, acc, dec) * dt
    out: F64 = v + np.clip(dv, -step, step)
    return out


def profile_move(p: F64, v: F64, goal: F64, vmax: F64, acc: F64, dec: F64,
                 dt: F64) -> tuple[F64, F64, npt.NDArray[np.bool_]]:
    """One cycle of a trapezoidal move: (position, velocity, arrived).

    The velocity goal is the profile velocity, or less where braking with
    ``dec`` must start to stop at ``goal``; the velocity then ramps towards it.
    An axis within one cycle's travel of the goal at a velocity it can stop
    from in one cycle lands on the goal with velocity 0.
    """
    d = goal - p
    # The fastest velocity V for the end of this cycle from which a ramp sampled every
    # dt still stops at the goal: |d| = (v + V) dt / 2 + V^2 / (2 dec).
    half = 0.5 * dec * dt
    toward = v * np.sign(d)
    room = np.maximum(np.abs(d) - toward * 0.5 * dt, 0.0)
    brake = (np.sqrt(half * half + 2.0 * dec * room) - half) * np.sign(d)
    vg = np.clip(brake, -vmax, vmax)
    vn = ramp_velocity(v, vg, acc, dec, dt)
    pn = p + (v + vn) * 0.5 * dt
    rest = goal - pn
    arrived = (np.abs(rest) <= np.maximum(np.abs(vn) * dt, 0.5)) & (np.abs(vn) <= dec * dt * 1.5)
    overshot = (rest * d < 0) & (np.abs(vn) <= dec * dt * 1.5)
    arrived |= overshot | (d == 0) & (v == 0)
    pn = np.where(arrived, goal, pn)
    vn = np.where(arrived, 0.0, vn)
    return pn, vn, arrived
