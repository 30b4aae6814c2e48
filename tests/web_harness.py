"""`usb2rc web` as a subprocess, and headless chromium (Debian's, through chromedriver).

`WebProcess` starts the server on a free localhost port and waits until it answers;
`browser()` drives the system chromium with selenium (no browser is downloaded: without
/usr/bin/chromium and chromedriver the test skips with one line, and under CI fails)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import ROOT, wait_until

CHROMIUM = ("chromium", "chromium-browser")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class WebProcess:
    """`python -m usb2rc web --socket PATH` on 127.0.0.1:<free port>; log in log_path.
    socket_path None: no `--socket` (the default `usb2rc run` shares); `prefix`: a command
    that runs it (another user, another mount namespace)."""

    def __init__(
        self,
        socket_path: Path | None,
        log_path: Path,
        *extra: str,
        prefix: Sequence[str] = (),
    ) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        socket_args = [] if socket_path is None else ["--socket", str(socket_path)]
        self.proc = subprocess.Popen(
            [
                *prefix,
                sys.executable,
                "-m",
                "usb2rc",
                "web",
                *socket_args,
                "--listen",
                f"127.0.0.1:{self.port}",
                *extra,
            ],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=ROOT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        try:
            wait_until(self._answers, f"usb2rc web on {self.url}", timeout=20)
        except BaseException:
            self.stop()  # no server left behind by a test that failed here
            raise

    def _answers(self) -> bool:
        assert self.proc.poll() is None, self.log()
        try:
            self.get("/api/status")
        except urllib.error.HTTPError:
            return True  # it answers (401: a token is needed)
        except (urllib.error.URLError, ConnectionError):
            return False
        return True

    def get(self, path: str, headers: dict[str, str] | None = None) -> Any:
        request = urllib.request.Request(self.url + path, headers=headers or {})
        with urllib.request.urlopen(request, timeout=5) as response:
            return json.loads(response.read())

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self) -> int:
        self.proc.terminate()
        try:
            code = self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._log.close()
        return code


def _browser_or_skip() -> tuple[str, str]:
    binary = next((found for name in CHROMIUM if (found := shutil.which(name))), None)
    driver = shutil.which("chromedriver")
    if binary and driver:
        return binary, driver
    reason = (
        "chromium and chromium-driver are not installed (apt-get install chromium chromium-driver)"
    )
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the browser test, but: {reason}", pytrace=False)
    pytest.skip(reason)


@contextmanager
def browser(width: int = 900, height: int = 1000) -> Iterator[Any]:
    """A headless chromium session (selenium WebDriver), its viewport `width` px wide."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    binary, driver_path = _browser_or_skip()
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    options.add_argument(f"--window-size={width},{height}")
    driver = webdriver.Chrome(service=Service(driver_path), options=options)
    try:
        # headless chromium keeps a window at least 500 px wide from --window-size; set
        # again, the viewport is what was asked (a phone's 390 px)
        driver.set_window_size(width, height)
        yield driver
    finally:
        driver.quit()
