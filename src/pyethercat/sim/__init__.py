"""The EtherCAT network simulator: a segment of register-level ESC models.

Typical use::

    from pyethercat.sim import load_topology

    segment = load_topology("demo.toml").build()   # a Segment
    reply = segment.process(frame)                  # one Ethernet frame in, its return out

- :class:`Segment`: the slaves, their wiring and faults; ``process(frame)``
  walks one frame through them.
- :func:`load_topology` / :func:`parse_topology`: a topology TOML file (or
  text) -> :class:`Topology`; :func:`build_segment` (or ``Topology.build()``)
  makes the segment.
- :class:`VirtualClock` / :class:`WallClock`: the segment's time source.
- :mod:`pyethercat.sim.server`: serve a segment on an interface, UDP or a
  Unix socket (``pyethercat sim``).

The names are loaded on first use, so importing a submodule stays cheap.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pyethercat.clock import VirtualClock, WallClock
    from pyethercat.sim.segment import Segment
    from pyethercat.sim.topology import Topology, build_segment, load_topology, parse_topology

__all__ = [
    "Segment",
    "Topology",
    "VirtualClock",
    "WallClock",
    "build_segment",
    "load_topology",
    "parse_topology",
]

_HOME = {
    "Segment": "pyethercat.sim.segment",
    "Topology": "pyethercat.sim.topology",
    "build_segment": "pyethercat.sim.topology",
    "load_topology": "pyethercat.sim.topology",
    "parse_topology": "pyethercat.sim.topology",
    "VirtualClock": "pyethercat.clock",
    "WallClock": "pyethercat.clock",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'pyethercat.sim' has no attribute {name!r}")
    return getattr(import_module(home), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
