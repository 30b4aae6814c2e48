"""DeviceReader: one thread per open device, the only owner of that device.

It blocks in `device.read(timeout)`, feeds each report to the device's decoder and publishes
the decoded `InputState` by swapping one attribute (`snapshot`), so readers of the snapshot
never take a lock and never wait for the device. On unplug it calls `on_exit(reader, None)`,
on a read failure `on_exit(reader, ErrorCode.READ_FAILED)` — exactly once, from the reader
thread — and ends. `stop()` ends it without calling `on_exit`. The device is closed when the
thread ends.

Pacing (optional): the outputs only sample the snapshot once per tick, so with a `pause`
callable the reader, after a report, drains what is queued without blocking and then sleeps
until just before the next tick (`pause()` says how long). A 1 kHz device then wakes its
thread a few times per tick instead of twenty; the kernel queues the reports meanwhile and
the drain decodes every one of them, in order, before the tick reads the snapshot.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

from usb2rc.hid.backend import Device, DeviceGone, ErrorCode
from usb2rc.hid.descriptor import InputState

log = logging.getLogger(__name__)

READ_TIMEOUT_S = 0.1


class Decoder(Protocol):
    def feed(self, report: bytes) -> bool: ...

    def state(self) -> InputState: ...


OnExit = Callable[["DeviceReader", ErrorCode | None], None]


class DeviceReader:
    def __init__(
        self,
        device: Device,
        decoder: Decoder,
        on_exit: OnExit,
        read_timeout_s: float = READ_TIMEOUT_S,
        pause: Callable[[], float] | None = None,
    ) -> None:
        self.device = device
        self.info = device.info
        self.decoder = decoder
        self.snapshot: InputState = decoder.state()
        self.reports = 0  # reports the decoder accepted
        self.bad_reports = 0  # reports it refused (unknown ID, short)
        self.last_report_monotonic: float | None = None
        self.exit_code: ErrorCode | None = None
        self.error: BaseException | None = None  # what ended it, if not stop()
        self._on_exit = on_exit
        self._read_timeout_s = read_timeout_s
        self._pause = pause
        self._stop = threading.Event()
        name = f"hid-reader {self.info.port_path or self.info.path}"
        self._thread = threading.Thread(target=self._run, name=name)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        if threading.current_thread() is not self._thread and self._thread.ident is not None:
            self._thread.join(timeout)

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def _handle(self, report: bytes, publish: bool = True) -> None:
        if self.decoder.feed(report):
            self.reports += 1
            if publish:
                self._publish()
        else:
            self.bad_reports += 1

    def _publish(self) -> None:
        self.snapshot = self.decoder.state()
        self.last_report_monotonic = time.monotonic()

    def _loop(self) -> None:
        while not self._stop.is_set():
            report = self.device.read(self._read_timeout_s)
            if report is None:
                continue
            self._handle(report)
            if self._pause is None:
                continue
            reports = self.reports
            while (queued := self.device.read(0.0)) is not None:
                self._handle(queued, publish=False)
            if self.reports != reports:
                self._publish()  # once for the whole batch: the tick samples the latest
            pause = self._pause()
            if pause > 0:
                self._stop.wait(pause)

    def _run(self) -> None:
        ended: tuple[ErrorCode | None] | None = None
        try:
            self._loop()
        except DeviceGone as exc:
            self.error, ended = exc, (None,)
            log.info("%s: unplugged (%s)", self.info.path, exc)
        except Exception as exc:  # any failure must reach on_exit, never kill silently
            self.error, ended = exc, (ErrorCode.READ_FAILED,)
            log.error(
                "%s: read failed: %s", self.info.path, exc, exc_info=not isinstance(exc, OSError)
            )
        finally:
            with contextlib.suppress(Exception):
                self.device.close()
        if ended is not None and not self._stop.is_set():
            self.exit_code = ended[0]
            self._call_on_exit(ended[0])

    def _call_on_exit(self, code: ErrorCode | None) -> None:
        try:
            self._on_exit(self, code)
        except Exception:
            log.exception("%s: on_exit handler failed", self.info.path)
