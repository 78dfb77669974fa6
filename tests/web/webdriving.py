"""Helpers of the dashboard's browser tests: headless Chromium, DOM reads, a dashboard in process.

Debian's ``chromium`` and ``chromium-driver`` through Selenium (``make tools``
installs them). The pages redraw on every live message, so the DOM is read
by one script per question instead of through element handles that go stale.
:func:`serve_in_process` serves the dashboard of a master of the test's own
process (uvicorn in a thread, the master on an in-process simulated segment
and virtual time), for behaviour that needs the segment in the test's hands.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
#: How long a page may take to show something on a loaded 2-core host (a generous bound
#: on waiting, never an assertion on speed).
SLOW = 180.0


def tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        if IN_CI:
            pytest.fail(f"required under CI=true: {name} (make tools installs it)")
        pytest.skip(f"{name} is not installed (make tools installs it as root)")
    return path


def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """Headless Chromium at the screenshots' size (a generator: the driver, then its end)."""
    chromium = tool("chromium")
    driver_path = tool("chromedriver")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    profile = tmp_path_factory.mktemp("chromium-profile")
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1440,1000",
                f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(driver_path), options=opts)
    # Selenium reads attributes through a script: a renderer starved on a loaded host
    # answered after more than the default 30 s (below the driver's 120 s read time-out).
    driver.set_page_load_timeout(100)
    driver.set_script_timeout(100)
    try:
        yield driver
    finally:
        with contextlib.suppress(Exception):
            driver.quit()


def shot(driver: Any, name: str, out: Path, *, publish: bool = True) -> None:
    """A screenshot into ``out``; copied to ``$PYECAT_WEB_SCREENSHOTS`` when ``publish``
    (that is how docs/img/web-*.png are made; each picture comes from the one test
    whose segment shows that page best)."""
    path = out / f"web-{name}.png"
    driver.save_screenshot(str(path))
    assert path.stat().st_size > 20_000
    extra = os.environ.get("PYECAT_WEB_SCREENSHOTS")
    if extra and publish:
        shutil.copy(path, Path(extra) / path.name)


def wait(driver: Any, what: Callable[[Any], Any], timeout: float = 60.0,
         describe: Callable[[Any], str] | None = None) -> Any:
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.support.ui import WebDriverWait

    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(what)
    except TimeoutException:
        if describe is None:
            raise
        raise TimeoutException(f"after {timeout:g} s: {describe(driver)}") from None


def q(driver: Any, css: str, what: str = "text") -> str | None:
    """Text (or an attribute) of the first element matching ``css``, read in one script."""
    return driver.execute_script(  # type: ignore[no-any-return]
        "const e = document.querySelector(arguments[0]);"
        "if (!e) return null;"
        "return arguments[1] === 'text' ? e.textContent : e.getAttribute(arguments[1]);",
        css, what)


def page(driver: Any, name: str) -> None:
    from selenium.webdriver.common.by import By

    driver.find_element(By.CSS_SELECTOR, f'nav a[data-page="{name}"]').click()
    wait(driver, lambda d: not d.find_element(By.ID, f"page-{name}").get_attribute("class")
         .count("hidden"))


def fits(driver: Any, css: str) -> tuple[int, int]:
    """(scroll width, client width) of the element: it fits when the first is not larger."""
    return tuple(driver.execute_script(  # type: ignore[return-value]
        "const e = document.querySelector(arguments[0]); return [e.scrollWidth, e.clientWidth];",
        css))


def severe_log(driver: Any) -> list[Any]:
    """Script errors and content-security-policy violations the browser logged."""
    return [e for e in driver.get_log("browser")
            if e["level"] == "SEVERE" and "favicon" not in e["message"]]


@contextlib.contextmanager
def serve_in_process(master: Any, link: str, lock: threading.Lock, *,
                     rate: float = 10.0) -> Iterator[str]:
    """The dashboard of ``master`` on a free loopback port, served from a thread.

    Every request of the dashboard runs under ``lock`` (its
    :class:`~pyethercat.web.source.DirectConnection`); the test holds the same
    lock while it steps the cyclic loop or changes the simulated segment, so
    the dashboard's frames and the test's never interleave on the virtual clock.
    Yields the address (read-only, no token: loopback).
    """
    pytest.importorskip("uvicorn")
    import uvicorn

    from pyethercat.master.control.handlers import MasterContext
    from pyethercat.web.app import create_app
    from pyethercat.web.hub import Hub
    from pyethercat.web.security import Access
    from pyethercat.web.server import bind_socket, dashboard_url
    from pyethercat.web.source import DirectConnection

    sock = bind_socket("127.0.0.1", 0)
    access = Access("127.0.0.1", sock.getsockname()[1])
    hub = Hub(DirectConnection(MasterContext(master, link), lock), rate=rate)
    server = uvicorn.Server(uvicorn.Config(create_app(hub, access), log_level="warning",
                                           access_log=False, lifespan="on",
                                           ws="websockets-sansio"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]},
                              name="web-in-process", daemon=True)
    thread.start()
    try:
        yield dashboard_url(access.host, access.port, None)
    finally:
        server.should_exit = True
        thread.join(30)
        sock.close()
