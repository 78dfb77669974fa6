"""SOEM's process-data round trip through our simulator, KickCAT's and a bare echo, in one run.

The same two devices on both simulators: KickCAT's example slaves
Freedom-K64F (EasyCAT, LAN9252) and XMC4800 Relax, from their ESI files
(corpus ``esi/kickcat_freedom-k64f.xml``, ``esi/kickcat_xmc4800.xml``, which
give our simulator the SII and the CoE object dictionary SOEM reads the PDO
mapping from; KickCAT's ``network_simulator`` reads its EEPROM dumps and the
same ESI files through its ``simulation/slave_configs/*.json``). pysoem (SOEM) on one end of a veth
pair brings them to OP and then times ``send_processdata`` +
``receive_processdata``, the LRW of one cycle, ``--rounds`` times:

- through ``pyethercat sim`` (SCHED_FIFO ``--priority``, its busy-poll on);
- through the same pysoem master's frames echoed unchanged by a bare Python
  echo (a raw socket, receive into one buffer, send back; it polls without
  sleeping as our simulator's serve loop does after a frame): the floor a
  Python server on this machine and veth pair can reach;
- through KickCAT's ``network_simulator`` (C++, same priority), when built
  (``../shared/tools/build-kickcat.sh``; its binary and source tree are
  looked up at /tmp/kickcat-build and /tmp/kickcat-src, or ``--kickcat``).

SOEM reads the PDO layout without SDO complete access on both simulators
(``--soem-complete-access`` to let it): KickCAT's emulator answers a
complete-access upload of 0x1C00 without padding subindex 0 to 16 bits, so
SOEM took SM2 for a 3-byte input SM and dropped SM3 and every output, and
the KickCAT figure was for a smaller exchange (expected WKC 2, not 6). Each
segment's mapping (output/input bytes per slave, expected and seen WKC) is
in the JSON line.

The three alternate ``--alternations`` times so that the host's load hits
them alike; medians and p99 are over the pooled samples. Printed: the
figures, ours / KickCAT (target <= 1) and ours / echo. Needs root (veth
pairs, SCHED_FIFO). The last output line is one JSON object.

Usage: python benchmarks/sim_rtt.py [--rounds 2000] [--alternations 5] [--priority 20]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
from common import KICKCAT_BINARY, KICKCAT_SRC, Soem, chrt, have_kickcat, kickcat_simulator, veth

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT.parent / "shared" / "corpus" / "esi"
DEVICES = ("kickcat_freedom-k64f.xml", "kickcat_xmc4800.xml")
KICKCAT_CONFIGS = ("slave_configs/freedom-k64f.json", "slave_configs/xmc4800.json")

# The echo: one buffer, recv_into without blocking in a loop, send back what came.
ECHO = textwrap.dedent("""
    import os, socket, sys
    iface = sys.argv[1]
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x88A4))
    s.setsockopt(263, 23, 1)  # SOL_PACKET, PACKET_IGNORE_OUTGOING: only the peer's frames
    s.bind((iface, 0x88A4))
    buf = bytearray(2048)
    view = memoryview(buf)
    print("ready", flush=True)
    while True:
        try:
            n = s.recv_into(buf, 2048, socket.MSG_DONTWAIT)
        except BlockingIOError:
            continue
        s.send(view[:n])
""")


def wait_line(proc: subprocess.Popen[str], want: str, seconds: float = 30.0) -> None:
    assert proc.stdout is not None
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        if want in line:
            return
    raise RuntimeError(f"{proc.args!r} did not say {want!r}")


def ours_and_echo(iface_m: str, iface_s: str, topo: Path, rounds: int, priority: int,
                  ca: bool) -> tuple[dict[str, object], list[float], list[float]]:
    """pysoem through our simulator, then the same master's frames through the echo."""
    from pyethercat.sim.server import start_sim_process

    sim = start_sim_process(topo, link=f"iface:{iface_s}", realtime=priority)
    soem = None
    try:
        soem = Soem(iface_m, complete_access=ca)
        ours = soem.rtts(rounds)
        info: dict[str, object] = {"slaves": soem.slaves, "op": soem.op, "wkc": soem.wkc,
                                   **soem.mapping}
    finally:
        sim.stop()
    echo = subprocess.Popen([*chrt(priority), sys.executable, "-c", ECHO, iface_s],
                            stdout=subprocess.PIPE, text=True)
    try:
        wait_line(echo, "ready")
        floor = soem.rtts(rounds)
    finally:
        echo.kill()
        echo.wait()
        soem.m.close()
    return info, ours, floor


def kickcat(iface_m: str, iface_s: str, binary: Path, src: Path, rounds: int,
            priority: int, ca: bool) -> tuple[dict[str, object], list[float]]:
    with kickcat_simulator(iface_s, list(KICKCAT_CONFIGS), priority, binary, src):
        soem = Soem(iface_m, complete_access=ca)
        try:
            rtts = soem.rtts(rounds)
            return {"slaves": soem.slaves, "op": soem.op, "wkc": soem.wkc, **soem.mapping}, rtts
        finally:
            soem.close()


def figures(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples)
    return {"median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99)),
            "samples": int(a.size)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2000, help="round trips per run and server")
    ap.add_argument("--alternations", type=int, default=5)
    ap.add_argument("--priority", type=int, default=20,
                    help="SCHED_FIFO priority of the servers and of pysoem (0: none)")
    ap.add_argument("--kickcat", type=Path, default=KICKCAT_BINARY)
    ap.add_argument("--kickcat-src", type=Path, default=KICKCAT_SRC)
    ap.add_argument("--soem-complete-access", action="store_true",
                    help="let SOEM read the PDO layout with complete access (unequal on KickCAT)")
    args = ap.parse_args()
    if os.geteuid() != 0:
        print(json.dumps({"error": "needs root (veth pairs)"}))
        sys.exit(1)
    kickcat_built = have_kickcat(args.kickcat, args.kickcat_src)
    if not kickcat_built:
        print(f"KickCAT's network_simulator not at {args.kickcat}: build it with "
              "../shared/tools/build-kickcat.sh; measuring ours and the echo only")
    if args.priority:
        # pysoem below the servers, above everything else on a shared machine.
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, args.priority - 1)))
    out: dict[str, object] = {"load_average_start": os.getloadavg(), "rounds": args.rounds,
                              "alternations": args.alternations, "priority": args.priority}
    pooled: dict[str, list[float]] = {"ours": [], "echo": [], "kickcat": []}
    a, b = veth()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            topo = Path(tmp) / "kickcat-pair.toml"
            topo.write_text("".join(f'[[slave]]\nname = "s{i}"\nesi = "{CORPUS / d}"\n\n'
                                    for i, d in enumerate(DEVICES)))
            for k in range(args.alternations):
                info, ours, floor = ours_and_echo(a, b, topo, args.rounds, args.priority,
                                                  args.soem_complete_access)
                out["ours_segment"] = info
                pooled["ours"] += ours
                pooled["echo"] += floor
                line = (f"round {k + 1}: ours {np.median(ours):.1f} us, "
                        f"echo {np.median(floor):.1f} us")
                if kickcat_built:
                    kinfo, kc = kickcat(a, b, args.kickcat, args.kickcat_src, args.rounds,
                                        args.priority, args.soem_complete_access)
                    out["kickcat_segment"] = kinfo
                    pooled["kickcat"] += kc
                    line += f", KickCAT {np.median(kc):.1f} us"
                print(line, flush=True)
    finally:
        subprocess.run(["ip", "link", "del", a], check=False, capture_output=True)
    for name, samples in pooled.items():
        if samples:
            out[name] = figures(samples)
    ours_m = np.median(pooled["ours"])
    out["ours_over_echo"] = float(ours_m / np.median(pooled["echo"]))
    text = (f"SOEM process-data round trip, median (p99): ours {ours_m:.1f} us "
            f"({np.percentile(pooled['ours'], 99):.1f}), echo {np.median(pooled['echo']):.1f} us; "
            f"ours/echo {out['ours_over_echo']:.2f}")
    if pooled["kickcat"]:
        out["ours_over_kickcat"] = float(ours_m / np.median(pooled["kickcat"]))
        text += (f"; KickCAT {np.median(pooled['kickcat']):.1f} us "
                 f"({np.percentile(pooled['kickcat'], 99):.1f}); ours/KickCAT "
                 f"{out['ours_over_kickcat']:.2f} (target <= 1)")
    out["load_average_end"] = os.getloadavg()
    for name in ("ours_segment", "kickcat_segment"):
        seg = out.get(name)
        if isinstance(seg, dict):  # the two must match for a like-for-like figure
            print(f"{name}: out/in bytes per slave {seg['out_in_bytes']}, "
                  f"WKC {seg['wkc']} (SOEM expects {seg['expected_wkc']})")
    print(text)
    print(f"load average {out['load_average_start']} -> {out['load_average_end']}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
