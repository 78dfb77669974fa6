"""State transitions of a master's slaves, with explicit hooks.

:class:`Transitions` walks slaves through the EtherCAT state machine
(:func:`pyethercat.master.states.set_state`: the standard path, every step
for all slaves at once) and calls its :class:`TransitionHook` objects around
each step, in the order they were added:

- ``before_step(step)`` before the step's state is requested (mailbox sync
  managers before INIT -> PREOP, start-up commands of PS before SAFE-OP,
  process-data sync managers and FMMUs, distributed clocks);
- ``after_step(step)`` once the step's slaves reached it (start-up commands
  of IP, which need the mailbox of PRE-OP).

A :class:`Step` names the target state, the slaves taking it and where each
came from, so every hook sees the same transition (``step.transition(s)``:
``"PS"``...). The master's hooks are its services; a caller may add hooks
for one call (``extra``), which run after the standing ones.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from pyethercat.master import states
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave import Slave
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.wire.al import AlState, transition_name

__all__ = ["Step", "TransitionHook", "Transitions"]


@dataclass(frozen=True, slots=True)
class Step:
    """One step of a state change: ``target`` for ``slaves``, which were in ``origins``."""

    target: AlState
    slaves: Sequence[Slave]
    #: The state of each slave (by position) before the step.
    origins: Mapping[int, AlState]

    def origin(self, slave: SlaveInfo) -> AlState | None:
        """Where ``slave`` came from (None: not part of this step)."""
        return self.origins.get(slave.position)

    def transition(self, slave: SlaveInfo) -> str | None:
        """The ESI name of the slave's transition (``"PS"``), None when it stays."""
        origin = self.origins.get(slave.position)
        return None if origin is None else transition_name(origin, self.target)


class TransitionHook(Protocol):
    """Work a service does around each step of a state change."""

    def before_step(self, step: Step) -> None:
        """Before the step's state is requested."""
        ...

    def after_step(self, step: Step) -> None:
        """After every slave of the step reached it."""
        ...


class Transitions:
    """Brings slaves to a state step by step, calling the hooks around every step."""

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        #: Standing hooks, called in this order.
        self.hooks: list[TransitionHook] = []

    def add_hook(self, hook: TransitionHook) -> None:
        """Call ``hook`` around every step from now on (after the hooks added before)."""
        self.hooks.append(hook)

    def set_state(self, slaves: Sequence[Slave], state: AlState,
                  timeout: float = states.DEFAULT_STATE_TIMEOUT, *, ack_errors: bool = True,
                  extra: Sequence[TransitionHook] = (),
                  hooks: Sequence[TransitionHook] | None = None, wait: bool = True) -> None:
        """Bring ``slaves`` to ``state`` through the standard path and wait for it.

        ``hooks`` replaces the standing hooks for this call (``()``: none);
        ``extra`` hooks run after them. Refusals raise
        :class:`~pyethercat.errors.AlStatusError`, slow slaves
        :class:`~pyethercat.errors.StateTimeoutError` (``timeout`` per step).
        Without ``wait`` the last step is requested and not waited for.
        """
        chain = [*(self.hooks if hooks is None else hooks), *extra]
        steps: dict[tuple[AlState, tuple[int, ...]], Step] = {}
        by_position = {s.position: s for s in slaves}

        def prepare(_scheduler: Scheduler, target: AlState, group: Sequence[SlaveInfo]) -> None:
            members = [by_position[s.position] for s in group]
            step = Step(target, members, {s.position: s.al_state for s in members})
            steps[(target, tuple(s.position for s in group))] = step
            for hook in chain:
                hook.before_step(step)

        def finish(_scheduler: Scheduler, target: AlState, group: Sequence[SlaveInfo]) -> None:
            step = steps.pop((target, tuple(s.position for s in group)), None)
            if step is None:
                members = [by_position[s.position] for s in group]
                step = Step(target, members, {})
            for hook in chain:
                hook.after_step(step)

        states.set_state(self.scheduler, slaves, state, timeout, ack_errors=ack_errors,
                         prepare=prepare if chain else None, finish=finish if chain else None,
                         wait=wait)
