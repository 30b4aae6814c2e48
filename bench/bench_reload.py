"""A config reload (SIGHUP) measured from the far end of the line: how long the output stalls.

    .venv/bin/python bench/bench_reload.py [--entries 2000] [--megabytes 10] [--reloads 3]

The daemon (`python -m usb2rc run`, one replayed T.16000M, C2-16B at 50 Hz on a pty) runs
with a small config; the config file is then replaced by each test config and the daemon
gets SIGHUP. What is measured, per config:

- reload: SIGHUP -> the daemon's log line that ends the reload (`reloaded` or `rejected`);
- gap: the longest time between two frames arriving on the pty from the SIGHUP to that line
  (a tick is 20 ms: a gap well above it is ticks the reload held up); idle gap: the same
  in the second before the SIGHUP, the noise floor of the machine.
- stop: the same config, SIGHUP then SIGTERM 50 ms later: SIGTERM -> the first `!` (a
  failsafe data frame) on the pty, and how many data frames came between.

Configs: one with --entries device entries (automatic nodes, one axis each), a --megabytes
one (a long YAML comment block after a valid config), and the largest of each kind that the
limits take (config.MAX_DEVICE_ENTRIES entries; 1 KiB under config.MAX_CONFIG_BYTES).
Nothing is asserted: the figures go to docs/CONFIG.md ("Reload").
"""

from __future__ import annotations

import argparse
import itertools
import json
import signal
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from daemon_harness import (  # noqa: E402
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    install,
    recording,
    run_daemon,
)

from usb2rc.configfile import MAX_CONFIG_BYTES, MAX_DEVICE_ENTRIES  # noqa: E402
from usb2rc.protocols.c2_16b.codec import FAILSAFE  # noqa: E402

SMALL = "devices:\n  - name: stick\n    match: {vid: 0x044f, pid: 0xb10a}\n    node_id: 4\n"


def entries_config(count: int) -> str:
    """`count` entries (automatic nodes, one axis each): far more than anyone plugs in."""
    lines = ["devices:"]
    for i in range(count):
        lines += [
            f"  - name: dev{i}",
            f"    match: {{vid: 0x1234, pid: {i % 0xFFFF:#06x}}}",
            "    axes:",
            "      x: {usage: X}",
        ]
    return "\n".join(lines) + "\n"


def megabytes_config(megabytes: float) -> str:
    comment = "# " + "x" * 78 + "\n"
    return SMALL + comment * int(megabytes * 1024 * 1024 / len(comment))


def wait_log(log_path: Path, offset: int, words: tuple[str, ...], timeout: float) -> float:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        tail = log_path.read_text(errors="replace")[offset:]
        if any(w in tail for w in words):
            return time.monotonic()
        time.sleep(0.002)
    raise TimeoutError(f"none of {words} in the log")


def is_failsafe(frame: object) -> bool:
    return any(f.status == FAILSAFE for f in data_frames([frame]))


def max_gap(line: PtyLine, start: float, end: float) -> float:
    times = [s.time for s in line.seen_now() if start - 0.05 <= s.time <= end]
    return max((b - a for a, b in itertools.pairwise(times)), default=0.0)


IDLE_WINDOW_S = 1.0  # the noise floor: the longest gap in the second before the SIGHUP


def one_reload(daemon: DaemonProcess, line: PtyLine, config: Path, text: str) -> dict[str, float]:
    config.write_text(text)
    offset = len(daemon.log())
    sent = time.monotonic()
    daemon.signal(signal.SIGHUP)
    done = wait_log(daemon.log_path, offset, ("reloaded", "rejected"), 60)
    time.sleep(0.1)  # frames after the end, so the gap that ends the reload is seen
    idle = max_gap(line, sent - IDLE_WINDOW_S, sent)
    return {
        "reload_s": done - sent,
        "gap_ms": max_gap(line, sent, done) * 1000,
        "idle_gap_ms": idle * 1000,
    }


def started(tmp: Path, name: str) -> tuple[PtyLine, Path, DaemonProcess]:
    """A daemon on a fresh pty with one stick and config tmp/name.yaml (SMALL), running."""
    line = PtyLine()
    replay = tmp / f"replay-{name}"
    replay.mkdir()
    install(replay / "stick.hid", recording([StickState()]))
    config = tmp / f"{name}.yaml"
    config.write_text(SMALL)
    daemon = run_daemon(tmp, line.path, replay, "--config", str(config))
    line.wait_for(lambda frames: len(frames) > 20, 30)
    return line, config, daemon


def stop_during_reload(tmp: Path, text: str, name: str) -> dict[str, float]:
    line, config, daemon = started(tmp, name)
    try:
        config.write_text(text)
        daemon.signal(signal.SIGHUP)
        time.sleep(0.05)
        before = len(line.frames())
        sent = time.monotonic()
        daemon.signal(signal.SIGTERM)
        seen = line.wait_seen(lambda s: [x for x in s[before:] if is_failsafe(x.frame)], 30)
        first = seen[0]
        between = sum(1 for s in line.seen_now()[before:] if s.time < first.time)
        return {"stop_to_bang_s": first.time - sent, "frames_between": between}
    finally:
        daemon.stop()
        line.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--entries", type=int, default=2000)
    parser.add_argument("--megabytes", type=float, default=10.0)
    parser.add_argument("--reloads", type=int, default=3)
    args = parser.parse_args()
    at_limit_kib = MAX_CONFIG_BYTES / 1024 - 1
    configs = {
        f"{args.entries} entries": entries_config(args.entries),
        f"{args.megabytes:g} MB": megabytes_config(args.megabytes),
        f"{MAX_DEVICE_ENTRIES} entries": entries_config(MAX_DEVICE_ENTRIES),
        f"{at_limit_kib:g} KiB": megabytes_config(at_limit_kib / 1024),
    }
    results: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        line, config, daemon = started(tmp, "usb2rc")
        try:
            for label, text in configs.items():
                runs = [one_reload(daemon, line, config, text) for _ in range(args.reloads)]
                results[label] = {k: max(r[k] for r in runs) for k in runs[0]}
                config.write_text(SMALL)
                time.sleep(IDLE_WINDOW_S)  # an idle second before the next SIGHUP
            print(daemon.log().count("Traceback"), "tracebacks", file=sys.stderr)
        finally:
            daemon.stop()
            line.close()
        for i, (label, text) in enumerate(configs.items()):
            results[label].update(stop_during_reload(tmp, text, f"stop{i}"))
    for label, figures in results.items():
        print(f"{label:>14}: " + "  ".join(f"{k} {v:.3f}" for k, v in figures.items()))
    print(json.dumps({"bench": "reload", "figures": results}))


if __name__ == "__main__":
    main()
