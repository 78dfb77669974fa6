"""The user's side of the isolated cyclic engine: :class:`IsolatedRunner`.

``Master.start(..., isolated=True)`` returns one of these instead of a
:class:`~pyethercat.master.cyclic.CyclicRunner` running in a thread. It is
a ``CyclicRunner`` to everything that reads one (the live view, the control
socket, mailboxes waiting for the mailbox-status byte), but the loop runs in
a process of its own (:mod:`~pyethercat.master.engine.child`):

- the process images live in shared memory (:mod:`~pyethercat.master.engine.shared`);
  ``slave.inputs[...]`` and ``slave.outputs[...]`` read and write them as
  before, never half a value (the images' :class:`EngineImageSync`);
- ``stats``, ``groups``, ``health`` and ``events`` are read from the
  engine's status block when asked for (any rate: reading never slows the
  engine);
- the master's scheduler sends its frames to the engine (:class:`~pyethercat.master.engine.router.EngineLink`),
  which carries their datagrams in its cyclic frames, so SDOs, FoE, EoE,
  register access and state changes work while the engine cycles;
- a watcher thread serves the engine's requests (recovery: the
  configuration is here) and notices its end; if it ended without being
  asked, every access raises :class:`~pyethercat.errors.EngineDiedError`;
- ``callback`` (and :meth:`cycles`) run in this process after the engine's
  cycles, never inside them: a callback that is slow misses cycles
  (``consumer_missed``), the engine does not wait for it.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Unpack

from pyethercat.clock import PerfClock
from pyethercat.errors import ConfigError, EngineDiedError, EtherCATError, LinkError
from pyethercat.link.base import Link
from pyethercat.master.config import GroupConfig, ProcessDataConfig
from pyethercat.master.cyclic import (
    DEFAULT_CHECK_INTERVAL,
    DEFAULT_CYCLE,
    Cycle,
    CycleStats,
    CyclicRunner,
    GroupStatus,
    RunnerOptions,
)
from pyethercat.master.engine.channel import recv_message, send_message
from pyethercat.master.engine.plan import EnginePlan, dumps
from pyethercat.master.engine.readout import EngineReadout, Lifeline
from pyethercat.master.engine.router import EngineLink
from pyethercat.master.engine.shared import AreaLayout, ImageSeq, SharedArea
from pyethercat.master.engine.status import (
    ENGINE_FIELDS,
    STATE_NAMES,
    group_fields,
    stats_fields,
)
from pyethercat.master.image import PdoValue, ProcessImage
from pyethercat.master.scheduler import Scheduler

__all__ = ["EngineImageSync", "IsolatedRunner", "Lifeline"]

#: Samples kept in the shared rings (period, latency, round trip): 2 MiB each.
SHARED_CAPACITY = 1 << 18
# How long the engine has to start (an interpreter and numpy to import).
_START_TIMEOUT = 30.0


class EngineImageSync:
    """Consistent access to one shared image (:class:`~pyethercat.master.image.ImageSync`).

    Reads retry while the engine writes inputs; writes make the outputs'
    sequence number odd, so the engine keeps sending the last whole outputs.
    Nested writes (``with image.writing():``) are one write; threads of this
    process take turns.
    """

    def __init__(self, seq: ImageSeq, lifeline: Lifeline) -> None:
        self._seq = seq
        self._life = lifeline
        self._lock = threading.RLock()
        self._depth = 0
        self._out = seq.output_seq()

    def read(self, get: Callable[[], PdoValue]) -> PdoValue:
        life = self._life
        if life.why is not None:
            raise EngineDiedError(life.why)
        seq = self._seq.input_seq
        for _ in range(10_000):
            before = seq()
            if before & 1:
                continue
            value = get()
            if seq() == before:
                return value
        # The engine stopped in the middle of a copy (SIGSTOP): the bytes are what they are.
        life.check()
        return get()

    def begin_write(self) -> None:
        life = self._life
        if life.why is not None:
            raise EngineDiedError(life.why)
        self._lock.acquire()
        self._depth += 1
        if self._depth == 1:
            self._out += 1
            self._seq.set_output_seq(self._out)

    def end_write(self) -> None:
        self._depth -= 1
        if self._depth == 0:
            self._out += 1
            self._seq.set_output_seq(self._out)
        self._lock.release()


class SharedImage(ProcessImage):
    """A group's image in the engine's shared memory: its input age and validity are
    the engine's (``age()`` reads them from the status block)."""

    def __init__(self, group: GroupConfig, buffer: memoryview, safe: memoryview,
                 sync: EngineImageSync, age: Callable[[], tuple[int, bool]]) -> None:
        self._age = age
        super().__init__(group, buffer=buffer, sync=sync, safe=safe)

    @property
    def input_age(self) -> int:
        return self._age()[0]

    @input_age.setter
    def input_age(self, value: int) -> None:
        pass  # the engine counts it

    @property
    def inputs_valid(self) -> bool:
        return self._age()[1]

    @inputs_valid.setter
    def inputs_valid(self, value: bool) -> None:
        pass


def _names(groups: Sequence[str] | None) -> list[str] | None:
    return list(groups) if groups is not None else None


class IsolatedRunner(EngineReadout, CyclicRunner):
    """The cyclic loop in a process of its own (see the module text).

    ``realtime``: SCHED_FIFO priority of the engine (0: normal scheduling),
    ``cpu`` its CPU, ``lock_memory`` mlockall; what it could not get is
    logged as events and in :attr:`realtime_missing`. ``use_images(images)``
    is called with the shared images when the engine starts and with private
    copies when it ends (the master rebinds ``slave.inputs``/``outputs``).
    """

    def __init__(self, scheduler: Scheduler, config: ProcessDataConfig,
                 images: dict[str, ProcessImage], slaves: Sequence[object], *, priority: int = 0,
                 cpu: int | None = None, lock_memory: bool = False, spin: float = 0.0001,
                 use_images: Callable[[dict[str, ProcessImage]], None] | None = None,
                 **options: Unpack[RunnerOptions]) -> None:
        clock = options.get("clock")
        if clock is not None and not isinstance(clock, PerfClock):
            raise ConfigError("the isolated engine keeps its own time (a PerfClock): give no clock")
        super().__init__(scheduler, config, images, slaves, **options)
        #: What the engine's own runner is built with (the plan carries it over).
        self._options = options
        self._private = images
        self._use_images = use_images
        self.priority = priority
        self.cpu = cpu
        self.lock_memory = lock_memory
        self.spin_ns = int(spin * 1e9)
        self.life = Lifeline()
        #: What the engine could not get of its real-time settings (one line each).
        self.realtime_missing: list[str] = []
        #: What it got ("SCHED_FIFO 80, CPU 1, memory locked").
        self.realtime_text = ""
        self.engine_pid: int | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._control: socket.socket | None = None
        self._link_saved: Link | None = None
        self._watcher: threading.Thread | None = None
        self._follower: threading.Thread | None = None
        self._supervising_wish = True
        self._stopped = threading.Event()
        self._event_serial = 0
        self._layout_fields: tuple[str, ...] = ()
        self._stats_names: tuple[str, ...] = ()
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - kept open while the engine runs

    def status_lines(self) -> list[str]:
        self.poll_events()
        return [*super().status_lines(), self.engine_line()]

    # -- start --------------------------------------------------------------------------------

    def start(self) -> IsolatedRunner:
        """Start the engine's process and wait until it cycles."""
        if self._proc is not None and self._proc.poll() is None:
            raise ConfigError("the cyclic engine is already running")
        sched = self.scheduler
        link = sched.link
        stats_names = stats_fields(CycleStats(self.period_ns, 1))
        gfields: list[str] = []
        for i, g in enumerate(self._groups_list()):
            gfields += group_fields(i, len(g.plan))
        fields = (*stats_names, *gfields, *ENGINE_FIELDS)
        layout = AreaLayout(fields, tuple((g.name, g.config.size) for g in self._groups_list()),
                            SHARED_CAPACITY, len(self.slaves))
        area = SharedArea.create(layout)
        self.area = area
        self._stats_names = stats_names
        # (the same object the orderly stop watches; its counters are the engine's from
        # the first refresh on)
        self._stats_view.keep_samples_in(area.rings["periods"], area.rings["latency"],
                                         area.rings["rtt"])
        # The images move into shared memory (what the application set so far goes along).
        shared: dict[str, ProcessImage] = {}
        for g in self._groups_list():
            private = self._private[g.name]
            buf = area.images[g.name]
            buf[:] = private.buffer
            area.safe[g.name][:] = private.safe
            shared[g.name] = SharedImage(private.group, buf, area.safe[g.name],
                                         EngineImageSync(area.seqs[g.name], self.life),
                                         self._age_reader(area, len(shared)))
            g.image = shared[g.name]
        self.images = shared
        control, engine_control = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        frames, engine_frames = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            plan = EnginePlan(
                link=link, config=self.config, groups=_names(self._options.get("groups")),
                cycle=self._options.get("cycle", DEFAULT_CYCLE),
                slaves=[(int(getattr(s, "position")), int(getattr(s, "station_address")))  # noqa: B009
                        for s in self.slaves],
                area_path=area.path, layout=layout, stats_fields=stats_names,
                control_fd=engine_control.fileno(), frames_fd=engine_frames.fileno(),
                parent_pid=os.getpid(), target=self.target,
                check_interval=self._options.get("check_interval", DEFAULT_CHECK_INTERVAL),
                late_fraction=self.late_threshold_ns / self.period_ns,
                frame_timeout=self.frame_timeout, link_timeout=self._options.get("link_timeout"),
                state_timeout=self._options.get("state_timeout"), dc=self.dc,
                supervising=self._supervising_wish, safe_cycles=self.safe_cycles,
                recover=self.supervisor.recover_fn is not None,
                timeout=sched.timeout, retries=sched.retries, max_in_flight=sched.max_in_flight,
                src=sched.src, priority=self.priority, cpu=self.cpu,
                lock_memory=self.lock_memory, spin_ns=self.spin_ns)
            data, fds = dumps(plan)
            # Frames in flight now would come back to the engine: none may be.
            saved = sched.replace_link(EngineLink(frames, f"engine:{link.name}"))
            self._link_saved = saved
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "pyethercat.master.engine.child"],
                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._stderr,
                pass_fds=(*fds, engine_control.fileno(), engine_frames.fileno()),
                close_fds=True)
            assert self._proc.stdin is not None
            self._proc.stdin.write(data)
            self._proc.stdin.close()
        except BaseException:
            self._undo_start()
            raise
        finally:
            engine_control.close()
            engine_frames.close()
        self._control = control
        try:
            ready = self._wait_ready()
        except BaseException:
            self._kill()
            self._undo_start()
            raise
        self.engine_pid = int(ready["pid"])
        self.realtime_text = str(ready.get("realtime", ""))
        self.realtime_missing = list(ready.get("missing", []))
        self._stopped.clear()
        self._stop.clear()
        if self._use_images is not None:
            self._use_images(shared)
        self._watcher = threading.Thread(target=self._watch, name="ecat-engine-watch",
                                         daemon=True)
        self._watcher.start()
        self._follower = threading.Thread(target=self._follow, name="ecat-engine-follow",
                                          daemon=True)
        self._follower.start()
        return self

    def _wait_ready(self) -> dict[str, Any]:
        control = self._control
        proc = self._proc
        assert control is not None and proc is not None
        limit = time.monotonic() + _START_TIMEOUT
        while True:
            left = limit - time.monotonic()
            if left <= 0:
                raise LinkError(f"the cyclic engine did not start within {_START_TIMEOUT:.0f} s")
            ready, _, _ = select.select([control], [], [], min(left, 0.2))
            if ready:
                try:
                    msg = recv_message(control)
                except (EOFError, OSError):
                    msg = {}
                if msg.get("op") == "ready":
                    return msg
            if proc.poll() is not None:
                raise LinkError(f"the cyclic engine exited at start (status {proc.returncode}): "
                                f"{self._child_stderr()}")

    def _child_stderr(self) -> str:
        self._stderr.seek(0)
        text = self._stderr.read().decode(errors="replace").strip()
        return text.splitlines()[-1] if text else "no message"

    def _undo_start(self) -> None:
        if self._link_saved is not None:
            self.scheduler.replace_link(self._link_saved)
            self._link_saved = None
        for g in self._groups_list():
            g.image = self._private[g.name]
        self.images = self._private
        if self.area is not None:
            self.area.close()
            self.area = None

    def _kill(self) -> None:
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    # -- the watcher: the engine's requests, its end ---------------------------------------

    def _watch(self) -> None:
        control = self._control
        proc = self._proc
        assert control is not None and proc is not None
        control.setblocking(False)
        while True:
            try:
                ready, _, _ = select.select([control], [], [], 0.1)
            except (OSError, ValueError):
                ready = []
            if ready:
                try:
                    msg = recv_message(control)
                except BlockingIOError:
                    continue
                except (EOFError, OSError):
                    msg = {"op": "closed"}
                op = msg.get("op")
                if op == "recover":
                    threading.Thread(target=self._recover_for_engine, args=(msg,),
                                     name="ecat-recover", daemon=True).start()
                    continue
                if op in ("stopped", "closed"):
                    self._ended(proc)
                    return
            if proc.poll() is not None:
                self._ended(proc)
                return

    def _recover_for_engine(self, msg: dict[str, Any]) -> None:
        error: str | None = None
        try:
            fn = self.supervisor.recover_fn
            if fn is None:
                error = "no recovery"
            else:
                fn([int(p) for p in msg["positions"]])
        except EtherCATError as exc:
            error = str(exc)
        except Exception as exc:  # noqa: BLE001 - reported to the engine's log
            error = repr(exc)
        self._send({"op": "answer", "id": msg["id"], "error": error})

    def _ended(self, proc: subprocess.Popen[bytes]) -> None:
        """The engine's process has ended (asked to or not)."""
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        self.poll_events()
        st = self.status()
        asked = self._stopped.is_set()
        if not asked and self.life.why is None:
            code = proc.returncode
            how = f"killed by signal {-code}" if code < 0 else f"exited with status {code}"
            state = STATE_NAMES.get(st.get("state", 0), "?")
            self.life.why = (f"the cyclic engine (pid {proc.pid}) {how} ({state}); process data "
                             "is no longer exchanged")
            if state == "stopped":
                self.life.why += " (the slaves were taken to SAFEOP)"
            link = self.scheduler.link
            if isinstance(link, EngineLink):
                link.why = self.life.why
            self.log(self.life.why)
            self.error = EngineDiedError(self.life.why)
        self._restore_link()
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def _restore_link(self) -> None:
        saved = self._link_saved
        if saved is not None:
            self._link_saved = None
            old = self.scheduler.replace_link(saved, wait=False)
            if isinstance(old, EngineLink) and self.life.why is None:
                old.close()

    # -- the follower: the callback and cycles() ---------------------------------------------

    def _follow(self) -> None:
        """Run the callback once per engine cycle, after the replies that cycle carried.

        The engine writes its tick every cycle and only then sends the replies to
        this process's requests, so a reply that wakes :meth:`_carry` finds its
        cycle done: the callback runs at once with the answers at hand, and what
        it queues reaches the engine in time for the next cycle's frames (an EoE
        service gets a mailbox exchange every cycle, as in-process).
        """
        last = -1
        area = self.area
        assert area is not None
        sched = self.scheduler
        core = sched.core
        pause = min(self.period_ns / 2e9, 0.0005)
        # (replies of the cycle just done are on their way: microseconds behind the tick,
        # or, for frames of their own, as soon as those are back)
        settle = self.period_ns / 2e9
        while not self._stop.is_set():
            n = area.read_tick()
            if n != last:
                with self._cond:
                    self.cycle.index = max(0, n - 1)
                    self._cond.notify_all()
                if self.callback is not None and last >= 0 and n > last:
                    if n > last + 1:
                        self.consumer_missed += n - last - 1
                    if core.in_flight:
                        # (an engine that has gone is reported by its lifeline)
                        with contextlib.suppress(EtherCATError):
                            sched.wait_until(lambda: not core.in_flight, settle)
                    try:
                        self.callback(self.cycle)
                    except Exception as exc:  # noqa: BLE001 - the callback's own bug
                        self.log(f"callback failed: {exc!r}")
                last = n
            if self._carry(sched, pause):
                continue
            # Every half period for a callback; otherwise only waiters of wait_cycles()
            # are told, and they look again every 50 ms anyway.
            time.sleep(pause if self.callback is not None else 0.002)

    def _carry(self, sched: Scheduler, budget: float) -> bool:
        """Do the in-process loop's part for requests nobody waits on; whether there were any.

        In-process, datagrams queued without a flush (an EoE service ticking from
        the callback) leave with the next cyclic frame, and the loop's thread
        receives every reply. Here no cycle runs in this process: this thread
        sends them to the engine (they ride in its next cyclic frame) and takes
        the replies, waiting at most ``budget`` seconds, in place of its pause.
        """
        if not sched.queued and not sched.in_flight:
            return False
        try:
            sched.flush()
            core = sched.core  # (done() is called under the scheduler's lock)
            sched.wait_until(lambda: not core.in_flight, budget)
        except EtherCATError:
            # (the engine has gone or the link was handed back: the lifeline and the
            # requests' own waiters report it)
            time.sleep(budget)
        return True

    # -- control ------------------------------------------------------------------------------

    def _send(self, msg: dict[str, Any]) -> bool:
        control = self._control
        if control is None:
            return False
        try:
            send_message(control, msg)
        except OSError:
            return False
        return True

    @property
    def running(self) -> bool:
        proc = self._proc
        return proc is not None and proc.poll() is None and not self._stop.is_set()

    @property
    def supervising(self) -> bool:
        return self._supervising_wish

    @supervising.setter
    def supervising(self, value: bool) -> None:
        self.__dict__["_supervising_wish"] = value
        if self.__dict__.get("_control") is not None:
            self._send({"op": "supervise", "on": value})

    def request_recovery(self, positions: list[int]) -> None:
        self._send({"op": "recover", "positions": list(positions)})

    def send_safe_outputs(self) -> None:
        """From the next cycle on, the engine sends the safe outputs."""
        self._send({"op": "safe"})

    def run(self, seconds: float | None = None, cycles: int | None = None) -> CycleStats:
        """Wait while the engine runs ``seconds`` (or ``cycles``), then return the statistics."""
        if self._proc is None:
            self.start()
        end = None if seconds is None else time.monotonic() + seconds
        target = None if cycles is None else self.stats.cycles + cycles
        while self.running:
            if end is not None and time.monotonic() >= end:
                break
            if target is not None and self.stats.cycles >= target:
                break
            self._stop.wait(0.01)
        return self.stats

    def halt(self) -> None:
        """End the engine now (no safe outputs, no state changes) and wait for it.

        :meth:`stop` (the base class's) is the orderly stop: the engine sends
        the safe outputs, the master's requests to SAFEOP ride in its frames,
        then it ends here and the master takes the slaves to the final state
        over its own link again.
        """
        self._halt()
        self.join()

    def _halt(self, timeout: float = 5.0) -> None:
        proc = self._proc
        if proc is None:
            return
        self._stopped.set()
        if proc.poll() is None:
            self._send({"op": "halt"})
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        w = self._watcher
        if w is not None and w is not threading.current_thread():
            w.join(timeout)
        self._restore_link()
        self._finish()

    def _finish(self) -> None:
        """Back to private images holding the last values; the shared memory goes."""
        area = self.area
        if area is None:
            return
        self.poll_events()
        self.refresh()
        self._stop.set()
        f = self._follower
        if f is not None and f is not threading.current_thread():
            f.join(1.0)
        for g in self._groups_list():
            private = self._private[g.name]
            # (the engine has ended: nothing writes the shared image any more)
            shared_image = g.image
            private.buffer[:] = bytes(shared_image.buffer)
            private.safe[:] = bytes(shared_image.safe)
            private.input_age = shared_image.input_age
            private.inputs_valid = shared_image.inputs_valid
            g.image = private
        self.images = self._private
        if self._use_images is not None:
            self._use_images(self._private)
        # Views of the shared file may still be held by the application: the mapping
        # lives as long as they do, only the name goes now.
        area.unlink()
        if self._control is not None:
            self._control.close()
            self._control = None

    def join(self, timeout: float | None = None) -> None:
        if self.error is not None and not isinstance(self.error, KeyboardInterrupt):
            err, self.error = self.error, None
            raise err

    def wait_exchanges(self, name: str, count: int, timeout: float) -> bool:
        """Wait until ``count`` more exchanges of group ``name`` are done, as the engine
        writes them with the group's inputs every cycle (the status block's counters
        come every millisecond at most)."""
        if count <= 0:
            return True
        seq = self._seq_of(name)
        now = seq.exchange() if seq is not None else None
        if seq is None or now is None:
            return False
        want = now[0] + count
        limit = time.monotonic() + timeout
        # (a mailbox waits here for its status byte: a tenth of a millisecond late at most)
        pause = min(self.period_ns / 8e9, 0.0001)
        while self.running:
            got = seq.exchange()
            if got is not None and got[0] >= want:
                return True
            if time.monotonic() >= limit:
                return False
            time.sleep(pause)
        return False

    def exchanges_after_now(self) -> int:
        """As the base class's, from the cycles the engine has begun and done."""
        area = self.area
        return 2 if area is None or area.under_way() else 1

    def group_status(self, name: str) -> GroupStatus:
        """As the base class's; exchanges and the working-counter verdict are those of
        the inputs now in the shared image (written with them), not the status block's."""
        g = self._group(name)
        img = g.image
        seq = self._seq_of(name)
        got = seq.exchange() if seq is not None else None
        exchanges, ok = (g.exchanges, g.wkc_ok) if got is None else got
        return GroupStatus(g.name, exchanges, ok, memoryview(img.buffer).toreadonly(),
                           img.input_age, img.inputs_valid)

    def _seq_of(self, name: str) -> ImageSeq | None:
        area = self.area
        return None if area is None else area.seqs.get(name)

    def exchange_once(self) -> bool:
        raise ConfigError("exchange_once() is for the in-process loop (isolated=False)")

    def cycles(self, timeout: float = 1.0) -> Iterator[Cycle]:
        last = -1
        area = self.area
        while self.running and area is not None:
            n = area.read_tick()
            if n != last and n > 0:
                if last >= 0 and n > last + 1:
                    self.consumer_missed += n - last - 1
                last = n
                yield Cycle(index=n - 1)
                continue
            time.sleep(min(self.period_ns / 2e9, 0.0005))
