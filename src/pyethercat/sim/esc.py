"""Register-level model of one EtherCAT slave controller (ESC).

(Skeleton: the model is being filled in; profiles are final.)
"""

from __future__ import annotations

from pyethercat.sim.profiles import PROFILES, EscProfile, profile

__all__ = ["PROFILES", "EscProfile", "profile"]
