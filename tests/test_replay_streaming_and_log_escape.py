"""Issue 19 point 12, through the real daemon: a device-chosen name with ESC/BEL is escaped
in the daemon's log (usb2rc/runtime/log_escape.py), and a large replayed recording is streamed
from its file, not held (usb2rc/hid/replay.py): the daemon's peak RSS replaying a 20 MB
recording stays within the file's size of the RSS replaying a small one."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from daemon_harness import (
    DaemonProcess,
    PtyLine,
    StickState,
    install,
    recording,
    run_daemon,
    stats_until,
    wait_until,
)

EVIL_NAME = "Evil\x1b]0;pwned\x07Stick\x1b[31m"  # a window title, a bell, a colour


def test_a_device_name_with_esc_and_bel_is_escaped_in_the_log(
    tmp_path: Path, replay_dir: Path, line: PtyLine
) -> None:
    install(replay_dir / "evil.hid", recording([StickState()], name=EVIL_NAME))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        wait_until(lambda: "device plugged" in daemon.log(), "the plug's log line")
    finally:
        assert daemon.stop() == 0
    raw = daemon.log_path.read_bytes()
    assert b"\x1b" not in raw and b"\x07" not in raw
    assert "Evil\\x1b]0;pwned\\x07Stick\\x1b[31m" in daemon.log()


def big_recording(size: int) -> str:
    """A stick recording of at least `size` bytes: one report a millisecond (minutes of
    events, so the daemon is still playing it when its memory is measured)."""
    small = recording([StickState()])
    header = "\n".join(x for x in small.splitlines() if not x.startswith("E:"))
    event = next(x for x in small.splitlines() if x.startswith("E:"))
    payload = event.split(" ", 2)[2]  # "LENGTH HEX..." after "E: TIME"
    count = size // (len(event) + 1) + 1
    events = "\n".join(f"E: {i / 1000:.6f} {payload}" for i in range(count))
    return f"{header}\n{events}\n"


def peak_rss_bytes(daemon: DaemonProcess) -> int:
    status = Path(f"/proc/{daemon.proc.pid}/status").read_text()
    match = re.search(r"^VmHWM:\s+(\d+) kB", status, re.MULTILINE)
    assert match, status
    return int(match.group(1)) * 1024


def replaying_peak_rss(tmp_path: Path, text: str) -> int:
    """The daemon's peak RSS once it has played reports of a recording of `text`."""
    replay_dir = tmp_path / "replay"
    replay_dir.mkdir()
    install(replay_dir / "stick.hid", text)
    line = PtyLine()
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        stats_until(daemon, r"\): [1-9]\d* reports", timeout=15)
        return peak_rss_bytes(daemon)
    finally:
        assert daemon.stop() == 0
        line.close()


def test_a_20_mb_recording_is_streamed_not_held(tmp_path: Path) -> None:
    size = 20 * 1024 * 1024
    text = big_recording(size)
    small = tmp_path / "small"
    big = tmp_path / "big"
    small.mkdir()
    big.mkdir()
    baseline = replaying_peak_rss(small, recording([StickState()]))
    growth = replaying_peak_rss(big, text) - baseline
    # held whole (text, a text buffer, every event parsed) it grew ~5x the file's size
    assert growth < len(text), f"peak RSS grew {growth / 2**20:.1f} MB for a 20 MB file"


def test_the_filter_escapes_values_and_messages_but_keeps_the_messages_own_layout() -> None:
    import logging

    from usb2rc.runtime.log_escape import EscapeFilter

    def formatted(msg: str, *args: Any) -> str:
        record = logging.LogRecord("t", logging.INFO, __file__, 1, msg, args or None, None)
        assert EscapeFilter().filter(record)
        return record.getMessage()

    # a value's newline would fake a log line: escaped; the format's own newline stays
    assert formatted("plugged: %s\n\tnext", "a\nb\x07") == "plugged: a\\x0ab\\x07\n\tnext"
    assert formatted(f"f-string {EVIL_NAME}") == "f-string Evil\\x1b]0;pwned\\x07Stick\\x1b[31m"
    assert formatted("%d reports, %.1f s", 3, 1.5) == "3 reports, 1.5 s"
    assert formatted("%(name)s", {"name": "x\x9by"}) == "x\\x9by"  # C1 CSI
    assert formatted("%s", OSError(5, "bad \x1b name")) == "[Errno 5] bad \\x1b name"
