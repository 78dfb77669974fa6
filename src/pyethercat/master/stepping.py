"""Blocking work in step with the cyclic loop: a worker thread that the loop drives.

Bringing a hot-swapped slave back (address, SII, mailbox, CoE start-up,
sync managers, FMMUs, DC, state by state up to OP) is written as plain
blocking calls on the scheduler. While the cyclic loop runs, those calls
must not hold frames of their own or move a virtual clock under the loop's
feet; IgH runs such state machines from the cyclic context for the same
reason (``master/fsm_slave_config.c``). A :class:`Stepper` gives the same
determinism to blocking code:

- :meth:`Stepper.run` starts the work in a worker thread;
- every wait of the worker (a request's result, a sleep) blocks until the
  loop resumes it: requests are queued without a frame of their own and
  ride in the next cyclic frames;
- after each cycle the loop calls :meth:`Stepper.step`: every worker whose
  wait is over (its requests answered, its sleep or timeout past on the
  loop's clock) runs until it waits again or ends, one after the other,
  while the loop waits. Worker and loop alternate strictly, so a run in
  virtual time is repeatable.

:meth:`Stepper.release` (the loop stops) lets waiting workers go on alone.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Stepper"]


@dataclass
class _Worker:
    thread: threading.Thread
    #: "running", "waiting" or "done".
    state: str = "running"
    done: Callable[[], bool] | None = None
    #: Scheduler time at which the wait ends anyway (None: only ``done``).
    limit: float | None = None
    #: The wait ended because ``limit`` passed.
    timed_out: bool = False


class Stepper:
    """Worker threads run in step with a driver (see the module text)."""

    def __init__(self, now: Callable[[], float]) -> None:
        self._now = now
        self._cond = threading.Condition()
        self._workers: dict[threading.Thread, _Worker] = {}
        self._released = False

    # -- the worker's side ---------------------------------------------------------------

    def run(self, fn: Callable[[], None], name: str = "ecat-stepped") -> threading.Thread:
        """Start ``fn`` in a worker thread; it first runs until its first wait."""

        def main() -> None:
            with self._cond:
                pass  # registered by run() before it lets go of the condition
            try:
                fn()
            finally:
                with self._cond:
                    w = self._workers.pop(threading.current_thread(), None)
                    if w is not None:
                        w.state = "done"
                    self._cond.notify_all()

        t = threading.Thread(target=main, name=name, daemon=True)
        with self._cond:
            self._released = False
            self._workers[t] = _Worker(t)
            t.start()
        return t

    def is_worker(self) -> bool:
        """Whether the calling thread is a stepped worker (its waits go through :meth:`wait`)."""
        return not self._released and threading.current_thread() in self._workers

    def wait(self, done: Callable[[], bool], limit: float | None) -> bool:
        """Block the worker until the driver resumes it: True when ``done()``, False at ``limit``."""
        with self._cond:
            w = self._workers.get(threading.current_thread())
            if w is None or self._released:
                return done()
            w.state, w.done, w.limit, w.timed_out = "waiting", done, limit, False
            self._cond.notify_all()
            while w.state == "waiting" and not self._released:
                self._cond.wait()
            if w.state == "waiting":  # released: the worker goes on alone
                w.state = "running"
            return not w.timed_out

    # -- the driver's side ---------------------------------------------------------------

    @property
    def busy(self) -> bool:
        """Whether any worker is alive."""
        return bool(self._workers)

    def step(self) -> None:
        """Resume every worker whose wait is over; return when each waits again or has ended."""
        if not self._workers:
            return
        with self._cond:
            for key in list(self._workers):
                w = self._workers.get(key)
                if w is None:
                    continue
                # A worker that just started runs up to its first wait first.
                while w.state == "running":
                    self._cond.wait()
                if w.state != "waiting":
                    continue
                over = w.limit is not None and self._now() >= w.limit
                ready = w.done is not None and w.done()
                if not (ready or over):
                    continue
                w.timed_out = over and not ready
                w.state = "running"
                self._cond.notify_all()
                while w.state == "running":
                    self._cond.wait()

    def release(self) -> None:
        """The driver stops: waiting workers wake and go on by themselves."""
        with self._cond:
            self._released = True
            self._cond.notify_all()
