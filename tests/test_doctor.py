"""`usb2rc doctor`, black box: the real command (`python -m usb2rc doctor`) against far ends
the tests play on a pty and on UDP, and against hidraw nodes on umockdev.

The far ends share no code with usb2rc: the CRSF module reads the ping with the tests'
own decoder (tests/rc_reference.py) and answers with a device-info frame built here by
hand, as an ExpressLRS TX module does; the MAVLink vehicle is pymavlink. The module
answers only while the line is at its own baud rate (the pty's speed, read from the master
side): bytes sent at another rate are noise on a wire, and doctor must find the rate.

The hidraw nodes are checked by a user who is not root (`setpriv` to nobody): as root,
every node would open whatever its mode, and doctor would say nothing a user sees.
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import grp
import json
import os
import select
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import T16000M_DESCRIPTOR
from pymavlink.dialects.v20 import common as mavlink2
from rc_reference import RefCrsfReader, crc8_d5, crsf_frame
from umockdev_harness import FakeStick, UsbBed, require_umockdev, usb_bed

from usb2rc.protocols.crsf import codec
from usb2rc.protocols.crsf.device_info import (
    device_info_of,
    encode_device_ping,
    parse_device_info,
)

ROOT = Path(__file__).resolve().parent.parent
RULES = ROOT / "usb2rc" / "data" / "system" / "70-usb2rc.rules"
TCGETS2 = 0x802C542A  # asm-generic/ioctls.h: _IOR('T', 0x2A, struct termios2)
TERMIOS2_SPEEDS = 36  # struct termios2: 4 flags, c_line, c_cc[19], then c_ispeed, c_ospeed
PING, DEVICE_INFO = 0x28, 0x29
RUN_TIMEOUT_S = 120.0


def doctor(
    *args: str, env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*prefix, sys.executable, "-m", "usb2rc", "doctor", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=None if env is None else {**os.environ, **env},
        stdin=subprocess.DEVNULL,
        timeout=RUN_TIMEOUT_S,
        check=False,
    )


def records(done: subprocess.CompletedProcess[str]) -> list[dict[str, Any]]:
    assert done.returncode in (0, 1), done.stderr
    found = json.loads(done.stdout)
    assert isinstance(found, list)
    return found


def only(found: list[dict[str, Any]], check: str) -> dict[str, Any]:
    matching = [r for r in found if r["check"] == check]
    assert len(matching) == 1, found
    return matching[0]


@pytest.fixture
def scratch_root(tmp_path: Path) -> Path:
    """The system's files for doctor's --root: no Pi, no udev rule installed."""
    root = tmp_path / "root"
    root.mkdir()
    return root


def write_config(folder: Path, text: str) -> str:
    path = folder / "doctor.yaml"
    path.write_text(text)
    path.chmod(0o644)
    return str(path)


# --------------------------------------------------------------------------- a pty far end


def line_speed(master: int) -> int:
    """The baud rate the pty's user set: the master reads the slave's termios (TCGETS2
    carries rates that have no B constant, 400000 say)."""
    buffer = array.array("B", bytes(64))
    fcntl.ioctl(master, TCGETS2, buffer)
    return int(struct.unpack_from("I", buffer.tobytes(), TERMIOS2_SPEEDS + 4)[0])


class PtyFarEnd:
    """The far end of a pty: a thread reads the master and `answer`s what came. The slave
    is closed here, so that doctor finds no process holding the port."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.path = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(self.master, False)  # a write never waits for a reader
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"far end {self.path}")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                self.idle()
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:  # EIO while no one has the slave open
                self._stop.wait(0.01)
                continue
            self.answer(data)

    def idle(self) -> None:
        """Nothing came for 50 ms."""

    def answer(self, data: bytes) -> None:
        """Bytes from doctor."""

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10)
        os.close(self.master)


@dataclass
class Ping:
    address: int
    destination: int
    origin: int
    speed: int


class ElrsModule(PtyFarEnd):
    """An ExpressLRS TX module as it answers a device ping: its name, `ELRS` as the serial
    number, the firmware version in the software id's low three bytes, its parameter count,
    protocol version 0; only while the line is at `baudrate`."""

    def __init__(self, name: str, version: tuple[int, int, int], baudrate: int) -> None:
        self.reader = RefCrsfReader()
        self.pings: list[Ping] = []
        self.frame = crsf_frame(
            0xEA,  # to the handset
            DEVICE_INFO,
            bytes((0xEA, 0xEE))  # destination: the handset; origin: the module
            + name.encode()
            + b"\0"
            + b"ELRS"  # serial number
            + bytes(4)  # hardware id: unused by ExpressLRS
            + bytes((0, *version))  # software id
            + bytes((19, 0)),  # parameter count, parameter protocol version
        )
        self.baudrate = baudrate
        super().__init__()

    def answer(self, data: bytes) -> None:
        for frame in self.reader.feed(data):
            if frame.type != PING or len(frame.payload) != 2:
                continue
            speed = line_speed(self.master)
            self.pings.append(Ping(frame.address, *frame.payload, speed))
            if speed == self.baudrate:
                with contextlib.suppress(OSError):
                    os.write(self.master, self.frame)


@contextlib.contextmanager
def elrs_module(
    name: str = "ELRS TX", version: tuple[int, int, int] = (3, 4, 0), baudrate: int = 400000
) -> Iterator[ElrsModule]:
    module = ElrsModule(name, version, baudrate)
    try:
        yield module
    finally:
        module.close()


def crsf_config(folder: Path, port: str, baudrate: int = 400000) -> str:
    return write_config(
        folder,
        f"outputs:\n  - protocol: crsf\n    port: {port}\n    baudrate: {baudrate}\n"
        "    channels: [node0.x, node0.y, node0.z, node0.rz]\n",
    )


# --------------------------------------------------------------------------- CRSF


def test_an_elrs_module_is_named_with_its_firmware(scratch_root: Path, tmp_path: Path) -> None:
    with elrs_module() as module:
        config = crsf_config(tmp_path, module.path)
        args = ("--config", config, "--replay", "demo", "--root", str(scratch_root))
        done = doctor(*args)
        assert done.returncode == 0, done.stdout + done.stderr
        lines = [line for line in done.stdout.splitlines() if line.split()[1:2] == ["far"]]
        assert len(lines) == 1, done.stdout
        assert lines[0].startswith("ok ")
        assert "ELRS TX" in lines[0] and "ExpressLRS firmware 3.4.0" in lines[0]
        assert "400000 baud" in lines[0]
        # the ping as a handset sends it: to the module, for every device, from the handset
        assert module.pings[0] == Ping(0xEE, 0x00, 0xEA, 400000)
        as_json = records(doctor(*args, "--json"))
    far_end = only(as_json, "far end")
    assert far_end["ok"] is True
    assert far_end["facts"]["module"] == "ELRS TX"
    assert far_end["facts"]["firmware"] == "3.4.0"
    assert far_end["facts"]["baudrate"] == 400000
    assert all(r["ok"] for r in as_json), as_json


def test_a_module_at_another_baud_rate_is_found_and_named(
    scratch_root: Path, tmp_path: Path
) -> None:
    with elrs_module(baudrate=921600) as module:
        config = crsf_config(tmp_path, module.path, baudrate=400000)
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root), "--json")
        speeds = [ping.speed for ping in module.pings]
    assert done.returncode == 1, done.stderr
    far_end = only(records(done), "far end")
    assert far_end["ok"] is False
    assert "answers at 921600 baud, not at the configured 400000" in far_end["found"]
    assert "baudrate: 921600" in far_end["fix"]
    assert far_end["facts"]["baudrate"] == 921600
    assert speeds[0] == 400000 and speeds[-1] == 921600  # the configured rate first


def test_a_silent_crsf_line_names_every_rate_it_tried(scratch_root: Path, tmp_path: Path) -> None:
    with elrs_module(baudrate=57600) as module:  # a rate no CRSF module uses: no answer
        config = crsf_config(tmp_path, module.path)
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root), "--json")
        speeds = sorted({ping.speed for ping in module.pings})
    assert done.returncode == 1, done.stderr
    far_end = only(records(done), "far end")
    assert far_end["ok"] is False
    assert (
        "no answer to a device ping at 400000, 921600, 1870000, 115200, 3750000 baud"
        in (far_end["found"])
    )
    assert speeds == [115200, 400000, 921600, 1870000, 3750000]


# --------------------------------------------------------------------------- C2-16B


class TalkingC2Receiver(PtyFarEnd):
    """A C2-16B far end that asks for the config (`<`) every 50 ms."""

    def idle(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self.master, b"H-<" + bytes(32))


def test_a_c2_16b_far_end_that_sends_is_alive(scratch_root: Path, tmp_path: Path) -> None:
    far = TalkingC2Receiver()
    try:
        args = ("--port", far.path, "--replay", "demo", "--root", str(scratch_root), "--json")
        done = doctor(*args)
    finally:
        far.close()
    assert done.returncode == 0, done.stdout + done.stderr
    far_end = only(records(done), "far end")
    assert far_end["ok"] is True and far_end["facts"]["bytes"] > 0


def test_a_silent_c2_16b_far_end_fails_with_what_to_check(scratch_root: Path) -> None:
    far = PtyFarEnd()
    try:
        done = doctor("--port", far.path, "--replay", "demo", "--root", str(scratch_root))
    finally:
        far.close()
    assert done.returncode == 1
    line = next(line for line in done.stdout.splitlines() if " far end: " in line)
    assert line.startswith("FAIL") and "nothing from it in 1 s at 115200 baud" in line
    assert "Fix: its TX to this port's RX" in line


# --------------------------------------------------------------------------- MAVLink


@dataclass
class Vehicle:
    """A UDP MAVLink vehicle (pymavlink): answers each GCS heartbeat with its own."""

    answer: bool = True
    system: int = 1
    sock: socket.socket = field(default_factory=lambda: socket.socket(type=socket.SOCK_DGRAM))
    gcs_heartbeats: list[tuple[int, int]] = field(default_factory=list)  # (system, component)

    def __post_init__(self) -> None:
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.parser = mavlink2.MAVLink(None)
        self.mav = mavlink2.MAVLink(None, srcSystem=self.system, srcComponent=1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="vehicle")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not select.select([self.sock], [], [], 0.05)[0]:
                continue
            data, sender = self.sock.recvfrom(65535)
            for message in self.parser.parse_buffer(data) or []:
                if message.get_type() == "HEARTBEAT" and message.type == mavlink2.MAV_TYPE_GCS:
                    self.gcs_heartbeats.append(
                        (message.get_srcSystem(), message.get_srcComponent())
                    )
                    if self.answer:
                        self.sock.sendto(self._heartbeat(), sender)

    def _heartbeat(self) -> bytes:
        message = self.mav.heartbeat_encode(
            mavlink2.MAV_TYPE_QUADROTOR,
            mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            0,
            0,
            mavlink2.MAV_STATE_STANDBY,
        )
        return bytes(message.pack(self.mav))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10)
        self.sock.close()


@contextlib.contextmanager
def vehicle(answer: bool = True, system: int = 1) -> Iterator[Vehicle]:
    stand_in = Vehicle(answer, system)
    try:
        yield stand_in
    finally:
        stand_in.close()


def mavlink_config(folder: Path, port: str) -> str:
    return write_config(
        folder,
        f"outputs:\n  - protocol: mavlink\n    port: {port}\n    channels: [node0.x, node0.y]\n",
    )


def test_a_mavlink_vehicle_that_heartbeats_is_ok(scratch_root: Path, tmp_path: Path) -> None:
    with vehicle() as stand_in:
        config = mavlink_config(tmp_path, f"udpout:127.0.0.1:{stand_in.port}")
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root), "--json")
        heard = list(stand_in.gcs_heartbeats)
    assert done.returncode == 0, done.stdout + done.stderr
    far_end = only(records(done), "far end")
    assert far_end["ok"] is True
    assert far_end["facts"] == {
        "system": 1,
        "type": "MAV_TYPE_QUADROTOR",
        "autopilot": "MAV_AUTOPILOT_ARDUPILOTMEGA",
    }
    assert heard[0] == (255, 190)  # usb2rc's GCS heartbeat, as the output sends it


def test_no_mavlink_heartbeat_in_3_s_fails(scratch_root: Path, tmp_path: Path) -> None:
    with vehicle(answer=False) as stand_in:
        config = mavlink_config(tmp_path, f"udpout:127.0.0.1:{stand_in.port}")
        started = time.monotonic()
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root))
        took = time.monotonic() - started
    assert done.returncode == 1
    line = next(line for line in done.stdout.splitlines() if " far end: " in line)
    assert line.startswith("FAIL") and "no vehicle HEARTBEAT in 3 s" in line
    assert took >= 3.0


def test_a_vehicle_of_another_system_names_the_target_system_to_set(
    scratch_root: Path, tmp_path: Path
) -> None:
    with vehicle(system=2) as stand_in:  # the output's target_system is 1 (the default)
        config = mavlink_config(tmp_path, f"udpout:127.0.0.1:{stand_in.port}")
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root), "--json")
    assert done.returncode == 1
    far_end = only(records(done), "far end")
    assert far_end["found"] == "heartbeats from system 2, none from target_system 1"
    assert "target_system: 2" in far_end["fix"]


@contextlib.contextmanager
def calling_vehicle(port: int) -> Iterator[None]:
    """A vehicle that calls a udpin port: its HEARTBEAT every 0.2 s (pymavlink)."""
    stop = threading.Event()
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)

    def call() -> None:
        with socket.socket(type=socket.SOCK_DGRAM) as sock:
            while not stop.wait(0.2):
                message = mav.heartbeat_encode(
                    mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_PX4, 0, 0, 0
                )
                sock.sendto(bytes(message.pack(mav)), ("127.0.0.1", port))

    thread = threading.Thread(target=call, name="calling vehicle")
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(10)


def test_a_vehicle_that_calls_a_udpin_port_is_ok(scratch_root: Path, tmp_path: Path) -> None:
    with socket.socket(type=socket.SOCK_DGRAM) as probe:  # a free port, for doctor to bind
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = mavlink_config(tmp_path, f"udpin:127.0.0.1:{port}")
    with calling_vehicle(port):
        done = doctor("--config", config, "--replay", "demo", "--root", str(scratch_root), "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    assert only(records(done), "far end")["facts"] == {
        "system": 1,
        "type": "MAV_TYPE_FIXED_WING",
        "autopilot": "MAV_AUTOPILOT_PX4",
    }


# --------------------------------------------------------------------------- hidraw nodes


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A folder the user nobody can read (pytest's tmp_path is root's alone)."""
    folder = Path(tempfile.mkdtemp(prefix="usb2rc-doctor-", dir="/tmp"))
    try:
        folder.chmod(0o755)
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def as_nobody() -> tuple[str, ...]:
    """A user who is not root and in no group: as root every node opens, whatever its mode."""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.fail("the hidraw checks need util-linux's setpriv to run doctor as nobody")
    if os.geteuid() != 0:
        return ()
    return (setpriv, "--reuid=nobody", "--regid=nogroup", "--clear-groups")


@pytest.fixture
def bed() -> Iterator[UsbBed]:
    require_umockdev()
    with usb_bed() as testbed:
        os.chmod(testbed.root, 0o755)  # the fake /sys and /dev, for a user who is not root
        yield testbed


def open_the_plumbing(bed: UsbBed) -> None:
    """umockdev's preload connects to a node's ioctl socket at each open, whatever the
    node's mode; the sockets are root's (0755) and a connect needs write: the testbed's
    plumbing is opened to every user, the nodes keep their own modes."""
    for folder, _, names in os.walk(os.path.join(bed.root, "ioctl")):
        for name in names:
            os.chmod(os.path.join(folder, name), 0o777)


def stick(port: str, pid: int, product: str) -> FakeStick:
    return FakeStick(port, 0x044F, pid, T16000M_DESCRIPTOR, product, "Thrustmaster")


def by_subject(found: list[dict[str, Any]], check: str, word: str) -> dict[str, Any]:
    matching = [r for r in found if r["check"] == check and word in r["subject"]]
    assert len(matching) == 1, found
    return matching[0]


def test_an_unreadable_hidraw_node_names_the_rule_or_the_group(
    bed: UsbBed, shared_dir: Path
) -> None:
    dialout = grp.getgrnam("dialout").gr_gid
    closed = bed.add(stick("1-1", 0xB10A, "T.16000M"), mode=0o600)  # the kernel's default
    grouped = bed.add(stick("1-2", 0xB687, "TWCS Throttle"), mode=0o660)
    os.chown(os.path.join(bed.root, grouped.lstrip("/")), -1, dialout)  # as a rule would
    bed.add(stick("1-3", 0xB108, "T.Flight"), mode=0o666)
    open_the_plumbing(bed)
    far, slave = os.openpty()  # a serial port of group dialout, as the kernel makes them
    try:
        pty = os.ttyname(slave)
        os.close(slave)
        os.chown(pty, -1, dialout)
        os.chmod(pty, 0o660)
        (shared_dir / "serial-line").symlink_to(pty)  # outside /dev: the testbed has its own
        config = write_config(
            shared_dir, f"outputs:\n  - protocol: c2-16b\n    port: {shared_dir}/serial-line\n"
        )
        root = shared_dir / "root"
        root.mkdir()
        args = ("--config", config, "--root", str(root), "--json")
        without_rule = doctor(*args, env=bed.env(), prefix=as_nobody())
        rules = root / "etc" / "udev" / "rules.d"
        rules.mkdir(parents=True)
        shutil.copy(RULES, rules / "70-usb2rc.rules")
        with_rule = doctor(*args, env=bed.env(), prefix=as_nobody())
    finally:
        os.close(far)
    assert without_rule.returncode == 1, without_rule.stderr
    found = records(without_rule)
    node = by_subject(found, "device", closed)
    assert node["ok"] is False
    assert "user nobody may not open it (crw------- root:root)" in node["found"]
    assert "install the udev rule" in node["fix"] and "70-usb2rc.rules" in node["fix"]
    assert "udevadm trigger --subsystem-match=hidraw" in node["fix"]
    throttle = by_subject(found, "device", grouped)
    assert throttle["ok"] is False and "crw-rw---- root:dialout" in throttle["found"]
    assert "sudo usermod -aG dialout nobody" in throttle["fix"]
    assert by_subject(found, "device", "T.Flight")["ok"] is True
    port = only(found, "port access")
    assert port["ok"] is False and "user nobody may not read and write it" in port["found"]
    assert "join group dialout" in port["fix"]
    assert not [r for r in found if r["check"] == "far end"]  # not probed: no access

    assert with_rule.returncode == 1, with_rule.stderr
    node = by_subject(records(with_rule), "device", closed)
    assert "is installed but did not apply to this node" in node["fix"]
    assert 'ATTRS{idVendor}=="044f", ATTRS{idProduct}=="b10a"' in node["fix"]


# --------------------------------------------------------------------------- Pi, service, usage


def test_a_pi_with_the_uart_off_and_a_console_on_it(tmp_path: Path) -> None:
    root = tmp_path / "root"
    (root / "proc" / "device-tree").mkdir(parents=True)
    (root / "proc" / "device-tree" / "model").write_bytes(b"Raspberry Pi 4 Model B Rev 1.4\0")
    (root / "boot" / "firmware").mkdir(parents=True)
    cmdline = "console=serial0,115200 console=tty1 root=PARTUUID=1234-02 rootwait\n"
    (root / "boot" / "firmware" / "cmdline.txt").write_text(cmdline)
    (root / "boot" / "firmware" / "config.txt").write_text("[all]\n#enable_uart=1\n")
    done = doctor("--port", "/dev/serial0", "--replay", "demo", "--root", str(root), "--json")
    found = records(done)
    uart, console = only(found, "pi uart"), only(found, "pi console")
    assert uart["ok"] is False and "no enable_uart" in uart["found"]
    assert "enable_uart=1" in uart["fix"]
    assert console["ok"] is False and "console=serial0,115200" in console["found"]
    assert uart["subject"] == "Raspberry Pi 4 Model B Rev 1.4"

    (root / "boot" / "firmware" / "cmdline.txt").write_text(cmdline.split(" ", 1)[1])
    (root / "boot" / "firmware" / "config.txt").write_text("[all]\nenable_uart=1\n")
    found = records(doctor("--port", "/dev/serial0", "--root", str(root), "--json"))
    assert only(found, "pi uart")["ok"] and only(found, "pi console")["ok"]


SYSTEMCTL_SHOW = """#!/bin/sh
# What `systemctl show --property=...` prints: one KEY=VALUE a line.
printf 'LoadState=%s\\nActiveState=%s\\nSubState=%s\\nUnitFileState=%s\\n' {states}
"""


@pytest.mark.parametrize(
    ("states", "ok", "said"),
    [
        ("not-found inactive dead ''", True, "not installed: fine when running by hand"),
        ("loaded failed failed enabled", False, "failed (failed): it stopped on an error"),
        ("loaded active running enabled", True, "active (running), enabled at boot"),
    ],
)
def test_the_service_state(tmp_path: Path, states: str, ok: bool, said: str) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "systemctl").write_text(SYSTEMCTL_SHOW.format(states=states))
    (bin_dir / "systemctl").chmod(0o755)
    path = f"{bin_dir}{os.pathsep}{os.environ['PATH']}"
    done = doctor("--replay", "demo", "--json", env={"PATH": path})
    service = only(records(done), "service")
    assert service["ok"] is ok and said in service["found"]
    if not ok:
        assert "journalctl -u usb2rc" in service["fix"]


def test_usage_errors_exit_2(tmp_path: Path) -> None:
    assert doctor("--replay", str(tmp_path / "none")).returncode == 2
    assert doctor("--port", "ttyUSB0").returncode == 2  # a name, not a path
    assert doctor("--bogus").returncode == 2


# --------------------------------------------------------------------------- the CRSF frames


def test_the_device_ping_is_the_handsets() -> None:
    body = bytes((PING, 0x00, 0xEA))
    assert encode_device_ping() == bytes((0xEE, 4)) + body + bytes((crc8_d5(body),))
    assert encode_device_ping(0xC8)[0] == 0xC8


def test_device_info_from_the_wire() -> None:
    ids = b"ELRS" + bytes(4) + bytes((0, 3, 4, 0)) + bytes((19, 0))
    frame = crsf_frame(0xEA, DEVICE_INFO, b"\xea\xee" + b"ELRS TX\0" + ids)
    (decoded,) = codec.CrsfDecoder().feed(frame)
    info = device_info_of(decoded)
    assert info is not None
    assert (info.name, info.maker, info.firmware, info.parameter_count) == (
        "ELRS TX",
        "ExpressLRS",
        "3.4.0",
        19,
    )
    tbs = parse_device_info(b"\xea\xee" + b"TBS CROSSFIRE TX\0" + bytes(8) + b"\0\0\x05\x0f\0\0")
    assert tbs is not None and (tbs.maker, tbs.firmware) == ("CRSF", "5.15")
    assert parse_device_info(b"\xea\xee" + b"ELRS TX\0" + ids[:-1]) is None  # cut short
    assert parse_device_info(b"\xea\xeeELRS TX") is None  # no terminating null
