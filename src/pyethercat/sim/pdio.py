"""Process data of many slaves at once: one gather of outputs, one scatter of inputs.

A device model (``sim.model``) handles all instances of its kind with array
operations. :class:`ProcessIo` gives it the PDI side of the process data for
any set of slaves:

- :meth:`ProcessIo.outputs` is one gather from the complete-buffer shadow
  (what each ESC's PDI reads of its output SM: the newest buffer the master
  completed, ESC datasheet section I "SyncManager", 3-buffer mode);
- :meth:`ProcessIo.set_inputs` is one scatter into the input SMs' buffers
  and one table lookup that advances their SM status (buffer index, write
  event), as a PDI write of the buffer's last byte does.

The index arrays of a set of slaves are computed once per SM configuration
(the SM start addresses come from the registers the master wrote) and cached.
A slave whose output (input) SM is not enabled, not buffered or of the wrong
direction is left out: its outputs read as zeros, its inputs are not written.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.sim.access import buffer_written
from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory
from pyethercat.wire import registers as R

__all__ = ["ProcessIo"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
_BUFFERED = int(R.SmMode.BUFFERED)
#: SM status after the PDI completed an input buffer, by old status.
_AFTER_PDI_WRITE = np.array([buffer_written(old) & 0xFF for old in range(256)], np.uint8)


class _Gather:
    """Index arrays of one (slaves, length, direction) shape."""

    __slots__ = ("idx", "valid", "all_valid", "status")

    def __init__(self, idx: I64, valid: npt.NDArray[np.bool_], status: I64) -> None:
        self.idx = idx
        self.valid = valid
        self.all_valid = bool(valid.all())
        self.status = status


class ProcessIo:
    """Process-data access for sets of slaves (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc], now_ns: Callable[[], int],
                 has_outputs: Callable[[int], bool]) -> None:
        self.memory = memory
        self.escs = escs
        #: The segment's time.
        self.now_ns = now_ns
        #: Whether a slave received a complete output buffer since it entered SAFEOP.
        self.has_outputs = has_outputs
        self._plans: dict[tuple[bytes, int, bool], _Gather] = {}
        #: Counts the invalidations: index arrays a model derives from :meth:`plan`
        #: (fused with its own) are good while this is unchanged.
        self.version = 0

    def invalidate(self) -> None:
        """SM registers changed: index arrays are computed again when next used."""
        self._plans.clear()
        self.version += 1

    def plan(self, slaves: I64, length: int, outputs: bool) -> _Gather:
        """The index arrays of ``slaves``' output (input) buffers, ``length`` bytes each:
        ``idx`` (len(slaves), length) into the memory (:attr:`EscMemory.shadow_flat`
        for outputs, :attr:`EscMemory.flat` for inputs), ``valid`` where a buffer
        byte is, ``status`` the input SMs' status bytes. Good until :attr:`version` moves."""
        return self._plan(slaves, length, outputs)

    def _plan(self, slaves: I64, length: int, outputs: bool) -> _Gather:
        key = (slaves.tobytes(), length, outputs)
        plan = self._plans.get(key)
        if plan is not None:
            return plan
        stride = self.memory.stride
        k = len(slaves)
        starts = np.zeros(k, np.int64)
        valid = np.zeros((k, length), bool)
        status = np.full(k, -1, np.int64)
        for j, s in enumerate(slaves.tolist()):
            esc = self.escs[s]
            n = esc.output_sm if outputs else esc.input_sm
            if n >= esc.profile.sm_count:
                continue
            sm = esc.sm(n)
            if not sm.enabled or sm.mode != _BUFFERED or sm.ecat_writes != outputs:
                continue
            starts[j] = sm.start
            valid[j, : min(length, sm.length, R.ADDRESS_SPACE - sm.start)] = True
            status[j] = s * stride + R.sm_address(n) + R.SM_STATUS
        idx = slaves[:, None] * stride + starts[:, None] + np.arange(length, dtype=np.int64)
        # Positions without a buffer point at the slave's first byte (read, then zeroed).
        idx = np.where(valid, idx, slaves[:, None] * stride)
        plan = _Gather(idx, valid, status[status >= 0] if not outputs else status)
        if len(self._plans) > 4096:
            self._plans.clear()
        self._plans[key] = plan
        return plan

    def outputs(self, slaves: I64, length: int) -> U8:
        """The newest complete output buffers of ``slaves``: (len(slaves), length) bytes."""
        plan = self._plan(slaves, length, True)
        data: U8 = self.memory.shadow_flat[plan.idx]
        if not plan.all_valid:
            data[~plan.valid] = 0
        return data

    def set_inputs(self, slaves: I64, data: U8) -> None:
        """Write (len(slaves), n) input bytes as complete input buffers."""
        plan = self._plan(slaves, data.shape[1], False)
        flat = self.memory.flat
        if plan.all_valid:
            flat[plan.idx] = data
        else:
            flat[plan.idx[plan.valid]] = data[plan.valid]
        self.inputs_written(plan.status)

    def inputs_written(self, status: I64) -> None:
        """The PDI wrote the last byte of the input buffers whose SM status bytes are ``status``
        (indices into :attr:`EscMemory.flat`): buffer index and write event advance."""
        if len(status):
            flat = self.memory.flat
            flat[status] = _AFTER_PDI_WRITE[flat[status]]
