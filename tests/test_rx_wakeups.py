"""A serial output's reader thread (`lines.rx.LinkReader`) sleeps until its far end sends:
it polls the port's fd beside the link's doorbell, so a quiet far end, or no port at all,
costs it no wake-up; bytes, a new port, a lost one and the stop wake it at once. Handlers
with no fd to poll (`loop://`) are read with their read timeout, as before.

Wake-ups are the thread's voluntary context switches (/proc), counted over a quiet window:
the reader used to wake 20 times a second on its read timeout (10 while no port was open).
"""

from __future__ import annotations

import os
import select
import socket
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial
from thread_wakeups import QUIET_WAKEUPS_MAX, WAIT_S, until, wakeups_in_quiet_window

from usb2rc.lines.link import LineEvent
from usb2rc.lines.rx import LinkReader
from usb2rc.lines.serial_link import SerialLink, read_fd
from usb2rc.runtime.doorbell import Doorbell


def follow(link: SerialLink) -> LineEvent | None:
    """What the driver does with the link each tick."""
    if not link.is_open:
        link.try_open()
    return link.line_event()


def adopted(url: str, reopen_interval_s: float = 1.0) -> SerialLink:
    """A link with its port open and adopted, as after the driver's first tick."""
    link = SerialLink(url, 115200, reopen_interval_s=reopen_interval_s)
    assert link.open_now() and link.line_event() is LineEvent.OPENED
    return link


def received(link: SerialLink) -> bytes:
    return b"".join(data for data, _ in link.take_received())


def read_until(link: SerialLink, want: bytes) -> None:
    got = b""

    def has_all() -> bool:
        nonlocal got
        got += received(link)
        return got == want

    until(has_all, f"{want!r} handed to the driver")


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    """A pty: the far end's master fd, the slave's path (usb2rc's port)."""
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    os.close(slave)
    try:
        yield master, path
    finally:
        os.close(master)


@pytest.fixture
def running() -> Iterator[Callable[[SerialLink], LinkReader]]:
    """Starts a reader on a link; stops and joins it, and closes the link, whatever
    happens."""
    started: list[tuple[LinkReader, SerialLink]] = []

    def start(link: SerialLink) -> LinkReader:
        reader = LinkReader("rx", link)
        started.append((reader, link))
        reader.start()
        return reader

    try:
        yield start
    finally:
        for reader, link in started:
            reader.stop()
            joined = reader.join(WAIT_S)
            link.close()
            assert joined, "the reader did not end after its stop"


def test_a_quiet_far_end_costs_the_reader_no_wakeup_and_bytes_wake_it_at_once(
    pty_pair: tuple[int, str], running: Callable[[SerialLink], LinkReader]
) -> None:
    master, path = pty_pair
    link = adopted(path)
    reader = running(link)
    os.write(master, b"first")
    read_until(link, b"first")  # the reader polls the port now
    assert wakeups_in_quiet_window(reader._thread) <= QUIET_WAKEUPS_MAX
    os.write(master, b"second")
    read_until(link, b"second")


def test_the_stop_wakes_a_reader_waiting_for_bytes(
    pty_pair: tuple[int, str], running: Callable[[SerialLink], LinkReader]
) -> None:
    _, path = pty_pair
    link = adopted(path)
    reader = running(link)
    until(lambda: reader._polled_fd is not None, "the reader polls the port")
    reader.stop()
    assert reader.join(WAIT_S)  # no timeout of its own would have ended the wait


def test_with_no_port_the_reader_sleeps_until_one_is_adopted(
    tmp_path: Path, pty_pair: tuple[int, str], running: Callable[[SerialLink], LinkReader]
) -> None:
    """The port is missing at start (a USB adapter not plugged yet): the reader waits for
    the writer to adopt one, without waking meanwhile, then reads it at once."""
    master, pty_path = pty_pair
    path = tmp_path / "ttyUSB0"  # where the adapter's port appears
    link = SerialLink(str(path), 115200, reopen_interval_s=0.0)
    assert not link.open_now()
    reader = running(link)
    assert wakeups_in_quiet_window(reader._thread) <= QUIET_WAKEUPS_MAX
    path.symlink_to(pty_path)  # plugged
    until(lambda: follow(link) is LineEvent.OPENED, "the port adopted")
    os.write(master, b"hello")
    read_until(link, b"hello")


def test_a_lost_port_is_let_go_and_the_new_one_is_read(
    pty_pair: tuple[int, str], running: Callable[[SerialLink], LinkReader]
) -> None:
    """The writer loses the port (a failed write) and reopens it: the reader leaves the old
    fd when the writer gives it up, waits without waking, and reads the new port."""
    master, path = pty_pair
    link = adopted(path, reopen_interval_s=3600.0)  # reopened by the test only
    reader = running(link)
    old_fd = link.read_fd
    until(lambda: reader._polled_fd == old_fd, "the reader polls the first port")
    link._lost(OSError("write failed"))  # what a failed write does, on the writer's thread
    until(lambda: reader._polled_fd is None, "the reader let go of the closed port")
    assert wakeups_in_quiet_window(reader._thread) <= QUIET_WAKEUPS_MAX
    link._next_attempt = 0.0
    until(lambda: follow(link) is LineEvent.OPENED, "the port reopened")
    os.write(master, b"again")
    read_until(link, b"again")
    assert link.stats.opens == 2 and link.stats.losses == 1


def test_a_far_end_that_hangs_up_is_reported_once_not_polled_in_a_loop(
    running: Callable[[SerialLink], LinkReader],
) -> None:
    """A pty whose far end closed polls readable for ever: the read fails once, the link
    is marked broken for the writer, and the reader sleeps until the writer acts."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        link = adopted(path)
    finally:
        os.close(slave)
    reader = running(link)
    until(lambda: reader._polled_fd is not None, "the reader polls the port")
    os.close(master)  # the far end hangs up
    until(lambda: not link.readable, "the failed read reported")
    assert wakeups_in_quiet_window(reader._thread) <= QUIET_WAKEUPS_MAX
    assert follow(link) is LineEvent.LOST


def test_loop_has_no_fd_and_is_read_with_its_timeout(
    running: Callable[[SerialLink], LinkReader],
) -> None:
    """pyserial's `loop://` keeps its bytes in a queue: nothing to poll. Its reader reads
    with the handler's read timeout, as every reader did before."""
    link = adopted("loop://")
    assert link.read_fd is None
    running(link)
    assert link.write(b"echo").sent == 4
    read_until(link, b"echo")


# --- which pyserial handlers read their fd as it is (`read_fd`): held to the real ones ---------


def test_a_readable_fd_means_a_read_returns_at_once_on_the_handlers_that_have_one(
    pty_pair: tuple[int, str],
) -> None:
    """The posix port, `spy://` on it and `socket://` read their fd as it is: when it polls
    readable, reading what waits does not wait for the read timeout (a long one here)."""
    master, path = pty_pair
    listener = socket.create_server(("127.0.0.1", 0))
    ports = [
        serial.serial_for_url(path, timeout=5.0),
        serial.serial_for_url(f"spy://{path}?file=/dev/null", timeout=5.0),
        serial.serial_for_url(f"socket://127.0.0.1:{listener.getsockname()[1]}", timeout=5.0),
    ]
    far_socket, _ = listener.accept()

    def to_pty(data: bytes) -> int:
        return os.write(master, data)

    senders: list[Callable[[bytes], int]] = [to_pty, to_pty, far_socket.send]
    try:
        for port, send in zip(ports, senders, strict=True):
            fd = read_fd(port)
            assert fd is not None, port
            assert not select.select([fd], [], [], 0)[0]
            send(b"x")
            assert select.select([fd], [], [], WAIT_S)[0]
            started = time.monotonic()
            assert port.read(max(1, port.in_waiting)) == b"x"
            assert time.monotonic() - started < 2.5  # not the 5 s read timeout
    finally:
        for port in ports:
            port.close()
        far_socket.close()
        listener.close()


def test_loop_and_rfc2217_have_no_fd_to_poll() -> None:
    """`loop://` reads a queue; `rfc2217://` a queue its own thread fills from the socket:
    the socket polling readable says nothing about them."""
    from serial import rfc2217

    assert read_fd(serial.serial_for_url("loop://")) is None
    assert read_fd(rfc2217.Serial()) is None  # no port given: not opened


def test_a_doorbell_rung_before_the_wait_is_not_missed() -> None:
    bell = Doorbell()
    bell.ring()
    assert bell.wait(0)
    bell.clear()
    assert not bell.wait(0)
    for _ in range(100_000):  # more rings than the pipe holds: none blocks
        bell.ring()
    assert bell.wait(0)
    bell.clear()
    assert not bell.wait(0)
