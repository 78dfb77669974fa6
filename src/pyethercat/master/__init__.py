"""The EtherCAT master: scheduler, scan, states, diagnostics (see ``Master``)."""

from pyethercat.master.master import Master
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave import Identity, Slave

__all__ = ["Master", "Scheduler", "Slave", "Identity"]
