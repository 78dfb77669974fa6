"""Device models: the behaviour of one device kind for all its instances in a segment.

A segment of 1,000 slaves must answer a cyclic frame in a fraction of its
wire time, so a device kind does not run Python per slave and per frame. One
:class:`DeviceModel` object per kind and segment holds the state of all the
kind's instances in arrays indexed by instance, and is called once per frame
with the instances concerned:

- :meth:`DeviceModel.on_outputs`: the master completed the output buffers of
  these instances in this frame (only when ``output_events`` is True: a kind
  without behaviour on outputs costs nothing);
- :meth:`DeviceModel.on_sync0`: the SYNC0 pulses of these instances fired
  (only when ``sync_events`` is True);
- :meth:`DeviceModel.on_state_change`: one instance changed its AL state
  (a rare event: plain Python per instance is fine there).

Process data go through :attr:`DeviceModel.io` (``sim.pdio.ProcessIo``): one
gather of the outputs of all the instances concerned, numpy work on the
state arrays, one scatter of their inputs. :meth:`DeviceModel.array` declares
a state array that grows with the instances.

Per-instance objects (a mailbox device with its protocol servers, a
``sim.device.DeviceApp``) stay for rare events; a kind may have none.
``docs/simulator.md`` ("Device models") walks through a new kind.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from pyethercat.sim.device import DeviceApp
from pyethercat.sim.pdio import ProcessIo
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import SiiInfo

__all__ = ["DeviceModel"]

I64 = npt.NDArray[np.int64]


class DeviceModel:
    """Base class of device models (see the module docstring)."""

    #: :meth:`on_outputs` is called when output buffers complete.
    output_events: ClassVar[bool] = False
    #: :meth:`on_sync0` is called when SYNC0 pulses fire.
    sync_events: ClassVar[bool] = False

    def __init__(self) -> None:
        #: Number of instances.
        self.count = 0
        #: Segment slave index of each instance (-1 until it is placed in a segment).
        self.slaves: I64 = np.zeros(0, np.int64)
        #: Process-data access of the segment (set when the first instance is placed).
        self.io: ProcessIo | None = None
        self._arrays: dict[str, tuple[npt.DTypeLike, Any]] = {}

    # --- state arrays ----------------------------------------------------------------

    def array(self, name: str, dtype: npt.DTypeLike, fill: Any = 0) -> npt.NDArray[Any]:
        """Declare a per-instance state array, kept as attribute ``name`` (grows with the instances)."""
        self._arrays[name] = (dtype, fill)
        arr = np.full(len(self.slaves), fill, dtype)
        setattr(self, name, arr)
        return arr

    def _grow(self, capacity: int) -> None:
        old = len(self.slaves)
        slaves = np.full(capacity, -1, np.int64)
        slaves[:old] = self.slaves
        self.slaves = slaves
        for name, (dtype, fill) in self._arrays.items():
            arr = np.full(capacity, fill, dtype)
            arr[:old] = getattr(self, name)
            setattr(self, name, arr)

    def new_instance(self) -> int:
        """Room for one more instance; its number (state arrays hold their fill values)."""
        if self.count == len(self.slaves):
            self._grow(max(4, 2 * self.count))
        self.count += 1
        return self.count - 1

    def instance_app(self, info: SiiInfo) -> tuple[int, DeviceApp | None]:
        """A new instance for a slave with SII ``info``: its number and its per-slave application.

        The default has no per-slave application; a kind with a mailbox
        returns one (``sim.coe_model.CoeModel``)."""
        return self.new_instance(), None

    def placed(self, instance: int, slave: int, io: ProcessIo) -> None:
        """The segment added ``instance`` as slave ``slave`` (called by ``Segment.add_slave``)."""
        self.slaves[instance] = slave
        self.io = io

    # --- events ------------------------------------------------------------------------

    def on_outputs(self, instances: I64) -> None:
        """Output buffers of ``instances`` (sorted, unique) completed in this frame."""

    def on_sync0(self, instances: I64, time_ns: int) -> None:
        """SYNC0 pulses of ``instances`` fired at system time ``time_ns`` (of the first of them)."""

    def on_state_change(self, instance: int, old: AlState, new: AlState) -> None:
        """One instance changed its AL state (also on error fall-backs)."""

    def on_power_on(self, instance: int) -> None:
        """One instance was powered on (also the first time)."""
