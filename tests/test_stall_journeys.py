"""Issue 19, point 4: after a far-end stall no stale frame reaches the receiver.

The journey: the real daemon (a subprocess) with five outputs on five ptys, C2-16B, SUMD,
CRSF, SBUS and MAVLink, fed by one replayed stick whose X axis ramps with time, so the age
of any frame can be read from its value. Every far end reads, then stops reading for
`STALL_S`, then reads again; each frame that arrives after the resume must be at most one
tick (+ `TOLERANCE_S`) old, except what the far end's own line discipline held
(`PTY_FAR_END_BUFFER`: only the reader can drop that, see `test_what_a_pty_flush_drops`).
C2-16B is held to its own, weaker bound (docs/ICD.md, "A stalled line").

The ages are measured from outside: values are decoded with the tests' reference readers
(SUMD with usb2rc's codec, whose own tests pin it to the spec), and the offset between the
ramp's clock and the reader's is calibrated on the frames that arrived before the stall.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import statistics
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import DECODERS, PtyLine, StickState, install, run_daemon, timed_recording

from usb2rc.lines.serial_link import SOCKET_SEND_BUFFER
from usb2rc.protocols.c2_16b import codec as c2_16b

REST_S = 0.5  # the stick rests first: the neutral guard arms on a stick at rest
RAMP_S = 20.0  # then X ramps from 0 to 16383 in this long, a report every EVENT_S
EVENT_S = 0.01  # a report every 10 ms
STALL_S = 4.0  # the far ends do not read for this long (the scenario itself)
# value steps (MAVLink: 20 ms), report spacing, and this test reader's own scheduling on a
# loaded 2-core machine (seen: 0.32 s while two suites ran); stale frames were 2-3.4 s old
TOLERANCE_S = 1.0
# What the far end's own N_TTY line discipline holds: the writer cannot drop it (measured in
# test_what_a_pty_flush_drops); it holds the first bytes written after the far end stopped.
PTY_FAR_END_BUFFER = 4095
CRSF_RC_FRAME_LEN = 26  # address, length, type, 22 channel bytes, CRC
PTY_KERNEL_QUEUE = 16384  # at least what the kernel queues on the writer's side of a pty
PTY_KERNEL_QUEUE_MAX = 16896  # ... and at most (measured: Linux 6.x, 256-byte writes)


@dataclass(frozen=True)
class Protocol:
    """How one protocol's far end reads channel 1 (node 0's X) off a decoded frame."""

    config: str  # the output's config line, with {port}
    rate_hz: float
    value: Callable[[Any], int | None]  # channel 1 of a live frame, else None
    low: int  # channel 1 at X = 0 and at X = 16383
    high: int

    def ramp_time(self, value: int) -> float:
        """When (in the recording) X had the value this wire value carries."""
        return REST_S + (value - self.low) / (self.high - self.low) * RAMP_S


def _c2_value(frame: Any) -> int | None:
    if isinstance(frame, c2_16b.DataFrame) and frame.node_id == 0 and frame.status == ord(">"):
        return frame.axes[0]
    return None


def _sumd_value(frame: Any) -> int | None:
    return None if frame.failsafe else int(frame.channels[0])


def _crsf_value(frame: Any) -> int | None:
    return int(frame.channels[0]) if frame.type == 0x16 else None


def _sbus_value(frame: Any) -> int | None:
    return None if frame.failsafe or frame.frame_lost else int(frame.channels[0])


def _mavlink_value(message: Any) -> int | None:
    if message.get_type() != "RC_CHANNELS_OVERRIDE" or not 1000 <= message.chan1_raw <= 2000:
        return None  # the stop's override releases the channels (0): no value
    return int(message.chan1_raw)


LISTED = "[node0.x, node0.y]"
PROTOCOLS: dict[str, Protocol] = {
    "c2-16b": Protocol("{{protocol: c2-16b, port: {port}}}", 50, _c2_value, -32768, 32767),
    "sumd": Protocol(  # the default channels: 8, so 21-byte frames
        "{{protocol: sumd, port: {port}}}",
        100,
        _sumd_value,
        0x2260,
        0x3B60,
    ),
    "crsf": Protocol(
        "{{protocol: crsf, port: {port}, channels: " + LISTED + "}}", 250, _crsf_value, 172, 1811
    ),
    "sbus": Protocol(
        "{{protocol: sbus, port: {port}, channels: " + LISTED + "}}", 100, _sbus_value, 172, 1811
    ),
    "mavlink": Protocol(
        "{{protocol: mavlink, port: {port}, channels: " + LISTED + "}}",
        50,
        _mavlink_value,
        1000,
        2000,
    ),
}


def ramp_recording() -> str:
    events: list[tuple[float, StickState]] = [(0.0, StickState()), (REST_S / 2, StickState())]
    steps = int(RAMP_S / EVENT_S)
    for step in range(steps + 1):
        events.append((REST_S + step * EVENT_S, StickState(x=round(16383 * step / steps))))
    return timed_recording(events)


# --- the far end ------------------------------------------------------------------------


@dataclass
class Read:
    time: float
    data: bytes


class RecordingLine(PtyLine):
    """A pty far end that keeps every read with its time and can stop reading."""

    def __init__(self, protocol: str) -> None:
        self.protocol = protocol
        self.reads: list[Read] = []
        self.reading = threading.Event()
        self.reading.set()
        self.resumed_at_read = 0
        super().__init__(protocol)

    def _run(self) -> None:
        tty.setraw(self.master)  # as a receiver reads a serial port: no line editing
        super()._run()

    def _reading(self) -> bool:
        return self.reading.wait(0.05)

    def _received(self, now: float, data: bytes, frames: list[Any]) -> None:
        self.reads.append(Read(now, data))
        super()._received(now, data, frames)

    def stall(self) -> None:
        self.reading.clear()

    def resume(self) -> float:
        with self._cond:
            self.resumed_at_read = len(self.reads)
        self.reading.set()
        return time.monotonic()


@dataclass
class Ages:
    """What a far end read after the resume: frames inside its own buffer, frames after."""

    in_far_end_buffer: int
    fresh_frames: int
    oldest_s: float  # the oldest frame after the far end's buffer
    oldest_overall_s: float
    stale_frames: int  # after the far end's buffer: frames older than a tick + TOLERANCE_S


def frame_ages(
    line: RecordingLine, protocol: Protocol, far_end_buffer: int = PTY_FAR_END_BUFFER
) -> Ages:
    """Decode the bytes again, in order, each read with its time; the clock offset is the
    median of arrival minus ramp time over the live frames read before the stall."""
    decoder = DECODERS.get(line.protocol, c2_16b.Decoder)()
    with line._cond:
        reads, resumed_at = list(line.reads), line.resumed_at_read
    offsets = []
    at_rest: int | None = None  # the centre, before the ramp starts at X = 0
    for read in reads[:resumed_at]:
        for value in map(protocol.value, decoder.feed(read.data)):
            if value is None or at_rest in (None, value):
                at_rest = value if at_rest is None else at_rest
                continue
            at_rest = -1  # the ramp started: every value from now on is on it
            offsets.append(read.time - protocol.ramp_time(value))
    assert len(offsets) > 20, f"{line.protocol}: the ramp was not seen before the stall"
    offset = statistics.median(offsets)
    after = b"".join(r.data for r in reads[resumed_at:])
    buffered = decoder.feed(after[:far_end_buffer])
    buffered_ages = [
        reads[resumed_at].time - offset - protocol.ramp_time(v)
        for v in map(protocol.value, buffered)
        if v is not None
    ]
    ages: list[float] = []
    position = 0
    for read in reads[resumed_at:]:
        start, position = position, position + len(read.data)
        chunk = read.data[max(0, far_end_buffer - start) :]
        for frame in decoder.feed(chunk) if chunk else []:
            value = protocol.value(frame)
            if value is not None:
                ages.append(read.time - offset - protocol.ramp_time(value))
    assert ages, f"{line.protocol}: nothing fresh after the resume"
    stale = sum(age > 1 / protocol.rate_hz + TOLERANCE_S for age in ages)
    return Ages(len(buffered), len(ages), max(ages), max([*ages, *buffered_ages]), stale)


# --- the journey ------------------------------------------------------------------------


def five_outputs(tmp_path: Path, lines: dict[str, RecordingLine]) -> Path:
    config = tmp_path / "five.yaml"
    outputs = [PROTOCOLS[name].config.format(port=line.path) for name, line in lines.items()]
    config.write_text("outputs:\n" + "".join(f"  - {o}\n" for o in outputs))
    return config


def on_ramp(line: RecordingLine, protocol: Protocol) -> Callable[[list[Any]], bool]:
    def seen(frames: list[Any]) -> bool:
        values = [v for v in map(protocol.value, frames) if v is not None]
        started = (protocol.high - protocol.low) * 0.1 + protocol.low  # the ramp starts at 0
        first = next((i for i, v in enumerate(values) if v < started), len(values))
        return len(values) - first > 50  # enough frames on the ramp to calibrate the clock

    return seen


@pytest.mark.slow  # a long journey: the fast suite keeps shorter ones of its kind
def test_no_stale_frame_reaches_a_pty_receiver_after_a_stall(
    tmp_path: Path, replay_dir: Path, record_property: Callable[[str, Any], None]
) -> None:
    lines = {name: RecordingLine(protocol=name) for name in PROTOCOLS}
    config = five_outputs(tmp_path, lines)
    daemon = run_daemon(tmp_path, lines["c2-16b"].path, replay_dir, "--config", str(config))
    try:
        install(replay_dir / "ramp.hid", ramp_recording())
        for name, line in lines.items():
            line.wait_for(on_ramp(line, PROTOCOLS[name]), timeout=15)
        for line in lines.values():
            line.stall()
        time.sleep(STALL_S)  # the far ends' stall: the scenario itself
        for line in lines.values():
            line.resume()
        for line in lines.values():  # a second of fresh frames after the resume
            done = time.monotonic() + 1.0
            line.wait_seen(lambda seen, done=done: seen and seen[-1].time > done, timeout=10)
    finally:
        assert daemon.stop() == 0
        for line in lines.values():
            line.close()
    assert "Traceback" not in daemon.log()
    results = {name: frame_ages(line, PROTOCOLS[name]) for name, line in lines.items()}
    for name, ages in results.items():
        record_property(f"{name}_oldest_s", round(ages.oldest_s, 3))
        print(f"{name}: {ages}")
    for name in ("sumd", "crsf", "sbus", "mavlink"):
        bound = 1 / PROTOCOLS[name].rate_hz + TOLERANCE_S
        assert results[name].oldest_s <= bound, (name, results[name])
    # C2-16B's own bound (docs/ICD.md): at most what the pty holds, as old as the stall
    c2_stale_bytes = results["c2-16b"].stale_frames * (c2_16b.FRAME_LEN + 1)
    record_property("c2_stale_bytes", c2_stale_bytes)
    assert c2_stale_bytes <= PTY_KERNEL_QUEUE_MAX, results["c2-16b"]


# --- what a pty flush can drop ------------------------------------------------------------


def fill(fd: int) -> int:
    """Write until the kernel takes no more; how many bytes it took. The kernel hands what
    it queued to the far end's line discipline in the background: the pty is full once it
    stays unwritable."""
    os.set_blocking(fd, False)
    taken = 0
    while select.select([], [fd], [], 0.2)[1]:
        with contextlib.suppress(BlockingIOError):
            while True:
                taken += os.write(fd, bytes(256))
    return taken


def read_all(fd: int) -> int:
    got = 0
    while select.select([fd], [], [], 0.2)[0]:
        got += len(os.read(fd, 65536))
    return got


def test_what_a_pty_flush_drops() -> None:
    """The experiment behind the design (docs/ICD.md, "A stalled line"): usb2rc writes on
    the slave and the far end reads the master. TCOFLUSH on the slave drops the kernel's
    queue on the writer's side; what the far end's line discipline holds (4095 bytes in
    raw mode) survives. TCIFLUSH on the slave drops nothing of it (that is the slave's own
    input)."""
    master, slave = os.openpty()
    try:
        tty.setraw(master)
        tty.setraw(slave)
        written = fill(slave)
        assert written >= PTY_FAR_END_BUFFER + PTY_KERNEL_QUEUE
        termios.tcflush(slave, termios.TCIFLUSH)
        assert fill(slave) == 0  # nothing was dropped: still full
        termios.tcflush(slave, termios.TCOFLUSH)
        assert read_all(master) == PTY_FAR_END_BUFFER  # all but the far end's buffer went
    finally:
        os.close(master)
        os.close(slave)


def test_a_dropped_pty_queue_takes_bytes_at_once() -> None:
    """After the flush the writer's side is empty although the far end still does not
    read: being writable again does not mean the far end drained (why a stalled line
    resumes on writability only where nothing was flushed, docs/ICD.md)."""
    master, slave = os.openpty()
    try:
        tty.setraw(master)
        fill(slave)
        assert not select.select([], [slave], [], 0)[1]
        termios.tcflush(slave, termios.TCOFLUSH)
        assert select.select([], [slave], [], 0)[1]
    finally:
        os.close(master)
        os.close(slave)


# --- socket://: what cannot be flushed is bounded by the buffers --------------------------


class TcpFarEnd(RecordingLine):
    """A TCP bridge that reads what usb2rc sends to `socket://`, can stop reading, and
    keeps its own receive buffer at `SOCKET_SEND_BUFFER` (as usb2rc keeps its send buffer)."""

    def __init__(self, protocol: str) -> None:
        self.server = socket.socket()
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SOCKET_SEND_BUFFER)
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.conn: socket.socket | None = None
        super().__init__(protocol)
        self.pty_master = self.master  # the pty PtyLine opened: unused here

    def _run(self) -> None:
        self.server.settimeout(10)
        self.conn, _ = self.server.accept()
        self.master = self.conn.fileno()  # PtyLine's loop reads it as it reads a pty master
        PtyLine._run(self)

    def close(self) -> None:
        super().close()  # closes the socket's fd as `master`
        os.close(self.pty_master)
        if self.conn is not None:
            self.conn.detach()
        self.server.close()


def test_a_stalled_socket_delivers_no_more_than_its_buffers_hold(
    tmp_path: Path, replay_dir: Path, record_property: Callable[[str, Any], None]
) -> None:
    """docs/ICD.md, "A stalled line": a `socket://` line cannot be flushed, so what was
    queued when the far end stopped reading arrives after it, as old as the stall; how much
    is bounded by usb2rc's send buffer (`SOCKET_SEND_BUFFER`, which Linux doubles) plus the
    far end's receive buffer (here the same, doubled too)."""
    crsf = PROTOCOLS["crsf"]
    far_end = TcpFarEnd("crsf")
    config = tmp_path / "tcp.yaml"
    config.write_text("outputs:\n  - " + crsf.config.format(port=far_end.url) + "\n")
    daemon = run_daemon(tmp_path, far_end.url, replay_dir, "--config", str(config))
    try:
        install(replay_dir / "ramp.hid", ramp_recording())
        far_end.wait_for(on_ramp(far_end, crsf), timeout=15)
        far_end.stall()
        time.sleep(STALL_S)  # the bridge's stall: longer than its buffers take to fill
        far_end.resume()
        done = time.monotonic() + 1.0
        far_end.wait_seen(lambda seen: seen and seen[-1].time > done, timeout=10)
    finally:
        assert daemon.stop() == 0
        far_end.close()
    ages = frame_ages(far_end, crsf, far_end_buffer=0)
    bound_bytes = 2 * SOCKET_SEND_BUFFER + 2 * SOCKET_SEND_BUFFER
    stale_bytes = ages.stale_frames * CRSF_RC_FRAME_LEN
    record_property("socket_stale_bytes", stale_bytes)
    print(f"socket:// crsf: {ages}, {stale_bytes} stale bytes, bound {bound_bytes}")
    assert STALL_S * crsf.rate_hz * CRSF_RC_FRAME_LEN > bound_bytes  # the buffers filled
    assert 0 < stale_bytes <= bound_bytes, ages
