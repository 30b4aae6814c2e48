"""Helpers for the fuzz, fault-injection and soak suites (tests/test_fuzz_*.py,
tests/test_stress_faults.py, tests/test_soak.py).

- `CheckedLine`: the far end of a pty like daemon_harness.PtyLine, but it checks the stream as
  it goes instead of only storing it: message codes per node (gaps = frames lost), data frames
  of nodes that never had a connect sequence (frames invented), decoder skips and CRC
  failures, and keeps per-node timelines of status changes and service frames (small, so a
  10-minute soak does not keep 100 000 frames in memory).
- `proc_stats(pid)`: threads, RSS and open fds of a process, from /proc.
- `figures(request, suite, data)`: merges a suite's figures into
  bench/results/stress-summary.json and prints one compact line on the terminal (also
  without `-s`), so CI logs show them.
- `env_int` / `env_float`: durations and counts, configurable per environment variable.
- seeded byte mutators shared by the fuzz suites.
"""

from __future__ import annotations

import json
import os
import random
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon_harness import ROOT, PtyLine

from usb2rc.protocols.c2_16b import codec as c2_16b

RESULTS = ROOT / "bench" / "results" / "stress-summary.json"
_RESULTS_LOCK = threading.Lock()


# --- configuration --------------------------------------------------------------------------


def env_int(name: str, default: int) -> int:
    value = os.environ.get(name, "").strip()
    return int(value) if value else default


def env_float(name: str, default: float) -> float:
    value = os.environ.get(name, "").strip()
    return float(value) if value else default


# --- figures --------------------------------------------------------------------------------


def figures(request: Any, suite: str, data: dict[str, Any]) -> None:
    """Record a suite's figures in the JSON summary and print them as one terminal line."""
    with _RESULTS_LOCK:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        try:
            summary = json.loads(RESULTS.read_text())
        except (OSError, ValueError):
            summary = {}
        summary[suite] = {"recorded_at": time.strftime("%Y-%m-%dT%H:%M:%S"), **data}
        tmp = RESULTS.with_name(RESULTS.name + ".tmp")
        tmp.write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
        os.replace(tmp, RESULTS)
    compact = ", ".join(f"{k}={_fmt(v)}" for k, v in data.items())
    line = f"[stress] {suite}: {compact}"
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.ensure_newline()
        reporter.write_line(line)
    else:  # pragma: no cover - without the terminal plugin
        print(line)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def summarize(values: Iterable[float]) -> dict[str, float]:
    """min / median / max of a list of durations (seconds), for the figures."""
    v = sorted(values)
    if not v:
        return {}
    return {"n": len(v), "min_s": v[0], "median_s": v[len(v) // 2], "max_s": v[-1]}


# --- process statistics ---------------------------------------------------------------------


@dataclass(frozen=True)
class ProcStats:
    threads: int
    rss_kb: int
    fds: int

    def as_dict(self) -> dict[str, int]:
        return {"threads": self.threads, "rss_kb": self.rss_kb, "fds": self.fds}


def proc_stats(pid: int) -> ProcStats:
    status = Path(f"/proc/{pid}/status").read_text()
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    threads = int(fields["Threads"].strip())
    rss_kb = int(fields["VmRSS"].split()[0])
    fds = len(os.listdir(f"/proc/{pid}/fd"))
    return ProcStats(threads, rss_kb, fds)


# --- the far end of the line ----------------------------------------------------------------

CONNECT = ("connected", "vid-pid", "device-string", "device-type")


@dataclass
class NodeLog:
    """What one node did on the line."""

    data_frames: int = 0
    last_code: int | None = None
    code_gaps: list[tuple[int, int]] = field(default_factory=list)  # (expected, got)
    status: int | None = None
    status_changes: list[tuple[float, int]] = field(default_factory=list)  # (time, status)
    services: list[tuple[float, str, int | None]] = field(default_factory=list)
    connect_sequences: int = 0
    rollovers: int = 0
    last_axes: tuple[int, ...] = ()
    last_group1: int = 0

    def names(self) -> list[str]:
        return [name for _, name, _ in self.services]

    def first_status_after(self, t0: float, status: int) -> float | None:
        for t, s in self.status_changes:
            if t >= t0 and s == status:
                return t
        return None

    def first_service_after(self, t0: float, name: str) -> float | None:
        for t, n, _ in self.services:
            if t >= t0 and n == name:
                return t
        return None


class CheckedLine(PtyLine):
    """A pty pair whose master the test reads; every frame is checked as it arrives.

    `configured`: Node-IDs that may send data frames without a connect sequence (pinned in
    the config). A data frame from any other node that never had a connect sequence (nor an
    error frame, which a device that failed to open gets) is counted in `invented`.
    """

    def __init__(self, configured: Iterable[int] = (), keep: int = 5000) -> None:
        self.configured = set(configured)
        self.nodes: dict[int, NodeLog] = {}
        self.recent: deque[tuple[float, Any]] = deque(maxlen=keep)
        self.startups: list[float] = []
        self.invented: list[int] = []
        self.data_before_startup = 0
        self.total_frames = 0
        self.first_frame_at: float | None = None
        self._pending_connect: dict[int, int] = {}  # node -> how far into 1,6,5,7
        self._announced: set[int] = set()
        super().__init__("c2-16b")  # starts the reading thread: every field exists by now

    def _record(self, now: float, frames: list[Any]) -> None:
        for frame in frames:
            self._account(now, frame)

    def node(self, node_id: int) -> NodeLog:
        log = self.nodes.get(node_id)
        if log is None:
            log = self.nodes[node_id] = NodeLog()
        return log

    def _account(self, now: float, frame: Any) -> None:
        self.total_frames += 1
        if self.first_frame_at is None:
            self.first_frame_at = now
        self.recent.append((now, frame))
        if isinstance(frame, c2_16b.ServiceFrame):
            name = frame.service.service_name
            if frame.service == c2_16b.Service.STARTUP:
                self.startups.append(now)
                return
            log = self.node(frame.node_id)
            log.services.append((now, name, frame.error_code))
            step = self._pending_connect.get(frame.node_id, 0)
            if name == CONNECT[step]:
                step += 1
                if step == len(CONNECT):
                    log.connect_sequences += 1
                    self._announced.add(frame.node_id)
                    step = 0
            else:
                step = 1 if name == CONNECT[0] else 0
            self._pending_connect[frame.node_id] = step
            if name == "error":
                self._announced.add(frame.node_id)
            return
        if not self.startups:
            self.data_before_startup += 1
        log = self.node(frame.node_id)
        if frame.node_id not in self._announced and frame.node_id not in self.configured:
            self.invented.append(frame.node_id)
        if log.last_code is not None:
            want = (log.last_code + 1) & 0xFF
            if frame.code != want:
                log.code_gaps.append((want, frame.code))
            if frame.code == 0 and log.last_code == 255:
                log.rollovers += 1
        log.last_code = frame.code
        log.data_frames += 1
        log.last_axes = frame.axes
        log.last_group1 = frame.group1
        if frame.status != log.status:
            log.status = frame.status
            log.status_changes.append((now, frame.status))

    # waiting -----------------------------------------------------------------------------

    def wait_for(self, predicate: Callable[[CheckedLine], Any], timeout: float = 15.0) -> Any:
        """Wait until predicate(self) is truthy (called under the lock); return its value."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                result = predicate(self)
                if result:
                    return result
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(
                        f"timed out after {timeout} s; {self.total_frames} frames, "
                        f"nodes {self.summary()}"
                    )
                self._cond.wait(min(left, 0.5))

    def locked(self) -> Any:
        return self._cond

    # checks ------------------------------------------------------------------------------

    def gaps(self) -> dict[int, list[tuple[int, int]]]:
        with self._cond:
            return {n: list(log.code_gaps) for n, log in self.nodes.items() if log.code_gaps}

    def data_frames_total(self) -> int:
        with self._cond:
            return sum(log.data_frames for log in self.nodes.values())

    def rollovers(self) -> int:
        with self._cond:
            return sum(log.rollovers for log in self.nodes.values())

    def summary(self) -> dict[int, str]:
        return {
            n: f"{log.data_frames} data, status {chr(log.status) if log.status else '-'}, "
            f"services {log.names()[-6:]}"
            for n, log in self.nodes.items()
        }

    def assert_clean(self, *, allow_rx_garbage: bool = False) -> None:
        """No frame lost (codes consecutive), none invented, nothing skipped on the line."""
        with self._cond:
            assert not self.gaps(), f"message code gaps (frames lost): {self.gaps()}"
            assert not self.invented, f"data frames of unannounced nodes: {self.invented[:10]}"
            assert self.data_before_startup == 0
            assert self.decoder.bytes_skipped == 0, self.decoder.bytes_skipped
            assert self.decoder.crc_failures == 0, self.decoder.crc_failures


# --- daemon helpers -------------------------------------------------------------------------


def wait_exit(proc: Any, timeout: float) -> tuple[int | None, float]:
    """(returncode or None on timeout, seconds waited)."""
    t0 = time.monotonic()
    try:
        code = proc.wait(timeout)
    except Exception:
        return None, time.monotonic() - t0
    return code, time.monotonic() - t0


def terminate(proc: Any, timeout: float = 10.0) -> tuple[int, float]:
    """SIGTERM; (exit code, seconds to exit). SIGKILL after timeout (then code is negative)."""
    t0 = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    code, _ = wait_exit(proc, timeout)
    if code is None:
        proc.kill()
        code = proc.wait()
    return code, time.monotonic() - t0


# --- mutation -------------------------------------------------------------------------------

INTERESTING = (0x00, 0x01, 0x7F, 0x80, 0xFF, 0x48, 0x2D, 0x0A, 0xA8, 0x81, 0x3E, 0x21)


def mutate(data: bytes, rng: random.Random, max_ops: int = 8) -> bytes:
    """A few byte-level mutations: flips, interesting bytes, inserts, deletes, splices."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, max_ops)):
        op = rng.randrange(7)
        pos = rng.randrange(len(buf) + 1)
        if op == 0 and buf:
            buf[min(pos, len(buf) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1 and buf:
            buf[min(pos, len(buf) - 1)] = rng.choice(INTERESTING)
        elif op == 2 and buf:
            buf[min(pos, len(buf) - 1)] = rng.randrange(256)
        elif op == 3:
            buf[pos:pos] = rng.randbytes(rng.randint(1, 8))
        elif op == 4:
            del buf[pos : pos + rng.randint(1, 8)]
        elif op == 5 and buf:
            a = rng.randrange(len(buf))
            chunk = buf[a : a + rng.randint(1, 16)]
            buf[pos:pos] = chunk  # duplicate a slice elsewhere
        elif op == 6 and len(buf) > 1:
            a, b = sorted(rng.sample(range(len(buf)), 2))
            buf[a:b] = bytes(reversed(buf[a:b]))
    return bytes(buf)


def chunks(data: bytes, rng: random.Random) -> list[bytes]:
    """Split data at random points (one byte at a time included)."""
    out, pos = [], 0
    while pos < len(data):
        n = rng.choice((1, 1, 2, 3, 7, 35, 36, 64, 200))
        out.append(data[pos : pos + n])
        pos += n
    return out


def elapsed(t0: float) -> float:
    return round(time.monotonic() - t0, 1)
