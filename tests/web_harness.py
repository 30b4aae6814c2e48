"""`usb2rc web` as a subprocess, and headless chromium (Debian's, through chromedriver).

`WebProcess` starts the server on a free localhost port and waits until it answers;
`browser()` drives the system chromium with selenium (no browser is downloaded: without
/usr/bin/chromium and chromedriver the test skips with one line, and under CI fails).
`FarEnds` talks back on a daemon's lines (a C2-16B downlink, a CRSF module's telemetry, a
pymavlink vehicle), and `led_stick_recording()` is a replayed device with outputs to drive:
what the page's "Telemetry & feedback" card shows."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import ROOT, PtyLine, timed_recording, wait_until
from pymavlink.dialects.v20 import common as mavlink2
from umockdev_harness import LED_STICK_DESCRIPTOR

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf import telemetry as crsf_telemetry

CHROMIUM = ("chromium", "chromium-browser")
SEND_EVERY_S = 0.1  # the far ends repeat themselves, as real ones do
HALF = 16384  # a downlink axis: 0..32767 is 0..100 %
# Two rules on a stick named `leds` (each rule's first line: the line its actions name)
FEEDBACK_RULES = """\
feedback:
  - when: mavlink.armed
    device: leds
    led: LED Caps Lock
  - when: crsf.link_quality < 90
    device: leds
    led: LED Scroll Lock
"""
# Three outputs on the far ends' lines ({c2}, {crsf}, {mavlink}), the LED stick pinned to
# node 1 as `leds`, and the rules
FEEDBACK_CONFIG = (
    """\
outputs:
  - protocol: c2-16b
    port: {c2}
  - protocol: crsf
    port: {crsf}
    channels: [node1.x, node1.y]
  - protocol: mavlink
    port: {mavlink}
    channels: [node1.x, node1.y]
devices:
  - name: leds
    match: {{vid: 0x1209, pid: 0x0001}}
    node_id: 1
"""
    + FEEDBACK_RULES
)
ARMED_RULE_LINE = FEEDBACK_CONFIG.splitlines().index("  - when: mavlink.armed") + 1
LQ_RULE_LINE = FEEDBACK_CONFIG.splitlines().index("  - when: crsf.link_quality < 90") + 1


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
    # chromium leaves its singleton socket's directory in TMPDIR after it quits: given one
    # of its own, removed with the session, nothing of it outlives the test
    with tempfile.TemporaryDirectory(prefix="usb2rc-chromium-") as scratch:
        options.add_argument(f"--user-data-dir={scratch}/profile")
        service = Service(driver_path, env={**os.environ, "TMPDIR": scratch})
        driver = webdriver.Chrome(service=service, options=options)
        try:
            # headless chromium keeps a window at least 500 px wide from --window-size; set
            # again, the viewport is what was asked (a phone's 390 px)
            driver.set_window_size(width, height)
            yield driver
        finally:
            driver.quit()


def led_stick_recording() -> str:
    """A replayed "LED stick" (1209:0001): X and Y centred; 8 indicators and a brightness
    by its descriptor (tests/umockdev_harness.py's)."""
    return timed_recording(
        [(0.0, LedStick())], "LED stick", descriptor=LED_STICK_DESCRIPTOR, ids="1209 0001"
    )


class LedStick:
    """The LED stick's input report (ID 1): X and Y centred (0..4095), no button."""

    def report(self) -> bytes:
        return bytes([1]) + (2048).to_bytes(2, "little") * 2 + b"\0"


class FarEnds:
    """The three far ends, each sending what it has to say every SEND_EVERY_S on its own
    thread until stopped: a C2-16B far end (a `>` downlink for `node`: indicator 0 lit,
    brightness half), a CRSF module (LQ 87 %, RSSI -60 dBm, SNR 9 dB, 15.2 V, 76 %, ACRO),
    a vehicle (armed in LOITER, 12.6 V, 64 %). `quiet[name].set()` silences one."""

    def __init__(self, c2: PtyLine, module: PtyLine, vehicle: PtyLine, node: int = 1) -> None:
        self.c2, self.module, self.vehicle, self.node = c2, module, vehicle, node
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.quiet = {name: threading.Event() for name in ("c2", "crsf", "mavlink")}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        talks: dict[str, Callable[[], None]] = {
            "c2": self._downlink,
            "crsf": self._module,
            "mavlink": self._vehicle,
        }
        for name, talk in talks.items():
            thread = threading.Thread(target=self._repeat, args=(name, talk), name=name)
            self._threads.append(thread)
            thread.start()

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(5)

    def _repeat(self, name: str, talk: Callable[[], None]) -> None:
        while not self._stop.wait(SEND_EVERY_S):
            if not self.quiet[name].is_set():
                talk()

    def _downlink(self) -> None:
        axes = [0, 0, 0, 0, HALF, 0, 0, 0, 0, 0]  # brightness (axis 5) half
        self.c2.send(c2_16b.encode_data(c2_16b.LIVE, self.node, 0, axes, 0b1, 0))  # indicator 0

    def _module(self) -> None:
        link = crsf.LinkStatistics(60, 71, 87, 9, 0, 4, 3, 70, 87, 8)
        self.module.send(crsf.encode_link_statistics(link))
        self.module.send(crsf_telemetry.encode_battery(152, 31, 1300, 76))
        self.module.send(crsf_telemetry.encode_flight_mode("ACRO"))

    def _vehicle(self) -> None:
        flags = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        heartbeat = self.mav.heartbeat_encode(
            mavlink2.MAV_TYPE_QUADROTOR,
            mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            flags,
            5,  # ArduCopter's LOITER
            mavlink2.MAV_STATE_ACTIVE,
        )
        status = self.mav.sys_status_encode(0, 0, 0, 0, 12600, -1, 64, 0, 0, 0, 0, 0, 0)
        self.vehicle.send(bytes(heartbeat.pack(self.mav)) + bytes(status.pack(self.mav)))
