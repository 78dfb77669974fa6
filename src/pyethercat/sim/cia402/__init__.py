"""The simulated CiA 402 servo drive: one array model for all drives of a kind.

- ``sim.cia402.model``: :class:`~pyethercat.sim.cia402.model.Cia402Model`, the
  device model (synchronisation on SYNC0 or SM2, the EtherCAT errors, emergencies);
- ``sim.cia402.engine``: one drive cycle (power state machine, modes, statusword);
- ``sim.cia402.axis``: motor, load and the drive's control loops;
- ``sim.cia402.profile``, ``sim.cia402.homing``: set-point generators and homing methods;
- ``sim.cia402.objects``: the drive's objects and their defaults.
"""

__all__: list[str] = []
