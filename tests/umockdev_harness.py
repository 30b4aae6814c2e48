"""The real hidapi path on fake USB devices: umockdev, driven from the tests.

`UsbBed` runs tests/umockdev_bed.py under Debian's python3 (the one with `gi`) and talks to
it over a pipe; `UsbBed.env()` is what a process needs to see the fake /sys and /dev
(`UMOCKDEV_DIR`, `LD_PRELOAD=libumockdev-preload.so.0`). Nothing else here needs umockdev,
so this module imports anywhere; `require_umockdev()` decides between running, skipping
(with a one-line reason) and failing: under CI (`CI` set) a missing umockdev is a failure,
since a suite that silently skips there proves nothing.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
BED = ROOT / "tests" / "umockdev_bed.py"
SYSTEM_PYTHON = os.environ.get("USB2RC_GI_PYTHON", "/usr/bin/python3")
PRELOAD = "libumockdev-preload.so.0"
DEBIAN_PACKAGES = "umockdev gir1.2-umockdev-1.0 python3-gi"
REPLY_TIMEOUT_S = 10.0


def _preload_present() -> bool:
    """The preload library is where the dynamic linker finds it (ldconfig's cache)."""
    try:
        out = subprocess.run(
            ["/sbin/ldconfig", "-p"], capture_output=True, text=True, timeout=10, check=False
        ).stdout
    except OSError:
        return False
    return PRELOAD in out


def missing_reason() -> str | None:
    """Why the umockdev tests cannot run here, or None when they can."""
    if not sys.platform.startswith("linux"):
        return "umockdev tests need Linux"
    if not os.access(SYSTEM_PYTHON, os.X_OK):
        return f"no {SYSTEM_PYTHON} for the umockdev testbed (apt install {DEBIAN_PACKAGES})"
    probe = subprocess.run(
        [
            SYSTEM_PYTHON,
            "-c",
            "import gi; gi.require_version('UMockdev', '1.0'); from gi.repository import UMockdev",
        ],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    if probe.returncode != 0:
        return f"no UMockdev GObject bindings for {SYSTEM_PYTHON} (apt install {DEBIAN_PACKAGES})"
    if not _preload_present():
        return f"no {PRELOAD} (apt install {DEBIAN_PACKAGES})"
    return None


_reason_cache: list[str | None] = []


def require_umockdev() -> None:
    """Skip the calling test with a one-line reason when umockdev is missing; under CI fail."""
    import pytest  # here: the bench scripts use this module without pytest installed

    if not _reason_cache:
        _reason_cache.append(missing_reason())
    reason = _reason_cache[0]
    if reason is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the umockdev tests, but: {reason}", pytrace=False)
    pytest.skip(reason)


@dataclass(frozen=True)
class FakeStick:
    """What `UsbBed.add` plugs: a USB HID device at a port path."""

    port: str
    vid: int
    pid: int
    descriptor: bytes
    product: str = ""
    manufacturer: str = ""
    serial: str = ""


# A stick with outputs (for the output-report tests): report 1 in (X, Y 0..4095 in 16 bits,
# buttons 1..8), report 2 out: LEDs Num Lock .. Kana (1 bit each), 3 bits padding, LED
# Intensity (8 bits, 0..255), Ordinal instances 1, 2 and a vendor bit (1 bit each), 5 bits
# padding: 3 data bytes after the ID.
LED_STICK_DESCRIPTOR = bytes.fromhex(
    "05010904a101"  # Generic Desktop, Joystick, Collection (Application)
    "850109300931150026ff0f751095028102"  # ID 1: X, Y
    "05091901290815002501750195088102"  # buttons 1..8
    "850205081901290515002501750195059102"  # ID 2: LEDs 1..5
    "950175039101"  # padding
    "095626ff00750895019102"  # LED Intensity
    "050a190129022501750195029102"  # Ordinal 1, 2
    "0600ff090195019102"  # vendor 0xFF00:0x0001
    "95059101"  # padding
    "c0"
)
LED_STICK_OUTPUT_BYTES = 3  # report 2's data bytes


class BedError(RuntimeError):
    """The testbed refused a command or went away."""


def bed_env() -> dict[str, str]:
    """The bed runs Debian's python (not the venv's) under the preload library itself:
    umockdev resolves the /sys paths of `uevent()` through the fake tree, not the real one."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.pop("UMOCKDEV_DIR", None)
    env["LD_PRELOAD"] = PRELOAD
    return env


class UsbBed:
    """The bed subprocess. Every command waits for its reply (the bed answers in order)."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [SYSTEM_PYTHON, str(BED)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=bed_env(),
        )
        self._lock = threading.Lock()
        hello = self._reply()
        self.root: str = hello["root"]

    def _reply(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise BedError(f"umockdev bed ended: {err.strip()[-2000:]}")
        try:
            reply: dict[str, Any] = json.loads(line)
        except ValueError:
            raise BedError(f"umockdev bed said: {line!r}") from None
        if not reply.get("ok"):
            raise BedError(reply.get("error", "bed refused the command"))
        return reply

    def command(self, cmd: str, **args: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(json.dumps({"cmd": cmd, **args}) + "\n")
            self.proc.stdin.flush()
            return self._reply()

    def env(self) -> dict[str, str]:
        """Environment additions for a process that must see the fake devices."""
        preload = " ".join(p for p in (PRELOAD, os.environ.get("LD_PRELOAD", "")) if p)
        return {"UMOCKDEV_DIR": self.root, "LD_PRELOAD": preload}

    def python(self, code: str) -> subprocess.Popen[str]:
        """`python -c code` (this venv's) under the preload library, seeing the testbed; text
        pipes on stdin and stdout. The caller stops it (kill, wait)."""
        return subprocess.Popen(
            [sys.executable, "-c", code],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            env=dict(os.environ, **self.env()),
        )

    def add(self, stick: FakeStick, mode: int | None = None) -> str:
        """Plug `stick`; its /dev/hidrawN (as seen inside the testbed). `mode`: the node's
        permissions from the start (it never exists with others)."""
        extra = {} if mode is None else {"mode": mode}
        reply = self.command(
            "add",
            port=stick.port,
            vid=stick.vid,
            pid=stick.pid,
            product=stick.product,
            manufacturer=stick.manufacturer,
            serial=stick.serial,
            descriptor=stick.descriptor.hex(),
            **extra,
        )
        return str(reply["hidraw"])

    def report(self, hidraw: str, data: bytes) -> float:
        """Write one input report; the monotonic time right after the write."""
        return float(self.command("report", hidraw=hidraw, data=data.hex())["t"])

    def written(self, hidraw: str) -> bytes:
        """What programs wrote to the node since the last call (output reports, glued), at
        once: b"" when nothing came."""
        return bytes.fromhex(self.command("written", hidraw=hidraw)["data"])

    def remove(self, hidraw: str) -> float:
        """Unplug; the monotonic time the unplug began (a uevent watcher may act from then
        on). When this returns the node is gone and its readers were woken."""
        return float(self.command("remove", hidraw=hidraw)["t"])

    def chmod(self, hidraw: str, mode: int) -> None:
        self.command("chmod", hidraw=hidraw, mode=mode)

    def close(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(OSError, ValueError):
                assert self.proc.stdin is not None
                self.proc.stdin.write('{"cmd": "quit"}\n')
                self.proc.stdin.flush()
            try:
                self.proc.wait(REPLY_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            with contextlib.suppress(OSError, ValueError):
                if stream is not None:
                    stream.close()
        shutil.rmtree(self.root, ignore_errors=True)


@contextlib.contextmanager
def usb_bed() -> Iterator[UsbBed]:
    bed = UsbBed()
    try:
        yield bed
    finally:
        bed.close()


def serial_port_link(tmp_path: Path, pty_path: str) -> str:
    """A path outside /dev for a serial pty: inside the testbed /dev is the testbed's, so the
    daemon must not open /dev/pts/N by that name (umockdev would take it for its own)."""
    link = tmp_path / "serial-line"
    link.symlink_to(pty_path)
    return str(link)


def wait_until(predicate: Any, timeout: float, what: str, interval: float = 0.01) -> Any:
    """Poll `predicate` until truthy (for state outside a condition variable, e.g. a file)."""
    deadline = time.monotonic() + timeout
    while True:
        result = predicate()
        if result:
            return result
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def run_real_contract(bed: UsbBed, timeout: float = 60.0) -> list[dict[str, Any]]:
    """tests/hidapi_contract.py against the real `hidraw` module in a process under the
    preload library; this process plugs, sends and unplugs for it on the testbed."""
    from hidapi_contract import DESCRIPTOR, PID, VID

    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "hidapi_contract.py"), "--stdio"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, **bed.env()),
    )
    assert proc.stdin is not None and proc.stdout is not None
    ports = (f"1-{n}" for n in range(1, 100))
    watchdog = threading.Timer(timeout, proc.kill)  # a read that never returns ends here
    watchdog.start()
    try:
        for line in proc.stdout:
            message = json.loads(line)
            if "results" in message:
                return list(message["results"])
            request = message["request"]
            try:
                if request["op"] == "plug":
                    path = bed.add(FakeStick(next(ports), VID, PID, DESCRIPTOR, "T.16000M"))
                    reply: dict[str, Any] = {"path": path}
                elif request["op"] == "report":
                    bed.report(request["path"], bytes.fromhex(request["data"]))
                    reply = {}
                elif request["op"] == "written":
                    reply = {"data": bed.written(request["path"]).hex()}
                else:
                    bed.remove(request["path"])
                    reply = {}
            except BedError as exc:
                reply = {"error": str(exc)}
            proc.stdin.write(json.dumps(reply) + "\n")
            proc.stdin.flush()
        raise AssertionError(f"the contract process ended without results (exit {proc.wait()})")
    finally:
        watchdog.cancel()
        proc.kill()
        proc.wait()
