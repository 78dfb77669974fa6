"""EoE end to end as root: host IP stack -> TAP -> our master -> EtherCAT -> simulated drives.

The simulator (``pyethercat sim``) serves an ``eoe-web`` device and the seed
002 drive on one end of a ``pyecat-`` veth pair, each with its IP side in a
``pyecat-`` network namespace of its own (the kernel answers there, a web
server listens on port 80). Our master (``pyethercat run --eoe``) runs the
other end and joins the slaves to a TAP with the host's address. Then real
tools talk through it: ``ping``, ``curl``, a 1 MiB download compared byte for
byte, the two slaves pinging each other through the master's switch, the same
download with 1 % of the EtherCAT frames dropped by the simulator, and
headless Chromium (through Selenium and Debian's chromedriver) loading the
diagnostic page twice.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
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


@pytest.fixture(scope="module")
def eoe_net(root: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[EoeNet]:
    ping = _tool("ping")
    _tool("curl")
    tag = uuid.uuid4().hex[:5]
    net = f"10.213.{random.randint(1, 250)}"
    tmp = tmp_path_factory.mktemp("eoe")
    web_ns, drive_ns = f"pyecat-e{tag}-web", f"pyecat-e{tag}-drive"
    topo = tmp / "eoe.toml"
    topo.write_text(f"""
[[slave]]
name = "web"
device = "builtin:eoe-web"
eoe = {{ ip = "{net}.10/24", gateway = "{net}.1", netns = "{web_ns}" }}
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
eoe = {{ ip = "{net}.11/24", gateway = "{net}.1", netns = "{drive_ns}" }}
""")
    a, b = make_veth_pair()
    tap = f"pyecat-{tag}t"
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
            master = subprocess.Popen(
                [sys.executable, "-m", "pyethercat", "--iface", b, "run", "--eoe", "--eoe-tap", tap,
                 "--eoe-host-ip", f"{net}.1/24", "--seconds", "900"],
                stdout=log, stderr=subprocess.STDOUT)
        end = time.monotonic() + START_LIMIT
        while subprocess.run([ping, "-c", "1", "-W", "1", f"{net}.10"],
                             capture_output=True).returncode != 0:
            assert master.poll() is None, master_log.read_text()[-2000:]
            assert time.monotonic() < end, f"no ping through EoE within {START_LIMIT} s"
        yield EoeNet(b, net, f"{net}.10", f"{net}.11", web_ns, drive_ns, tap, control, master_log)
    finally:
        _stop(master)
        _stop(sim)
        delete_veth(a)
        for ns in (web_ns, drive_ns):  # the simulator removes them; a crash must not leak
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", tap], capture_output=True)


def test_ping_through_the_tap_ethercat_and_the_drive_namespace(eoe_net: EoeNet) -> None:
    done = subprocess.run(["ping", "-c", "20", "-i", "0.2", eoe_net.drive_ip],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert " 0% packet loss" in done.stdout
    rtt = re.search(r"= ([\d.]+)/([\d.]+)/([\d.]+)/", done.stdout)
    assert rtt is not None
    print(f"\nping -c 20 host -> drive through EoE: rtt min/avg/max {rtt.group(1)}/"
          f"{rtt.group(2)}/{rtt.group(3)} ms")


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
    _control(eoe_net.control, {"cmd": "drop", "probability": 0.01, "seed": 7})
    try:
        _download(eoe_net.web_ip, tmp_path)
        stats = _control(eoe_net.control, {"cmd": "stats"})
        assert int(str(stats["lost"])) > 0  # frames really were dropped
    finally:
        _control(eoe_net.control, {"cmd": "drop", "probability": 0.0})


def test_headless_chromium_loads_the_page_and_the_live_value_changes(
        eoe_net: EoeNet, tmp_path: Path) -> None:
    """Selenium drives Debian's chromedriver/chromium (no browser download at run time)."""
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
        first = browser.find_element(By.ID, "live-value").text
        assert "Servo Positioning Controller" in browser.title
        time.sleep(1.0)
        browser.get(f"http://{eoe_net.drive_ip}/")
        second = browser.find_element(By.ID, "live-value").text
        assert first and second and first != second
        assert browser.find_element(By.ID, "state").text == "OP"
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
