"""pyethercat: an EtherCAT master and a register-level EtherCAT network simulator."""

from __future__ import annotations

__version__ = "0.1.0"
