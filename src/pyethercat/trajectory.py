"""Point-to-point motion profiles for many axes at once, sampled at the cycle time.

- :func:`trapezoid`: velocity-limited, acceleration-limited (a trapezoidal
  velocity, a triangle when the velocity limit is not reached);
- :func:`s_curve`: also jerk-limited (seven phases: jerk +, a const, jerk -,
  cruise, jerk -, a const, jerk +; the phases shrink when a limit cannot be
  reached, as in Biagiotti and Melchiorri, "Trajectory Planning for
  Automatic Machines and Robots", section 3.4).

Every axis moves rest to rest from its start to its end with its own limits
(scalars apply to all axes). The result holds one row per cycle until the
slowest axis arrives; faster axes hold their end position. With
``synchronized=True`` every axis takes the time of the slowest (its limits
scaled down), so multi-axis moves start and stop together.

The arithmetic is numpy over (samples x axes): the cost does not grow with a
Python loop per axis or per sample::

    traj = s_curve([0, 0], [100_000, -50_000], vmax=400_000, amax=4e6, jmax=8e7, dt=0.001)
    traj.position.shape        # (cycles, 2), increments, float64
    traj.position_counts()     # rounded to int64 for the drives
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError

__all__ = ["Trajectory", "s_curve", "trapezoid"]

F64 = npt.NDArray[np.float64]
ArrayLike = float | int | npt.ArrayLike


@dataclass(frozen=True)
class Trajectory:
    """A sampled move: ``t`` (samples,), the others (samples, axes)."""

    t: F64
    position: F64
    velocity: F64
    acceleration: F64
    #: Time each axis needs (s).
    duration: F64
    dt: float

    @property
    def axes(self) -> int:
        return int(self.position.shape[1])

    def __len__(self) -> int:
        return int(self.position.shape[0])

    def position_counts(self) -> npt.NDArray[np.int64]:
        """Positions rounded to whole increments (what a drive's 0x607A takes)."""
        out: npt.NDArray[np.int64] = np.rint(self.position).astype(np.int64)
        return out


def _axes(start: ArrayLike, end: ArrayLike, *limits: ArrayLike) -> tuple[F64, ...]:
    s = np.atleast_1d(np.asarray(start, np.float64))
    e = np.atleast_1d(np.asarray(end, np.float64))
    n = max(len(s), len(e))
    out = [np.broadcast_to(s, (n,)).astype(np.float64), np.broadcast_to(e, (n,)).astype(np.float64)]
    for lim in limits:
        arr = np.broadcast_to(np.atleast_1d(np.asarray(lim, np.float64)), (n,)).astype(np.float64)
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise ConfigError(f"motion limits must be positive and finite, got {lim!r}")
        out.append(arr)
    if not (np.all(np.isfinite(out[0])) and np.all(np.isfinite(out[1]))):
        raise ConfigError("start and end positions must be finite")
    return tuple(out)


def _grid(duration: F64, dt: float) -> F64:
    if dt <= 0:
        raise ConfigError(f"the sample time must be positive, got {dt}")
    n = int(np.ceil(float(duration.max(initial=0.0)) / dt - 1e-9)) + 1
    t: F64 = np.arange(n, dtype=np.float64) * dt
    return t


def _scale(durations: F64, synchronized: bool) -> F64:
    """Time scale per axis (>= 1) that makes every axis take the slowest one's time."""
    if not synchronized:
        return np.ones_like(durations)
    longest = float(durations.max(initial=0.0))
    out: F64 = np.where(durations > 0, longest / np.maximum(durations, 1e-300), 1.0)
    return out


def trapezoid(start: ArrayLike, end: ArrayLike, vmax: ArrayLike, amax: ArrayLike, dt: float, *,
              synchronized: bool = False) -> Trajectory:
    """Trapezoidal velocity profiles from ``start`` to ``end`` (see the module docstring)."""
    s, e, vm, am = _axes(start, end, vmax, amax)
    d = np.abs(e - s)
    sign = np.sign(e - s)
    full = d >= vm * vm / am                      # the velocity limit is reached
    ta = np.where(full, vm / am, np.sqrt(d / am))
    vpeak = am * ta
    tc = np.where(full, (d - vpeak * ta) / np.maximum(vpeak, 1e-300), 0.0)
    total = 2 * ta + tc
    k = _scale(total, synchronized)
    ta, tc, total = ta * k, tc * k, total * k
    vpeak = np.where(ta + tc > 0, d / np.maximum(ta + tc, 1e-300), 0.0)
    acc = np.where(ta > 0, vpeak / np.maximum(ta, 1e-300), 0.0)
    t = _grid(total, dt)[:, None]
    t1, t2 = ta, ta + tc
    tt = np.minimum(t, total)
    up = tt < t1
    cruise = (tt >= t1) & (tt < t2)
    td = tt - t2
    pos = np.where(up, 0.5 * acc * tt ** 2,
                   np.where(cruise, 0.5 * acc * t1 ** 2 + vpeak * (tt - t1),
                            0.5 * acc * t1 ** 2 + vpeak * tc + vpeak * td - 0.5 * acc * td ** 2))
    vel = np.where(up, acc * tt, np.where(cruise, vpeak, vpeak - acc * td))
    accel = np.where(up, acc, np.where(cruise, 0.0, -acc))
    done = t >= np.minimum(total, t[-1])  # the last sample is the end (the grid rounds)
    pos = np.where(done, d, pos)
    vel = np.where(done, 0.0, vel)
    accel = np.where(done, 0.0, accel)
    return Trajectory(t[:, 0], s + sign * pos, sign * vel, sign * accel, total, dt)


def s_curve(start: ArrayLike, end: ArrayLike, vmax: ArrayLike, amax: ArrayLike,
            jmax: ArrayLike, dt: float, *, synchronized: bool = False) -> Trajectory:
    """Jerk-limited (seven-phase) profiles from ``start`` to ``end`` (see the module docstring)."""
    s, e, vm, am, jm = _axes(start, end, vmax, amax, jmax)
    d = np.abs(e - s)
    sign = np.sign(e - s)
    # acceleration phase for the velocity limit: Tj (jerk time) and Ta (whole phase)
    a_reached = vm * jm >= am * am
    tj = np.where(a_reached, am / jm, np.sqrt(vm / jm))
    ta = np.where(a_reached, tj + vm / am, 2 * tj)
    tv = d / vm - ta
    short = tv < 0                                 # the velocity limit is not reached
    a_short = d >= 2 * am ** 3 / jm ** 2
    tj_s = np.where(a_short, am / jm, np.cbrt(d / (2 * jm)))
    ta_s = np.where(a_short, tj_s / 2 + np.sqrt((tj_s / 2) ** 2 + d / am), 2 * tj_s)
    tj = np.where(short, tj_s, tj)
    ta = np.where(short, ta_s, ta)
    tv = np.where(short, 0.0, tv)
    total = 2 * ta + tv
    k = _scale(total, synchronized)
    tj, ta, tv, total = tj * k, ta * k, tv * k, total * k
    # the jerk that covers d exactly with these times: d = vlim (Ta + Tv), vlim = j Tj (Ta - Tj)
    denom = tj * (ta - tj) * (ta + tv)
    jerk = np.where(denom > 0, d / np.maximum(denom, 1e-300), 0.0)
    # seven phases: durations and jerks
    durs = np.stack([tj, ta - 2 * tj, tj, tv, tj, ta - 2 * tj, tj])
    jerks = np.stack([jerk, 0 * jerk, -jerk, 0 * jerk, -jerk, 0 * jerk, jerk])
    bounds = np.vstack([np.zeros_like(tj), np.cumsum(durs, axis=0)])
    # states at the phase starts
    p0 = np.zeros((8, len(d)))
    v0 = np.zeros((8, len(d)))
    a0 = np.zeros((8, len(d)))
    for i in range(7):
        h, j = durs[i], jerks[i]
        p0[i + 1] = p0[i] + v0[i] * h + a0[i] * h ** 2 / 2 + j * h ** 3 / 6
        v0[i + 1] = v0[i] + a0[i] * h + j * h ** 2 / 2
        a0[i + 1] = a0[i] + j * h
    t = _grid(total, dt)[:, None]
    pos = np.zeros((len(t), len(d)))
    vel = np.zeros_like(pos)
    acc = np.zeros_like(pos)
    for i in range(7):
        m = (t >= bounds[i]) & (t < bounds[i + 1])
        h = t - bounds[i]
        j = jerks[i]
        pos = np.where(m, p0[i] + v0[i] * h + a0[i] * h ** 2 / 2 + j * h ** 3 / 6, pos)
        vel = np.where(m, v0[i] + a0[i] * h + j * h ** 2 / 2, vel)
        acc = np.where(m, a0[i] + j * h, acc)
    done = t >= np.minimum(total, t[-1])  # the last sample is the end (the grid rounds)
    pos = np.where(done, d, pos)
    vel = np.where(done, 0.0, vel)
    acc = np.where(done, 0.0, acc)
    return Trajectory(t[:, 0], s + sign * pos, sign * vel, sign * acc, total, dt)
