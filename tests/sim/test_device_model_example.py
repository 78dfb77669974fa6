"""The worked example of docs/simulator.md ("Device models"), run end to end.

A new device kind, ``inv8``: one output byte, one input byte; the inputs
are the outputs inverted, one frame later, and a per-instance counter counts
the output buffers each instance received. The code of the kind below is
the code the document shows; the tests take it through our master to OP
and check the behaviour per slave, and that the kind costs one call per
frame however many instances it has.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.sim.devices import DEVICES
from pyethercat.sim.devices.builtin import BuiltinDevice, BuiltinPdo, BuiltinPdoEntry, BuiltinSm
from pyethercat.sim.devices.registry import DeviceRegistry
from pyethercat.sim.model import DeviceModel
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import FmmuUsage, SiiPortType, SyncManagerType

# --- the example (docs/simulator.md, "Device models") ------------------------------------------


class InverterModel(DeviceModel):
    """All ``inv8`` slaves of a segment: inputs = outputs inverted."""

    output_events = True  # on_outputs runs when output buffers complete

    def __init__(self) -> None:
        super().__init__()
        # One entry per instance, grown by the base class as instances come.
        self.received = self.array("received", np.uint32)

    def on_outputs(self, instances: npt.NDArray[np.int64]) -> None:
        assert self.io is not None
        slaves = self.slaves[instances]
        out = self.io.outputs(slaves, 1)      # one gather: (len(instances), 1) bytes
        self.received[instances] += 1         # state arrays indexed by instance
        self.io.set_inputs(slaves, ~out)      # one scatter, SM status advanced


INV8 = BuiltinDevice(
    key="inv8", product_code=0x00050008, order="PEC-INV8", name="PEC-INV8 8 bit inverter",
    group="DigOut", profile="ET1200",
    ports=(SiiPortType.EBUS, SiiPortType.EBUS, SiiPortType.NOT_USED, SiiPortType.NOT_USED),
    sync_managers=(
        BuiltinSm(0x1000, 1, R.sm_control(R.SmMode.BUFFERED, R.SmDirection.WRITE), SyncManagerType.OUTPUTS),
        BuiltinSm(0x1100, 1, R.sm_control(R.SmMode.BUFFERED, R.SmDirection.READ), SyncManagerType.INPUTS),
    ),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.INPUTS),
    rx_pdos=(BuiltinPdo(0x1600, 0, "Outputs", (BuiltinPdoEntry(0x7000, 1, 8, "Out", 5),)),),
    tx_pdos=(BuiltinPdo(0x1A00, 1, "Inputs", (BuiltinPdoEntry(0x6000, 1, 8, "In", 5),)),),
    model=InverterModel,
)

# --- the tests ---------------------------------------------------------------------------------


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> DeviceRegistry:
    """A registry with the example kind (the shared one stays as it was)."""
    reg = DeviceRegistry()
    reg.register(INV8)
    monkeypatch.setattr("pyethercat.sim.devices.DEVICES", reg)
    return reg


TOPOLOGY = "".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:{k}"\n'
                   for i, k in enumerate(["coupler", "inv8", "do8", "inv8", "inv8"]))


def _in_op_then_stepped(m: Master) -> CyclicRunner:
    """Bring the segment to OP, then end the cyclic thread (the slaves stay in OP).

    The checks step frames by hand with ``exchange_once``: a loop thread on a
    virtual clock runs as many cycles as real time lets it, which a loaded host
    made too few for the frame the inputs follow.
    """
    runner = m.start(cycle=0.001, clock=VirtualClock())
    runner.halt()
    return runner


def test_the_example_kind_runs_under_our_master(registry: DeviceRegistry) -> None:
    seg = parse_topology(TOPOLOGY).build(clock=VirtualClock())
    models = {type(m) for m in seg.apps.models}
    assert InverterModel in models and "inv8" not in DEVICES
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.configure()
    runner = _in_op_then_stepped(m)
    assert all(s.al_state == AlState.OP for s in m.slaves)
    inv = [s for s in m.slaves if s.name.startswith("PEC-INV8")]
    assert len(inv) == 3
    for value in (0x00, 0x5A, 0xFF, 0x81):
        for k, s in enumerate(inv):
            s.outputs["Out"] = (value + k) & 0xFF
        assert runner.exchange_once()  # the outputs reach the slaves
        assert runner.exchange_once()  # the inputs follow one frame later
        assert [s.inputs["In"] for s in inv] == [~(value + k) & 0xFF for k in range(3)]
    model = next(x for x in seg.apps.models if isinstance(x, InverterModel))
    assert model.count == 3 and (model.received[: model.count] > 0).all()


def test_one_call_per_frame_for_all_instances(registry: DeviceRegistry,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """The kind's cost does not grow with Python per instance: one on_outputs per frame."""
    seg = parse_topology("".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:inv8"\n'
                                 for i in range(50))).build(clock=VirtualClock())
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.configure()
    runner = _in_op_then_stepped(m)
    model = next(x for x in seg.apps.models if isinstance(x, InverterModel))
    calls: list[int] = []
    original = model.on_outputs

    def counted(instances: npt.NDArray[np.int64]) -> None:
        calls.append(len(instances))
        original(instances)

    monkeypatch.setattr(model, "on_outputs", counted)
    for _ in range(5):
        assert runner.exchange_once()
    assert calls == [50] * 5  # every frame: one call for the 50 instances
