"""The replay backend's own cost per report, as a reader drains it (issue 40).

Four real descriptors (X52, T.16000M, TWCS, WingMan: `tests/daemon_harness.py:
BENCH_MODELS`), 12 s recordings of random reports at 1 kHz each, looped, each opened
on the replay backend. Every `--step-ms` (10) each device is drained as `hid/reader.py`
drains it: `read(timeout)`, then `read_due` (where the device has it) and `read(0.0)` until
that returns None.

    .venv/bin/python bench/bench_replay.py [--seconds 5] [--step-ms 10]
    .venv/bin/python bench/bench_replay.py --callgrind        # instructions per report

Figures:
- `replay_cpu_us_per_report`: thread CPU (`time.thread_time`) of the drains per report, on
  the real clock, sleeping `--step-ms` between them (cold caches, as in the daemon);
- `replay_busy_us_per_report`: what the device's own `busy_s` counts per report (wall time
  inside `read` other than waiting: the figure the daemon's stats line and `bench_daemon.py`
  show; it also counts a GIL wait or a preemption inside `read`, so on a busy host it is
  higher than the CPU figure);
- `replay_ir_per_report` (`--callgrind`): instructions per report under valgrind's
  callgrind, on a virtual clock (`--virtual`: the replay module's `time.monotonic` is a
  counter the bench moves by `--step-ms` per drain, so the run is the same every time); two
  runs of different lengths, so the start (imports, files, opens) cancels out. Instruction
  counts do not move with the host's load: the figure to compare trees by on a shared host.

Runs against any tree whose replay backend has `ReplayBackend(dir, loop=)`:
`PYTHONPATH=<tree> python bench/bench_replay.py` (the A/B of issue 40).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from daemon_harness import BENCH_MODELS, named_device_recordings

from usb2rc.hid import replay
from usb2rc.hid.replay import ReplayBackend

SECONDS = 12.0  # each recording's length (bench_daemon.py's REAL_SECONDS)
RATE_HZ = 1000.0


def drain(device: Any) -> int:
    """A reader's drain (`DeviceReader._drain`) after a read: the reports it took."""
    if device.read(0.1) is None:
        return 0
    taken = 1
    read_due = getattr(device, "read_due", None)
    while True:
        if read_due is not None:
            taken += len(read_due(1000))
        if device.read(0.0) is None:
            return taken
        taken += 1


class VirtualClock:
    """The replay module's `time`, with a monotonic clock that only the bench moves."""

    def __init__(self) -> None:
        self.now = time.monotonic()

    def install(self) -> None:
        replay.time = SimpleNamespace(  # type: ignore[attr-defined,assignment]
            monotonic=lambda: self.now, perf_counter=time.perf_counter
        )


def run(seconds: float, step_s: float, virtual: bool) -> dict[str, float]:
    clock = VirtualClock()
    if virtual:
        clock.install()
    texts = named_device_recordings(BENCH_MODELS, SECONDS, RATE_HZ)
    with tempfile.TemporaryDirectory(prefix="usb2rc-bench-replay-") as tmp:
        for i, text in enumerate(texts):
            Path(tmp, f"device{i}.hid").write_text(text)
        backend = ReplayBackend(tmp, loop=True)
        devices = [backend.open(info) for info in backend.enumerate()]
        reports, cpu_s = 0, 0.0
        for _ in range(round(seconds / step_s)):
            if virtual:
                clock.now += step_s
            else:
                time.sleep(step_s)
            started = time.thread_time()
            reports += sum(drain(device) for device in devices)
            cpu_s += time.thread_time() - started
        busy_s = sum(device.busy_s for device in devices)
        for device in devices:
            device.close()
    return {
        "replay_reports": reports,
        "replay_cpu_us_per_report": cpu_s / max(1, reports) * 1e6,
        "replay_busy_us_per_report": busy_s / max(1, reports) * 1e6,
    }


def callgrind_instructions(seconds: float, step_ms: float) -> tuple[int, int]:
    """Instructions of one virtual run under callgrind, and the reports it drained."""
    command = [
        "valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
        sys.executable, __file__, "--virtual", "--seconds", str(seconds),
        "--step-ms", str(step_ms),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    collected = re.search(r"Collected : (\d+)", done.stderr)
    figures = json.loads(done.stdout.strip().splitlines()[-1])["figures"]
    if collected is None:
        raise RuntimeError("no 'Collected' line from callgrind:\n" + done.stderr[-2000:])
    return int(collected.group(1)), int(figures["replay_reports"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="drained time (5 s)")
    parser.add_argument("--step-ms", type=float, default=10.0, help="between drains (10)")
    parser.add_argument("--virtual", action="store_true", help="a virtual clock, no sleeps")
    parser.add_argument(
        "--callgrind", action="store_true", help="instructions per report (valgrind)"
    )
    args = parser.parse_args()
    if args.callgrind:
        short = callgrind_instructions(args.seconds, args.step_ms)
        long = callgrind_instructions(2 * args.seconds, args.step_ms)
        per_report = (long[0] - short[0]) / (long[1] - short[1])
        figures: dict[str, float] = {"replay_ir_per_report": per_report}
        print(f"replay_ir_per_report  {per_report:.0f} instructions")
    else:
        figures = run(args.seconds, args.step_ms / 1000, args.virtual)
        for name in ("replay_cpu_us_per_report", "replay_busy_us_per_report"):
            print(f"{name:28} {figures[name]:.2f} µs")
    tree = os.environ.get("PYTHONPATH", str(Path(__file__).resolve().parent.parent))
    print(json.dumps({"bench": "replay", "tree": tree, "figures": figures}))


if __name__ == "__main__":
    main()
