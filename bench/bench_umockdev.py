"""Report -> first frame carrying it, on the real hidapi path over umockdev.

    .venv/bin/python bench/bench_umockdev.py [--reports 300] [--report-ms 23] [--json PATH]

A fake T.16000M on a umockdev testbed (tests/umockdev_bed.py), read by the daemon as a
subprocess through cython-hidapi's `hidraw` module, hidapi and libudev under umockdev's
preload library; the far end of its serial pty is bench_daemon's reader subprocess (one JSON
line per frame, stamped with CLOCK_MONOTONIC). Each report has a unique X, one every
--report-ms (23 ms: longer than a tick, so every report is carried by some frame, and the
phase walks through the tick; see bench/README.md). Latency = arrival of the first frame whose
X is the report's scaled X - the moment the testbed wrote the report to the node, so unlike
bench_daemon's replay figure it includes the reader's wake-up and its pacing.

Without umockdev (Debian: umockdev gir1.2-umockdev-1.0 python3-gi) it prints why and a JSON
line with no figures. A table, then one JSON line ({"bench": "umockdev", ...}).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_daemon import X_MAX, PtyReader, latency_figures  # noqa: E402
from daemon_harness import T16000M_DESCRIPTOR, DaemonProcess, StickState, scale  # noqa: E402
from umockdev_harness import FakeStick, missing_reason, serial_port_link, usb_bed  # noqa: E402

SETTLE_S = 1.0  # after the node is live: the first ticks settle, as in bench_daemon


def measure(workdir: Path, reports: int, report_ms: float) -> dict[str, Any]:
    with usb_bed() as bed:
        hidraw = bed.add(
            FakeStick("1-1.2", 0x044F, 0xB10A, T16000M_DESCRIPTOR, "T.16000M", "Thrustmaster")
        )
        reader = PtyReader(workdir)
        daemon = DaemonProcess(
            ["--port", serial_port_link(workdir, reader.path), "--log-level", "info"],
            workdir / "daemon.log",
            env=bed.env(),
        )
        try:
            reader.wait_for(lambda f: reader.data(), timeout=20, what="the first data frame")
            bed.report(hidraw, StickState().report())  # live (centred: the guard) before the ramp
            reader.wait_for(lambda f: reader.data()[-1]["s"] == 0x3E, 5, "a live frame")
            deliveries = ramp(bed, hidraw, reports, report_ms / 1000)
            last = scale(deliveries[-1][1], 0, X_MAX)
            reader.wait_for(lambda f: any(d["a"][0] == last for d in reader.data()), 5, "last")
            frames = reader.data(deliveries[0][0] - 1.0)
        finally:
            code = daemon.stop()
            reader.close()
        if code != 0:
            raise RuntimeError(f"the daemon exited {code}:\n{daemon.log()[-3000:]}")
    figures = latency_figures(deliveries, frames)
    return {f"umockdev_{key}": value for key, value in figures.items()}


def ramp(bed: Any, hidraw: str, reports: int, step_s: float) -> list[tuple[float, int]]:
    """X = 0, 1, 2 ... one report every step_s on absolute deadlines; (write time, X)."""
    start = time.monotonic() + SETTLE_S
    out = []
    for i in range(reports):
        time.sleep(max(0.0, start + i * step_s - time.monotonic()))
        x = i % (X_MAX + 1)
        out.append((bed.report(hidraw, StickState(x=x, y=8192).report()), x))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reports", type=int, default=300, help="reports in the ramp (300)")
    parser.add_argument("--report-ms", type=float, default=23.0, help="one report every (23)")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON line here")
    args = parser.parse_args()
    reason = missing_reason()
    if reason is not None:
        print(f"umockdev: not measured: {reason}")
        result: dict[str, Any] = {"bench": "umockdev", "skipped": reason, "figures": {}}
    else:
        with tempfile.TemporaryDirectory(prefix="usb2rc-bench-umockdev-") as tmp:
            figures = measure(Path(tmp), args.reports, args.report_ms)
        print(
            "report -> frame (real hidapi, umockdev)"
            f"  mean {figures['umockdev_latency_mean_ms']:.2f} ms"
            f"  p50 {figures['umockdev_latency_p50_ms']:.2f} ms"
            f"  p99 {figures['umockdev_latency_p99_ms']:.2f} ms"
            f"  max {figures['umockdev_latency_max_ms']:.2f} ms"
            f"  ({figures['umockdev_latency_reports']} reports,"
            f" {figures['umockdev_latency_unmatched']} unmatched)"
        )
        result = {"bench": "umockdev", "figures": figures, "report_ms": args.report_ms}
    line = json.dumps(result)
    if args.json:
        Path(args.json).write_text(line + "\n")
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
