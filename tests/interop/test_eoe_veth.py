"""EoE end to end as root: host IP stack -> TAP -> our master -> EtherCAT -> simulated drives.

The simulator (``pyethercat sim``) serves an ``eoe-web`` device and the seed
002 drive on one end of a ``pyecat-`` veth pair, each with its IP side in a
``pyecat-`` network namespace of its own (the kernel answers there, a web
server listens on port 80). Our master (``pyethercat run --eoe``) runs the
other end and joins the slaves to a TAP with the host's address. Then real
tools talk through it: ``ping``, ``curl``, a 1 MiB download compared byte for
byte, the two slaves pinging each other through the master's switch, the same
download with 1 % of the EtherCAT frames dropped by the simulator before any
slave sees them and, harder, with 1 % of them corrupted on their way back
after both slaves processed them (EoE fragments the slave handed over are
lost), ping and the download again with the cyclic loop in the isolated
engine (``run --isolated --eoe``), and headless Chromium (through Selenium and Debian's chromedriver)
loading the diagnostic page before and after the drive is moved.

Without a veth pair: ``run --eoe --eoe-per-slave`` on an in-process
simulated segment (one TAP per slave, as IgH's ``eoeXsY``), and ``run --eoe``
without CAP_NET_ADMIN (one line that says so).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pwd
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import delete_veth, make_veth_pair

from pyethercat.sim.eoe_web import blob

pytestmark = [pytest.mark.root, pytest.mark.slow]

#: Seconds the simulator and the master have to come up, a page to load, a command to
#: run (limits for a broken feature; a loaded CI machine is slow, not broken).
START_LIMIT = 180


@dataclass
class EoeNet:
    iface: str
    net: str
    web_ip: str
    drive_ip: str
    web_ns: str
    drive_ns: str
    tap: str
    control: str
    master_log: Path


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(f"required under CI=true: {name} (make tools installs it)")
        pytest.skip(f"{name} is not installed (make tools installs it as root)")
    return path


def _control(path: str, request: dict[str, object]) -> dict[str, object]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(5)
        s.connect(path)
        s.sendall(json.dumps(request).encode() + b"\n")
        data = b""
        while not data.endswith(b"\n"):
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    answer: dict[str, object] = json.loads(data)
    assert answer.get("ok"), answer
    return answer


def _stop(proc: subprocess.Popen[bytes] | None) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@dataclass
class _Running:
    iface: str
    tap: str
    control: str
    master_log: Path
    master: subprocess.Popen[bytes]


@contextlib.contextmanager
def _eoe_segment(tmp: Path, topology: str, netns: list[str], tap: str, host_ip: str,
                 ping_ip: str, run_args: list[str]) -> Iterator[_Running]:
    """``pyethercat sim`` serving ``topology`` on one end of a new veth pair, our master
    (``run --eoe`` and ``run_args``) on the other with TAP ``tap`` at ``host_ip``; yields
    once ``ping_ip`` answers through EoE. Everything it made is removed afterwards."""
    ping = _tool("ping")
    topo = tmp / "eoe.toml"
    topo.write_text(topology)
    a, b = make_veth_pair()
    control = str(tmp / "sim.sock")
    master_log = tmp / "master.log"
    sim = master = None
    try:
        sim = subprocess.Popen([sys.executable, "-m", "pyethercat", "sim", str(topo), "--iface", a,
                                "--control", control, "-q"])
        # (a loaded CI machine needs tens of seconds to start both processes)
        end = time.monotonic() + START_LIMIT
        while not os.path.exists(control):
            assert sim.poll() is None, "the simulator stopped"
            assert time.monotonic() < end, "the simulator did not come up"
            time.sleep(0.1)
        with open(master_log, "wb") as log:
            # --retries: the scan and the SDOs of `drive` go through this master, and the
            # simulator is Python on a loaded machine that can stall for seconds, longer
            # than 4 x 50 ms. (Not a longer frame time-out: the EoE datagrams are not sent
            # again by the scheduler, and a lost one holds its slave's EoE for that long.)
            master = subprocess.Popen(
                [sys.executable, "-m", "pyethercat", "--iface", b, "--retries", "100", "run",
                 *run_args, "--eoe", "--eoe-tap", tap, "--eoe-host-ip", host_ip,
                 "--seconds", "900"],
                stdout=log, stderr=subprocess.STDOUT)
        end = time.monotonic() + START_LIMIT
        while subprocess.run([ping, "-c", "1", "-W", "1", ping_ip],
                             capture_output=True).returncode != 0:
            assert master.poll() is None, master_log.read_text()[-2000:]
            assert time.monotonic() < end, f"no ping through EoE within {START_LIMIT} s"
        yield _Running(b, tap, control, master_log, master)
    finally:
        _stop(master)
        _stop(sim)
        delete_veth(a)
        for ns in netns:  # the simulator removes them; a crash must not leak
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", tap], capture_output=True)


@pytest.fixture(scope="module")
def eoe_net(root: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[EoeNet]:
    _tool("curl")
    tag = uuid.uuid4().hex[:5]
    net = f"10.213.{random.randint(1, 250)}"
    web_ns, drive_ns = f"pyecat-e{tag}-web", f"pyecat-e{tag}-drive"
    topology = f"""
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = {{ ip = "{net}.10/24", gateway = "{net}.1", netns = "{web_ns}" }}
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = {{ ip = "{net}.11/24", gateway = "{net}.1", netns = "{drive_ns}" }}
"""
    with _eoe_segment(tmp_path_factory.mktemp("eoe"), topology, [web_ns, drive_ns],
                      f"pyecat-{tag}t", f"{net}.1/24", f"{net}.10", []) as run:
        yield EoeNet(run.iface, net, f"{net}.10", f"{net}.11", web_ns, drive_ns, run.tap,
                     run.control, run.master_log)


def _mtu(name: str) -> int:
    return int(Path(f"/sys/class/net/{name}/mtu").read_text())


def _cli(*args: str, sim: str | None = None, iface: str | None = None,
         check: bool = True) -> subprocess.CompletedProcess[str]:
    where = ["--sim", sim] if sim is not None else ["--iface", str(iface)]
    done = subprocess.run([sys.executable, "-m", "pyethercat", *where, *args],
                          capture_output=True, text=True, timeout=START_LIMIT)
    if check:
        assert done.returncode == 0, done.stderr
    return done


def _eoe_rows(**where: str) -> dict[int, dict[str, str]]:
    """The running master's ``eoe`` listing: its columns by slave position."""
    lines = _cli("eoe", **where).stdout.splitlines()
    head = lines[0].split()
    rows = [dict(zip(head, ln.split(), strict=True)) for ln in lines[1:]]
    return {int(r["Slave"]): r for r in rows}


def _tcp_retransmits(netns: str) -> int:
    """Segments TCP sent again in a namespace (``RetransSegs`` of its /proc/net/snmp)."""
    text = subprocess.run(["ip", "netns", "exec", netns, "cat", "/proc/net/snmp"],
                          capture_output=True, text=True, check=True).stdout
    head, values = (ln.split()[1:] for ln in text.splitlines() if ln.startswith("Tcp:"))
    return int(dict(zip(head, values, strict=True))["RetransSegs"])


def test_ping_through_the_tap_ethercat_and_the_drive_namespace(eoe_net: EoeNet) -> None:
    done = subprocess.run(["ping", "-c", "20", "-i", "0.2", eoe_net.drive_ip],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert " 0% packet loss" in done.stdout
    rtt = re.search(r"= ([\d.]+)/([\d.]+)/([\d.]+)/", done.stdout)
    assert rtt is not None
    print(f"\nping -c 20 host -> drive through EoE: rtt min/avg/max {rtt.group(1)}/"
          f"{rtt.group(2)}/{rtt.group(3)} ms")


def test_a_full_1500_byte_packet_crosses_without_fragmenting(eoe_net: EoeNet) -> None:
    """MTU 1500 on the TAP, through EoE and on the drive's namespace interface: a
    1472-byte ping (a 1500-byte IP packet) with Don't Fragment set goes and comes back."""
    assert _mtu(eoe_net.tap) == 1500
    done = subprocess.run(["ping", "-c", "3", "-i", "0.2", "-M", "do", "-s", "1472",
                           eoe_net.drive_ip], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "3 received" in done.stdout


def test_curl_gets_the_diagnostic_page(eoe_net: EoeNet) -> None:
    done = subprocess.run(["curl", "-s", "-m", "120", f"http://{eoe_net.drive_ip}/"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    page = done.stdout
    assert "Servo Positioning Controller" in page and 'id="live-value"' in page
    assert "0x264860D2" in page and "Temperatures" in page
    assert ">OP<" in page  # the state the master brought it to


def _download(ip: str, tmp: Path, size: int = 1 << 20) -> None:
    out = tmp / f"blob-{ip}"
    done = subprocess.run(["curl", "-s", "-m", "240", "-o", str(out),
                           f"http://{ip}/blob?size={size}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert hashlib.sha256(out.read_bytes()).digest() == hashlib.sha256(blob(size)).digest()


def test_one_mib_download_is_byte_identical(eoe_net: EoeNet, tmp_path: Path) -> None:
    _download(eoe_net.web_ip, tmp_path)


def test_two_slaves_reach_each_other_through_the_masters_switch(eoe_net: EoeNet) -> None:
    done = subprocess.run(["ip", "netns", "exec", eoe_net.web_ns, "ping", "-c", "3", "-i", "0.2",
                           eoe_net.drive_ip], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    # and the other way, by the drive's own stack
    done = subprocess.run(["ip", "netns", "exec", eoe_net.drive_ns, "ping", "-c", "2", "-i", "0.2",
                           eoe_net.web_ip], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_download_survives_one_percent_dropped_frames(eoe_net: EoeNet, tmp_path: Path) -> None:
    # Dropped before any slave sees them: the mailbox datagrams are sent again, so no
    # EoE fragment is lost here (the test below loses them).
    _control(eoe_net.control, {"cmd": "drop", "probability": 0.01, "seed": 7})
    try:
        _download(eoe_net.web_ip, tmp_path)
        stats = _control(eoe_net.control, {"cmd": "stats"})
        assert int(str(stats["lost"])) > 0  # frames really were dropped
    finally:
        _control(eoe_net.control, {"cmd": "drop", "probability": 0.0})


def test_download_survives_fragments_lost_after_the_slave_sent_them(
        eoe_net: EoeNet, tmp_path: Path) -> None:
    """1 % of the frames get a CRC error on their way back, at the web device's port 1:
    both slaves processed them, the master's NIC drops them. An SM1 read lost so
    leaves a fragment the slave handed over that the master never sees: the frame
    it belonged to is discarded by reassembly (never delivered broken), TCP sends
    the data again, and the download is still byte for byte the same."""
    before = _eoe_rows(iface=eoe_net.iface)[0]
    retransmits = _tcp_retransmits(eoe_net.web_ns)
    _control(eoe_net.control, {"cmd": "crc_rate", "slave": "web", "port": 1, "rate": 0.01,
                               "seed": 7})
    try:
        _download(eoe_net.web_ip, tmp_path)
    finally:
        _control(eoe_net.control, {"cmd": "crc_rate", "slave": "web", "port": 1, "rate": 0.0})
    after = _eoe_rows(iface=eoe_net.iface)[0]
    assert int(after["Dropped"]) > int(before["Dropped"])  # frames discarded on the master
    assert _tcp_retransmits(eoe_net.web_ns) > retransmits


#: Increments the drive is moved between the two page loads.
MOVE = 100_000


def _move_drive(iface: str) -> None:
    """Enable the drive and move it MOVE increments through the running master's cycle.

    A loaded machine can stall the loop past the drive's sync manager watchdog (the
    drive then faults: 0x7500, EtherCAT left OP while enabled, and the master takes it
    back to OP) or past the time `drive` waits for the next cycles: reset and try again.
    """
    why = ""
    end = time.monotonic() + START_LIMIT
    while time.monotonic() < end:
        for action in (["reset"], ["enable", "--timeout", "60"],
                       ["move", str(MOVE), "--relative", "--timeout", "60"]):
            done = _cli("drive", "-p", "1", *action, iface=iface, check=False)
            if done.returncode:
                why = done.stderr
                break
        else:
            return
    pytest.fail(f"the drive could not be moved: {why}")


def _live_position(browser: object) -> int:
    """The page's large live value: the drive's position actual value, from its model."""
    from selenium.webdriver.common.by import By

    label = browser.find_element(By.ID, "live-label").text  # type: ignore[attr-defined]
    assert label.lower() == "position actual value"
    value = browser.find_element(By.ID, "live-value").text  # type: ignore[attr-defined]
    got = re.fullmatch(r"(-?\d+) inc", value)
    assert got is not None, value
    return int(got.group(1))


def test_headless_chromium_loads_the_page_and_the_live_value_changes(
        eoe_net: EoeNet, tmp_path: Path) -> None:
    """Selenium drives Debian's chromedriver/chromium (no browser download at run time).

    The live value is the drive's position actual value: the test moves the drive
    through the master between the two loads, and the page must show the move.
    """
    chromium = _tool("chromium")
    driver_path = _tool("chromedriver")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1280,900",
                f"--user-data-dir={tmp_path / 'profile'}"):
        opts.add_argument(arg)
    browser = webdriver.Chrome(service=Service(driver_path), options=opts)
    try:
        browser.set_page_load_timeout(START_LIMIT)
        browser.get(f"http://{eoe_net.drive_ip}/")
        first = _live_position(browser)
        assert "Servo Positioning Controller" in browser.title
        _move_drive(eoe_net.iface)
        browser.get(f"http://{eoe_net.drive_ip}/")
        second = _live_position(browser)
        # moved by MOVE (to within its position window), or further if a try faulted
        assert second - first >= MOVE // 2, (first, second)
        assert browser.find_element(By.ID, "state").text == "OP"
        assert "0x264860D2" in browser.find_element(By.ID, "identity").text
        shot = Path(os.environ.get("PYECAT_EOE_SCREENSHOT", str(tmp_path / "eoe-page.png")))
        browser.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
    finally:
        with contextlib.suppress(Exception):
            browser.quit()


def test_eoe_and_ip_reach_the_running_master(eoe_net: EoeNet) -> None:
    """``eoe`` lists the live handlers, ``ip`` re-addresses the drive's namespace interface."""
    cli = [sys.executable, "-m", "pyethercat", "--iface", eoe_net.iface]
    done = subprocess.run([*cli, "eoe"], capture_output=True, text=True, timeout=START_LIMIT)
    assert done.returncode == 0, done.stderr
    rows = [ln.split() for ln in done.stdout.splitlines()[1:]]
    assert [r[:3] for r in rows] == [[eoe_net.tap, "0", "up"], [eoe_net.tap, "1", "up"]]
    assert all(int(r[3]) > 0 for r in rows)  # bytes received from both slaves already
    new = f"{eoe_net.net}.21"
    done = subprocess.run([*cli, "ip", "-p", "1", "--ip", f"{new}/24", "--dns", f"{eoe_net.net}.1"],
                          capture_output=True, text=True, timeout=START_LIMIT)
    assert done.returncode == 0, done.stderr
    try:
        shown = subprocess.run(["ip", "-n", eoe_net.drive_ns, "-o", "addr", "show"],
                               capture_output=True, text=True).stdout
        assert f"{new}/24" in shown
        resolv = Path("/etc/netns") / eoe_net.drive_ns / "resolv.conf"
        assert resolv.read_text() == f"nameserver {eoe_net.net}.1\n"
        ping = subprocess.run(["ping", "-c", "2", "-i", "0.2", new], capture_output=True, text=True)
        assert ping.returncode == 0, ping.stdout
    finally:
        subprocess.run([*cli, "ip", "-p", "1", "addr", f"{eoe_net.drive_ip}/24"],
                       capture_output=True, timeout=START_LIMIT)


@pytest.fixture
def echo_topology() -> Iterator[tuple[str, str, str]]:
    """A topology with two EoE slaves on the Python echo stack and a di8 between them, in a
    directory anyone may read (the no-privilege test runs as nobody). (path, net0, net2)"""
    base = random.randrange(2, 250, 2)
    net0, net2 = f"10.217.{base}", f"10.217.{base + 1}"
    tmp = tempfile.mkdtemp(prefix="pyecat-eoe-")
    os.chmod(tmp, 0o755)
    path = os.path.join(tmp, "eoe.toml")
    with open(path, "w") as f:
        f.write(f"""
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = {{ ip = "{net0}.2/24" }}
[[slave]]
name = "di"
device = "builtin:di8"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = {{ ip = "{net2}.2/24" }}
""")
    os.chmod(path, 0o644)
    try:
        yield path, net0, net2
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def test_run_eoe_per_slave_makes_one_tap_per_slave(root: None, tmp_path: Path,
                                                   echo_topology: tuple[str, str, str]) -> None:
    """``run --eoe --eoe-per-slave``: a TAP per EoE slave named <prefix>s<position> as
    IgH's eoeXsY (none for the di8 at position 1), MTU 1500, each joined to its own slave
    only: the host's ARP broadcast on the first never reaches the second slave."""
    topo, net0, net2 = echo_topology
    _tool("ping")
    prefix = f"pyecat-{uuid.uuid4().hex[:4]}"
    tap0, tap1, tap2 = (f"{prefix}s{n}" for n in range(3))
    log = tmp_path / "master.log"
    with open(log, "wb") as out:
        master = subprocess.Popen(
            [sys.executable, "-m", "pyethercat", "--sim", topo, "run", "--eoe",
             "--eoe-per-slave", "--eoe-tap", prefix, "--seconds", "900"],
            stdout=out, stderr=subprocess.STDOUT)
    try:
        end = time.monotonic() + START_LIMIT
        while not (os.path.exists(f"/sys/class/net/{tap0}")
                   and os.path.exists(f"/sys/class/net/{tap2}")):
            assert master.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() < end, "the TAP interfaces did not come up"
            time.sleep(0.1)
        assert not os.path.exists(f"/sys/class/net/{tap1}")  # the di8 speaks no EoE
        assert _mtu(tap0) == _mtu(tap2) == 1500
        subprocess.run(["ip", "addr", "add", f"{net0}.1/24", "dev", tap0], check=True)
        ping = subprocess.run(["ping", "-c", "3", "-i", "0.2", "-W", "20", f"{net0}.2"],
                              capture_output=True, text=True)
        assert ping.returncode == 0, ping.stdout + ping.stderr
        rows = _eoe_rows(sim=topo)
        assert [(p, r["Interface"], r["State"]) for p, r in sorted(rows.items())] == [
            (0, tap0, "up"), (2, tap2, "up")]
        assert int(rows[0]["TxFrames"]) >= 4  # ARP and 3 pings to the web device
        assert int(rows[2]["TxFrames"]) == 0  # switched as one TAP, the ARP reached it too
        subprocess.run(["ip", "addr", "add", f"{net2}.1/24", "dev", tap2], check=True)
        ping = subprocess.run(["ping", "-c", "3", "-i", "0.2", "-W", "20", f"{net2}.2"],
                              capture_output=True, text=True)
        assert ping.returncode == 0, ping.stdout + ping.stderr
        assert int(_eoe_rows(sim=topo)[2]["RxFrames"]) >= 3
    finally:
        _stop(master)
        for tap in (tap0, tap1, tap2):
            subprocess.run(["ip", "link", "del", tap], capture_output=True)


@pytest.mark.parametrize("drop", [
    ["--reuid=nobody", "--regid=nogroup", "--clear-groups"],  # not root
    ["--bounding-set=-net_admin"],  # root without CAP_NET_ADMIN
], ids=["nobody", "root-without-cap-net-admin"])
def test_run_eoe_without_cap_net_admin_is_one_line(root: None, drop: list[str],
                                                   echo_topology: tuple[str, str, str]) -> None:
    setpriv = _tool("setpriv")
    topo = echo_topology[0]
    tap = f"pyecat-{uuid.uuid4().hex[:6]}"
    env = dict(os.environ)
    if "--reuid=nobody" in drop:  # a private runtime directory of nobody's own
        runtime = os.path.join(os.path.dirname(topo), "runtime")
        os.mkdir(runtime, 0o700)
        nobody = pwd.getpwnam("nobody")
        os.chown(runtime, nobody.pw_uid, nobody.pw_gid)
        env["PYETHERCAT_RUNTIME_DIR"] = runtime
    done = subprocess.run([setpriv, *drop, sys.executable, "-m", "pyethercat", "--sim", topo,
                           "run", "--eoe", "--eoe-tap", tap, "--seconds", "30"],
                          capture_output=True, text=True, timeout=START_LIMIT, cwd="/", env=env)
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stderr == (f"pyethercat: error: creating TAP interface {tap} needs root or "
                           f"CAP_NET_ADMIN\n")
    assert not os.path.exists(f"/sys/class/net/{tap}")


def test_eoe_through_the_isolated_engine(root: None, tmp_path: Path) -> None:
    """``run --isolated --eoe`` (as ``run --web`` starts it where the link allows): the
    EoE service ticks in the user's process after each engine cycle and its datagrams
    ride in the engine's frames. Ping and a 1 MiB download, byte for byte, with the
    loop in the engine's child process."""
    ping = _tool("ping")
    _tool("curl")
    tag = uuid.uuid4().hex[:5]
    net = f"10.211.{random.randint(1, 250)}"
    web_ns = f"pyecat-i{tag}-web"
    topology = f"""
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = {{ ip = "{net}.10/24", gateway = "{net}.1", netns = "{web_ns}" }}
"""
    with _eoe_segment(tmp_path, topology, [web_ns], f"pyecat-{tag}i", f"{net}.1/24",
                      f"{net}.10", ["--isolated"]) as run:
        done = subprocess.run([ping, "-c", "5", "-i", "0.2", f"{net}.10"], capture_output=True,
                              text=True)
        assert done.returncode == 0 and " 0% packet loss" in done.stdout, done.stdout
        _download(f"{net}.10", tmp_path)
        # The loop ran in the engine: a child process of the master's.
        pid = run.master.pid
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        assert any(b"pyethercat.master.engine.child" in Path(f"/proc/{c}/cmdline").read_bytes()
                   for c in children), children
