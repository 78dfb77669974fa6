"""What several benchmark scripts share: a pyecat- veth pair, SOEM (pysoem) in OP,
KickCAT's ``network_simulator`` serving a segment, and how the host's idle CPUs
wait (KVM guest halt polling).

The scripts run as ``python benchmarks/NAME.py``, so this folder is on the
import path and they ``from common import ...``.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pyethercat.realtime import CPUIDLE_DRIVER, GUEST_HALT_POLL_NS


def veth() -> tuple[str, str]:
    """A fresh veth pair ``pyecat-<tag>a/b``, up and with carrier (the caller removes it)."""
    tag = uuid.uuid4().hex[:6]
    a, b = f"pyecat-{tag}a", f"pyecat-{tag}b"
    subprocess.run(["ip", "link", "add", a, "type", "veth", "peer", "name", b], check=True)
    for name in (a, b):
        subprocess.run(["sysctl", "-qw", f"net.ipv6.conf.{name}.disable_ipv6=1"], check=False)
        subprocess.run(["ip", "link", "set", name, "up"], check=True)
    limit = time.monotonic() + 5.0
    while time.monotonic() < limit:
        if all(Path(f"/sys/class/net/{x}/operstate").read_text().strip() == "up" for x in (a, b)):
            break
        time.sleep(0.01)
    return a, b


_HALT_POLL = Path("/sys") / GUEST_HALT_POLL_NS


def host_idle() -> dict[str, object]:
    """How this host's idle CPUs wait: the cpuidle driver and, on a KVM guest with
    ``cpuidle-haltpoll``, how long an idle vCPU polls before it halts (a halted vCPU
    needs the host to run it again when a frame comes: tens of microseconds more)."""
    out: dict[str, object] = {}
    with contextlib.suppress(OSError):
        out["cpuidle_driver"] = (Path("/sys") / CPUIDLE_DRIVER).read_text().strip()
    with contextlib.suppress(OSError, ValueError):
        out["guest_halt_poll_ns"] = int(_HALT_POLL.read_text())
    return out


@contextlib.contextmanager
def guest_halt_poll(ns: int | None) -> Iterator[None]:
    """Set ``guest_halt_poll_ns`` for the runs inside (root, KVM guest), then put it back."""
    if ns is None or not _HALT_POLL.exists():
        if ns is not None:
            print("no cpuidle-haltpoll on this host: --guest-halt-poll-ns ignored", file=sys.stderr)
        yield
        return
    before = _HALT_POLL.read_text().strip()
    _HALT_POLL.write_text(str(ns))
    try:
        yield
    finally:
        _HALT_POLL.write_text(before)


class Soem:
    """A pysoem master that brought the segment to OP; ``rtts(n)`` times process-data cycles.

    ``startup_s``: from opening the interface to OP (config_init, config_map,
    SAFE-OP, then process data until OP shows). ``complete_access=False``
    makes SOEM read the PDO assignment and mapping one subindex at a time
    even where the SII announces SDO complete access: an emulator whose
    complete-access answer does not pad subindex 0 to 16 bits (ETG.1000.6;
    KickCAT's lib/src/ESI/Parser.cc puts 0x1C00:n at byte n) otherwise
    misleads SOEM's ``config_map``, which reads the types from byte 2 on.
    ``mapping``: output and input bytes per slave and SOEM's expected WKC.
    """

    def __init__(self, iface: str, *, complete_access: bool = True) -> None:
        import pysoem

        self.pysoem: Any = pysoem
        self.m = m = pysoem.Master()
        t0 = time.perf_counter()
        m.open(iface)
        self.slaves = m.config_init()
        if self.slaves <= 0:
            m.close()
            raise RuntimeError(f"SOEM found no slaves on {iface}")
        if not complete_access:
            for s in m.slaves:
                s._disable_complete_access()
        m.config_map()
        self.mapping: dict[str, object] = {
            "out_in_bytes": [[len(s.output), len(s.input)] for s in m.slaves],
            "expected_wkc": m.expected_wkc}
        m.state_check(pysoem.SAFEOP_STATE, 2_000_000)
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(5000):
            m.send_processdata()
            m.receive_processdata(10000)
            if m.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                break
        self.startup_s = time.perf_counter() - t0
        self.op = m.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE
        self.wkc = 0

    def rtts(self, rounds: int) -> list[float]:
        """``rounds`` process-data cycles (send + receive) after a warm-up, in microseconds."""
        m = self.m
        for _ in range(200):
            m.send_processdata()
            self.wkc = m.receive_processdata(10000)
        out = []
        clock = time.perf_counter_ns
        for _ in range(rounds):
            t = clock()
            m.send_processdata()
            m.receive_processdata(10000)
            out.append((clock() - t) / 1000)
        return out

    def close(self) -> None:
        """Back to INIT, interface closed."""
        m = self.m
        m.state = self.pysoem.INIT_STATE
        m.write_state()
        m.close()


#: Where ``../shared/tools/build-kickcat.sh`` leaves KickCAT's C++ ESC emulator and its
#: source tree (the emulator runs from the tree's ``simulation/`` folder: its slave
#: configurations name their EEPROM dumps and ESI files relative to it).
KICKCAT_BINARY = Path("/tmp/kickcat-build/build/simulation/network_simulator")
KICKCAT_SRC = Path("/tmp/kickcat-src")


def have_kickcat(binary: Path = KICKCAT_BINARY, src: Path = KICKCAT_SRC) -> bool:
    """Whether KickCAT's emulator is built (see :data:`KICKCAT_BINARY`)."""
    return binary.exists() and (src / "simulation").is_dir()


def chrt(priority: int) -> list[str]:
    """The command prefix that runs a program under SCHED_FIFO ``priority`` (0: none)."""
    return ["chrt", "-f", str(priority)] if priority else []


@contextlib.contextmanager
def kickcat_simulator(iface: str, configs: list[str], priority: int,
                      binary: Path = KICKCAT_BINARY, src: Path = KICKCAT_SRC) -> Iterator[None]:
    """KickCAT's ``network_simulator`` serving the slaves of ``configs`` (paths relative
    to its ``simulation/`` folder, one per slave, in line) on ``iface``."""
    proc = subprocess.Popen([*chrt(priority), str(binary), "-i", iface, "-s", *configs],
                            cwd=src / "simulation", stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        if proc.poll() is not None:
            raise RuntimeError(f"network_simulator exited ({proc.returncode})")
        yield
    finally:
        proc.kill()
        proc.wait()
