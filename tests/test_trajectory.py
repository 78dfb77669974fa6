"""Point-to-point profiles: exact ends, rest to rest, the limits kept, axes together."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import ConfigError
from pyethercat.trajectory import Trajectory, s_curve, trapezoid

DT = 0.001
TOL = 1 + 1e-9

moves = st.floats(-2e6, 2e6, allow_nan=False).filter(lambda d: abs(d) >= 1.0)
vmaxes = st.floats(1e3, 1e6)
amaxes = st.floats(1e4, 1e8)
jmaxes = st.floats(1e5, 1e10)


def check_rest_to_rest(tr: Trajectory, start: np.ndarray, end: np.ndarray,
                       amax: float = 4e6) -> None:
    assert np.allclose(tr.position[0], start) and np.array_equal(tr.position[-1], end)
    assert not tr.velocity[0].any() and not tr.velocity[-1].any()
    assert not tr.acceleration[-1].any()
    # no overshoot: every axis moves one way only
    steps = np.diff(tr.position, axis=0) * np.sign(end - start)
    assert (steps >= -1e-6 * np.maximum(np.abs(end - start), 1)).all()
    # the sampled velocity is the derivative of the sampled position: the trapezoidal rule
    # over one sample is off by at most amax dt^2 / 4 (the velocity bends by amax at most)
    mean_v = (tr.velocity[1:] + tr.velocity[:-1]) / 2
    err = np.abs(np.diff(tr.position, axis=0) - mean_v * DT).max(initial=0)
    assert err <= amax * DT * DT / 4 * TOL + 1e-6


@settings(max_examples=80, deadline=None)
@given(moves, vmaxes, amaxes)
def test_trapezoid_keeps_velocity_and_acceleration_limits(d: float, vmax: float, amax: float) -> None:
    tr = trapezoid(100.0, 100.0 + d, vmax, amax, DT)
    check_rest_to_rest(tr, np.array([100.0]), np.array([100.0 + d]), amax)
    assert np.abs(tr.velocity).max() <= vmax * TOL
    assert np.abs(np.diff(tr.position, axis=0)).max() <= vmax * DT * TOL
    assert np.abs(tr.acceleration).max() <= amax * TOL
    # the time it takes: a triangle below vmax^2/amax, else accelerate, cruise, brake
    want = 2 * np.sqrt(abs(d) / amax) if abs(d) < vmax ** 2 / amax else abs(d) / vmax + vmax / amax
    assert tr.duration[0] == pytest.approx(want, rel=1e-9)
    assert len(tr) == int(np.ceil(want / DT - 1e-9)) + 1


@settings(max_examples=80, deadline=None)
@given(moves, vmaxes, amaxes, jmaxes)
def test_s_curve_keeps_velocity_acceleration_and_jerk_limits(d: float, vmax: float, amax: float,
                                                               jmax: float) -> None:
    tr = s_curve(0.0, d, vmax, amax, jmax, DT)
    check_rest_to_rest(tr, np.array([0.0]), np.array([d]), amax)
    assert np.abs(tr.velocity).max() <= vmax * TOL
    assert np.abs(np.diff(tr.position, axis=0)).max() <= vmax * DT * TOL
    assert np.abs(tr.acceleration).max() <= amax * TOL
    # the acceleration is continuous: it changes by at most jmax per second
    assert np.abs(np.diff(tr.acceleration[:-1], axis=0)).max(initial=0) <= jmax * DT * TOL + 1e-6
    # never slower than the trapezoid with the same velocity and acceleration limits
    assert tr.duration[0] >= trapezoid(0.0, d, vmax, amax, DT).duration[0] * (1 - 1e-9)


def test_s_curve_reaches_each_limit_when_the_move_is_long() -> None:
    tr = s_curve(0, 1_000_000, vmax=400_000, amax=4e6, jmax=8e7, dt=DT)
    assert np.abs(tr.velocity).max() == pytest.approx(400_000, rel=1e-3)
    assert np.abs(tr.acceleration).max() == pytest.approx(4e6, rel=1e-2)
    # seven phases: Tj = a/j = 50 ms, Ta = Tj + v/a = 150 ms, cruise d/v - Ta = 2.35 s
    assert tr.duration[0] == pytest.approx(2 * 0.15 + 2.35, rel=1e-9)


def test_many_axes_with_their_own_limits_and_synchronized_moves() -> None:
    start = np.array([0.0, 1000.0, -500.0, 7.0])
    end = np.array([100_000.0, -49_000.0, 20_000.0, 7.0])     # the last one does not move
    vmax = np.array([4e5, 2e5, 1e5, 1e5])
    free = s_curve(start, end, vmax, 4e6, 8e7, DT)
    assert free.axes == 4 and len(np.unique(free.duration[:3])) == 3
    assert free.duration[3] == 0 and (free.position[:, 3] == 7.0).all()
    check_rest_to_rest(free, start, end)
    sync = s_curve(start, end, vmax, 4e6, 8e7, DT, synchronized=True)
    moving = sync.duration[:3]
    assert np.allclose(moving, free.duration.max())            # all take the slowest one's time
    check_rest_to_rest(sync, start, end)
    for k in range(3):                                          # the slowed axes stay in limits
        assert np.abs(sync.velocity[:, k]).max() <= vmax[k] * TOL
        assert np.abs(sync.acceleration[:, k]).max() <= 4e6 * TOL
        arrive = np.nonzero(sync.position[:, k] != end[k])[0].max()
        assert arrive == len(sync) - 2                          # all arrive at the last sample
    counts = sync.position_counts()
    assert counts.dtype == np.int64 and (counts[-1] == end.astype(np.int64)).all()
    trap = trapezoid(start, end, vmax, 4e6, DT, synchronized=True)
    assert np.allclose(trap.duration[:3], trap.duration.max())
    check_rest_to_rest(trap, start, end)


@pytest.mark.parametrize("call", [
    lambda: s_curve(0, 10, 0, 1, 1, DT),
    lambda: s_curve(0, 10, 1, -1, 1, DT),
    lambda: trapezoid(0, 10, float("inf"), 1, DT),
    lambda: trapezoid(0, float("nan"), 1, 1, DT),
    lambda: trapezoid(0, 10, 1, 1, 0.0),
])
def test_bad_limits_are_config_errors(call) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ConfigError):
        call()
