"""pyethercat: an EtherCAT master and a register-level EtherCAT network simulator.

Run a segment with the master::

    from pyethercat import Master

    with Master.open(iface="eth1") as master:     # or udp="host:34980", or link=...
        master.scan()                             # addresses, SII, topology
        master.configure()                        # process image: slave.inputs / outputs
        with master.start(cycle=0.001):           # to OP, cyclic exchange at 1 kHz
            master.slaves[1].outputs["Output 1"] = 1

Simulate one (no hardware)::

    from pyethercat import load_topology

    segment = load_topology("demo.toml").build()  # a Segment; segment.process(frame)

and run the master on it in the same process::

    from pyethercat.link import PairLink

    master = Master(PairLink.responder_link(segment.process))

Names here:

- :class:`Master`, :class:`Slave`: the master (``pyethercat.master``).
- :class:`AlState`: the EtherCAT state machine's states (INIT, PREOP, ...).
- :mod:`errors`: every error pyethercat raises; all derive from
  :class:`EtherCATError`.
- :class:`Segment`, :func:`load_topology`: the simulator (``pyethercat.sim``).

The master and the simulator load on first use: ``import pyethercat`` is cheap,
and using the master does not load the simulator (nor the other way round).
Lower layers: ``pyethercat.wire`` (codecs), ``pyethercat.link`` (frame
transports), ``pyethercat.esi`` (ESI/ENI files).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from pyethercat import errors
from pyethercat.errors import EtherCATError

if TYPE_CHECKING:
    from pyethercat.master.master import Master
    from pyethercat.master.slave import Slave
    from pyethercat.sim.segment import Segment
    from pyethercat.sim.topology import load_topology
    from pyethercat.version import __version__
    from pyethercat.wire.al import AlState

__all__ = [
    "AlState",
    "EtherCATError",
    "Master",
    "Segment",
    "Slave",
    "__version__",
    "errors",
    "load_topology",
]

# Where each lazily loaded name lives.
_HOME = {
    "Master": "pyethercat.master.master",
    "Slave": "pyethercat.master.slave",
    "AlState": "pyethercat.wire.al",
    "Segment": "pyethercat.sim.segment",
    "load_topology": "pyethercat.sim.topology",
    "__version__": "pyethercat.version",
}


def __getattr__(name: str) -> Any:
    # Lazy, so that ``import pyethercat.wire...`` does not pull in the master or the simulator.
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'pyethercat' has no attribute {name!r}")
    return getattr(import_module(home), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
