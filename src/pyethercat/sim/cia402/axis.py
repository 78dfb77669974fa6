"""Motor, load and the drive's inner control loops, for all axes of a drive kind at once.

Each axis is a rigid motor and load: inertia J, viscous friction b, Coulomb
friction (sticking at standstill up to its value), a constant load torque,
and a torque limit (0x6072 per mille of the rated torque 0x6076). The drive
controls it in cascade, as servo drives do: a position loop (gain 0x2100:06)
with velocity feed-forward, a PI velocity loop tuned from the inertia for the
bandwidth 0x2100:05, the torque limit with anti-windup. Position is kept in
encoder increments; the actual position is the encoder's count (quantised),
the actual velocity the change of that count over the cycle.

The loops run at an internal rate of at least 1 kHz, with steps short enough
that bandwidth x step of the velocity loop stays below 0.8: a cycle of ``dt`` is integrated
in that many substeps, the demand interpolated
linearly from the previous cycle's set-point to this one's (what drives do
between SYNC0 events). The number of numpy operations per cycle does not
depend on the number of axes.

The plan for the next cycle (``plan_*`` arrays) is set by the profile layer
(``sim.cia402.engine``): the control mode (off / position / velocity /
torque), the demand at the start and the end of the cycle, feed-forwards.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cia402.keys import all_of, any_of
from pyethercat.sim.cia402.objects import AXIS_OBJECT, AxisSub
from pyethercat.sim.coe_model import CoeModel
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire.mailbox.objects import Cia402Object
from pyethercat.wire.sii import SiiInfo

__all__ = ["AXIS_FIELDS", "AxisModel", "CTRL_OFF", "CTRL_POSITION", "CTRL_TORQUE",
           "CTRL_VELOCITY", "Rows"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Rows = slice | I64
_O: Any = SimpleNamespace(**{m.name: int(m) for m in Cia402Object})  # plain ints: cheap lookups
_AX: Any = SimpleNamespace(**{m.name: int(m) for m in AxisSub})
#: Control modes of a cycle's plan.
CTRL_OFF, CTRL_POSITION, CTRL_VELOCITY, CTRL_TORQUE = 0, 1, 2, 3
#: Longest internal loop period (s): at least 1 kHz.
_H_MAX = 1e-3
_MAX_SUBSTEPS = 64
#: Longest interval integrated at once (s): a drive whose events stopped for longer
#: does not jump (its own loops would have held the axis meanwhile).
_DT_MAX = 0.016
_TWO_PI = 2.0 * math.pi

#: Parameter entries the physics reads (image columns beyond the PDO-mappable ones).
AXIS_FIELDS: tuple[tuple[int, int], ...] = (
    *((AXIS_OBJECT, int(s)) for s in AxisSub),
    (_O.POSITION_ENCODER_RESOLUTION, 1), (_O.POSITION_ENCODER_RESOLUTION, 2),
    (_O.MOTOR_RATED_TORQUE, 0), (_O.MAX_TORQUE, 0), (_O.MAX_MOTOR_SPEED, 0),
)


class _Constants(NamedTuple):
    """Per-axis constants of the loops and the mechanics (arrays)."""

    counts_per_rad: F64
    inertia: F64
    kp: F64
    kv: F64
    ki: F64
    acc_gain: F64
    viscous: F64
    coulomb: F64
    load: F64
    max_torque: F64
    max_speed: F64


class AxisModel(CoeModel):
    """The physical axes of a drive kind and their inner loops (see the module docstring)."""

    def __init__(self, dictionary: Callable[[SiiInfo, MailboxDevice], SimObjectDictionary], *,
                 details: int, capacity_out: int = 128, capacity_in: int = 128,
                 fields: tuple[tuple[int, int], ...] = ()) -> None:
        super().__init__(dictionary, details=details, capacity_out=capacity_out,
                         capacity_in=capacity_in, fields=AXIS_FIELDS + fields)
        self._pcache: dict[tuple[int, int], F64] = {}
        self._consts: _Constants | None = None
        #: Figures derived from the cached constants (dropped with them).
        self._derived: dict[object, float | bool] = {}
        #: The constants of a slice of rows, as last handed out (dropped with the constants).
        self._row_consts: dict[tuple[int | None, int | None], _Constants] = {}
        self._live: frozenset[tuple[int, int]] | None = None
        self._tx: frozenset[tuple[int, int]] | None = None
        self._live_count = -1
        arr = self.array
        #: Motor position (raw encoder increments since power-on) and velocity (inc/s).
        self.p: F64 = arr("p", np.float64, 0.0)
        self.v: F64 = arr("v", np.float64, 0.0)
        #: Velocity-loop integrator and the last torque (N m).
        self.integ: F64 = arr("integ", np.float64, 0.0)
        self.torque: F64 = arr("torque", np.float64, 0.0)
        #: Encoder count published last (raw) for the velocity actual value.
        self.enc_prev: F64 = arr("enc_prev", np.float64, 0.0)
        #: Plan of the next cycle: control mode, demand from/to (raw inc), velocity and
        #: torque feed-forward, velocity command (velocity mode), torque command (N m).
        self.plan_mode = arr("plan_mode", np.int8, CTRL_OFF)
        self.plan_from: F64 = arr("plan_from", np.float64, 0.0)
        self.plan_to: F64 = arr("plan_to", np.float64, 0.0)
        self.plan_vff: F64 = arr("plan_vff", np.float64, 0.0)
        self.plan_tff: F64 = arr("plan_tff", np.float64, 0.0)
        #: Acceleration of the demand over the next cycle (inc/s²), the one the torque
        #: feed-forward assumes: the demand between set-points is a parabola with it.
        self.plan_acc: F64 = arr("plan_acc", np.float64, 0.0)
        self.plan_v: F64 = arr("plan_v", np.float64, 0.0)
        self.plan_t: F64 = arr("plan_t", np.float64, 0.0)

    # --- parameters --------------------------------------------------------------------

    def col(self, index: int, sub: int, r: Rows) -> F64:
        """Entry ``index:sub`` of rows ``r`` as float64 (read-only).

        Parameters change only by SDO, so their float columns are cached until
        one is written; entries a PDO maps into the outputs are read afresh.
        """
        key = (index, sub)
        cached = self._pcache.get(key)
        if cached is None:
            cached = self.field(index, sub).astype(np.float64)
            if key not in self._live_keys():
                self._pcache[key] = cached
        out: F64 = cached[r]
        return out

    def _live_keys(self) -> frozenset[tuple[int, int]]:
        """Entries some instance's PDO layout maps into its outputs."""
        self._layout_keys()
        assert self._live is not None
        return self._live

    def tx_keys(self) -> frozenset[tuple[int, int]]:
        """Entries some instance's PDO layout maps into its inputs."""
        self._layout_keys()
        assert self._tx is not None
        return self._tx

    def _layout_keys(self) -> None:
        if self._live is None or self._live_count != len(self._layouts):
            rx: set[tuple[int, int]] = set()
            tx: set[tuple[int, int]] = set()
            for layout in self._layouts:
                rx |= layout.rx_keys
                tx |= layout.tx_keys
            self._live, self._tx = frozenset(rx), frozenset(tx)
            self._live_count = len(self._layouts)

    def _write(self, instance: int, key: tuple[int, int], raw: bytes) -> None:
        super()._write(instance, key, raw)
        self._pcache.pop(key, None)
        self._consts = None

    def _grow(self, capacity: int) -> None:
        super()._grow(capacity)
        self._pcache.clear()
        self._consts = None

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        instance, app = super().instance_app(info)
        self._pcache.clear()
        self._consts = None
        return instance, app

    def constants(self, r: Rows) -> _Constants:
        """The loops' gains and the mechanics of rows ``r``, from the parameters (cached with them)."""
        consts = self._consts
        key = (r.start, r.stop) if isinstance(r, slice) else None
        if consts is not None and key is not None:
            hit = self._row_consts.get(key)
            if hit is not None:  # the same rows as last time: their views
                return hit
        if consts is None:
            live = self._live_keys()
            every = slice(None)
            col = self.col
            k = self.counts_per_rad(every)
            j = col(AXIS_OBJECT, _AX.INERTIA, every)
            wv = _TWO_PI * col(AXIS_OBJECT, _AX.VELOCITY_BANDWIDTH, every)
            kv = j * wv / k                              # N m per (inc/s)
            consts = _Constants(
                k, j, col(AXIS_OBJECT, _AX.POSITION_GAIN, every), kv,
                kv * wv * 0.25,                          # N m per inc (per s of error)
                k / np.maximum(j, 1e-12),                # inc/s² per N m
                col(AXIS_OBJECT, _AX.VISCOUS_FRICTION, every) / k,
                col(AXIS_OBJECT, _AX.COULOMB_FRICTION, every),
                col(AXIS_OBJECT, _AX.LOAD_TORQUE, every),
                self.max_torque(every), self.max_speed(every))
            if not any(field in live for field in AXIS_FIELDS):
                self._consts = consts
                self._derived = {}
                self._row_consts = {}
        out = _Constants(*(a[r] for a in consts))
        if key is not None and self._consts is not None:
            self._row_consts[key] = out
        return out

    def counts_per_rad(self, r: Rows) -> F64:
        """Encoder increments per radian (0x608F:01 per 0x608F:02 revolutions)."""
        inc = self.col(_O.POSITION_ENCODER_RESOLUTION, 1, r)
        rev = np.maximum(self.col(_O.POSITION_ENCODER_RESOLUTION, 2, r), 1.0)
        out: F64 = np.maximum(inc, 1.0) / rev / _TWO_PI
        return out

    def max_torque(self, r: Rows) -> F64:
        """Torque limit (N m): 0x6072 per mille of 0x6076 mNm."""
        out: F64 = self.col(_O.MAX_TORQUE, 0, r) * self.col(_O.MOTOR_RATED_TORQUE, 0, r) * 1e-6
        return out

    def max_speed(self, r: Rows) -> F64:
        """Speed limit (inc/s) from 0x6080 max motor speed (rpm); infinite when 0."""
        rpm = self.col(_O.MAX_MOTOR_SPEED, 0, r)
        out: F64 = np.where(rpm > 0, rpm / 60.0 * _TWO_PI * self.counts_per_rad(r), np.inf)
        return out

    def max_acceleration(self, r: Rows) -> F64:
        """What the torque limit can do against inertia and friction (inc/s²)."""
        j = self.col(AXIS_OBJECT, _AX.INERTIA, r)
        spare = np.maximum(self.max_torque(r) - self.col(AXIS_OBJECT, _AX.COULOMB_FRICTION, r)
                           - np.abs(self.col(AXIS_OBJECT, _AX.LOAD_TORQUE, r)), 0.0)
        out: F64 = spare / j * self.counts_per_rad(r)
        return out

    # --- integration ---------------------------------------------------------------------

    def integrate(self, r: Rows, dt: F64) -> None:
        """Run the loops and the mechanics of rows ``r`` over ``dt`` seconds along their plan."""
        dt = np.minimum(np.maximum(dt, 0.0), _DT_MAX)
        longest = float(dt.max()) if len(dt) else 0.0
        if longest <= 0.0:
            return
        _k, _j, kp, kv, ki, acc_gain, b, tc, load, tmax, vmax = self.constants(r)
        # at least 1 kHz, and few enough steps per velocity-loop time constant that the
        # explicit integration stays well damped (bandwidth x step < 0.8)
        wv_max = self._bandwidth_max(r, _k, _j, kv)
        n = min(_MAX_SUBSTEPS, max(1, math.ceil(longest / _H_MAX - 1e-9),
                                   math.ceil(longest * wv_max / 0.8 - 1e-9)))
        h = dt / n
        mode = self.plan_mode[r]
        pos = mode == CTRL_POSITION
        all_pos = all_of(pos)
        if all_pos:  # the usual cycle (CSP, PP, stops): no mask work
            any_torque, trq, all_on, on = False, pos, True, pos
        else:
            any_torque = any_of(mode == CTRL_TORQUE)
            trq = mode == CTRL_TORQUE
            all_on = all_of(mode != CTRL_OFF)
            on = (mode != CTRL_OFF).astype(np.float64)
        limit_speed = self._limit_speed(vmax)
        # The demand between two set-points: a parabola from plan_from to plan_to whose
        # acceleration is the one the torque feed-forward gives the axis, its velocity
        # (the velocity feed-forward) ramping from vff - acc dt/2 to vff + acc dt/2. A
        # straight line with the cycle's mean velocity would make the velocity loop fight
        # the torque feed-forward (ahead of the ramp early in the cycle, behind it late)
        # and push the axis ahead of the demand while it accelerates.
        acc = self.plan_acc[r]
        acc_h = acc * h
        acc_hh = acc_h * h
        pref = self.plan_from[r]
        step_p = (self.plan_to[r] - pref) / n - acc_hh * (0.5 * (n - 1))  # first substep
        vff = self.plan_vff[r] - acc_h * (0.5 * n)                     # at the start
        tff = self.plan_tff[r]
        vcmd, tcmd = self.plan_v[r], self.plan_t[r]
        p, v, integ = self.p[r], self.v[r], self.integ[r]
        ki_h, gain_h = ki * h, acc_gain * h
        neg_tmax, neg_tc, half_h = -tmax, -tc, 0.5 * h
        neg_vmax = -vmax if limit_speed else vmax
        tq = np.zeros_like(p)
        for step in range(1, n + 1):
            # ufunc minimum/maximum rather than np.clip: clip's Python wrapper costs more
            # than the arithmetic on these short arrays
            if step > 1:  # the demand and its velocity where the substep starts
                pref = pref + step_p
                step_p = step_p + acc_hh
                vff = vff + acc_h
            vref = vff + kp * (pref - p) if all_pos else np.where(pos, vff + kp * (pref - p), vcmd)
            if limit_speed:
                vref = np.minimum(np.maximum(vref, neg_vmax), vmax)
            ev = vref - v
            integ = np.minimum(np.maximum(integ + ki_h * ev, neg_tmax), tmax)
            tq = kv * ev + integ + tff
            if any_torque:
                tq = np.where(trq, np.where(np.abs(v) > vmax, 0.0, tcmd), tq)
            if not all_on:
                integ = integ * on
                tq = tq * on
            tq = np.minimum(np.maximum(tq, neg_tmax), tmax)
            drive = tq - load - b * v
            vn = v + (drive - tc * np.sign(v)) * gain_h
            stick = vn * v <= 0.0  # standing, or friction would turn the axis round
            if any_of(stick):
                # Coulomb friction holds the axis up to its value, and only stops it
                rest = drive - np.minimum(np.maximum(drive, neg_tc), tc)
                vn = np.where(stick, np.where(np.abs(drive) <= tc, 0.0, rest * gain_h), vn)
            p = p + (v + vn) * half_h
            v = vn
        self.p[r], self.v[r], self.integ[r], self.torque[r] = p, v, integ, tq

    def _bandwidth_max(self, r: Rows, k: F64, j: F64, kv: F64) -> float:
        """Highest velocity-loop bandwidth (rad/s) of rows ``r`` (cached with the constants
        when they are for every instance)."""
        key = ("wv", r.start, r.stop) if isinstance(r, slice) else None
        if key is not None and self._consts is not None and key in self._derived:
            return float(self._derived[key])
        out = float((kv / np.maximum(j / k, 1e-300)).max(initial=0.0))
        if key is not None and self._consts is not None:
            self._derived[key] = out
        return out

    def _limit_speed(self, vmax: F64) -> bool:
        """Some axis has a speed limit (cached with the constants)."""
        cached = self._derived.get("vmax") if self._consts is not None else None
        if cached is not None:
            return bool(cached)
        out = bool(np.isfinite(vmax).any())
        if self._consts is not None and len(vmax) == self.count:
            self._derived["vmax"] = out
        return out

    def encoder(self, r: Rows) -> F64:
        """The encoder's count (raw increments, whole numbers)."""
        out: F64 = np.floor(self.p[r] + 0.5)
        return out

    def reset_axis(self, instance: int) -> None:
        """Power-on: the axis stands at raw position 0 with its loops idle."""
        for name in ("p", "v", "integ", "torque", "enc_prev", "plan_from", "plan_to",
                     "plan_vff", "plan_tff", "plan_acc", "plan_v", "plan_t"):
            arr: Any = getattr(self, name)
            arr[instance] = 0.0
        self.plan_mode[instance] = CTRL_OFF
