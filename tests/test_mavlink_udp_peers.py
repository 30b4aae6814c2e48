"""Who a MAVLink output talks to and whether the vehicle can trust it, through the real
daemon on real UDP sockets on 127.0.0.1, with pymavlink as the vehicle (docs/ICD.md,
"MAVLink output"; docs/CONFIG.md, "MAVLink outputs"):

- `udpin:` locks to the first sender of a valid HEARTBEAT from `target_system`: garbage and
  spoofed HEARTBEATs from another port (another system, or the target system itself while
  the vehicle talks) are counted and ignored, and never redirect the override stream;
- `allow:` takes calls only from the listed addresses or networks;
- `signing_key_file:` signs every message (MAVLink 2 signing), which a pymavlink receiver
  with the key verifies; a udpin output with a key locks only to a signed HEARTBEAT; a key
  file others can read is refused, naming the file and `chmod 600`;
- a UDP host that does not resolve is retried once a second and logged once, not per tick.
"""

from __future__ import annotations

import hashlib
import os
import re
import select
import socket
import threading
import time
from pathlib import Path
from typing import Any

from cli_harness import usb2rc
from daemon_harness import (
    DaemonProcess,
    StickState,
    channels,
    install,
    of_type,
    pwm_of_int16,
    recording,
    scale,
    stats_until,
    wait_until,
)
from pymavlink.dialects.v20 import common

PASSPHRASE = "usb2rc test passphrase"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()  # as MAVProxy's `signing setup`
CENTRED = StickState()
STICK = StickState(x=16383, y=4000, rz=0, slider=0, buttons=0)
X_LIVE = pwm_of_int16(scale(STICK.x, 0, 16383))  # channel 1: node 0's x


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def heartbeat(system: int, key: bytes | None = None, kind: int = common.MAV_TYPE_QUADROTOR) -> Any:
    """A pymavlink sender as the vehicle (or a spoofer claiming to be one)."""
    mav = common.MAVLink(None, srcSystem=system, srcComponent=1)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    return lambda: mav.heartbeat_encode(kind, common.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4).pack(mav)


def receiver(key: bytes | None = None) -> Any:
    """pymavlink's parser as an autopilot holds it: with a key, only signed messages."""
    parser = common.MAVLink(None)
    parser.robust_parsing = True
    if key is not None:
        parser.signing.secret_key = key
    return parser


class Vehicle:
    """An autopilot on UDP: calls `port` with a HEARTBEAT every 0.1 s from its own socket
    (bound to `host`) and parses what comes back with pymavlink."""

    def __init__(
        self, port: int, system: int = 1, key: bytes | None = None, host: str = "127.0.0.1"
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.address = self.sock.getsockname()
        self.port = port
        self.beat = heartbeat(system, key)
        self.parser = receiver(key)
        self.messages: list[Any] = []
        self.bad = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="vehicle")
        self._thread.start()

    def _run(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_beat:
                self.sock.sendto(self.beat(), ("127.0.0.1", self.port))
                next_beat = time.monotonic() + 0.1
            if not select.select([self.sock], [], [], 0.02)[0]:
                continue
            data = self.sock.recv(65535)
            with self._lock:
                for message in self.parser.parse_buffer(data) or []:
                    if message.get_type() == "BAD_DATA":
                        self.bad += 1
                    else:
                        self.messages.append(message)

    def overrides(self) -> list[Any]:
        with self._lock:
            return of_type(self.messages, "RC_CHANNELS_OVERRIDE")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()


def udpin_config(tmp_path: Path, port: int, extra: str = "") -> Path:
    config = tmp_path / "udpin.yaml"
    config.write_text(f"outputs:\n  - protocol: mavlink\n    port: udpin:127.0.0.1:{port}\n{extra}")
    return config


def start(tmp_path: Path, replay_dir: Path, config: Path) -> DaemonProcess:
    """The daemon on the config's own port (`--port` would override it)."""
    return DaemonProcess(
        ["--replay", str(replay_dir), "--config", str(config)], tmp_path / "daemon.log"
    )


def test_udpin_keeps_the_vehicle_that_called_against_garbage_and_spoofed_heartbeats(
    tmp_path: Path, replay_dir: Path
) -> None:
    port = free_udp_port()
    daemon = start(tmp_path, replay_dir, udpin_config(tmp_path, port))
    vehicle = Vehicle(port)
    spoofer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    spoofer.bind(("127.0.0.1", 0))
    try:
        wait_until(lambda: vehicle.overrides() or of_type(vehicle.messages, "HEARTBEAT"), "a")
        install(replay_dir / "stick.hid", recording([CENTRED, STICK]))
        wait_until(lambda: any(channels(m)[0] == X_LIVE for m in vehicle.overrides()), "live")
        # what took the stream with mavutil's learn-the-last-sender udpin: a 40-byte
        # datagram, HEARTBEATs of another system, and of the target system itself
        sent = [os.urandom(40), heartbeat(42)(), heartbeat(42)(), heartbeat(1)()]
        for datagram in sent:
            spoofer.sendto(datagram, ("127.0.0.1", port))
        stats_until(daemon, rf"from others ignored {len(sent)}\b")
        before = len(vehicle.overrides())
        wait_until(lambda: len(vehicle.overrides()) >= before + 10, "overrides going on")
        assert channels(vehicle.overrides()[-1])[0] == X_LIVE
        spoofer.setblocking(False)
        try:
            got = spoofer.recv(65535)
        except BlockingIOError:
            got = b""
        assert got == b"", "the spoofer was answered"
        peer = "{}:{}".format(*vehicle.address)
        assert re.search(rf"peer {re.escape(peer)}\b", daemon.log())
        assert f"{peer} called; answering it only" in daemon.log()
    finally:
        assert daemon.stop() == 0
        vehicle.close()
        spoofer.close()


def answers_only_the_right_caller(
    daemon: DaemonProcess, wrong: Vehicle, ignored: str, **right: Any
) -> list[Any]:
    """`wrong` calls and is counted (`ignored`: a stats line pattern), never answered; then
    a `Vehicle(**right)` calls and is answered, and `wrong` still is not. Stops both."""
    try:
        stats_until(daemon, ignored)
        assert not wrong.messages
        answered = Vehicle(wrong.port, **right)
        try:
            wait_until(lambda: of_type(answered.messages, "HEARTBEAT"), "an answer")
            assert answered.bad == 0 and not wrong.messages
            return list(answered.messages)
        finally:
            answered.close()
    finally:
        assert daemon.stop() == 0
        wrong.close()


def test_udpin_allow_takes_calls_only_from_the_listed_network(
    tmp_path: Path, replay_dir: Path
) -> None:
    port = free_udp_port()
    config = udpin_config(tmp_path, port, "    allow: [127.0.0.2/32]\n")
    daemon = start(tmp_path, replay_dir, config)
    outsider = Vehicle(port)  # 127.0.0.1: a valid HEARTBEAT of system 1, not allowed
    answers_only_the_right_caller(daemon, outsider, r"not allowed [1-9]", host="127.0.0.2")


def key_file(tmp_path: Path, mode: int = 0o600) -> Path:
    path = tmp_path / "mavlink.key"
    path.write_text(PASSPHRASE + "\n")
    path.chmod(mode)
    return path


def test_signed_udpout_stream_verifies_with_the_key_and_not_without(
    tmp_path: Path, replay_dir: Path
) -> None:
    far = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    far.bind(("127.0.0.1", 0))
    config = tmp_path / "signed.yaml"
    config.write_text(
        "outputs:\n  - protocol: mavlink\n"
        f"    port: udpout:127.0.0.1:{far.getsockname()[1]}\n"
        f"    signing_key_file: {key_file(tmp_path).name}\n"  # relative to the config
    )
    daemon = start(tmp_path, replay_dir, config)
    with_key, wrong_key, datagrams = receiver(KEY), receiver(b"\x01" * 32), []
    try:
        far.settimeout(10)
        while len(datagrams) < 40:  # the release goes 1 s at 50 Hz (no stick), a heartbeat
            datagrams.append(far.recv(65535))
        verified = [m for d in datagrams for m in with_key.parse_buffer(d) or []]
        assert {m.get_type() for m in verified} == {"HEARTBEAT", "RC_CHANNELS_OVERRIDE"}
        assert all(m._signed for m in verified)
        # a tick's messages share a datagram (docs/ICD.md, "MAVLink output"): every one signed
        assert with_key.signing.goodsig_count == len(verified) >= len(datagrams)
        refused = [m for d in datagrams for m in wrong_key.parse_buffer(d) or []]
        assert {m.get_type() for m in refused} == {"BAD_DATA"}
        packets = [bytes(m.get_msgbuf()) for m in verified]
        stamps = [int.from_bytes(p[-12:-6], "little") for p in packets]
        assert stamps == sorted(set(stamps))  # strictly increasing: no replay refused
        now = int((time.time() - 1420070400) * 100_000)
        assert abs(stamps[-1] - now) < 60 * 100_000  # on the wall clock (10 µs units)
        assert {p[-13] for p in packets} == {0}  # link id 0
    finally:
        assert daemon.stop() == 0
        far.close()


def test_signed_udpin_locks_only_to_a_signed_heartbeat(tmp_path: Path, replay_dir: Path) -> None:
    port = free_udp_port()
    config = udpin_config(tmp_path, port, f"    signing_key_file: {key_file(tmp_path)}\n")
    daemon = start(tmp_path, replay_dir, config)
    unsigned = Vehicle(port)  # right system, no signature: a spoofer without the key
    waiting = r"peer none \(no vehicle has called yet\).*from others ignored [1-9]"
    answers = answers_only_the_right_caller(daemon, unsigned, waiting, key=KEY)
    assert all(m._signed for m in answers)


def test_a_key_file_others_can_read_is_refused_with_the_fix(tmp_path: Path) -> None:
    key = key_file(tmp_path, 0o644)
    config = tmp_path / "signed.yaml"
    config.write_text(
        "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
        f"    signing_key_file: {key}\n"
    )
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2, result.stdout + result.stderr
    text = result.stdout + result.stderr
    assert f"{key}: mode 0644" in text and f"chmod 600 {key}" in text
    assert "signing_key_file" in text and ":4" in text  # the key's line
    key.chmod(0o600)
    assert usb2rc("check", "--config", str(config)).returncode == 0


def test_a_udp_host_that_does_not_resolve_is_logged_once_not_every_tick(
    tmp_path: Path, replay_dir: Path
) -> None:
    url = "udpout:no-such-host.invalid:14550"
    config = tmp_path / "unresolved.yaml"
    config.write_text(f"outputs:\n  - protocol: mavlink\n    port: {url}\n    rate_hz: 100\n")
    daemon = start(tmp_path, replay_dir, config)
    try:
        wait_until(lambda: "(attempt 3)" in daemon.log(), "three retries", timeout=20)
        errors = [
            line for line in daemon.log().splitlines() if "ERROR" in line and "no-such-host" in line
        ]
        assert len(errors) == 1, errors
        assert "retrying every 1 s" in errors[0]
    finally:
        assert daemon.stop() == 0
