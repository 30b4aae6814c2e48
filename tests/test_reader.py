"""DeviceReader over replayed devices: every report in order, one on_exit, device closed."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from daemon_harness import StickState, recording
from output_fakes import RecordingPort
from test_replay import numbered, recording_text

from usb2rc.hid.backend import DeviceInfo, ErrorCode, OutputPort
from usb2rc.hid.descriptor import InputState, parse_descriptor
from usb2rc.hid.reader import DeviceReader
from usb2rc.hid.replay import ReplayBackend, install_file

WAIT_S = 10.0


class RecordingDecoder:
    """Keeps every report; refuses the report b"BAD"."""

    def __init__(self) -> None:
        self.reports: list[bytes] = []
        self.refused = threading.Event()

    def feed(self, report: bytes) -> bool:
        if report == b"BAD":
            self.refused.set()
            return False
        self.reports.append(report)
        return True

    def feed_batch(self, reports: list[bytes], on_buttons: object = None) -> tuple[int, int]:
        accepted = sum(self.feed(r) for r in reports)
        return accepted, len(reports) - accepted

    def state(self) -> InputState:
        return InputState((len(self.reports),), 0)


class Exits:
    def __init__(self) -> None:
        self.calls: list[ErrorCode | None] = []
        self.event = threading.Event()

    def __call__(self, reader: DeviceReader, code: ErrorCode | None) -> None:
        self.calls.append(code)
        self.event.set()


class CloseSpy:
    def __init__(self, device) -> None:
        self.device = device
        self.info: DeviceInfo = device.info
        self.closed = threading.Event()

    def report_descriptor(self) -> bytes:
        return self.device.report_descriptor()

    def read(self, timeout_s: float) -> bytes | None:
        return self.device.read(timeout_s)

    def open_output(self) -> OutputPort:
        return self.device.open_output()

    def close(self) -> None:
        self.device.close()
        self.closed.set()


def start_reader(directory: Path, **kw) -> tuple[DeviceReader, RecordingDecoder, Exits, CloseSpy]:
    backend = ReplayBackend(directory, **kw)
    device = CloseSpy(backend.open(backend.enumerate()[0]))
    decoder, exits = RecordingDecoder(), Exits()
    reader = DeviceReader(device, decoder, exits)
    reader.start()
    return reader, decoder, exits, device


def test_every_report_in_order_then_one_exit_on_unplug(tmp_path: Path) -> None:
    events = [*numbered(300, step=0.0005), (0.2, b"BAD")]
    path = install_file(tmp_path / "s.hid", recording_text(events))
    reader, decoder, exits, device = start_reader(tmp_path)
    assert decoder.refused.wait(WAIT_S)  # the last report reached the decoder
    path.unlink()
    assert exits.event.wait(WAIT_S)
    reader.join(WAIT_S)
    assert not reader.is_alive()
    assert exits.calls == [None]
    assert device.closed.is_set()
    assert decoder.reports == [r for _, r in events[:-1]]
    assert (reader.reports, reader.bad_reports) == (300, 1)
    assert reader.snapshot == InputState((300,), 0)
    assert reader.last_report_monotonic is not None


def test_fault_line_ends_with_read_failed(tmp_path: Path) -> None:
    install_file(tmp_path / "f.hid", recording_text(numbered(10, 0.001), fault_at=0.02))
    reader, decoder, exits, device = start_reader(tmp_path)
    assert exits.event.wait(WAIT_S)
    reader.join(WAIT_S)
    assert exits.calls == [ErrorCode.READ_FAILED]
    assert reader.exit_code == ErrorCode.READ_FAILED
    assert len(decoder.reports) == 10
    assert device.closed.is_set()


def test_stop_ends_without_on_exit_and_closes(tmp_path: Path) -> None:
    install_file(tmp_path / "s.hid", recording_text(numbered(1)))
    reader, _, exits, device = start_reader(tmp_path)
    reader.stop()
    reader.join(WAIT_S)
    assert not reader.is_alive()
    assert exits.calls == []
    assert device.closed.is_set()


def test_on_exit_may_join_its_own_reader(tmp_path: Path) -> None:
    path = install_file(tmp_path / "s.hid", recording_text([]))
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    joined = threading.Event()

    def on_exit(reader: DeviceReader, code: ErrorCode | None) -> None:
        reader.join()  # from inside the reader thread: must not raise or hang
        joined.set()

    reader = DeviceReader(device, RecordingDecoder(), on_exit)
    reader.start()
    path.unlink()
    assert joined.wait(WAIT_S)
    reader.join(WAIT_S)


class Exploding:
    def __init__(self, info: DeviceInfo) -> None:
        self.info = info
        self.closed = False

    def report_descriptor(self) -> bytes:
        return b""

    def read(self, timeout_s: float) -> bytes | None:
        raise ValueError("not an OSError: a bug in a backend")

    def open_output(self) -> RecordingPort:
        return RecordingPort()

    def close(self) -> None:
        self.closed = True


def test_unexpected_exception_still_reports_read_failed() -> None:
    device = Exploding(DeviceInfo(key="k", path="p", vid=1, pid=2))
    exits = Exits()
    reader = DeviceReader(device, RecordingDecoder(), exits)
    reader.start()
    assert exits.event.wait(WAIT_S)
    reader.join(WAIT_S)
    assert exits.calls == [ErrorCode.READ_FAILED]
    assert device.closed


class OneReport:
    """A device with one report queued, then nothing (polls return None at once)."""

    def __init__(self, report: bytes) -> None:
        self.info = DeviceInfo(key="k", path="k", vid=1, pid=2)
        self._queue = [report]

    def report_descriptor(self) -> bytes:
        return b""

    def read(self, timeout_s: float) -> bytes | None:
        return self._queue.pop() if self._queue else None

    def open_output(self) -> RecordingPort:
        return RecordingPort()

    def close(self) -> None:
        pass


class StateGate(RecordingDecoder):
    """Holds the reader thread between "the report is counted" and "its state is built"."""

    def __init__(self) -> None:
        super().__init__()
        self.inside = threading.Event()
        self.release = threading.Event()

    def state(self) -> InputState:
        if self.reports:
            self.inside.set()
            assert self.release.wait(WAIT_S)
        return super().state()


def test_the_count_and_the_state_are_published_together() -> None:
    """Forced interleaving: the reader has decoded a report and is building its state. A
    table reading the reader now must see the old record whole (0 reports, not live), never
    the new count with the initial, mid-scale state."""
    decoder = StateGate()
    reader = DeviceReader(OneReport(b"R1"), decoder, Exits(), read_timeout_s=0.01)
    reader.start()
    try:
        assert decoder.inside.wait(WAIT_S)
        seen = reader.record
        assert (seen.reports, seen.state) == (0, InputState((0,), 0))
        decoder.release.set()
    finally:
        decoder.release.set()
        reader.stop()
        reader.join(WAIT_S)
    assert (reader.record.reports, reader.record.state) == (1, InputState((1,), 0))


def test_a_pulled_reader_counts_every_report_and_shows_the_last(tmp_path: Path) -> None:
    """Pulled, the reader drains what is queued as one batch at each pull (decoding only what
    shows in the state): every report is counted, and the state is the last report's."""
    states = [StickState(x=i * 50, y=16383 - i * 50, buttons=i) for i in range(200)]
    install_file(tmp_path / "s.hid", recording(states, hold_s=0.0002, rest_s=0))  # 200 in 40 ms
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    layout = parse_descriptor(device.report_descriptor())
    reader = DeviceReader(device, layout.make_decoder(), Exits(), pulled=True)
    reader.start()
    pulls = 0
    try:
        deadline = time.monotonic() + WAIT_S
        while reader.record.reports < len(states) and time.monotonic() < deadline:
            time.sleep(0.004)  # a node step's period: the pulls' pace, not a wait for a result
            reader.pull()
            pulls += 1
    finally:
        reader.stop()
        reader.join(WAIT_S)
    expected = layout.make_decoder()
    for state in states:
        expected.feed(state.report())
    assert (reader.record.reports, reader.record.bad_reports) == (len(states), 0)
    assert reader.record.state == expected.state()
    assert 0 < pulls < len(states)  # drained in batches, far fewer than reports came
