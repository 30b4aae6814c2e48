"""The return path's figures, on the real hidapi over umockdev (docs/ICD.md "Downlink").

    .venv/bin/python bench/bench_downlink.py [--changes 100] [--flood-s 5] [--json PATH]

A fake LED stick (tests/umockdev_harness.py) on node 0, the daemon as a subprocess with
C2-16B on a pty (zero config), the test's side writing the far end's downlink frames:
- latency: a downlink that changes the indicators, every 100 ms, to the output report
  carrying it on the node's other side (p50/p99/max; the far end's write to the bed's read,
  so it includes the bed's own polling, ~1 ms);
- stale: from the last downlink to the rest report (the ICD: 1 s, within 1.5 s);
- flood: node 0's `>` frames a second before and during 2,000 downlink frames a second,
  and the daemon's CPU (from /proc) in both.
Without umockdev it prints why and a JSON line with no figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from daemon_harness import PtyLine  # noqa: E402
from test_feedback_journeys import (  # noqa: E402
    LED_REPORT,
    Written,
    downlink,
    led_stick,
    start,
)
from test_hid_outputs_umockdev import expected_report, input_report  # noqa: E402
from test_real_hidapi import wait_announced  # noqa: E402
from umockdev_harness import missing_reason, usb_bed, wait_until  # noqa: E402

from usb2rc.protocols.c2_16b import codec as c2_16b  # noqa: E402

CENTRE = 2048


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process and its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def latencies(line: PtyLine, written: Written, changes: int) -> tuple[list[float], float]:
    """Each change's latency (ms), and when the last downlink was sent."""
    out = []
    sent = 0.0
    for i in range(changes):
        mask = (i % 255) + 1
        sent = time.monotonic()
        line.send(downlink(0, i & 0xFF, group1=mask))
        want = expected_report(mask, 255)
        wait_until(lambda w=want: written.reports()[-1:] == [w], 10, "the report", 0.0005)
        out.append((written.times[-1] - sent) * 1000)
        time.sleep(0.1)
    return out, sent


def rate_and_cpu(line: PtyLine, pid: int, seconds: float) -> tuple[float, float]:
    start, cpu0 = time.monotonic(), cpu_s(pid)
    time.sleep(seconds)
    cpu = (cpu_s(pid) - cpu0) / (time.monotonic() - start) * 100
    frames = [
        s
        for s in line.seen_now()
        if s.time >= start and isinstance(s.frame, c2_16b.DataFrame) and s.frame.node_id == 0
    ]
    return len(frames) / (frames[-1].time - frames[0].time), cpu


def flood(line: PtyLine, pid: int, seconds: float) -> tuple[float, float]:
    import threading

    done = threading.Event()
    batch = b"".join(downlink(0, i, group1=i) for i in range(20))

    def send() -> None:
        start, n = time.monotonic(), 0
        while not done.is_set():
            line.send(batch)
            n += 1
            time.sleep(max(0.0, start + n * 0.01 - time.monotonic()))  # 2,000 frames/s

    thread = threading.Thread(target=send)
    thread.start()
    try:
        time.sleep(0.5)
        return rate_and_cpu(line, pid, seconds)
    finally:
        done.set()
        thread.join()


def measure(workdir: Path, changes: int, flood_s: float) -> dict[str, Any]:
    with usb_bed() as bed:
        node = led_stick(bed)
        written = Written(bed, node, LED_REPORT)
        line = PtyLine()
        daemon = start(workdir, bed, line)
        try:
            wait_announced(line, 0)
            bed.report(node, input_report(CENTRE))
            ms, last = latencies(line, written, changes)
            written.wait_for(expected_report(0, 255), "rest", timeout=10)
            stale_s = written.times[-1] - last
            rate_before, cpu_before = rate_and_cpu(line, daemon.proc.pid, flood_s)
            rate_flood, cpu_flood = flood(line, daemon.proc.pid, flood_s)
        finally:
            code = daemon.stop()
            line.close_at_the_end()
        if code != 0:
            raise RuntimeError(f"the daemon exited {code}:\n{daemon.log()[-3000:]}")
    ms.sort()
    return {
        "downlink_to_report_ms_p50": round(statistics.median(ms), 2),
        "downlink_to_report_ms_p99": round(ms[min(len(ms) - 1, int(len(ms) * 0.99))], 2),
        "downlink_to_report_ms_max": round(ms[-1], 2),
        "stale_to_rest_s": round(stale_s, 3),
        "frames_per_s_before_flood": round(rate_before, 2),
        "frames_per_s_in_flood": round(rate_flood, 2),
        "cpu_pct_before_flood": round(cpu_before, 2),
        "cpu_pct_in_flood": round(cpu_flood, 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--changes", type=int, default=100, help="indicator changes (100)")
    parser.add_argument("--flood-s", type=float, default=5.0, help="seconds measured (5)")
    parser.add_argument("--json", type=Path, help="also write the JSON line here")
    args = parser.parse_args()
    reason = missing_reason()
    figures: dict[str, Any] = {}
    if reason is not None:
        print(f"bench_downlink: skipped: {reason}")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            figures = measure(Path(tmp), args.changes, args.flood_s)
        for key, value in figures.items():
            print(f"{key:32} {value}")
    line = json.dumps({"bench": "downlink", **figures})
    print(line)
    if args.json:
        args.json.write_text(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
