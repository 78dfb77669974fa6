"""The device applications and device models of a segment, called on ESC events.

Two kinds of behaviour sit behind a slave (``docs/simulator.md``, "Device
models"):

- a device model (``sim.model.DeviceModel``): one object per device kind
  handles all instances of the kind with array operations; it is called
  once per frame with the instances whose output buffers completed, once per
  tick with those whose SYNC0 fired, and per instance for state changes;
- a device application (``sim.device.DeviceApp``): one object per slave for
  rare events (mailbox, state changes). One that sets ``wants_output_events``
  is called per slave on completed outputs: simple, and slow at scale.

:class:`DeviceApps` routes the events. The grouping of a frame's completed
slaves by model is cached by the set of slaves (cyclic frames complete the
same set every cycle), so a frame costs one dictionary lookup plus the
models' own work.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cache import ArrayKeyCache
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.model import DeviceModel
from pyethercat.wire.al import AlState

__all__ = ["DeviceApps"]

I64 = npt.NDArray[np.int64]
#: What completed output buffers of one set of slaves call: models with their
#: instances, and the slaves whose per-slave applications asked.
_Groups = tuple[tuple[tuple[DeviceModel, I64], ...], tuple[int, ...]]


class DeviceApps:
    """Applications and models by slave index (see the module docstring)."""

    def __init__(self) -> None:
        self.apps: list[DeviceApp | None] = []
        self.models: list[DeviceModel] = []
        #: Per slave: index into :attr:`models` (-1: none) and instance number.
        self.model_id: I64 = np.zeros(0, np.int64)
        self.instance: I64 = np.zeros(0, np.int64)
        #: Per slave: the application wants :meth:`DeviceApp.on_outputs` calls.
        self.wants_outputs = np.zeros(0, bool)
        self._output_models: list[int] = []
        #: Whether any model or application is called on completed outputs (else a frame's
        #: completed outputs cost no lookup here).
        self._listening = False
        self._sync_models: list[int] = []
        self._groups: ArrayKeyCache[_Groups] = ArrayKeyCache()
        self._pulses: dict[int, tuple[list[I64], int]] = {}
        #: sync0_models' split of a slave set by model: (model, first position, instances).
        self._sync_split: ArrayKeyCache[list[tuple[int, int, I64]]] = ArrayKeyCache(256)

    def add(self, app: DeviceApp | None, model: DeviceModel | None, instance: int) -> None:
        self.apps.append(app)
        self.model_id = np.append(self.model_id, self._model_index(model))
        self.instance = np.append(self.instance, instance)
        self.wants_outputs = np.append(self.wants_outputs, bool(app is not None and app.wants_output_events))
        self._groups.clear()
        self._sync_split.clear()
        self._listen()

    def replace(self, slave: int, app: DeviceApp | None, model: DeviceModel | None,
                instance: int) -> None:
        """Slave ``slave`` is another device now (hot swap); its old model instance is left idle."""
        self.apps[slave] = app
        self.model_id[slave] = self._model_index(model)
        self.instance[slave] = instance
        self.wants_outputs[slave] = bool(app is not None and app.wants_output_events)
        self._groups.clear()
        self._sync_split.clear()
        self._listen()

    def _model_index(self, model: DeviceModel | None) -> int:
        if model is None:
            return -1
        if model not in self.models:
            self.models.append(model)
            if model.output_events:
                self._output_models.append(len(self.models) - 1)
            if model.sync_events:
                self._sync_models.append(len(self.models) - 1)
        return self.models.index(model)

    def _group(self, slaves: I64) -> _Groups:
        groups = self._groups.get(slaves)
        if groups is None:
            mids = self.model_id[slaves]
            models = tuple((self.models[m], np.sort(self.instance[slaves[mids == m]]))
                           for m in self._output_models if (mids == m).any())
            legacy = tuple(slaves[self.wants_outputs[slaves]].tolist())
            groups = (models, legacy)
            self._groups.put(slaves, groups)
        return groups

    def _listen(self) -> None:
        self._listening = bool(self._output_models) or bool(self.wants_outputs.any())

    @property
    def listening(self) -> bool:
        """Whether any device model or application wants to hear of new outputs."""
        return self._listening

    def outputs_completed(self, slaves: I64) -> None:
        """New complete output buffers of ``slaves`` (one frame's worth)."""
        if not self._listening:
            return
        models, legacy = self._group(slaves)
        for model, instances in models:
            model.on_outputs(instances)
        apps = self.apps
        for s in legacy:
            app = apps[s]
            if app is not None:
                app.on_outputs()

    def state_changed(self, slave: int, old: AlState, new: AlState) -> None:
        mid = int(self.model_id[slave])
        if mid >= 0:
            self.models[mid].on_state_change(int(self.instance[slave]), old, new)

    def power_on(self, slave: int) -> None:
        mid = int(self.model_id[slave])
        if mid >= 0:
            self.models[mid].on_power_on(int(self.instance[slave]))
        app = self.apps[slave]
        if app is not None:
            app.on_power_on()

    # --- SYNC0 -------------------------------------------------------------------------

    def sync0(self, slave: int, time_ns: int) -> None:
        """A SYNC0 pulse of ``slave``: its application now, its model with the others at :meth:`flush`."""
        app = self.apps[slave]
        if app is not None:
            app.on_sync0(time_ns)
        mid = int(self.model_id[slave])
        if mid >= 0 and self.models[mid].sync_events:
            self._pulse(mid, self.instance[slave:slave + 1], time_ns)

    def sync0_models(self, slaves: I64, times: npt.NDArray[np.uint64]) -> None:
        """SYNC0 pulses of ``slaves`` whose applications do not listen (system time of each
        one's first pulse): their models take them at :meth:`flush`, no Python per slave."""
        split = self._sync_split.get(slaves)
        if split is None:
            # Per model that takes pulses: the position of its first slave among ``slaves``
            # and its instances, sorted (the same slave sets pulse every cycle).
            mids = self.model_id[slaves]
            split = []
            for mid in self._sync_models:
                where = np.flatnonzero(mids == mid)
                if len(where):
                    mine = np.sort(self.instance[slaves[where]])
                    mine.flags.writeable = False  # (handed to the model every cycle)
                    split.append((mid, int(where[0]), mine))
            self._sync_split.put(slaves, split)
        for mid, first, instances in split:
            self._pulse(mid, instances, int(times[first]))

    def _pulse(self, mid: int, instances: I64, time_ns: int) -> None:
        pending = self._pulses.get(mid)
        if pending is None:
            self._pulses[mid] = ([instances], time_ns)
        else:
            pending[0].append(instances)

    def flush(self) -> None:
        """Hand the SYNC0 pulses collected since the last flush to their models (one call each)."""
        if not self._pulses:
            return
        pulses, self._pulses = self._pulses, {}
        for mid, (parts, time_ns) in pulses.items():
            # (one part: sorted instances of distinct slaves; several may overlap)
            instances = parts[0] if len(parts) == 1 else np.unique(np.concatenate(parts))
            self.models[mid].on_sync0(instances, time_ns)

    @property
    def sync_models(self) -> Sequence[int]:
        """Models that take SYNC0 pulses (indices into :attr:`models`)."""
        return self._sync_models
