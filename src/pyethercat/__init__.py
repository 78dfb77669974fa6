"""pyethercat: an EtherCAT master and a register-level EtherCAT network simulator."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from pyethercat.master.master import Master

__all__ = ["Master", "__version__"]


def __getattr__(name: str) -> Any:
    # Lazy, so that ``import pyethercat.wire...`` does not pull in the master.
    if name == "Master":
        from pyethercat.master.master import Master

        return Master
    raise AttributeError(f"module 'pyethercat' has no attribute {name!r}")
