"""A fake output port (usb2rc.hid.backend.OutputPort) for the test devices: it keeps what was
written and when, can refuse (raise, as HidapiOutputPort raises for a write hidapi says
failed) or hold a write (a slow device), and refuses writes after close(), as a closed
hidapi handle does (tests/hidapi_contract.py)."""

from __future__ import annotations

import errno
import threading
import time

from usb2rc.hid.outputs import OutputWrite

WAIT_S = 10.0


class RecordingPort:
    def __init__(self) -> None:
        self.writes: list[tuple[float, OutputWrite]] = []  # (monotonic time, write)
        self.fail: BaseException | None = None  # raised by every write while set
        self.hold: threading.Event | None = None  # a write waits for it while set
        self.in_write = threading.Event()  # a write has started
        self.closed = False
        self.closed_at: float | None = None
        self.changed = threading.Condition()

    def write(self, w: OutputWrite) -> None:
        if self.closed:
            raise OSError(errno.EBADF, "output port is closed")
        self.in_write.set()
        if self.hold is not None:
            self.hold.wait(WAIT_S)
        if self.fail is not None:
            raise self.fail
        with self.changed:
            self.writes.append((time.monotonic(), w))
            self.changed.notify_all()

    def close(self) -> None:
        self.closed = True
        self.closed_at = time.monotonic()

    def written(self) -> list[OutputWrite]:
        with self.changed:
            return [w for _, w in self.writes]
