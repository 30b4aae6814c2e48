"""DeviceReader: one thread per open device, the only owner of that device.

It feeds each report to the device's decoder and publishes one immutable `ReaderRecord`
(state, report count, time) by a single assignment (`record`), so whoever reads it never
takes a lock, never waits for the device, and never sees a count that belongs to another
state (a node goes live on the count: it must come with its state).
On unplug it calls `on_exit(reader, None)`, on a read failure
`on_exit(reader, ErrorCode.READ_FAILED)` — exactly once, from the reader thread — and ends.
`stop()` ends it without calling `on_exit`. The device is closed when the thread ends.

Pulled (the daemon's readers, docs/DESIGN.md "The hot path"): the node step calls `pull()`
before it reads the records, and the pull drains what the device queued, without blocking,
as one batch (`ReportDecoder.feed_batch` decodes only what the state shows, and every press
is noted). A 1 kHz device then costs one short drain per step and no wake-up at all: the
kernel (or the replay backend) queues the reports meanwhile, as hidraw does for 64 of them.
The thread only holds the device: it waits for `stop()` or for a failure a pull met, which it
then reports as its own read would (`on_exit`), and it closes the device; a pull and the
close never overlap (`_device_lock`), and a pull after the close does nothing. A replay
device's pull runs in one C call where the HID stage's C loops are built
(`_speedups.pull`: the same steps on this reader's own fields; it hands the pull back to
Python when the lock is taken or the replay owes a read error).
A queue that fills between two steps loses reports: the kernel keeps 63 for each open fd of
a hidraw node and drops the newest while it is full, so the last state before a tick would
be old and a tap lost. A device that tells its reader so (`on_queue_full`: a hidraw fd read
up to the kernel's limit, `hidapi_backend.HidapiDevice`) is pulled by its reader's thread
too from then on, between the steps, often enough to take half the queue at the rate it
reports (`keep_every_s`): the same pull, so which thread pulls changes nothing but the age.

Outputs (pulled readers only): `post_output(driver, state)` leaves the newest state a device
should show in a mailbox (the feedback thread's call; a newer post replaces one not written
yet) and wakes the thread, which writes what changed (`driver.writes(state, shown)`) through
the device's output port (`device.open_output()`, opened when first needed, closed before the
device). The thread writes without `_device_lock`: a slow or refused write never delays a
pull. At most OUTPUT_RATE_HZ states a second are shown (a token bucket of OUTPUT_BURST: a
change after a quiet spell goes at once, one that must wait goes when a token comes, as the
newest state then). A refusal (the port cannot be opened, a write fails, the driver fails)
is logged once per device, counted (`outputs`), and tried again after OUTPUT_RETRY_S with
everything rewritten; the input goes on. At stop a state not shown yet is written once.
A reader that is not pulled ignores posts: its thread is in `device.read`.

Not pulled (`usb2rc calibrate`, tests), it blocks in `device.read(timeout)` and publishes
each report as it comes.

Bad reports (unknown report ID, too short): counted, and counted in a row. After
BAD_REPORTS_LIMIT refused in a row, with no accepted report between them, the device is in
error (`ReaderRecord.in_error`: its node sends `!`, docs/ICD.md "Device error codes", 0x06)
until it sends a good report again; the reader calls `on_bad_reports(reader, record)` after
it published a record that entered or left error (or began a new run of bad reports).
"""

from __future__ import annotations

import contextlib
import logging
import math
import operator
import threading
import time
from collections.abc import Callable, Sequence
from functools import reduce
from typing import NamedTuple, Protocol, TypeGuard

from usb2rc.hid import speedups
from usb2rc.hid.backend import Device, DeviceGone, ErrorCode, OutputPort
from usb2rc.hid.descriptor import InputState
from usb2rc.hid.outputs import OutputDriver, OutputState
from usb2rc.runtime.token_bucket import TokenBucket
from usb2rc.runtime.worker import Worker

log = logging.getLogger(__name__)

READ_TIMEOUT_S = 0.1
PRESSES_KEPT = 32  # rising edges a record remembers: a consumer one tick behind sees them all
MAX_BATCH = 1000  # reports decoded as one batch (a pull's drain)
# Refused reports in a row that put a device in error (`3`, BAD_REPORTS). A glitch on the
# bus truncates one report, not twenty; a device that refuses twenty in a row and none
# good between them is not understood (wrong descriptor, unknown report IDs).
BAD_REPORTS_LIMIT = 20
OUTPUT_RATE_HZ = 20.0  # output states shown per second and device, at most
OUTPUT_BURST = 3  # states shown at once after a quiet spell
OUTPUT_RETRY_S = 1.0  # after a refusal, the next try
# A device whose queue filled between two pulls (`HidapiDevice.on_queue_full`) is also pulled
# by its reader's thread from then on, often enough to take KEEP_SHARE of the queue at its
# report rate: the first after KEEP_FIRST_S, then between KEEP_MIN_S and KEEP_MAX_S apart.
KEEP_SHARE = 0.5
KEEP_FIRST_S = 0.002
KEEP_MIN_S = 0.001
KEEP_MAX_S = 0.02


class Decoder(Protocol):
    def feed(self, report: bytes) -> bool: ...

    def feed_batch(
        self, reports: Sequence[bytes], on_buttons: Callable[[int], None] | None = None
    ) -> tuple[int, int]: ...

    def state(self) -> InputState: ...


class ButtonsDecoder(Decoder, Protocol):
    """A decoder that tells the buttons each report pressed (descriptor.ReportDecoder): the
    reader then notes every press, for the taps between two ticks."""

    @property
    def buttons(self) -> int: ...

    def feed_presses(self, reports: list[bytes]) -> tuple[int, int, list[int]]: ...


def tells_presses(decoder: Decoder) -> TypeGuard[ButtonsDecoder]:
    """Whether `decoder` tells the buttons each report pressed (by its method, not by an
    `isinstance` of a runtime-checkable Protocol, which compiled modules do not have)."""
    return hasattr(decoder, "feed_presses")


OnExit = Callable[["DeviceReader", ErrorCode | None], None]
OnBadReports = Callable[["DeviceReader", "ReaderRecord"], None]


class ReaderRecord(NamedTuple):
    """What a reader published last, as one value: never a state from one batch with the
    count of another."""

    state: InputState
    reports: int = 0  # reports the decoder accepted; 0: the device's state is not known yet
    bad_reports: int = 0  # reports it refused (unknown ID, short)
    at: float | None = None  # monotonic time of the last published report
    # No lost taps (docs/ICD.md, "Taps"): the HID buttons that went down in each of the last
    # PRESSES_KEPT reports that pressed a button, oldest first. Presses are numbered one by
    # one: press_serial is the newest's, so entry i is press press_serial - len + 1 + i.
    presses: tuple[int, ...] = ()
    press_serial: int = 0
    refused_in_a_row: int = 0  # refused since the last accepted report
    bad_spells: int = 0  # times `refused_in_a_row` reached BAD_REPORTS_LIMIT
    # reports byte for byte the same as the one before: a device that sends them streams
    # (one that reports on change never does: usb2rc.nodes.silence)
    repeats: int = 0

    @property
    def in_error(self) -> bool:
        """The device's last BAD_REPORTS_LIMIT reports or more were all refused."""
        return self.refused_in_a_row >= BAD_REPORTS_LIMIT

    def presses_after(self, serial: int) -> tuple[int, ...]:
        """What each press after press `serial` (a consumer's last `press_serial`) pressed,
        oldest first (those still kept)."""
        newer = self.press_serial - serial
        if newer <= 0:
            return ()
        return self.presses[-newer:]

    def pressed_since(self, serial: int) -> int:
        """The HID buttons pressed in any report after press `serial`: a tap that is over by
        now still shows in the consumer's next frame."""
        return reduce(operator.or_, self.presses_after(serial), 0)


class OutputRecord(NamedTuple):
    """A reader's outputs so far, as one value (replaced whole by its thread)."""

    written: int = 0  # writes made (reports, control transfers)
    refused: int = 0  # tries that failed (the port would not open, a write or driver failed)
    last_error: str = ""  # why the last one failed
    shown: OutputState | None = None  # what the device shows (None: not known, or nothing)


def _compiled_pull(device: object, replayed: bool) -> Callable[..., bool | None] | None:
    """The compiled pull for `device`, if the C loops are built: a replay device's (it has
    `read_due`), or that of a device read on an fd of its own (an int `read_fd`)."""
    c_loops = speedups.compiled()
    if c_loops is None:
        return None
    if replayed:
        pull: Callable[..., bool | None] = c_loops.pull
        return pull
    if isinstance(getattr(device, "read_fd", None), int):
        pull_fd: Callable[..., bool | None] = c_loops.pull_fd
        return pull_fd
    return None


class DeviceReader(Worker):
    def __init__(
        self,
        device: Device,
        decoder: Decoder,
        on_exit: OnExit,
        read_timeout_s: float = READ_TIMEOUT_S,
        pulled: bool = False,
    ) -> None:
        self.device = device
        self.info = device.info
        self.decoder = decoder
        self.record = ReaderRecord(decoder.state())
        self._reports = 0  # counted by the reader thread; published with the state
        self._bad_reports = 0
        self._refused_in_a_row = 0
        self._bad_spells = 0
        # Told when the device enters or leaves error (bad reports); set before start().
        self.on_bad_reports: OnBadReports | None = None
        # the decoder, where its button mask can be read per report (fakes in tests: None)
        self._press_decoder = decoder if tells_presses(decoder) else None
        # the replay backend's `read_due` (everything due, in one call), if the device has it
        self._read_due: Callable[[int], list[bytes]] | None = getattr(device, "read_due", None)
        # the compiled pull, if built: of a replay device (usb2rc.hid._speedups.pull), or of
        # a device read on an fd of its own (`pull_fd`: hidapi_backend.HidapiDevice)
        self._c_pull = _compiled_pull(device, self._read_due is not None)
        self._last_report = b""  # the raw report before, for `repeats`
        self._repeats = 0
        self._presses: tuple[int, ...] = ()
        self._press_serial = 0
        self.exit_code: ErrorCode | None = None
        self.error: BaseException | None = None  # what ended it, if not stop()
        self._on_exit = on_exit
        self._read_timeout_s = read_timeout_s
        # Pulled: the node step drains the device (`pull`); the pull and the close are never
        # at once, and a failure the pull meets ends this thread as a read's would.
        self._pulled = pulled
        self._device_lock = threading.Lock()
        self._closed = False
        self._pull_error: BaseException | None = None
        # stop(), a failure a pull met, an output post or a full queue: the thread's wake-up
        self._woken = threading.Event()
        # a device whose queue filled between pulls: how often the thread pulls it too (None:
        # never), and the reports and time at its last such pull (its report rate)
        self.keep_every_s: float | None = None
        self._keep_from_now = False
        self._kept_at: tuple[int, float] | None = None
        self._queue_reports = 0
        if pulled and hasattr(device, "on_queue_full"):
            device.on_queue_full = self._queue_filled
        # Outputs (module docstring): the mailbox, replaced whole by post_output; the rest is
        # the reader thread's own.
        self._output_post: tuple[OutputDriver, OutputState] | None = None
        self._output_port: OutputPort | None = None
        self._shown_by: OutputDriver | None = None  # the driver `outputs.shown` was written by
        self._output_bucket = TokenBucket(OUTPUT_RATE_HZ, OUTPUT_BURST, time.monotonic())
        self._output_retry_at = 0.0
        self._output_refusal_logged = False
        self.outputs = OutputRecord()
        super().__init__(f"hid-reader {self.info.port_path or self.info.path}")

    # Views of the record, for statistics and tests.
    @property
    def snapshot(self) -> InputState:
        return self.record.state

    @property
    def reports(self) -> int:
        return self.record.reports

    @property
    def bad_reports(self) -> int:
        return self.record.bad_reports

    @property
    def last_report_monotonic(self) -> float | None:
        return self.record.at

    def _handle(self, report: bytes) -> None:
        repeated = report == self._last_report
        self._last_report = report
        before = self._press_decoder.buttons if self._press_decoder is not None else 0
        if self.decoder.feed(report):
            self._repeats += repeated
            self._reports += 1
            if self._press_decoder is not None and (
                rising := self._press_decoder.buttons & ~before
            ):
                self._note_presses([rising])
            self._count_refused(accepted=1, refused=0)
        else:
            self._bad_reports += 1
            self._count_refused(accepted=0, refused=1)

    def _count_refused(self, accepted: int, refused: int) -> None:
        """Refused reports in a row. A batch is decoded as a whole: one accepted report in
        it ends the run (a device with good reports in every batch is not in error)."""
        if accepted:
            self._refused_in_a_row = 0
            return
        before = self._refused_in_a_row
        self._refused_in_a_row += refused
        if before < BAD_REPORTS_LIMIT <= self._refused_in_a_row:
            self._bad_spells += 1

    def _note_presses(self, pressed: list[int]) -> None:
        """Every press, even one released before the record is published (a tap): `pressed`
        holds the buttons each report pressed, for every report that pressed one, in order
        (a batch's, as `ReportDecoder.feed_presses` gives them); one entry each, numbered on
        from the last, the press log rebuilt once."""
        self._press_serial += len(pressed)
        self._presses = (*self._presses, *pressed)[-PRESSES_KEPT:]

    def _queued(self) -> list[bytes]:
        """What the device has queued, read without blocking, at most MAX_BATCH reports. The
        replay backend hands over what is due in one call (`ReplayDevice.read_due`), which
        returns nothing when a check of its own is due: `read(0.0)` then makes it. A device
        that never runs dry still gets published: MAX_BATCH at a time."""
        read_due = self._read_due
        if read_due is not None and (batch := read_due(MAX_BATCH)):
            return batch
        read = self.device.read
        if (report := read(0.0)) is None:
            return []
        batch = [report]
        while len(batch) < MAX_BATCH:
            if read_due is not None:
                batch += read_due(MAX_BATCH - len(batch))
            if len(batch) >= MAX_BATCH or (report := read(0.0)) is None:
                break
            batch.append(report)
        return batch

    def _drain(self, batch: list[bytes]) -> None:
        """`batch` decoded as one: at 1 kHz a few reports per pull, of which only the last
        of each report ID shows in the state (`ReportDecoder.feed_batch` decodes just
        those), and every press is noted, even one released within the batch (no lost
        taps)."""
        if self._press_decoder is not None:
            accepted, refused, pressed = self._press_decoder.feed_presses(batch)
            if pressed:
                self._note_presses(pressed)
        else:
            accepted, refused = self.decoder.feed_batch(batch)
        if not refused:  # a run of the same refused report is no sign of streaming
            self._repeats += sum(map(operator.eq, batch, [self._last_report, *batch[:-1]]))
        self._last_report = batch[-1]
        self._reports += accepted
        self._bad_reports += refused
        self._count_refused(accepted, refused)

    def _publish(self) -> None:
        """One assignment: the state, its counts and its time are seen together or not at all.
        Only when something changed (a refused report changes the counts, not the state)."""
        last = self.record
        if last.reports == self._reports and last.bad_reports == self._bad_reports:
            return
        at = time.monotonic() if self._reports != last.reports else last.at
        record = ReaderRecord(
            self.decoder.state(),
            self._reports,
            self._bad_reports,
            at,
            self._presses,
            self._press_serial,
            self._refused_in_a_row,
            self._bad_spells,
            self._repeats,
        )
        self.record = record
        # an edge: a new run of bad reports, or the device in error or out of it (which only
        # a change of its refused count can bring); the common publish compares two ints
        edge = record.bad_spells != last.bad_spells or (
            record.refused_in_a_row != last.refused_in_a_row and record.in_error != last.in_error
        )
        if edge and self.on_bad_reports is not None:
            self.on_bad_reports(self, record)

    def pull(self) -> None:
        """Pulled: decode and publish what the device has queued, without blocking (the node
        step's call, before it reads the records: the step reads every report that came
        before it). Not pulled: nothing (the thread reads)."""
        if not self._pulled:
            return
        c_pull = self._c_pull
        if c_pull is not None:
            try:
                pulled = c_pull(
                    self, self.device, time.monotonic(), MAX_BATCH, PRESSES_KEPT, BAD_REPORTS_LIMIT
                )
            except Exception as exc:
                with self._device_lock:
                    self._pull_failed(exc)
                return
            if pulled:
                return
            if pulled is None:  # never compiled for this device: the Python pull from now on
                self._c_pull = None
        with self._device_lock:
            if self._closed or self._pull_error is not None:
                return
            try:
                batch = self._queued()
                if batch:
                    self._drain(batch)
                    self._publish()
            except Exception as exc:
                self._pull_failed(exc)

    def _pull_failed(self, exc: Exception) -> None:
        """The thread reports what a pull met (on_exit), as its own read would (under
        `_device_lock`)."""
        if not self._closed and self._pull_error is None:
            self._pull_error = exc
            self._woken.set()

    def _queue_filled(self, queue_reports: int) -> None:
        """The device's queue (`queue_reports` deep) was full at a pull, whichever thread
        pulled: the thread pulls it too from now on, the first time KEEP_FIRST_S from now."""
        self._queue_reports = queue_reports
        self.keep_every_s = KEEP_FIRST_S
        self._keep_from_now = True
        self._woken.set()

    def _taken(self) -> int:
        record = self.record
        return record.reports + record.bad_reports

    def _keep_queue(self, now: float) -> float:
        """The thread's own pull of a device whose queue fills between steps; how long
        until the next: KEEP_SHARE of the queue at the rate it reported since the last."""
        self.pull()
        taken = self._taken()
        last = self._kept_at
        self._kept_at = (taken, now)
        if last is not None and now > last[1] and taken > last[0]:
            rate = (taken - last[0]) / (now - last[1])
            every = KEEP_SHARE * self._queue_reports / rate
            self.keep_every_s = max(KEEP_MIN_S, min(KEEP_MAX_S, every))
        else:
            self.keep_every_s = KEEP_MAX_S
        return self.keep_every_s

    def stop(self) -> None:
        super().stop()
        self._woken.set()

    # -- outputs -----------------------------------------------------------------------------

    def post_output(self, driver: OutputDriver, state: OutputState) -> None:
        """What the device should show now (the feedback thread's call, never blocks): the
        reader thread writes it, or a newer post, when the rate allows. Ignored when the
        reader is not pulled."""
        if not self._pulled:
            return
        self._output_post = (driver, state)
        self._woken.set()

    @property
    def outputs_written(self) -> int:
        return self.outputs.written

    @property
    def outputs_refused(self) -> int:
        return self.outputs.refused

    def _serve_outputs(self, now: float, flush: bool = False) -> float:
        """Write the newest posted state while one is not shown and the rate allows (flush:
        once, at once: at stop); how long until the next may be (TIMEOUT_MAX: none waits)."""
        wait = self._output_wait(now)
        while wait is not None and (wait <= 0 or flush):
            self._show_post(now)
            if flush:
                return threading.TIMEOUT_MAX
            wait = self._output_wait(now)
        return threading.TIMEOUT_MAX if wait is None else wait

    def _output_wait(self, now: float) -> float | None:
        """None when the newest post is shown (or there is none), else how long until a
        write may show it (<= 0: now)."""
        post = self._output_post
        if post is None or (post[0] is self._shown_by and post[1] == self.outputs.shown):
            return None
        return max(self._output_bucket.wait_s(now), self._output_retry_at - now)

    def _show_post(self, now: float) -> None:
        post = self._output_post
        assert post is not None
        driver, state = post
        shown = self.outputs.shown if driver is self._shown_by else None
        self._output_bucket.take(now)
        written = 0
        try:
            writes = driver.writes(state, shown)
            if writes:
                port = self._output_port
                if port is None:  # opened when first needed: a device never written keeps none
                    port = self._output_port = self.device.open_output()
                for w in writes:
                    port.write(w)
                    written += 1
        except Exception as exc:  # a refusal must never end the reader: its input goes on
            self._output_refused(exc, written, now)
            return
        self._shown_by = driver
        self.outputs = self.outputs._replace(written=self.outputs.written + written, shown=state)

    def _output_refused(self, exc: Exception, written: int, now: float) -> None:
        """Counted always, logged once per device; the port is closed and everything is
        written again at the next try (a partial write leaves the device unknown)."""
        # an OSError's own words, without "[Errno 5]"
        text = (exc.strerror if isinstance(exc, OSError) else None) or str(exc)
        text = text or type(exc).__name__
        if not self._output_refusal_logged:
            self._output_refusal_logged = True
            log.warning(
                "%s: output refused: %s (its input goes on; further refusals are only counted)",
                self.info.path,
                text,
                exc_info=not isinstance(exc, OSError),
            )
        self._close_output_port()
        self._shown_by = None
        self._output_retry_at = now + OUTPUT_RETRY_S
        record = self.outputs
        self.outputs = OutputRecord(record.written + written, record.refused + 1, text, shown=None)

    def _close_output_port(self) -> None:
        port, self._output_port = self._output_port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()

    # -- the thread --------------------------------------------------------------------------

    def _await_pull_failure(self) -> None:
        """Pulled: the thread holds the device until stop() or a failure a pull met, which
        it raises here (run() then ends it as a failed read), writes its outputs, and pulls
        a device whose queue fills between the steps (`keep_every_s`)."""
        timeout = threading.TIMEOUT_MAX
        keep_due = math.inf
        while not self.stopping:
            self._woken.wait(timeout)
            self._woken.clear()  # before the flags are read: a later one wakes it again
            if self.stopping:
                break
            if self._pull_error is not None:
                raise self._pull_error
            now = time.monotonic()
            if self._keep_from_now:  # the queue filled (again): the first pull soon
                self._keep_from_now = False
                self._kept_at = (self._taken(), now)
                keep_due = now + KEEP_FIRST_S
            elif now >= keep_due:
                keep_due = now + self._keep_queue(now)
            timeout = min(self._serve_outputs(now), keep_due - now)

    def _loop(self) -> None:
        if self._pulled:
            self._await_pull_failure()
            return
        while not self.stopping:
            report = self.device.read(self._read_timeout_s)
            if report is not None:
                self._handle(report)
                self._publish()

    def run(self) -> None:
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
            if ended is None and self.stopping:
                self._serve_outputs(time.monotonic(), flush=True)  # the last post, once
            self._close_output_port()
            with self._device_lock, contextlib.suppress(Exception):
                self._closed = True
                self.device.close()
        if ended is not None and not self.stopping:
            self.exit_code = ended[0]
            self._call_on_exit(ended[0])

    def _call_on_exit(self, code: ErrorCode | None) -> None:
        try:
            self._on_exit(self, code)
        except Exception:
            log.exception("%s: on_exit handler failed", self.info.path)
