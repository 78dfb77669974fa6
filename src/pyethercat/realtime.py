"""Real-time settings of a process: SCHED_FIFO, CPU affinity, locked memory.

A cyclic engine or a simulator asks for what it wants and is told what it
got: each call returns ``None`` on success or one line saying why not and
what would allow it (root, ``CAP_SYS_NICE``, ``CAP_IPC_LOCK``, ``ulimit -r``
or ``-l``), so the caller can report it and carry on at normal priority. Linux only; other
platforms get the reason and nothing changes. Shared by ``master/`` (the
isolated cyclic engine) and ``sim/`` (the serve loop).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["CPUIDLE_DRIVER", "GUEST_HALT_POLL_NS", "RealtimeReport", "apply_realtime",
           "die_with_parent", "idle_halt_hint", "lock_memory", "pin_cpu", "SpinBudget",
           "quiet_collector", "set_fifo", "set_timer_slack"]

# <sys/mman.h>: lock what is mapped now and what will be; MCL_ONFAULT (Linux 4.4)
# locks pages as they are first touched, so address space that is only reserved
# (thread stacks, allocator arenas) is not made resident.
_MCL_CURRENT = 1
_MCL_FUTURE = 2
_MCL_ONFAULT = 4
# <linux/prctl.h>: the signal the kernel sends this process when its parent dies.
_PR_SET_PDEATHSIG = 1
# <linux/prctl.h>: the calling thread's timer slack in nanoseconds (prctl(2)).
_PR_SET_TIMERSLACK = 29


def set_fifo(priority: int) -> str | None:
    """Run the calling process (all its threads created later) under SCHED_FIFO ``priority``."""
    if not 1 <= priority <= 99:
        return f"SCHED_FIFO priority {priority} is outside 1..99"
    policy = getattr(os, "SCHED_FIFO", None)
    if policy is None or not hasattr(os, "sched_setscheduler"):
        return "this platform has no SCHED_FIFO"
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as exc:
        # (without CAP_SYS_NICE, sched(7) allows SCHED_FIFO up to RLIMIT_RTPRIO)
        soft, _hard = resource.getrlimit(resource.RLIMIT_RTPRIO)
        limit = "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
        return (f"SCHED_FIFO {priority} refused ({exc.strerror or exc}; RLIMIT_RTPRIO {limit}): "
                "run as root, give the interpreter CAP_SYS_NICE (setcap cap_sys_nice+ep), "
                f"or raise 'ulimit -r' to {priority}")
    return None


def set_timer_slack(ns: int = 1) -> str | None:
    """Let the kernel wake the calling thread's timed waits at most ``ns`` late (prctl).

    A normal-priority thread's sleeps and ``select`` time-outs may end up to
    50 us late by default (the timer slack, prctl(2) PR_SET_TIMERSLACK), so
    that the kernel can batch wake-ups; SCHED_FIFO threads have none. A loop
    that sleeps to just before its deadline and spins the rest wants none
    either, whatever its priority. Needs no privilege.
    """
    name = ctypes.util.find_library("c")
    try:
        prctl = ctypes.CDLL(name, use_errno=True).prctl
    except (OSError, AttributeError):
        return "this platform has no prctl: the timer slack stays the default"
    if prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(max(1, ns)), 0, 0, 0) != 0:
        return f"prctl(PR_SET_TIMERSLACK) refused: {os.strerror(ctypes.get_errno())}"
    return None


def pin_cpu(cpu: int) -> str | None:
    """Keep the calling process on CPU ``cpu``; None on success, else why not."""
    if not hasattr(os, "sched_setaffinity"):
        return "this platform cannot pin a process to a CPU"
    allowed = os.sched_getaffinity(0)
    if cpu not in allowed:
        return f"CPU {cpu} is not among the CPUs this process may use ({sorted(allowed)})"
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError as exc:
        return f"pinning to CPU {cpu} refused: {exc.strerror or exc}"
    return None


def lock_memory() -> str | None:
    """``mlockall``: the process's pages stay in RAM (no page fault waits on the disk)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name, use_errno=True)
        mlockall = libc.mlockall
    except (OSError, AttributeError):
        return "this platform has no mlockall"
    flags = _MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT
    if mlockall(flags) != 0 and mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        limit = "unlimited" if soft == resource.RLIM_INFINITY else f"{soft // 1024} KiB"
        return (f"mlockall refused ({os.strerror(err)}; RLIMIT_MEMLOCK {limit}): run as root, "
                "give the interpreter CAP_IPC_LOCK, or raise 'ulimit -l'")
    return None


def die_with_parent(signum: int) -> str | None:
    """Have the kernel send ``signum`` to this process when its parent dies (Linux prctl).

    The signal comes when the *thread* that started this process ends, not
    only when its whole process does (prctl(2)): a handler should look at
    ``os.getppid()`` before it acts. None on success, else why not.
    """
    name = ctypes.util.find_library("c")
    try:
        prctl = ctypes.CDLL(name, use_errno=True).prctl
    except (OSError, AttributeError):
        return "this platform has no prctl: the engine notices its parent's death by polling"
    if prctl(_PR_SET_PDEATHSIG, ctypes.c_ulong(signum), 0, 0, 0) != 0:
        return f"prctl(PR_SET_PDEATHSIG) refused: {os.strerror(ctypes.get_errno())}"
    return None


#: Third collector threshold of :func:`quiet_collector`: no full collection comes on its own.
_NO_FULL_COLLECTIONS = 1 << 30


def quiet_collector() -> None:
    """Keep the garbage collector from stalling a loop that must answer within microseconds.

    Everything built so far is collected once and frozen out of the
    collector's generations, and full collections no longer start on their
    own: one walks every long-lived object (15-25 ms measured in a simulator
    serving a CoE slave), long enough for a master's frame to time out. The
    young generations are still collected (their cycles too; they are small);
    the caller runs a full :func:`gc.collect` when it is idle, if ever.
    """
    gc.collect()
    gc.freeze()
    young, middle, _full = gc.get_threshold()
    gc.set_threshold(young, middle, _NO_FULL_COLLECTIONS)


def rt_share() -> float | None:
    """The share of each period Linux lets real-time tasks run (``sched_rt_runtime_us`` /
    ``sched_rt_period_us``; 0.95 by default), or None when unlimited or unknown."""
    try:
        runtime = int(Path("/proc/sys/kernel/sched_rt_runtime_us").read_text())
        period = int(Path("/proc/sys/kernel/sched_rt_period_us").read_text())
    except (OSError, ValueError):
        return None
    if runtime < 0 or period <= 0:
        return None
    return runtime / period


#: Share of each second a polling loop spins on a virtual machine (SpinBudget.for_this_process).
VM_SPIN_SHARE = 0.2


def on_virtual_machine() -> bool:
    """Whether this Linux runs under a hypervisor (the ``hypervisor`` CPU flag)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return " hypervisor" in line
    except OSError:
        pass
    return False


#: Under /sys: the cpuidle driver in use, and (``haltpoll``, a KVM guest) how long an idle
#: vCPU polls before it halts, in ns. (Also read and set by the benchmarks.)
CPUIDLE_DRIVER = "devices/system/cpu/cpuidle/current_driver"
GUEST_HALT_POLL_NS = "module/haltpoll/parameters/guest_halt_poll_ns"


def idle_halt_hint(cycle_s: float, sys_root: Path = Path("/sys")) -> str | None:
    """What to change on a KVM guest whose idle vCPUs halt at once, for a loop with cycles
    under 1 ms; None when that is not the case (or not known).

    With the ``haltpoll`` cpuidle driver, an idle vCPU polls ``guest_halt_poll_ns``
    before it halts; a halted one needs the host to run it again when a frame comes,
    tens of microseconds on every round trip whose peer had gone idle (measured: the
    engine's round trip through the simulator 100-125 µs at 10 and 4 kHz with 0, 65-86
    µs with 200 µs; docs/realtime.md)."""
    if cycle_s >= 1e-3:
        return None
    cpuidle = sys_root / CPUIDLE_DRIVER
    poll = sys_root / GUEST_HALT_POLL_NS
    try:
        if cpuidle.read_text().strip() != "haltpoll" or int(poll.read_text()) != 0:
            return None
    except (OSError, ValueError):
        return None
    return (f"idle vCPUs halt at once (guest_halt_poll_ns 0): every round trip waits for the "
            f"host to run them again; for {cycle_s * 1e6:.0f} us cycles let them poll first: "
            f"echo 200000 > {poll} (root)")


def running_realtime() -> bool:
    """Whether this process runs under a real-time policy (SCHED_FIFO or SCHED_RR)."""
    try:
        return os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR)
    except (AttributeError, OSError):
        return False


class SpinBudget:
    """How long a polling loop may spin without sleeping, per second.

    A loop that spins too long is taken off the CPU for milliseconds: Linux
    lets real-time tasks run ``sched_rt_runtime_us`` of every
    ``sched_rt_period_us`` (950 ms of each second by default) and throttles
    them for the rest of the period, and a hypervisor's scheduler takes a
    vCPU that spins through its time slice off for a slice of its own (see
    :meth:`for_this_process`). A loop that polls asks :meth:`allowed` before
    it spins and reports the time it spun with :meth:`spent`; past ``share``
    of the current period it blocks instead (a wake-up costs microseconds,
    the stall milliseconds).
    """

    __slots__ = ("share", "period", "_since", "_spent")

    def __init__(self, share: float, period: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.share = share
        self.period = period
        self._since = clock()  # (the loop passes its own time to allowed())
        self._spent = 0.0

    @classmethod
    def for_this_process(cls, margin: float = 0.2) -> SpinBudget | None:
        """The budget of this process's polling loop, or None when it may spin freely.

        Under a real-time policy: ``margin`` below the kernel's real-time share.
        On a virtual machine (a CPU with the ``hypervisor`` flag) at most
        :data:`VM_SPIN_SHARE` whatever the policy: the host's scheduler takes a
        vCPU that spins for long off the CPU for its time slice (measured on
        a 2-vCPU KVM guest: replies stalled 10-36 ms with 0.3 ms of CPU time
        spent, and SOEM's segmented SDO transfers failed; with the share at
        0.1 no stall was over 7 ms)."""
        shares = []
        rt = cls.below_rt_throttle(margin)
        if rt is not None:
            shares.append(rt.share)
        if on_virtual_machine():
            shares.append(VM_SPIN_SHARE)
        return cls(min(shares)) if shares else None

    @classmethod
    def below_rt_throttle(cls, margin: float = 0.1) -> SpinBudget | None:
        """The budget of a real-time loop that must not be throttled, or None.

        Under a real-time policy with a finite ``sched_rt_runtime_us``: ``margin``
        below that share. A loop that spins through every cycle (the isolated
        engine at 10 kHz: the spin before each deadline and the poll for the
        reply fill the cycle) would otherwise run out the real-time share and be
        stopped for the rest of the period (measured: gaps of 50 ms at 10 kHz)."""
        limit = rt_share()
        if limit is None or not running_realtime():
            return None
        return cls(max(0.1, limit - margin))

    def allowed(self, now: float) -> bool:
        """Whether polling may go on at ``now`` (a new period starts afresh)."""
        if now - self._since >= self.period:
            self._since = now
            self._spent = 0.0
        return self._spent < self.share * self.period

    def spent(self, seconds: float) -> None:
        """The loop polled for ``seconds``."""
        self._spent += seconds


@dataclass
class RealtimeReport:
    """What a process asked for and got (``missing``: one line per refusal)."""

    priority: int = 0
    cpu: int | None = None
    locked: bool = False
    missing: list[str] = field(default_factory=list)

    def text(self) -> str:
        got = [f"SCHED_FIFO {self.priority}" if self.priority else "normal scheduling",
               f"CPU {self.cpu}" if self.cpu is not None else "any CPU",
               "memory locked" if self.locked else "memory not locked"]
        return ", ".join(got)


def apply_realtime(priority: int = 0, cpu: int | None = None, lock: bool = False) -> RealtimeReport:
    """Ask for each setting given; the report says what was had and what was refused."""
    report = RealtimeReport()
    if lock:
        why = lock_memory()
        if why is None:
            report.locked = True
        else:
            report.missing.append(why)
    if cpu is not None:
        why = pin_cpu(cpu)
        if why is None:
            report.cpu = cpu
        else:
            report.missing.append(why)
    if priority:
        why = set_fifo(priority)
        if why is None:
            report.priority = priority
        else:
            report.missing.append(why)
    return report
