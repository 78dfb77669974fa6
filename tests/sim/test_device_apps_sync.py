"""SYNC0 pulses reach device models through sim.apps.DeviceApps: one call per model and flush."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.sim.apps import DeviceApps
from pyethercat.sim.model import DeviceModel


class PulseLog(DeviceModel):
    """A model that takes SYNC0 pulses and writes down each call."""

    sync_events = True

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[list[int], int]] = []

    def on_sync0(self, instances: npt.NDArray[np.int64], time_ns: int) -> None:
        self.calls.append((instances.tolist(), time_ns))


def test_each_model_gets_its_instances_sorted_once_per_flush() -> None:
    a, b = PulseLog(), PulseLog()
    apps = DeviceApps()
    # slaves 0..4: a#1, b#0, a#0, (none), b#1 - the instances of a out of slave order
    for model, instance in ((a, 1), (b, 0), (a, 0), (None, 0), (b, 1)):
        apps.add(None, model, instance)
    every = np.array([0, 1, 2, 4])
    times = np.array([1000, 1001, 1002, 1004], np.uint64)  # (each slave's first pulse)
    for cycle in range(3):  # the same slave set each cycle: the split is reused
        apps.sync0_models(every, times + cycle)
        apps.flush()
    assert a.calls == [([0, 1], 1000), ([0, 1], 1001), ([0, 1], 1002)]
    assert b.calls == [([0, 1], 1001), ([0, 1], 1002), ([0, 1], 1003)]
    # two calls before a flush (pulses of a part of the segment, then of all of it):
    # each model once, each instance once, at the time of its first call
    a.calls.clear()
    b.calls.clear()
    apps.sync0_models(np.array([2, 4]), np.array([2002, 2004], np.uint64))
    apps.sync0_models(every, times + 1000)
    apps.flush()
    assert a.calls == [([0, 1], 2002)]
    assert b.calls == [([0, 1], 2004)]
    apps.flush()  # nothing pending: no call
    assert len(a.calls) == len(b.calls) == 1
