"""The dashboard end to end: the demo segment, ``run --web``, headless Chromium on every page.

The simulator serves ``examples/demo.toml`` over UDP with its control channel;
``pyethercat run --web`` runs the master (1 ms cycles) and starts the
dashboard beside it; Debian's chromium, driven by its chromedriver through
Selenium, opens the address ``run`` printed (token and all) and walks every
page. Screenshots go to the test's directory (and to ``$PYECAT_WEB_SCREENSHOTS``
when set: that is how docs/img/web-*.png are made).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import select
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT
from webdriving import browser as _browser
from webdriving import fits, severe_log
from webdriving import page as _page
from webdriving import q as _q
from webdriving import shot as _shot
from webdriving import wait as _wait

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "examples" / "demo.toml"
# How long a command may take to start and print its address: on a loaded 2-core host the
# interpreter and its imports alone took 10 s, a scan and start-up several times that.
STARTUP = 180.0
# The masters wait a second for a frame, as ``patient_cli`` makes the CLI tests' do: under
# a loaded CI host the DC set-up once saw no reply to four FRMW in 4 x 50 ms.
PATIENT = {"PYETHERCAT_FRAME_TIMEOUT": str(SIM_FRAME_TIMEOUT)}
# The simulator answers under SCHED_FIFO when it may (as the interop tests run it): on a
# loaded host the DC set-up's 50 ms frame time-out would otherwise measure the queueing.
REALTIME = ["--realtime", "10"] if os.geteuid() == 0 else []
# The master runs under normal scheduling: under SCHED_FIFO its 1 kHz loop and the
# simulator's took most of both cores and starved the browser on a loaded host.
MASTER = [sys.executable, "-m", "pyethercat"]
# ``run --web`` puts the loop in the isolated engine (SCHED_FIFO 40 by default as root):
# normal scheduling here too, for the same reason.
NORMAL = ["--realtime", "0"]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def control(path: Path, request: dict[str, object]) -> dict[str, object]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10)
        s.connect(str(path))
        s.sendall(json.dumps(request).encode() + b"\n")
        buf = b""
        while not buf.endswith(b"\n"):
            chunk = s.recv(65536)
            if not chunk:
                break
            buf += chunk
    answer: dict[str, object] = json.loads(buf)
    assert answer.get("ok", True) is not False, answer
    return answer


def wait_control(path: Path, timeout: float = 60.0) -> None:
    """Until the simulator answers on its control socket (it binds before it listens)."""
    limit = time.monotonic() + timeout
    while True:
        try:
            control(path, {"cmd": "ping"})
            return
        except OSError:
            if time.monotonic() > limit:
                raise
            time.sleep(0.05)


def read_line(proc: subprocess.Popen[bytes], prefix: str, timeout: float) -> str:
    """The first stdout line of ``proc`` starting with ``prefix`` (waits at most ``timeout``)."""
    assert proc.stdout is not None
    limit = time.monotonic() + timeout
    while time.monotonic() < limit:
        if proc.poll() is not None:
            break
        ready, _, _ = select.select([proc.stdout], [], [], 0.2)
        if ready:
            line = proc.stdout.readline().decode(errors="replace")
            if line.startswith(prefix):
                return line[len(prefix):].strip()
    raise AssertionError(f"no '{prefix}' line from {proc.args}")


@dataclass
class Running:
    url: str
    token: str
    base: str
    control: Path
    port: int
    env: dict[str, str]
    run: subprocess.Popen[bytes]


def _stop(proc: subprocess.Popen[bytes] | None) -> None:
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def running(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Running]:
    tmp = tmp_path_factory.mktemp("web")
    runtime = tmp / "runtime"
    runtime.mkdir(mode=0o700)
    env = dict(os.environ, PYETHERCAT_RUNTIME_DIR=str(runtime), **PATIENT)
    port = _free_udp_port()
    ctl = tmp / "sim.sock"
    sim = subprocess.Popen([sys.executable, "-m", "pyethercat", "sim", str(DEMO), "--udp",
                            f"127.0.0.1:{port}", "--control", str(ctl), "-q", *REALTIME], env=env)
    run = None
    try:
        wait_control(ctl)
        run = subprocess.Popen([*MASTER, "--udp", f"127.0.0.1:{port}",
                                "run", "--dc", *NORMAL, "--web", "--web-bind", "127.0.0.1:0",
                                "--web-token", "generate", "--web-allow-writes"],
                               stdout=subprocess.PIPE, env=env)
        url = read_line(run, "dashboard: ", STARTUP)
        base, _, token = url.partition("?token=")
        assert token and base.startswith("http://127.0.0.1:")
        yield Running(url, token, base.rstrip("/"), ctl, port, env, run)
    finally:
        _stop(run)
        _stop(sim)


@pytest.fixture
def browser(running: Running, tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    yield from _browser(tmp_path_factory)


def _request(url: str, *, body: dict[str, object] | None = None,
             headers: dict[str, str] | None = None) -> tuple[int, str]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={
        **({"Content-Type": "application/json"} if body is not None else {}), **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=STARTUP) as resp:
            return resp.status, resp.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def _sii_names() -> list[str]:
    """The slaves' SII names in ring order (as the simulator's device kinds define them)."""
    from pyethercat.sim.topology import load_topology

    topo = load_topology(DEMO)
    by_name = {s.name: s for s in topo.slaves}
    order = ["coupler", "branch-do8", "di8", "do8", "di2", "ai2"]  # ports 0 -> 3 -> 1
    return [by_name[n].info.device_name or "" for n in order]


def test_every_page_in_headless_chromium(running: Running, browser: object,
                                         tmp_path: Path) -> None:
    from selenium.webdriver.common.by import By

    d = browser
    d.get(running.url)  # type: ignore[attr-defined]
    # The token in the address became an HttpOnly cookie; the address no longer shows it.
    _wait(d, lambda d: _q(d, "#node-5", "data-state") is not None)
    assert "token" not in d.current_url  # type: ignore[attr-defined]
    assert all(c["httpOnly"] for c in d.get_cookies())  # type: ignore[attr-defined]
    names = _sii_names()

    # Topology: every slave by name, every state badge OP once the master got there.
    _wait(d, lambda d: all(_q(d, f"#node-{i}", "data-state") == "OP" for i in range(6)))
    text = _q(d, "#topo") or ""
    for name in names:
        assert name[:40] in text
    _shot(d, "topology", tmp_path)

    # Slaves: name and state per row, the counters of every port read.
    _page(d, "slaves")
    for i, name in enumerate(names):
        assert name in (_q(d, f"#slave-row-{i}") or "")
    # A starved master may miss the slaves' 100 ms watchdog on a loaded host; the
    # recovery brings them back to OP, which the page then shows.
    _wait(d, lambda d: all(_q(d, f"#slave-row-{i} .badge", "data-state") == "OP"
                           for i in range(len(names))))
    _wait(d, lambda d: _q(d, 'td.portcell[data-link="up"]') is not None)
    # run --dc: every slave's delay, offset and |Δt| (the DC column the old layout cut off)
    _wait(d, lambda d: all("delay" in (_q(d, f"#slave-row-{i} td.dc") or "")
                           for i in range(len(names))))
    scroll, width = fits(d, "#page-slaves .tablewrap")
    assert scroll <= width, f"the slaves table is {scroll} px wide in {width} px"
    _shot(d, "slaves", tmp_path)

    # Process data: a live value changes between two reads (the simulator's inputs move).
    _page(d, "pdo")
    # The ai2's inputs are not wired to any output: the simulator's control channel moves them.
    cell = '.pdo-card td.value[data-pos="5"][data-name="AI Channel 1.Value"]'
    _wait(d, lambda d: _q(d, cell) == str(0x1234))  # "3412" little endian in the topology
    first = _q(d, cell)
    control(running.control, {"cmd": "set_inputs", "slave": "ai2", "data": "7856cdab"})
    _wait(d, lambda d: _q(d, cell) == str(0x5678))
    second = _q(d, cell)
    assert (first, second) == (str(0x1234), str(0x5678))

    # Writing an output: off by default, on after a confirmation, each write confirmed.
    set_buttons = d.find_elements(By.CSS_SELECTOR, "#pdo-3 button")  # type: ignore[attr-defined]
    assert set_buttons and all(not b.is_enabled() for b in set_buttons)
    d.find_element(By.ID, "pdo-writes").click()  # type: ignore[attr-defined]
    d.find_element(By.ID, "modal-ok").click()  # type: ignore[attr-defined]
    row = d.find_elements(By.CSS_SELECTOR, "#pdo-3 tbody tr")[2]  # type: ignore[attr-defined]
    row.find_element(By.CSS_SELECTOR, "input").send_keys("1")
    row.find_element(By.CSS_SELECTOR, "button").click()
    d.find_element(By.ID, "modal-ok").click()  # type: ignore[attr-defined]
    # do8 (ring position 3) "Channel 3.Output" drives di8 input 3 through the wiring.
    wired = '.pdo-card td.value[data-pos="2"][data-name="Channel 3.Input"]'
    _wait(d, lambda d: _q(d, wired) == "1")
    assert bytes.fromhex(str(control(running.control, {"cmd": "outputs", "slave": "do8"})["data"]))[0] & 0x04
    _shot(d, "pdo", tmp_path)

    # Cycle: the counters move between two reads; the charts are drawn.
    _page(d, "cycle")
    kpi = "#cycle-kpis .kpi:nth-child(8) .value"
    def cycles(d: object) -> int:
        text = _q(d, kpi) or "0"
        return int("".join(ch for ch in text if ch.isdigit()) or 0)

    _wait(d, lambda d: cycles(d) > 0)
    c1 = cycles(d)
    _wait(d, lambda d: cycles(d) > c1)
    assert d.find_elements(By.CSS_SELECTOR, "#chart-jitter canvas")  # type: ignore[attr-defined]
    assert d.find_elements(By.CSS_SELECTOR, "#chart-hist canvas")  # type: ignore[attr-defined]
    time.sleep(1.0)  # let the charts gather a second of points for the picture
    _shot(d, "cycle", tmp_path)

    # DC (run --dc): the reference, the phase lock, |0x092C| of every DC slave over time.
    _page(d, "dc")
    _wait(d, lambda d: "Reference" in (_q(d, "#dc-kpis") or ""))
    _wait(d, lambda d: _q(d, "#chart-dc canvas", "width") is not None)
    assert len(d.find_elements(By.CSS_SELECTOR, "#dc-table tbody tr")) == 6  # type: ignore[attr-defined]
    time.sleep(1.0)
    _shot(d, "dc", tmp_path)

    _page(d, "drives")
    _wait(d, lambda d: "CiA 402" in (_q(d, "#drives") or ""))
    _shot(d, "drives", tmp_path, publish=False)

    _page(d, "mailbox")
    _wait(d, lambda d: _q(d, "#emcy-table tbody") is not None)
    _shot(d, "mailbox", tmp_path, publish=False)

    # A cable cut behind the di8: the topology marks that link and the slaves behind it.
    # The done-when's "within 1 s" is the dashboard's latency, counted in its pushes (at
    # most `rate` a second) so that a slow host or browser does not decide it: the last
    # push before the cut comes from the server, the first that showed the cut is named
    # by the page's mark; wall-clock figures are printed only.
    _page(d, "topology")
    rate = float(d.execute_script("return S.segment.rate;"))  # type: ignore[attr-defined]
    auth = {"Authorization": f"Bearer {running.token}"}
    before = json.loads(_request(f"{running.base}/api/live", headers=auth)[1])["push"]
    t_cut = time.time()
    control(running.control, {"cmd": "break_link", "slave": "di8", "port": 1})
    cut = time.time()
    try:
        _wait(d, lambda d: _q(d, 'path.edge.broken[data-to="3"]', "d") is not None,
              timeout=STARTUP)
        seen = time.time()
        since = float(_q(d, "#break-3", "data-since") or "nan")
        pushes = int(_q(d, "#break-3", "data-since-push") or "0") - before
        print(f"topology marked the cut in push {pushes} after it ({rate:g} pushes/s); the "
              f"snapshot was taken {(since - cut) * 1000:.0f} ms after the cut, the browser "
              f"showed it {(seen - cut) * 1000:.0f} ms after")
        assert since > t_cut  # a snapshot taken after the cut, not a stale mark
        assert 1 <= pushes <= math.ceil(rate * 1.0)
        label = _q(d, "#break-3") or ""
        assert "PEC-DI8" in label and "port 1" in label and "since" in label
        for i in (3, 4, 5):
            assert _q(d, f"#node-{i}", "data-state") == "LOST"
        # The whole picture before it is taken: the di8 answers, its port 1 has no link,
        # and the ring service located the cut (a register reading after the cut).
        port1 = '#node-2 circle[data-port="1"]'
        _wait(d, lambda d: _q(d, "#node-2", "data-state") == "OP"
              and _q(d, port1, "data-link") == "down"
              and "slave 2 port 1" in (_q(d, "#faults .fault") or ""), timeout=STARTUP,
              describe=lambda d: f"di8 {_q(d, '#node-2', 'data-state')}, port 1 "
                                 f"{_q(d, port1, 'data-link')}, faults {_q(d, '#faults')!r}")
        _shot(d, "topology-broken", tmp_path)
    finally:
        control(running.control, {"cmd": "restore_link", "slave": "di8", "port": 1})
    # The master brings them back; the mark goes away.
    _wait(d, lambda d: _q(d, "path.edge.broken", "d") is None, timeout=STARTUP)
    assert severe_log(d) == []  # no script error, no content-security-policy violation


def test_writes_need_the_token_and_reads_need_it_when_set(running: Running) -> None:
    live = f"{running.base}/api/live"
    assert _request(live)[0] == 403  # a token server: every request carries it
    status, body = _request(live, headers={"Authorization": f"Bearer {running.token}"})
    assert status == 200 and json.loads(body)["slaves"]
    write = {"position": 3, "name": "Channel 1.Output", "value": 1}
    assert _request(f"{running.base}/api/pdo/write", body=write)[0] == 403
    assert _request(f"{running.base}/api/pdo/write", body=write,
                    headers={"Authorization": "Bearer wrong"})[0] == 403
    ok = _request(f"{running.base}/api/pdo/write", body=write,
                  headers={"Authorization": f"Bearer {running.token}"})
    assert ok[0] == 200, ok


def test_web_reaches_the_running_master_read_only_by_default(running: Running) -> None:
    """A second dashboard (``pyethercat web``) finds ``run``'s master through its socket."""
    web = subprocess.Popen([sys.executable, "-m", "pyethercat", "--udp",
                            f"127.0.0.1:{running.port}", "web", "--bind", "127.0.0.1:0"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=running.env)
    try:
        url = read_line(web, "dashboard: ", STARTUP)
        assert "token" not in url  # loopback, no token asked for
        status, body = _request(f"{url}api/live")
        assert status == 200
        live = json.loads(body)
        assert live["cycle"]["running"] and live["cycle"]["cycles"] > 0  # run's loop, not its own
        write = {"position": 3, "name": "Channel 1.Output", "value": 1}
        status, body = _request(f"{url}api/pdo/write", body=write)
        assert status == 403 and "read-only" in body
        status, _ = _request(f"{url}api/sdo/write", body={"position": 0, "index": "0x1000",
                                                          "value": "1"})
        assert status == 403
    finally:
        _stop(web)
    assert web.stderr is not None and b"Traceback" not in web.stderr.read()


@pytest.mark.parametrize("argv", [
    ["web", "--bind", "0.0.0.0:0"],
    ["run", "--web", "--web-bind", "0.0.0.0:0", "--seconds", "1"],
])
def test_a_non_loopback_bind_without_a_token_refuses_to_start(running: Running,
                                                              argv: list[str]) -> None:
    done = subprocess.run([sys.executable, "-m", "pyethercat", "--udp", "127.0.0.1:9", *argv],
                          capture_output=True, text=True, timeout=STARTUP, env=running.env)
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "without a token" in done.stderr and "--token" in done.stderr


MAILBOX_TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
foe = true

[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""


def test_mailbox_and_drives_pages_on_coe_slaves(tmp_path: Path,
                                                 tmp_path_factory: pytest.TempPathFactory) -> None:
    """SDO browse, read and write, the FoE file list, an emergency, the drive's card.

    The Mailbox picture of the docs is this test's (the demo segment has no CoE slave).
    """
    from selenium.webdriver.common.by import By

    topo = tmp_path / "mailbox.toml"
    topo.write_text(MAILBOX_TOPOLOGY)
    runtime = tmp_path / "runtime"
    runtime.mkdir(mode=0o700)
    env = dict(os.environ, PYETHERCAT_RUNTIME_DIR=str(runtime), **PATIENT)
    port = _free_udp_port()
    ctl = tmp_path / "sim.sock"
    link = ["--udp", f"127.0.0.1:{port}"]
    sim = subprocess.Popen([sys.executable, "-m", "pyethercat", "sim", str(topo), *link,
                            "--control", str(ctl), "-q", *REALTIME], env=env)
    run = None
    gen = None
    try:
        wait_control(ctl)
        run = subprocess.Popen([*MASTER, *link, "run", *NORMAL, "--web",
                                "--web-bind", "127.0.0.1:0", "--web-allow-writes"],
                               stdout=subprocess.PIPE, env=env)
        url = read_line(run, "dashboard: ", STARTUP)
        assert "?token=" in url  # --allow-writes made one: writes always need it
        # A file written over FoE through the running master (the command line's way).
        payload = tmp_path / "notes.txt"
        payload.write_bytes(b"written by the test\n" * 20)
        done = subprocess.run([sys.executable, "-m", "pyethercat", *link, "foe_write", "-p", "0",
                               "-q", str(payload)], capture_output=True, text=True, env=env,
                              timeout=120)
        assert done.returncode == 0, done.stderr
        gen = _browser(tmp_path_factory)
        d = next(gen)
        d.get(url)  # type: ignore[attr-defined]
        _wait(d, lambda d: _q(d, "#node-1", "data-state") == "OP", timeout=STARTUP)

        _page(d, "mailbox")
        _wait(d, lambda d: _q(d, "#mbx-slave option") is not None)
        d.find_element(By.ID, "sdo-browse").click()  # type: ignore[attr-defined]
        _wait(d, lambda d: "0x1018" in (_q(d, "#sdo-list") or ""), timeout=STARTUP,
              describe=lambda d: f"SDO list: {(_q(d, '#sdo-list') or '')[:300]!r}")
        # A segment message comes again on every reconnection of the WebSocket (a
        # starved browser or server misses the keep-alive ping under load) and after a
        # rescan: with the same slave chosen, the browsed dictionary stays.
        d.execute_script("onSegment(JSON.parse(JSON.stringify(S.segment)));")  # type: ignore[attr-defined]
        assert "0x1018" in (_q(d, "#sdo-list") or "")
        assert d.execute_script(  # type: ignore[attr-defined]
            "return document.getElementById('mbx-slave').value;") == "0"
        assert "Settings" in (_q(d, "#sdo-list") or "")
        # Read 0x1018:01 (vendor id) by clicking its entry in the browsed dictionary.
        d.execute_script(  # type: ignore[attr-defined]
            "for (const s of document.querySelectorAll('#sdo-list summary'))"
            "  if (s.textContent.includes('0x1018')) s.parentElement.open = true;")
        rows = [r for r in d.find_elements(By.CSS_SELECTOR, "#sdo-list details[open] tr.entry")  # type: ignore[attr-defined]
                if r.text.startswith(":01")]
        rows[0].click()
        _wait(d, lambda d: "0x1018:1 =" in (_q(d, "#sdo-result") or ""), timeout=STARTUP)
        result = _q(d, "#sdo-result") or ""
        assert "0x00504543" in result.lower() or str(0x00504543) in result
        # Write 0x8000:01 (filter time) after the confirmation, read it back.
        for field, value in (("sdo-index", "0x8000"), ("sdo-sub", "1"), ("sdo-value", "250")):
            box = d.find_element(By.ID, field)  # type: ignore[attr-defined]
            box.clear()
            box.send_keys(value)
        d.find_element(By.ID, "sdo-write").click()  # type: ignore[attr-defined]
        d.find_element(By.ID, "modal-ok").click()  # type: ignore[attr-defined]
        _wait(d, lambda d: "written" in (_q(d, "#sdo-result") or ""), timeout=STARTUP)
        d.find_element(By.ID, "sdo-read").click()  # type: ignore[attr-defined]
        _wait(d, lambda d: "= 250" in (_q(d, "#sdo-result") or "")
              or " 250 " in (_q(d, "#sdo-result") or ""), timeout=STARTUP)
        # The FoE file list has the file written above; reading it gives its size.
        _wait(d, lambda d: "notes.txt" in (_q(d, "#foe-files") or ""), timeout=STARTUP)
        d.find_element(By.ID, "foe-name").send_keys("notes.txt")  # type: ignore[attr-defined]
        d.find_element(By.CSS_SELECTOR, "#foe-form button").click()  # type: ignore[attr-defined]
        _wait(d, lambda d: f"{len(payload.read_bytes())} bytes" in (_q(d, "#foe-result") or ""),
              timeout=STARTUP)
        # An emergency the io posts shows in the log with its code.
        assert control(ctl, {"cmd": "emergency", "slave": "io", "code": 0x8130,
                             "register": 0x11, "data": "0102030405"})["sent"]
        _wait(d, lambda d: "0x8130" in (_q(d, "#emcy-table") or ""), timeout=STARTUP)
        _shot(d, "mailbox", tmp_path)

        # The drive as run maps it by default (controlword, statusword, mode): its card
        # (a drive that moves is test_dashboard_inprocess.py's, and the Drives picture).
        _page(d, "drives")
        _wait(d, lambda d: _q(d, "#drive-1") is not None, timeout=STARTUP)
        assert "Statusword" in (_q(d, "#drive-1") or "")
        _shot(d, "drives-coe", tmp_path, publish=False)
    finally:
        if gen is not None:
            with contextlib.suppress(StopIteration):
                next(gen)
        _stop(run)
        _stop(sim)
