"""What usb2rc.lines.serial_link assumes of pyserial where pyserial has no public API for it, held
to the real handlers: a real pty, `loop://`, `socket://` to a local TCP server, `spy://`.

- `plain_fd`: which ports' `write` puts the bytes on their fd unchanged (the link writes
  there itself, non-blocking, to learn how much the OS took), and which must be written
  through `port.write` (spy:// logs what goes out);
- `fd_kind` / `is_pty`: a pty's TIOCOUTQ (`out_waiting`) reads 0 whatever waits in it, so
  the link must know a pty without hard-coded major numbers;
- the public API it does use: `fileno()`, `out_waiting`, `in_waiting`.
"""

from __future__ import annotations

import os
import select
import socket
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from usb2rc.lines.serial_link import FdKind, fd_kind, is_pty, plain_fd, pty_slave_majors


@pytest.fixture
def pty_port() -> Iterator[tuple[int, serial.SerialBase]]:
    """A real pty: (the far end's master fd, the slave opened by pyserial)."""
    master, slave = os.openpty()
    tty.setraw(master)
    port = serial.serial_for_url(os.ttyname(slave), timeout=0.05, exclusive=True)
    try:
        yield master, port
    finally:
        port.close()
        os.close(master)
        os.close(slave)


def test_a_pty_port_is_written_on_its_own_non_blocking_fd(
    pty_port: tuple[int, serial.SerialBase],
) -> None:
    master, port = pty_port
    fd = plain_fd(port)
    assert fd == port.fileno() and not os.get_blocking(fd)  # a full pty never blocks a tick
    assert os.write(fd, b"\x01\xff\x80") == 3
    assert select.select([master], [], [], 5)[0] and os.read(master, 16) == b"\x01\xff\x80"


def test_a_pty_is_known_as_one_and_hides_its_queue(pty_port: tuple[int, serial.SerialBase]) -> None:
    master, port = pty_port
    fd = plain_fd(port)
    assert fd is not None and is_pty(fd) and fd_kind(fd) is FdKind.PTY
    os.write(fd, bytes(200))  # the far end reads none of it
    assert port.out_waiting == 0  # why the link must know a pty: TIOCOUTQ says nothing
    assert select.select([master], [], [], 5)[0]  # ... although 200 bytes wait


def test_the_pty_drivers_majors_come_from_the_kernels_list(tmp_path: Path) -> None:
    devices = tmp_path / "devices"
    devices.write_text(
        "Character devices:\n  4 tty\n  5 /dev/ptmx\n128 ptm\n136 pts\n  3 ttyp\n\n"
        "Block devices:\n  7 loop\n"
    )
    assert pty_slave_majors(str(devices)) == frozenset({136, 3})
    assert pty_slave_majors(str(tmp_path / "none")) == frozenset()


def test_a_real_ptys_major_is_listed_by_the_kernel(pty_port: tuple[int, serial.SerialBase]) -> None:
    if not Path("/proc/devices").exists():
        pytest.skip("no /proc/devices")
    _, port = pty_port
    major = os.major(os.fstat(port.fileno()).st_rdev)
    # a kernel lists a driver's first major; a pty numbered past 1M takes the next ones
    assert major in pty_slave_majors() or os.ttyname(port.fileno()).startswith("/dev/pts/")


def test_loop_is_written_through_its_write_and_reports_its_queue() -> None:
    port = serial.serial_for_url("loop://", timeout=0.05)
    try:
        assert plain_fd(port) is None  # no fd: its own write, in pieces
        port.write(b"ab")
        assert port.out_waiting == 2 and port.in_waiting == 2
    finally:
        port.close()


def test_a_socket_port_is_written_on_the_sockets_own_non_blocking_fd() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = serial.serial_for_url(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.05)
        peer, _ = server.accept()
        try:
            fd = plain_fd(port)
            assert fd == port.fileno() and fd_kind(fd) is FdKind.SOCKET
            assert not os.get_blocking(fd)
            assert os.write(fd, b"\x0f\xff") == 2  # raw bytes: socket:// escapes nothing
            peer.settimeout(5)
            assert peer.recv(16) == b"\x0f\xff"
        finally:
            peer.close()
            port.close()


def test_spy_is_written_through_its_write_which_logs_it(
    pty_port: tuple[int, serial.SerialBase], tmp_path: Path
) -> None:
    master, plain = pty_port
    name = os.ttyname(plain.fileno())
    plain.close()  # opened exclusively: spy:// opens the same pty
    log = tmp_path / "spy.txt"
    port = serial.serial_for_url(f"spy://{name}?file={log}", timeout=0.05)
    try:
        assert isinstance(port, serial.Serial) and port.fileno() >= 0  # a posix port, but...
        assert plain_fd(port) is None  # ... its write logs: the link writes through it
        port.write(b"\x42")
        port.flush()
        assert select.select([master], [], [], 5)[0] and os.read(master, 4) == b"\x42"
    finally:
        port.close()
    assert "42" in log.read_text()
