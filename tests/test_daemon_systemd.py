"""The daemon under systemd's eyes: READY=1 after the first frame, the watchdog fed by the
scheduler, STOPPING=1 at the end; a missing port still becomes ready, with a status line."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from daemon_harness import StickState, data_frames, install, recording, run_daemon


class NotifySocket:
    """What systemd listens on: an AF_UNIX datagram socket collecting sd_notify messages."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.messages: list[str] = []

    def count(self, text: str) -> int:
        return sum(text in m for m in self.messages)

    def wait_for(self, text: str, timeout: float = 10.0, times: int = 1) -> None:
        deadline = time.monotonic() + timeout
        while self.count(text) < times:
            left = deadline - time.monotonic()
            assert left > 0, f"no {text!r} in {self.messages[-5:]}"
            self.sock.settimeout(left)
            try:
                self.messages.append(self.sock.recv(4096).decode())
            except TimeoutError:
                continue

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def notify(tmp_path: Path) -> Iterator[NotifySocket]:
    sock = NotifySocket(tmp_path / "notify.sock")
    yield sock
    sock.close()


def test_ready_after_first_frame_watchdog_and_stopping(tmp_path, line, replay_dir, notify):
    install(replay_dir / "stick.hid", recording([StickState()]))
    env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000"}
    daemon = run_daemon(tmp_path, line.path, replay_dir, env=env)
    try:
        notify.wait_for("READY=1")
        # the daemon sends READY=1 right after its first write() returned, so that frame is
        # already in the pty: our reader thread may only not have read it yet
        first = line.wait_for(lambda fr: fr[:1], timeout=2)
        assert first[0].service.service_name == "startup", "READY=1 before any frame"
        notify.wait_for("WATCHDOG=1", times=5)  # fed again and again while it ticks
        line.wait_for(lambda fr: len(data_frames(fr, 0)) > 5)
    finally:
        assert daemon.stop() == 0
    notify.wait_for("STOPPING=1")


def test_missing_port_is_ready_with_a_status(tmp_path, replay_dir, notify):
    env = {"NOTIFY_SOCKET": str(notify.path)}
    daemon = run_daemon(tmp_path, str(tmp_path / "no-such-tty"), replay_dir, env=env)
    try:
        notify.wait_for("READY=1")
        notify.wait_for("STATUS=waiting for the serial line")
    finally:
        assert daemon.stop() == 0
    assert "no-such-tty" in daemon.log() and "retrying every" in daemon.log()
