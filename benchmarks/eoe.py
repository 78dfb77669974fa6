"""EoE throughput through our master and the simulator, next to the mailbox-bound limit.

Run as root (veth pair, network namespaces, TAP)::

    .venv/bin/python benchmarks/eoe.py [--size BYTES] [--small BYTES] [--realtime PRIO]
        [--rates 1000,4000] [--subnet auto|A.B.C.0/24] [--guest-halt-poll-ns NS]

``--guest-halt-poll-ns NS``: on a KVM guest with the ``haltpoll`` cpuidle
driver, let idle vCPUs poll that long before they halt, for the run only
(the old value is put back). The 4 kHz figures depend on it: a halted vCPU
adds the host's wake-up to every round trip (docs/realtime.md).

``--loop isolated`` (or ``both``) runs the cyclic loop in the isolated
engine, as ``run --web`` does: the EoE service then ticks in this process
from the runner's callback, once per engine cycle it sees (the ``ticks``
column: EoE ticks per cycle run).

``--subnet`` is the IPv4 network of the host's TAP and the two slaves (.1,
.10, .11); ``auto`` (the default) takes the first /24 of 10.214.0.0/16, in
random order, that overlaps no address or route of the host.

This process (the cyclic loop among its threads) runs under SCHED_FIFO 5,
the simulator under 10, as in benchmarks/mailbox.py.

The simulator (``pyethercat sim``, a child process) serves ``builtin:eoe-web``
(1024-byte mailboxes) and the seed 002 drive (128-byte mailboxes), each with
the kernel's IP stack and web server in a ``pyecat-`` namespace; this process
runs our master on the other end of a veth pair with the EoE switch and a
TAP. For each cycle rate (1 kHz, 4 kHz) and device it downloads
``/blob?size=N`` over HTTP from the host and reports:

- the Ethernet bytes the slave sent per second (the frames rebuilt from its
  fragments, headers included) and the HTTP payload per second;
- the mailbox-bound limit: SM1 bytes per cycle x cycle rate (one mailbox read
  per cycle, as IgH's EoE handler does); and the ratios.

A full-size frame (1514 bytes) needs two 1024-byte or sixteen 128-byte
mailboxes (fragments carry multiples of 32 bytes, 992 or 96 of them), so
1514 / 2048 = 73.9 % of the limit is the most any master can carry with
these sizes. The last line is one JSON object of the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
import uuid
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

from common import guest_halt_poll, host_idle, veth  # noqa: E402

from pyethercat.master.eoe_switch import start_eoe  # noqa: E402
from pyethercat.master.master import Master  # noqa: E402


def _host_networks() -> list[ipaddress.IPv4Network]:
    """Networks the host uses: its IPv4 addresses' and its routes' (every table)."""
    nets: list[ipaddress.IPv4Network] = []
    for args in (["-4", "-o", "addr", "show"], ["-4", "route", "show", "table", "all"]):
        out = subprocess.run(["ip", *args], capture_output=True, text=True).stdout
        for word in out.split():
            if word[0].isdigit() and word.count(".") == 3:
                with contextlib.suppress(ValueError):
                    nets.append(ipaddress.IPv4Network(word, strict=False))
    return nets


def pick_subnet(text: str) -> ipaddress.IPv4Network:
    """The benchmark's network: ``auto`` (a free /24 of 10.214.0.0/16) or the one given."""
    used = _host_networks()
    if text != "auto":
        try:
            net = ipaddress.IPv4Network(text)
        except ValueError as exc:
            raise SystemExit(f"eoe.py: error: --subnet {text}: {exc}") from None
        if net.prefixlen > 28:
            raise SystemExit(f"eoe.py: error: --subnet {text}: needs room for .1, .10 and .11")
        clash = sorted({str(u) for u in used if u.overlaps(net) and u.prefixlen > 0})
        if clash:
            raise SystemExit(f"eoe.py: error: --subnet {text} overlaps the host's "
                             f"{', '.join(clash)}")
        return net
    candidates = list(ipaddress.IPv4Network("10.214.0.0/16").subnets(new_prefix=24))
    random.shuffle(candidates)
    for net in candidates:
        if not any(u.overlaps(net) and u.prefixlen > 0 for u in used):
            return net
    raise SystemExit("eoe.py: error: no free /24 in 10.214.0.0/16: give --subnet")


def _normal_priority() -> None:
    # (the child would inherit this process's SCHED_FIFO: a browser on the host runs
    # at normal priority)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def download(url: str, http_client: str) -> tuple[int, float]:
    """(bytes, seconds) of one HTTP GET: by ``curl`` in a process of its own (as a
    browser on the host would), or by ``urllib`` in this process, the master's."""
    if http_client == "urllib":
        t0 = time.perf_counter()
        body = urllib.request.urlopen(url, timeout=600).read()
        return len(body), time.perf_counter() - t0
    out = subprocess.run(["curl", "-sS", "--max-time", "600", "-o", "/dev/null",
                          "-w", "%{size_download} %{time_total}", url],
                         capture_output=True, text=True, preexec_fn=_normal_priority)
    if out.returncode != 0:
        raise SystemExit(f"eoe.py: error: curl {url}: {out.stderr.strip()}")
    got, seconds = out.stdout.split()
    return int(got), float(seconds)


def _measure(master: Master, cycle: float, targets: list[tuple[str, int, str]], size: int,
             tap: str, host_ip: str, http_client: str, loop: str) -> list[dict[str, Any]]:
    master.configure()
    # (the isolated engine under SCHED_FIFO 40, its default; this process stays at --realtime)
    runner = master.start(cycle, isolated=loop == "isolated")
    run = start_eoe(master, runner, tap=tap, host_ip=host_ip)
    rows: list[dict[str, Any]] = []
    try:
        for name, pos, ip in targets:
            client = run.clients[pos]
            sm1 = client.mailbox.tx_size
            # warm up: ARP, TCP slow start
            download(f"http://{ip}/blob?size=65536", http_client)
            before = client.stats.rx.bytes
            frags0, cycles0, skipped0, late0 = (client.stats.rx.fragments, runner.stats.cycles,
                                                runner.stats.skipped, client.stats.late)
            ticks0 = run.service.ticks
            got, dt = download(f"http://{ip}/blob?size={size}", http_client)
            if got != size:
                raise SystemExit(f"eoe.py: error: {got} of {size} bytes downloaded from {ip}")
            eth = client.stats.rx.bytes - before
            frags = client.stats.rx.fragments - frags0
            ran = runner.stats.cycles - cycles0
            ticks = ran + runner.stats.skipped - skipped0  # deadlines, run or skipped
            limit = sm1 / cycle
            rows.append({"device": name, "loop": loop, "cycle_hz": round(1 / cycle), "mailbox": sm1,
                         "seconds": round(dt, 2), "ethernet_Bps": round(eth / dt),
                         "http_Bps": round(got / dt), "limit_Bps": round(limit),
                         "ethernet_ratio": round(eth / dt / limit, 3),
                         "http_ratio": round(got / dt / limit, 3),
                         # fragments per cycle run, and cycles run per deadline: the
                         # first shows the EoE logic, the second the loop keeping up
                         "fragments_per_cycle": round(frags / max(1, ran), 3),
                         "cycles_run_per_deadline": round(ran / max(1, ticks), 3),
                         # EoE ticks per cycle run: 1 in-process; the isolated engine's
                         # follower in the user's process may miss some
                         "eoe_ticks_per_cycle": round((run.service.ticks - ticks0) / max(1, ran), 3),
                         # cycles whose EoE tick found last cycle's datagrams still out
                         "late_per_cycle": round((client.stats.late - late0) / max(1, ran), 3),
                         "load_average": round(os.getloadavg()[0], 1)})
    finally:
        run.close()
        runner.stop()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1 << 20, help="bytes per download")
    ap.add_argument("--small", type=int, default=256 << 10,
                    help="bytes per download from the 128-byte-mailbox drive")
    ap.add_argument("--realtime", type=int, default=5,
                    help="SCHED_FIFO priority of this process, the cyclic loop's thread among "
                         "its threads (0: normal scheduling); the simulator runs at 10")
    ap.add_argument("--rates", default="1000,4000",
                    help="cycle rates in Hz, comma-separated")
    ap.add_argument("--client", choices=("curl", "urllib"), default="curl",
                    help="who downloads: curl, a process of its own (as a browser on the "
                         "host), or urllib in this process, whose reads then take the GIL "
                         "from the cyclic loop's thread")
    ap.add_argument("--guest-halt-poll-ns", type=int, default=None, metavar="NS",
                    help="on a KVM guest with cpuidle-haltpoll: let idle vCPUs poll this long "
                         "before they halt, for the runs (put back after; docs/realtime.md)")
    ap.add_argument("--loop", choices=("thread", "isolated", "both"), default="thread",
                    help="the cyclic loop: a thread of this process (the default), the "
                         "isolated engine (a process of its own, as `run --web` starts it), "
                         "or both, one after the other")
    ap.add_argument("--subnet", default="auto",
                    help="IPv4 network of the TAP and the slaves (auto: a free /24 of "
                         "10.214.0.0/16)")
    args = ap.parse_args()
    try:
        rates = [int(r) for r in args.rates.split(",")]
    except ValueError:
        raise SystemExit(f"eoe.py: error: --rates {args.rates}: integers in Hz") from None
    if not rates or any(not 1 <= r <= 20000 for r in rates):
        raise SystemExit(f"eoe.py: error: --rates {args.rates}: 1..20000 Hz each")
    if os.geteuid() != 0:
        print(json.dumps({"skipped": "needs root (veth, namespaces, TAP)"}))
        return
    if args.realtime:
        # As benchmarks/mailbox.py and master_cycle.py: on a shared machine the cyclic loop
        # at normal priority skipped up to 90 % of its deadlines, which measured the
        # machine, not the EoE path (threads made from now on inherit the policy).
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
    tag = uuid.uuid4().hex[:4]
    subnet = pick_subnet(args.subnet)
    host_ip = f"{subnet[1]}/{subnet.prefixlen}"
    web_ip, drive_ip = subnet[10], subnet[11]
    a, b = veth()
    tmp = Path(tempfile.mkdtemp())
    topo = tmp / "eoe.toml"
    topo.write_text(f"""
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = {{ ip = "{web_ip}/{subnet.prefixlen}", netns = "pyecat-b{tag}-web" }}
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = {{ ip = "{drive_ip}/{subnet.prefixlen}", netns = "pyecat-b{tag}-drive" }}
""")
    print(f"network {subnet}: host {host_ip}, eoe-web {web_ip}, seed002-drive {drive_ip}",
          file=sys.stderr)
    control = tmp / "sim.sock"
    sim = subprocess.Popen([sys.executable, "-m", "pyethercat", "sim", str(topo), "--iface", a,
                            "-q", "--realtime", "10", "--control", str(control)])
    rows: list[dict[str, Any]] = []
    idle: dict[str, object] = {}
    try:
        end = time.monotonic() + 60
        while not control.exists() and time.monotonic() < end and sim.poll() is None:
            time.sleep(0.1)
        with Master.open(b) as m, guest_halt_poll(args.guest_halt_poll_ns):
            idle = host_idle()
            print(f"host idle: {idle}", file=sys.stderr)
            m.scan()
            loops = ("thread", "isolated") if args.loop == "both" else (args.loop,)
            for loop in loops:
                for cycle in (1 / r for r in rates):
                    rows += _measure(m, cycle, [("eoe-web", 0, str(web_ip))], args.size,
                                     f"pyecat-b{tag}t", host_ip, args.client, loop)
                    rows += _measure(m, cycle, [("seed002-drive", 1, str(drive_ip))],
                                     args.small, f"pyecat-b{tag}t", host_ip, args.client, loop)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(20)
        subprocess.run(["ip", "link", "del", a], capture_output=True)
    print(f"{'device':<14} {'loop':<8} {'cycle':>6} {'mailbox':>7} {'Ethernet B/s':>12} "
          f"{'HTTP B/s':>10} {'limit B/s':>10} {'eth/limit':>9} {'http/limit':>10} "
          f"{'frag/cycle':>10} {'cycles run':>10} {'ticks':>6} {'late':>6} {'load':>5}")
    for r in rows:
        print(f"{r['device']:<14} {r['loop']:<8} {r['cycle_hz']:>5}Hz {r['mailbox']:>7} "
              f"{r['ethernet_Bps']:>12} {r['http_Bps']:>10} {r['limit_Bps']:>10} "
              f"{r['ethernet_ratio']:>9.3f} {r['http_ratio']:>10.3f} "
              f"{r['fragments_per_cycle']:>10.3f} {r['cycles_run_per_deadline']:>10.3f} "
              f"{r['eoe_ticks_per_cycle']:>6.3f} {r['late_per_cycle']:>6.3f} "
              f"{r['load_average']:>5.1f}")
    print(json.dumps({"eoe": rows, "host_idle": idle}))


if __name__ == "__main__":
    main()
