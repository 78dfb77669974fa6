"""The isolated cyclic engine: the process-data loop in a process of its own.

``Master.start(..., isolated=True)`` (the default where the link can move to
another process) runs the cyclic exchange in a child process that nothing of
the user's program runs in: the user's threads, CPU burners and C calls that
hold the GIL do not move its deadlines. The parts:

- :mod:`~pyethercat.master.engine.shared`: the memory both processes map
  (images, a seqlock status block, sample rings, events, slave health);
- :mod:`~pyethercat.master.engine.plan`: the picklable plan the engine starts from;
- :mod:`~pyethercat.master.engine.child`: the engine's process (the same
  cyclic runner as the in-process mode, plus a rider that publishes and
  carries requests);
- :mod:`~pyethercat.master.engine.router`: the user's acyclic requests in
  the engine's frames;
- :mod:`~pyethercat.master.engine.runner`: the user's side, an
  :class:`~pyethercat.master.engine.runner.IsolatedRunner`;
  :mod:`~pyethercat.master.engine.readout`: what it reads of the engine
  (statistics, groups, health, events).

See docs/realtime.md.
"""

__all__: list[str] = []
