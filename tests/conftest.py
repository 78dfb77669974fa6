"""Fixtures shared by the whole suite: the shared corpus, root, tools, veth pairs.

Tests that need something from outside the repository (../shared, root, tshark)
skip with a reason on a developer machine, and fail under CI=true, where the
brief says they must run.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

#: Frame timeout (seconds) of the masters the tests open against a simulator in
#: another thread or process (UDP, veth, socketpair). The master's default of
#: 50 ms suits a real segment; a simulator here is Python sharing two loaded
#: CPUs with the whole suite, which can keep it off the CPU for longer than
#: the default's four attempts (200 ms). No test that uses it is about the
#: frame timeout: a frame that is really lost still ends as one.
#: (The command line takes it from the environment: the ``patient_cli`` fixture.)
SIM_FRAME_TIMEOUT = 1.0
#: SCHED_FIFO priority of simulator processes a peer with fixed timeouts talks to
#: (SOEM waits 2 ms for most replies, pysoem cannot change that): such a peer
#: would time out whenever the loaded machine kept the simulator off the CPU.
SIM_REALTIME = 10
#: How long :func:`wait_for` waits by default: what a test waits for happens in
#: milliseconds on an idle machine; the limit is only there so that a broken
#: feature fails the test instead of hanging it, and a loaded CI machine must
#: not hit it.
WAIT_LIMIT = 60.0


def wait_for(cond: Callable[[], bool], seconds: float = WAIT_LIMIT) -> bool:
    """Poll ``cond`` until it holds (True) or ``seconds`` have passed (False)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.005)
    return cond()
SHARED = REPO.parent / "shared"
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")


def _unavailable(reason: str) -> None:
    if IN_CI:
        pytest.fail(f"required under CI=true: {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        _unavailable(f"{SHARED} is absent")
    return SHARED


@pytest.fixture(scope="session")
def corpus_dir(shared_dir: Path) -> Path:
    corpus = shared_dir / "corpus"
    if not corpus.is_dir():
        _unavailable(f"{corpus} is absent")
    return corpus


@pytest.fixture(scope="session")
def tshark() -> str:
    path = shutil.which("tshark")
    if path is None:
        _unavailable("tshark is not installed (make test installs it when run as root)")
    assert path is not None
    return path


@pytest.fixture(scope="session")
def root() -> None:
    if os.geteuid() != 0:
        _unavailable("needs root (veth pairs / raw sockets)")


def make_veth_pair() -> tuple[str, str]:
    """Create a veth pair named pyecat-<random>a/b, both up. Caller deletes it."""
    tag = uuid.uuid4().hex[:6]
    a, b = f"pyecat-{tag}a", f"pyecat-{tag}b"
    subprocess.run(["ip", "link", "add", a, "type", "veth", "peer", "name", b], check=True)
    for name in (a, b):
        # No IPv6 autoconf chatter on our test wire.
        subprocess.run(["sysctl", "-qw", f"net.ipv6.conf.{name}.disable_ipv6=1"], check=False)
        subprocess.run(["ip", "link", "set", name, "up"], check=True)
    # "up" takes effect asynchronously: the kernel activates the transmit queue
    # from its link-watch work, which it may put off for up to a second while
    # other interfaces change (a loaded test run creating many pairs). A frame
    # sent before that is dropped, so wait until both ends say so.
    # (It used to give up silently after 5 s: on a loaded machine the test then
    # sent its first frames into a link that was not up yet and lost them.)
    def up() -> bool:
        return all(Path(f"/sys/class/net/{n}/operstate").read_text().strip() == "up"
                   for n in (a, b))

    if not wait_for(up):
        delete_veth(a)
        raise RuntimeError(f"veth pair {a}/{b} did not come up within {WAIT_LIMIT:g} s")
    return a, b


def delete_veth(name: str) -> None:
    subprocess.run(["ip", "link", "del", name], check=False, capture_output=True)


@pytest.fixture
def veth_pair(root: None) -> Iterator[tuple[str, str]]:
    """A fresh veth pair (pyecat- prefix), removed afterwards."""
    a, b = make_veth_pair()
    try:
        yield a, b
    finally:
        delete_veth(a)


@pytest.fixture
def patient_cli(monkeypatch: pytest.MonkeyPatch) -> None:
    """The masters the command line opens wait :data:`SIM_FRAME_TIMEOUT` for a frame.

    For tests whose simulator runs in a thread or another process and drops
    nothing. Not for a lossy segment: a cyclic loop waits out the frame timeout
    of every frame lost.
    """
    monkeypatch.setenv("PYETHERCAT_FRAME_TIMEOUT", str(SIM_FRAME_TIMEOUT))


@pytest.fixture(scope="session", autouse=True)
def private_runtime_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Control sockets and SII backups of this test run in its own directories.

    Masters opened on an interface serve a control socket named after it; a
    suite running beside another (or beside a user's master) must not meet
    their sockets. Child processes inherit the variables.
    """
    base = tmp_path_factory.mktemp("runtime")
    base.chmod(0o700)
    saved = {k: os.environ.get(k) for k in ("PYETHERCAT_RUNTIME_DIR", "XDG_STATE_HOME")}
    os.environ["PYETHERCAT_RUNTIME_DIR"] = str(base / "run")
    os.environ["XDG_STATE_HOME"] = str(base / "state")
    yield base
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    # Every process this run started carries the runtime directory in its
    # environment; one still alive now leaked (a simulator or engine child whose
    # parent died). On a 2-CPU CI machine a leaked busy process (worse: one under
    # SCHED_FIFO) starves everything that runs after it: end it and say so.
    marker = f"PYETHERCAT_RUNTIME_DIR={base / 'run'}".encode()
    leaked = _processes_with(marker)
    for pid, _cmd in leaked:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    if leaked:
        warnings.warn("processes left running by the tests (killed): "
                      + "; ".join(f"{pid} {cmd[:120]}" for pid, cmd in leaked), stacklevel=1)


def _processes_with(env_entry: bytes) -> list[tuple[int, str]]:
    """(pid, command line) of the processes whose environment holds ``env_entry``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if env_entry not in (entry / "environ").read_bytes().split(b"\0"):
                continue
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        found.append((int(entry.name), cmd.strip()))
    return found
