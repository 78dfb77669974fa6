"""The registry of simulated device kinds: ``device = "builtin:<key>"`` in a topology file.

Device kinds (:class:`~pyethercat.sim.devices.builtin.BuiltinDevice`) come
from providers, loaded the first time the registry is asked:

- the kinds of this package (``sim.devices.builtin``, ``sim.devices.coe_io``);
- every entry point of the group ``pyethercat.sim.devices`` (``pyproject.toml``
  ``[project.entry-points."pyethercat.sim.devices"]``): an object that is a
  ``BuiltinDevice``, an iterable of them, or a function returning either;
- :func:`register_device` calls (a test or a script adding its own kind).

Nothing is changed at import time: importing a module does not add kinds.
A key used twice is refused (:class:`ConfigError`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any

from pyethercat.errors import ConfigError
from pyethercat.sim.devices.builtin import BuiltinDevice

__all__ = ["DEVICES", "ENTRY_POINT_GROUP", "DeviceRegistry", "register_device"]

#: Entry-point group of third-party device kinds.
ENTRY_POINT_GROUP = "pyethercat.sim.devices"
#: Providers of the kinds shipped with pyethercat ("module:function").
_BUILTIN_PROVIDERS = (
    "pyethercat.sim.devices.builtin:io_devices",
    "pyethercat.sim.devices.coe_io:coe_devices",
    "pyethercat.sim.devices.eoe_web:eoe_devices",
)


def _kinds(obj: Any, where: str) -> list[BuiltinDevice]:
    if callable(obj) and not isinstance(obj, BuiltinDevice):
        obj = obj()
    if isinstance(obj, BuiltinDevice):
        return [obj]
    if isinstance(obj, Iterable):
        out = list(obj)
        if all(isinstance(k, BuiltinDevice) for k in out):
            return out
    raise ConfigError(f"device provider {where} gave {type(obj).__name__}, not BuiltinDevice(s)")


class DeviceRegistry(Mapping[str, BuiltinDevice]):
    """Device kinds by key (a read-only mapping once loaded; see the module docstring)."""

    def __init__(self, providers: Iterable[str] = _BUILTIN_PROVIDERS,
                 group: str | None = ENTRY_POINT_GROUP) -> None:
        self._providers = tuple(providers)
        self._group = group
        self._kinds: dict[str, BuiltinDevice] | None = None
        self._extra: list[BuiltinDevice] = []

    def _load(self) -> dict[str, BuiltinDevice]:
        if self._kinds is not None:
            return self._kinds
        kinds: dict[str, BuiltinDevice] = {}

        def add(kind: BuiltinDevice, where: str) -> None:
            if kind.key in kinds and kinds[kind.key] is not kind:
                raise ConfigError(f"device kind {kind.key!r} from {where} is defined twice")
            kinds[kind.key] = kind

        for spec in self._providers:
            module, _, name = spec.partition(":")
            for kind in _kinds(getattr(import_module(module), name), spec):
                add(kind, spec)
        if self._group is not None:
            for ep in entry_points(group=self._group):
                for kind in _kinds(ep.load(), f"entry point {ep.name!r}"):
                    add(kind, f"entry point {ep.name!r}")
        for kind in self._extra:
            add(kind, "register_device()")
        self._kinds = kinds
        return kinds

    def register(self, kind: BuiltinDevice) -> None:
        """Add a kind (:class:`ConfigError` if its key is taken by another)."""
        kinds = self._load()
        if kind.key in kinds and kinds[kind.key] is not kind:
            raise ConfigError(f"device kind {kind.key!r} is defined twice")
        kinds[kind.key] = kind
        self._extra.append(kind)

    def get_kind(self, key: str) -> BuiltinDevice:
        """The kind ``key``; :class:`ConfigError` naming the choices if unknown."""
        kind = self._load().get(key)
        if kind is None:
            raise ConfigError(f"unknown built-in device {key!r}: choose one of {', '.join(self.names())}")
        return kind

    def names(self) -> list[str]:
        """Keys accepted after ``builtin:``."""
        return sorted(self._load())

    def __getitem__(self, key: str) -> BuiltinDevice:
        return self._load()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())


#: The registry topology files and the command line use.
DEVICES = DeviceRegistry()


def register_device(kind: BuiltinDevice) -> None:
    """Add ``kind`` to :data:`DEVICES` (``device = "builtin:<kind.key>"`` then finds it)."""
    DEVICES.register(kind)
