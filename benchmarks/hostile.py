"""A hostile user for benchmarks/master_cycle.py: Python threads that burn CPU and a C call
that holds the GIL.

``HostileLoad(threads=4, hold_ms=5, every_ms=50)`` starts ``threads`` threads
running pure Python loops and one thread that calls a C function holding
the GIL for ``hold_ms`` every ``every_ms``. The C function is compiled here
with the system's C compiler and called through ``ctypes.PyDLL`` (which,
unlike ``CDLL``, keeps the GIL during the call, as a C extension that does
not release it would). Without a compiler a regular expression that
backtracks for about as long stands in (the ``re`` engine never releases
the GIL either).
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

__all__ = ["HostileLoad", "gil_holder"]

_C = r"""
#include <time.h>
/* Busy for ns nanoseconds of CLOCK_MONOTONIC, never giving up the GIL. */
void hold(long ns) {
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    do {
        clock_gettime(CLOCK_MONOTONIC, &b);
    } while ((b.tv_sec - a.tv_sec) * 1000000000L + (b.tv_nsec - a.tv_nsec) < ns);
}
"""


def gil_holder() -> tuple[str, object]:
    """(how, fn(ns)) where fn holds the GIL for about ns nanoseconds."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is not None:
        tmp = Path(tempfile.mkdtemp(prefix="pyecat-hostile-"))
        src, lib = tmp / "hold.c", tmp / "hold.so"
        src.write_text(_C)
        done = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(lib), str(src)],
                              capture_output=True, check=False)
        if done.returncode == 0:
            dll = ctypes.PyDLL(str(lib))
            dll.hold.argtypes = [ctypes.c_long]
            dll.hold.restype = None
            return "a C function called through ctypes.PyDLL", dll.hold
    # Backtracking regex: calibrate the subject length to the wanted time.
    pattern = re.compile(r"(a|aa)+b")

    def hold_re(ns: int) -> None:
        n = 20
        while True:
            t = time.perf_counter_ns()
            pattern.match("a" * n)
            if time.perf_counter_ns() - t >= ns or n > 60:
                return
            n += 1

    return "a backtracking regular expression (no C compiler)", hold_re


class HostileLoad:
    """CPU-burning Python threads plus a GIL-holding C call (see the module text)."""

    def __init__(self, threads: int = 4, hold_ms: float = 5.0, every_ms: float = 50.0) -> None:
        self.threads = threads
        self.hold_ns = int(hold_ms * 1e6)
        self.every_s = every_ms / 1000
        self.how, self._hold = gil_holder()
        self._stop = threading.Event()
        self._workers: list[threading.Thread] = []
        self.burn_loops = 0
        self.holds = 0

    def _burn(self) -> None:
        n = 0
        x = 0
        while not self._stop.is_set():
            for i in range(1000):
                x += i * i
            n += 1
        self.burn_loops += n

    def _holder(self) -> None:
        hold = self._hold
        nxt = time.monotonic()
        while not self._stop.is_set():
            hold(self.hold_ns)  # type: ignore[operator]
            self.holds += 1
            nxt += self.every_s
            time.sleep(max(0.0, nxt - time.monotonic()))

    def __enter__(self) -> HostileLoad:
        self._stop.clear()
        self._workers = [threading.Thread(target=self._burn, name=f"burn-{i}", daemon=True)
                         for i in range(self.threads)]
        self._workers.append(threading.Thread(target=self._holder, name="gil-holder",
                                              daemon=True))
        for t in self._workers:
            t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        for t in self._workers:
            t.join()

    def describe(self) -> str:
        return (f"{self.threads} threads burning CPU in Python loops, one thread holding the GIL "
                f"{self.hold_ns / 1e6:g} ms every {self.every_s * 1000:g} ms through {self.how}"
                f" (pid {os.getpid()})")
