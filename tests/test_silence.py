"""A device that falls silent fails safe (usb2rc.nodes.silence, docs/ICD.md "A device that
falls silent"): black-box on a C2-16B pty, and the rule against hand-made records."""

from __future__ import annotations

from pathlib import Path

from daemon_harness import (
    DaemonProcess,
    PtyLine,
    Seen,
    StickState,
    install,
    timed_recording,
)

from usb2rc.hid.descriptor import InputState
from usb2rc.hid.reader import ReaderRecord
from usb2rc.nodes.silence import MIN_SILENCE_S, STREAMING_AFTER, SilenceWatch
from usb2rc.protocols.c2_16b import codec as c2

LIVE, FAILSAFE = 0x3E, 0x21
MARK = 8192 + 300  # the x the pad holds in its last 0.1 s before it falls silent


def node0(seen: list[Seen]) -> list[Seen]:
    return [s for s in seen if isinstance(s.frame, c2.DataFrame) and s.frame.node_id == 0]


def start(tmp_path: Path, replay_dir: Path, line: PtyLine) -> DaemonProcess:
    args = ["--replay", str(replay_dir), "--port", line.path, "--status-socket", "off"]
    return DaemonProcess(args, tmp_path / "daemon.log")


def test_a_pad_streaming_at_250_hz_that_stops_fails_safe_within_half_a_second(
    tmp_path: Path, replay_dir: Path
) -> None:
    """Reports every 4 ms (the same report at rest: it streams), its last 0.1 s with X
    moved a little, then none for 2 s, then at rest again: `!` within 0.5 s of the stop,
    a `3` with 0x07 (SILENT), and `>` again once it reports and rests."""
    line = PtyLine()
    events = [(i * 0.004, StickState()) for i in range(int(1.9 / 0.004))]
    events += [(1.9 + i * 0.004, StickState(x=MARK)) for i in range(25)]
    events += [(4.0 + i * 0.004, StickState()) for i in range(int(3.0 / 0.004))]
    daemon = start(tmp_path, replay_dir, line)
    try:
        install(replay_dir / "pad.hid", timed_recording(events))
        moved = line.wait_seen(
            lambda seen: next(
                (s for s in node0(seen) if s.frame.status == LIVE and s.frame.axes[0] > 100), None
            ),
            timeout=30,
        )
        bang = line.wait_seen(
            lambda seen: next(
                (s for s in node0(seen) if s.time > moved.time and s.frame.status == FAILSAFE), None
            ),
            timeout=30,
        )
        assert bang.time - moved.time <= 0.1 + 0.5  # its last reports, then at most 0.5 s
        line.wait_seen(
            lambda seen: any(
                isinstance(s.frame, c2.ServiceFrame)
                and s.frame.service == c2.Service.ERROR
                and s.frame.payload[0] == 0x07
                for s in seen
            ),
            timeout=10,
        )
        line.wait_seen(
            lambda seen: any(s.time > bang.time and s.frame.status == LIVE for s in node0(seen)),
            timeout=30,
        )
        log = daemon.log()
        assert "went silent" in log and "reports again" in log
    finally:
        daemon.stop()
        line.close()


def test_a_device_that_reports_only_on_change_and_rests_for_10_s_stays_live(
    tmp_path: Path, replay_dir: Path
) -> None:
    """Every report differs from the one before (a stick moved slowly, 50 reports a second
    for 0.6 s), then it rests 10 s sending nothing: never judged by silence."""
    line = PtyLine()
    events = [(i * 0.02, StickState(x=8192 + i)) for i in range(30)]
    daemon = start(tmp_path, replay_dir, line)
    try:
        install(replay_dir / "stick.hid", timed_recording(events))
        first = line.wait_seen(
            lambda seen: next((s for s in node0(seen) if s.frame.status == LIVE), None), timeout=30
        )
        line.wait_seen(lambda seen: seen[-1].time > first.time + 10.6, timeout=40)
        after = [s for s in node0(line.seen_now()) if s.time > first.time]
        assert after and all(s.frame.status == LIVE for s in after)
        assert "went silent" not in daemon.log()
    finally:
        daemon.stop()
        line.close()


def record(reports: int, at: float, repeats: int) -> ReaderRecord:
    return ReaderRecord(InputState((0,), 0), reports, 0, at, repeats=repeats)


def test_the_watch_learns_streaming_from_repeated_reports_only() -> None:
    watch = SilenceWatch()
    assert not watch.silent(record(100, 1.0, STREAMING_AFTER - 1), 5.0)  # not learned yet
    late = 1.0 + MIN_SILENCE_S + 0.01
    assert not watch.silent(record(101, 1.0, STREAMING_AFTER), late)  # this step's reports
    assert watch.silent(record(101, 1.0, STREAMING_AFTER), late)  # none since: silent
    on_change = SilenceWatch(kind="on_change")
    assert not on_change.silent(record(100, 1.0, 10_000), 100.0)
    told = SilenceWatch(kind="streaming")
    told.silent(record(1, 1.0, 0), 1.0)
    assert told.silent(record(1, 1.0, 0), 1.0 + MIN_SILENCE_S + 0.01)


def test_the_limit_is_ten_usual_intervals_and_at_least_100_ms() -> None:
    watch = SilenceWatch(kind="streaming")
    watch.silent(record(1, 0.0, 0), 0.0)
    watch.silent(record(1 + 50, 1.0, 0), 1.0)  # 50 reports in 1 s: every 20 ms
    assert watch.limit_s() == 0.2
    fast = SilenceWatch(kind="streaming")
    fast.silent(record(1, 0.0, 0), 0.0)
    fast.silent(record(1001, 1.0, 0), 1.0)  # 1 kHz: 10 intervals are 10 ms
    assert fast.limit_s() == MIN_SILENCE_S
