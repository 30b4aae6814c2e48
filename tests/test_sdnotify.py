"""sd_notify against real AF_UNIX datagram sockets standing in for systemd."""

from __future__ import annotations

import fcntl
import os
import signal
import socket
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from types import FrameType

import pytest

from usb2rc.service.sdnotify import Notifier


@pytest.fixture
def short_dir() -> Iterator[Path]:
    # AF_UNIX paths are limited to 107 bytes; pytest's tmp_path can be longer.
    with tempfile.TemporaryDirectory(prefix="sdn", dir="/tmp") as name:
        yield Path(name)


@pytest.fixture
def receiver(short_dir: Path) -> Iterator[tuple[socket.socket, str]]:
    """A bound datagram socket (systemd's side) and its path."""
    path = str(short_dir / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.setblocking(False)
    yield sock, path
    sock.close()


def received(sock: socket.socket) -> list[str]:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except BlockingIOError:
            return out


@pytest.fixture
def hang_guard() -> Iterator[None]:
    """Turn a hang (a blocking send) into a test failure instead of a stuck run.

    Not a timing assertion: the bound is far above anything a non-blocking loop needs.
    """

    def on_alarm(signum: int, frame: FrameType | None) -> None:
        raise AssertionError("Notifier call blocked")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(60)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_messages_arrive(receiver: tuple[socket.socket, str]) -> None:
    sock, path = receiver
    with Notifier.from_env({"NOTIFY_SOCKET": path}) as notifier:
        assert notifier.enabled
        assert notifier.ready()
        assert notifier.watchdog()
        assert notifier.status("2 devices\n1 output")
        assert notifier.stopping()
        assert notifier.sent == 4
        assert notifier.dropped == 0
    assert received(sock) == [
        "READY=1",
        "WATCHDOG=1",
        "STATUS=2 devices 1 output",
        "STOPPING=1",
    ]


def test_reloading_carries_monotonic_usec(receiver: tuple[socket.socket, str]) -> None:
    sock, path = receiver
    before = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    with Notifier.from_env({"NOTIFY_SOCKET": path}) as notifier:
        assert notifier.reloading()
    after = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    (message,) = received(sock)
    lines = message.split("\n")
    assert lines[0] == "RELOADING=1"
    key, _, value = lines[1].partition("=")
    assert key == "MONOTONIC_USEC"
    assert before <= int(value) <= after  # CLOCK_MONOTONIC in µs, as systemd compares it


def test_abstract_namespace() -> None:
    name = f"usb2rc-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.setblocking(False)
    try:
        with Notifier.from_env({"NOTIFY_SOCKET": "@" + name}) as notifier:
            assert notifier.ready()
        assert received(sock) == ["READY=1"]
    finally:
        sock.close()


def test_full_queue_never_blocks(receiver: tuple[socket.socket, str], hang_guard: None) -> None:
    _sock, path = receiver  # nobody reads: the queue fills after a few hundred datagrams
    with Notifier.from_env({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"}) as notifier:
        flags = fcntl.fcntl(notifier.fileno(), fcntl.F_GETFL)
        assert flags & os.O_NONBLOCK, "a blocking socket would hang here once the queue fills"
        results = [notifier.watchdog() for _ in range(5000)]
    assert results[0] is True
    assert results[-1] is False
    assert notifier.dropped > 0
    assert notifier.sent + notifier.dropped == 5000


def test_refused_and_missing_socket_count_drops(short_dir: Path) -> None:
    stale = str(short_dir / "stale")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(stale)
    sock.close()  # the path stays, nobody listens: ECONNREFUSED
    with Notifier.from_env({"NOTIFY_SOCKET": stale}) as notifier:
        assert notifier.watchdog() is False
        assert notifier.dropped == 1
    with Notifier.from_env({"NOTIFY_SOCKET": str(short_dir / "missing")}) as notifier:
        assert notifier.ready() is False  # ENOENT
        assert notifier.dropped == 1


def test_absent_env_is_a_no_op() -> None:
    notifier = Notifier.from_env({})
    assert not notifier.enabled
    assert notifier.fileno() == -1
    assert notifier.ready() is False
    assert notifier.watchdog() is False
    assert notifier.status("x") is False
    assert notifier.stopping() is False
    assert notifier.reloading() is False
    assert notifier.watchdog_interval_s() is None
    assert (notifier.sent, notifier.dropped) == (0, 0)
    notifier.close()


@pytest.mark.parametrize("value", ["", "relative/path", "vsock:2:1234", "@"])
def test_unusable_socket_values_disable(value: str) -> None:
    assert not Notifier.from_env({"NOTIFY_SOCKET": value}).enabled


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({"WATCHDOG_USEC": "2000000"}, 1.0),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}, 1.0),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid() + 1)}, None),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "x"}, None),
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval(
    receiver: tuple[socket.socket, str], env: dict[str, str], expected: float | None
) -> None:
    _sock, path = receiver
    with Notifier.from_env({"NOTIFY_SOCKET": path, **env}) as notifier:
        assert notifier.watchdog_interval_s() == expected


def test_watchdog_interval_needs_socket() -> None:
    assert Notifier.from_env({"WATCHDOG_USEC": "2000000"}).watchdog_interval_s() is None


def test_close_then_send_is_a_counted_no_op(receiver: tuple[socket.socket, str]) -> None:
    _sock, path = receiver
    notifier = Notifier.from_env({"NOTIFY_SOCKET": path})
    notifier.close()
    assert notifier.watchdog() is False
    assert not notifier.enabled
