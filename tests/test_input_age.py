"""Every frame's input age (issue 42): from the read of the newest report a frame carries to
its write; each output's p50, p99 and max in /api/status, its stats line and the page.

Black-box: a stick that reports only on change sends its second report 1.5 s into the
recording and then nothing; every frame after carries that report, so the age of the
newest frames grows with the time since the test wrote that report (its moment in the
recording, from when the test plugged it)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from daemon_harness import (
    DaemonProcess,
    PtyLine,
    StickState,
    install,
    timed_recording,
    wait_until,
)
from web_harness import WebProcess

SECOND_REPORT_S = 1.5


def c2_output(record: dict[str, Any]) -> dict[str, Any]:
    return next(o for o in record["stats"]["outputs"] if o["protocol"] == "c2-16b")


def test_the_input_age_in_api_status_grows_with_the_time_since_the_report(
    tmp_path: Path, replay_dir: Path
) -> None:
    line = PtyLine()
    sock = tmp_path / "s.sock"
    args = ["--replay", str(replay_dir), "--port", line.path, "--status-socket", str(sock)]
    daemon = DaemonProcess([*args, "--stats-interval", "1"], tmp_path / "daemon.log")
    web = None
    try:
        wait_until(sock.exists, "the status socket", 30)
        web = WebProcess(sock, tmp_path / "web.log")
        status = wait_until(lambda: (r := web.get("/api/status")).get("stats") and r, "a status")
        before = c2_output(status)
        assert before["input_age_ms"] is None  # no live device's report carried yet
        events = [(0.0, StickState()), (SECOND_REPORT_S, StickState(x=8192 + 200))]
        plugged = time.monotonic()
        install(replay_dir / "stick.hid", timed_recording(events))
        written = plugged + SECOND_REPORT_S  # the report's moment, on the test's clock
        wait_until(lambda: time.monotonic() > written + 1.5, "1.5 s after the report", 30)
        ages = c2_output(web.get("/api/status"))["input_age_ms"]
        read = time.monotonic()
        assert ages is not None and 0 <= ages["p50"] <= ages["p99"] <= ages["max"]
        bound_ms = (read - written) * 1000  # no frame can carry the report for longer
        assert ages["max"] <= bound_ms
        # the newest frames carry it for nearly that long (the daemon saw the plug, read
        # the report and the status socket refreshed within half a second)
        assert ages["max"] >= bound_ms - 500
        assert "input age p50" in daemon.log()  # the stats line
    finally:
        if web is not None:
            web.stop()
        daemon.stop()
        line.close()
