"""CRSF timing and the RX paths stay within their bounds (issue 19 point 6).

- Following a module's timing corrections, the period between RC frames stays within the
  documented bounds (docs/ICD.md, "CRSF output": 1..100 ms, never below a frame's time on the
  line), however the module's offset pushes: a -0.5 ms offset on a 1 ms interval before every
  frame gave 1596 frames/s, a +50 ms offset on 100 ms gave 7 frames/s.
- What a far end sends is read at most at twice its line's rate (`RxBudget`), and waits for
  the output thread in a bounded queue (`Handoff`): a telemetry flood on a pty no longer stops
  the RC frames (0 for 19.6 s) nor grows the daemon (36 -> 178 MB RSS).

The timing is the session's (sans-IO: the clock is passed in, so the periods are exact); the
flood is black-box: the daemon as a subprocess, the flood on a real pty.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from daemon_harness import PtyLine, StickState, install, recording, run_daemon
from hypothesis import given, settings
from hypothesis import strategies as st
from rc_reference import crsf_frame

from usb2rc.lines.link import BITS_PER_BYTE_ON_WIRE
from usb2rc.lines.rx import Handoff, RxBudget
from usb2rc.protocols.crsf.session import MAX_INTERVAL_S, MIN_INTERVAL_S, CrsfModule

WAIT_S = 20.0
EPS = 1e-9  # the periods are differences of float deadlines
LINE_FRAME_S = 26 * BITS_PER_BYTE_ON_WIRE / 400000  # an RC frame at the default 400000 baud


def timing_correction(interval_us: float, offset_us: float) -> bytes:
    """An ELRS module's RADIO_ID timing correction, from the description (0.1 µs units)."""
    payload = bytes([0xEA, 0xEE, 0x10]) + struct.pack(
        ">Ii", round(interval_us * 10), round(offset_us * 10)
    )
    return crsf_frame(0xEA, 0x3A, payload)


def periods_followed(module: CrsfModule, corrections: list[bytes]) -> list[float]:
    """The module sends a correction before every frame; the periods the session sets."""
    due = 0.0
    periods = []
    for correction in corrections:
        module.received(correction, due)
        next_due = module.next_send(due, due)
        periods.append(next_due - due)
        due = next_due
    return periods


def test_a_negative_offset_before_every_frame_never_sends_faster_than_the_bounds():
    module = CrsfModule(0.004, min_interval_s=LINE_FRAME_S)
    periods = periods_followed(module, [timing_correction(1000, -500)] * 1000)
    assert min(periods) >= max(MIN_INTERVAL_S, LINE_FRAME_S) - EPS  # was 0.5 ms: 1596/s
    assert sum(periods) >= 1.0 - EPS  # 1000 frames take at least a second


def test_a_positive_offset_before_every_frame_never_sends_slower_than_the_bounds():
    module = CrsfModule(0.004, min_interval_s=LINE_FRAME_S)
    periods = periods_followed(module, [timing_correction(100_000, 50_000)] * 100)
    assert max(periods) <= MAX_INTERVAL_S + EPS  # was 150 ms: 7 frames/s


def test_a_line_slower_than_the_module_bounds_the_period_by_the_frame_time():
    frame_s = 26 * BITS_PER_BYTE_ON_WIRE / 115200  # 2.26 ms at 115200 baud
    module = CrsfModule(0.01, min_interval_s=frame_s)
    periods = periods_followed(module, [timing_correction(1000, -500)] * 50)
    assert min(periods) >= frame_s - EPS


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 200_000), st.integers(-200_000, 200_000)),
        min_size=1,
        max_size=40,
    ),
    st.sampled_from([115200, 400000, 921600, 5250000]),
)
def test_whatever_the_module_says_the_period_stays_within_the_bounds(corrections, baudrate):
    frame_s = 26 * BITS_PER_BYTE_ON_WIRE / baudrate
    module = CrsfModule(0.004, min_interval_s=frame_s)
    frames = [timing_correction(interval, offset) for interval, offset in corrections]
    for period in periods_followed(module, frames):
        assert period == pytest.approx(0.004) or (
            max(MIN_INTERVAL_S, frame_s) - EPS <= period <= MAX_INTERVAL_S + EPS
        )


def test_the_rx_budget_takes_twice_the_line_rate_and_counts_the_rest():
    budget = RxBudget(400000)  # 40000 bytes/s on the line: 80000 taken, 8000 at once
    assert budget.bytes_per_s == 80000 and budget.burst == 8000
    start = time.monotonic()
    taken = sum(len(budget.admit(bytes(4096), start)) for _ in range(100))
    assert taken == 4096 and budget.dropped_bytes == 99 * 4096  # whole reads: one fits
    assert budget.admit(bytes(4096), start + 0.002) == b""  # 3904 + 160 bytes of budget
    assert len(budget.admit(bytes(4096), start + 0.01)) == 4096  # 3904 + 800: it fits
    assert len(budget.admit(bytes(9000), start + 1.0)) == 8000  # longer than the burst: cut


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 4096), st.floats(0, 0.05)), max_size=200))
def test_the_rx_budget_takes_whole_reads_within_its_rate(reads: list[tuple[int, float]]):
    """Whatever the reads' sizes and timing: each read is taken whole or not at all (so what
    is taken decodes as the far end sent it), never more than the rate and one burst."""
    budget = RxBudget(115200, now=0.0)
    now, taken, offered = 0.0, 0, 0
    for size, gap in reads:
        now += gap
        data = bytes(size)
        got = budget.admit(data, now)
        assert got in (b"", data)
        taken += len(got)
        offered += size
    assert taken <= budget.burst + now * budget.bytes_per_s + 1e-6
    assert budget.dropped_bytes == offered - taken


def test_a_handoff_holds_at_most_its_cap_and_counts_the_rest():
    handoff: Handoff[int] = Handoff(3)
    for item in range(10):
        handoff.put(item)
    assert handoff.take_all() == [0, 1, 2] and handoff.dropped == 7
    assert handoff.take_all() == []


# --- black box: a telemetry flood on the module's pty ------------------------------------

FLOOD_MAX_BYTES = 64 * 1024 * 1024
RC_FRAMES_MEANWHILE = 50  # 0.2 s of frames at 250 Hz
LINK_STATISTICS = crsf_frame(0xEA, 0x14, bytes([40, 42, 100, 10, 0, 6, 3, 50, 99, 8]))


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


class ModuleLine(PtyLine):
    def __init__(self) -> None:
        super().__init__("crsf")

    def send_some(self, data: bytes) -> int:
        return os.write(self.master, data)


@dataclass
class Flood:
    """Valid LINK_STATISTICS frames, as fast as the daemon's side takes them, until `enough`
    RC frames came meanwhile or FLOOD_MAX_BYTES went (before the fix: 3 RC frames in 32 MB)."""

    line: ModuleLine
    started: float
    sent: int = 0

    def run(self) -> None:
        chunk = LINK_STATISTICS * (65536 // len(LINK_STATISTICS))
        while self.sent < FLOOD_MAX_BYTES and not self.enough():
            self.sent += self.line.send_some(chunk)

    def enough(self) -> bool:
        return rc_frames_since(self.line, self.started) >= RC_FRAMES_MEANWHILE


def rc_frames_since(line: PtyLine, since: float) -> int:
    return sum(1 for s in line.seen_now() if s.time >= since and s.frame.type == 0x16)


def test_a_telemetry_flood_never_stops_the_rc_frames_nor_grows_the_daemon(
    tmp_path: Path, replay_dir
):
    module = ModuleLine()
    install(replay_dir / "a.hid", recording([StickState(), StickState(x=3000)]))
    path = tmp_path / "crsf.yaml"
    path.write_text(
        f"outputs:\n  - {{protocol: crsf, port: {module.path}, channels: [node0.x]}}\n"
        "devices:\n  - {name: a, match: {port: replay-a}, node_id: 0}\n"
    )
    daemon = run_daemon(
        tmp_path, module.path, replay_dir, "--config", str(path), "--stats-format", "json"
    )
    try:
        module.wait_for(lambda frames: len(frames) >= 50, WAIT_S)
        rss_before = rss_kib(daemon.proc.pid)
        flood = Flood(module, time.monotonic())
        writer = threading.Thread(target=flood.run)
        writer.start()
        writer.join(2 * WAIT_S)
        assert not writer.is_alive(), "the daemon stopped reading the flood"
        ended = time.monotonic()
        assert flood.enough(), f"{rc_frames_since(module, flood.started)} RC frames in the flood"
        # RC frames right after it (before: none for 19.6 s, the output thread decoding)
        module.wait_seen(lambda _: rc_frames_since(module, ended) >= 25, 10.0)
        rss_growth_kib = rss_kib(daemon.proc.pid) - rss_before
        assert rss_growth_kib < 16 * 1024, f"RSS grew {rss_growth_kib} KiB"  # before: 140 MB
        daemon.signal(signal.SIGUSR1)
        deadline = time.monotonic() + WAIT_S
        while not (records := stats_records(daemon.log())):
            assert time.monotonic() < deadline, daemon.log()[-3000:]
            time.sleep(0.05)
    finally:
        daemon.stop()
        module.close()
    (crsf,) = records[-1]["outputs"]
    assert crsf["rx_dropped_bytes"] > 0  # the flood's excess, counted, and said once
    assert daemon.log().count("sends faster than 400000 baud carries") == 1
    assert crsf["module_rx_frames"] > 0  # what the budget took was decoded
    print(
        f"flood {flood.sent} B in {ended - flood.started:.2f} s: {RC_FRAMES_MEANWHILE} RC frames, "
        f"RSS +{rss_growth_kib} KiB, {crsf['rx_dropped_bytes']} B dropped"
    )


def stats_records(text: str) -> list[dict]:
    return [json.loads(line)["stats"] for line in text.splitlines() if line.startswith('{"stats"')]
