"""The running daemon, measured from the far end of a pty read by another process.

    .venv/bin/python bench/bench_daemon.py [--seconds 60] [--runs 1] [--json PATH]

A reader subprocess holds the pty master: it reads in 64 KiB chunks, stamps each chunk with
CLOCK_MONOTONIC (system-wide on Linux, so its times compare with this process's and the
daemon's) and prints one JSON line per decoded frame. What is measured:

- period: in-process `Daemon` (zero config) with one replayed T.16000M; the arrival times of
  node 0's data frames (one write per tick) over --seconds: p99 of |period - 20 ms| and the
  mean period (least-squares slope of arrival time over tick number, so a missed tick does
  not count as a long period). Late/missed ticks from the scheduler's own counters.
- latency: the same run. The replayed device is wrapped so that its `read()` stamps each
  report with the moment it was due (its recorded time from the replay's start: when a
  kernel would have queued it, whenever the daemon reads it); every report carries a
  unique X (a ramp
  stepping every --report-ms, 23 ms by default: longer than a tick, so every report is
  carried by some frame, and 23 vs 20 ms walks the phase through the whole tick). Latency =
  arrival of the first frame whose X equals the report's scaled X - the report's delivery.
- cpu/rss: `python -m usb2rc run --replay DIR --replay-loop --port PTY` with 4 replayed
  T.16000M at 1000 reports/s each; utime+stime from /proc/PID/stat over --cpu-seconds after
  --warmup, VmRSS/VmHWM from /proc/PID/status; SIGUSR1 stats at the start and the end of the
  window give each device's report rate (it must be ~1000/s) and late/missed ticks.
  With `--extra-outputs sumd crsf sbus mavlink` the daemon runs those outputs too, at their
  default rates, each on a pty of its own (MAVLink: UDP to a local socket), drained by a
  thread here; the C2-16B output stays on the reader's pty: the CPU figure is then the daemon
  with every output.
- crsf500: C2-16B plus CRSF at 500 Hz (ELRS's F500 packet rate, 921600 baud) on ptys, 4
  resting T.16000M at 1 kHz (a moving stick never arms, and CRSF's failsafe is silence), the
  daemon in this process: p50/p99 |period error| of each driver's own write-to-write periods
  over --crsf-seconds, CRSF's missed and late (> 1 ms) ticks from its own counters.
- start: spawning `python -m usb2rc run ...` (one replayed device) -> the startup frame
  (service 8) and the first data frame on the pty; median of --starts, after one untimed
  start that writes the bytecode (as installing the wheel does).
- stop: SIGTERM -> the process has exited (every start trial and the cpu run).

A readable table, then one JSON line ({"bench": "daemon", ...}). --runs N repeats everything
and reports medians (max for the worst-case figures).
"""

from __future__ import annotations

import argparse
import bisect
import functools
import itertools
import json
import logging
import os
import re
import select
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from daemon_harness import (  # noqa: E402
    BENCH_MODELS,
    StickState,
    named_device_recordings,
    real_device_recordings,
    recording,
    scale,
    timed_recording,
)

from usb2rc.protocols.c2_16b import codec as c2_16b  # noqa: E402

PERIOD_S = 0.020
X_MAX = 16383  # T.16000M X: 14 bits


# --- the reader subprocess --------------------------------------------------------------------


def reader_main(fd: int) -> None:
    """Read the pty master `fd`; one JSON line per frame on stdout, stamped per chunk."""
    decoder = c2_16b.Decoder()
    out = sys.stdout
    out.write('{"ready": true}\n')
    out.flush()
    while True:
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # EIO: no slave open any more (the bench closed it)
            break
        now = time.monotonic()
        if not chunk:
            break
        lines = []
        for frame in decoder.feed(chunk):
            if isinstance(frame, c2_16b.DataFrame):
                lines.append(
                    f'{{"t":{now:.6f},"k":"d","n":{frame.node_id},"s":{frame.status},'
                    f'"c":{frame.code},"a":{list(frame.axes)},"g1":{frame.group1},'
                    f'"g2":{frame.group2}}}\n'
                )
            else:
                lines.append(
                    f'{{"t":{now:.6f},"k":"s","n":{frame.node_id},'
                    f'"svc":"{frame.service.service_name}"}}\n'
                )
        if lines:
            out.write("".join(lines))
            out.flush()


class PtyReader:
    """A pty pair; the master goes to a reader subprocess, this process keeps the slave open
    (so the line never hangs up between daemons). Frames are read back from its output file."""

    def __init__(self, workdir: Path) -> None:
        master, self._slave = os.openpty()
        self.path = os.ttyname(self._slave)
        self.out_path = workdir / f"frames-{master}.jsonl"
        self._out = open(self.out_path, "wb")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--reader-fd", str(master)],
            stdout=self._out,
            stdin=subprocess.DEVNULL,
            pass_fds=(master,),
            cwd=ROOT,
        )
        os.close(master)
        self._offset = 0
        self.frames: list[dict[str, Any]] = []
        self.ready = False
        self.wait_for(lambda f: self.ready, timeout=10, what="the reader to start")

    def poll(self) -> list[dict[str, Any]]:
        """Parse what the reader wrote since the last call (whole lines only)."""
        with open(self.out_path, "rb") as f:
            f.seek(self._offset)
            data = f.read()
        end = data.rfind(b"\n") + 1
        self._offset += end
        for line in data[:end].splitlines():
            item = json.loads(line)
            if "k" in item:
                self.frames.append(item)
            else:
                self.ready = True
        return self.frames

    def wait_for(
        self, predicate: Callable[[list[dict[str, Any]]], Any], timeout: float, what: str
    ) -> Any:
        deadline = time.monotonic() + timeout
        while True:
            result = predicate(self.poll())
            if result:
                return result
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out after {timeout} s waiting for {what}")
            time.sleep(0.01)

    def data(self, since: float = 0.0, node: int = 0) -> list[dict[str, Any]]:
        return [f for f in self.poll() if f["k"] == "d" and f["n"] == node and f["t"] >= since]

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(5)
        self._out.close()
        os.close(self._slave)


Frame = dict[str, Any]  # one frame the reader decoded (its "t", "k", "svc", "n" ...)


def _connected_since(since: float, frames: list[Frame]) -> list[Frame]:
    """The connect frames of a node but 0 that came at or after `since`."""
    return [x for x in frames if x.get("svc") == "connected" and x["n"] != 0 and x["t"] >= since]


def _first_since(since: float, service: str | None, frames: list[Frame]) -> Frame | None:
    """The first frame at or after `since`: the service frame `service`, or (None) a data
    frame."""
    return next(
        (
            x
            for x in frames
            if x["t"] >= since and (x.get("svc") == service if service else x["k"] == "d")
        ),
        None,
    )


# --- recordings -------------------------------------------------------------------------------


def ramp_recording(count: int, step_s: float) -> str:
    """count reports, one every step_s, X = 8192, 8193 ... (unique while count <= 16384;
    from the centre, where the neutral guard lets the stick go live)."""
    states = [StickState(x=(8192 + i) % (X_MAX + 1), y=8192) for i in range(count)]
    return recording(states, hold_s=step_s)


def khz_recording(seconds: float, name: str) -> str:
    """1000 reports/s, every one different (X and Y ramps, from the centre: the guard)."""
    count = int(seconds * 1000)
    states = [
        StickState(x=(8192 + 7 * i) % (X_MAX + 1), y=(8192 + 13 * i) % (X_MAX + 1))
        for i in range(count)
    ]
    return recording(states, hold_s=0.001, name=name)


# --- period and latency (in-process daemon) ---------------------------------------------------


def period_figures(times: Sequence[float], missed: int = 0) -> dict[str, float]:
    """p99 |period - 20 ms| over consecutive frames; mean period = least-squares slope of arrival
    time over tick number. With no missed ticks (the scheduler's counter) frame i is tick i, so
    a frame delayed on its way (then followed by an early one) cannot shift the count; with
    missed ticks, a gap of k periods counts k ticks."""
    if len(times) < 3:
        raise RuntimeError(f"only {len(times)} data frames seen")
    deltas = [b - a for a, b in itertools.pairwise(times)]
    errors = sorted(abs(d - PERIOD_S) for d in deltas)
    if missed == 0:
        ticks = list(range(len(times)))
    else:
        ticks = [0]
        for d in deltas:
            ticks.append(ticks[-1] + max(1, round(d / PERIOD_S)))
    mean_k = statistics.fmean(ticks)
    mean_t = statistics.fmean(times)
    num = sum((k - mean_k) * (t - mean_t) for k, t in zip(ticks, times, strict=True))
    den = sum((k - mean_k) ** 2 for k in ticks)
    slope = num / den
    return {
        "frames": len(times),
        "gaps": sum(1 for d in deltas if d > 1.5 * PERIOD_S),
        "period_p99_error_ms": errors[min(len(errors) - 1, int(len(errors) * 0.99))] * 1e3,
        "period_max_error_ms": errors[-1] * 1e3,
        "period_mean_ms": slope * 1e3,
        "period_mean_error_pct": (slope - PERIOD_S) / PERIOD_S * 100,
    }


def latency_figures(
    deliveries: Sequence[tuple[float, int]], frames: Sequence[dict[str, Any]]
) -> dict[str, float]:
    """For each delivered report (time, raw X): the first later frame carrying its X."""
    times = [f["t"] for f in frames]
    latencies = []
    superseded = 0
    for t_delivered, x in deliveries:
        want = scale(x, 0, X_MAX)
        i = bisect.bisect_left(times, t_delivered)
        found = None
        while i < len(frames) and times[i] < t_delivered + 1.0:
            if frames[i]["a"][0] == want:
                found = times[i]
                break
            i += 1
        if found is None:
            superseded += 1
        else:
            latencies.append(found - t_delivered)
    if not latencies:
        raise RuntimeError("no report was matched to a frame")
    latencies.sort()
    return {
        "latency_reports": len(latencies),
        "latency_unmatched": superseded,
        "latency_mean_ms": statistics.fmean(latencies) * 1e3,
        "latency_p50_ms": latencies[len(latencies) // 2] * 1e3,
        "latency_p99_ms": latencies[min(len(latencies) - 1, int(len(latencies) * 0.99))] * 1e3,
        "latency_max_ms": latencies[-1] * 1e3,
        "latency_min_ms": latencies[0] * 1e3,
    }


def run_period_latency(workdir: Path, seconds: float, report_ms: float) -> dict[str, Any]:
    from usb2rc.configfile import Config
    from usb2rc.daemon import Daemon
    from usb2rc.hid.replay import ReplayBackend, ReplayDevice

    deliveries: list[tuple[float, int]] = []

    class StampedDevice:
        """A replayed device that notes, for each report handed to the daemon, the moment it
        was due (its time in the recording from the device's start): the moment a kernel
        would have queued it, whenever the daemon reads it (a pulled reader reads at the
        step, so the read's own moment would leave out the queue's wait)."""

        def __init__(self, inner: ReplayDevice) -> None:
            self.inner = inner
            self.info = inner.info
            self.started = time.monotonic()  # the replay's own start, a moment before

        def report_descriptor(self) -> bytes:
            return self.inner.report_descriptor()

        def read(self, timeout_s: float) -> bytes | None:
            report = self.inner.read(timeout_s)
            if report is not None:
                x = report[3] | (report[4] & 0x3F) << 8
                start = getattr(self.inner, "_t0", self.started)
                deliveries.append((start + due_s.get(x, time.monotonic() - start), x))
            return report

        def close(self) -> None:
            self.inner.close()

    class StampedBackend(ReplayBackend):
        def open(self, info):  # type: ignore[no-untyped-def]
            return StampedDevice(super().open(info))

    replay_dir = workdir / "latency"
    replay_dir.mkdir()
    step = report_ms / 1000
    count = min(X_MAX + 1, int((seconds + 10) / step) + 1)
    text = ramp_recording(count, step)
    (replay_dir / "stick.hid").write_text(text)
    due_s: dict[int, float] = {}  # X -> when its first report is due, from the start
    for line in text.splitlines():
        if line.startswith("E: "):
            fields = line.split()
            data = bytes(int(b, 16) for b in fields[3:])
            due_s.setdefault(data[3] | (data[4] & 0x3F) << 8, float(fields[1]))
    reader = PtyReader(workdir)
    try:
        backend = StampedBackend(replay_dir, loop=True)
        daemon = Daemon(Config.default(), backend, port_override=reader.path)
        t_start = time.monotonic()
        daemon.start()
        probe = host_sleep_probe(seconds, PERIOD_S)  # the host's own lateness, same window
        try:
            time.sleep(seconds)
        finally:
            t_end = time.monotonic()
            host_out = probe.communicate(timeout=seconds + 30)[0]
            stats = daemon.outputs[0].driver.stats
            late, missed, ticks = stats.late_ticks, stats.missed_ticks, stats.ticks
            # the driver's own write-to-write periods after the first second: its wake-up
            # and tick, without the pty's and the far end's (PtyReader) own jitter
            inside = stats.periods()[-max(1, int((seconds - 1.0) / PERIOD_S)) :]
            # the daemon's own figure: from the read of a frame's newest report to its write
            ages = stats.input_age_ms() if hasattr(stats, "input_age_ms") else None
            daemon.stop()
        time.sleep(0.2)
        frames = [f for f in reader.data(t_start) if f["t"] <= t_end]
    finally:
        reader.close()
    # Skip the first second (start-up: imports done, but the first ticks settle).
    steady = [f for f in frames if f["t"] >= t_start + 1.0]
    result: dict[str, Any] = period_figures([f["t"] for f in steady], missed)
    result.update(latency_figures([d for d in deliveries if d[0] >= t_start + 1.0], frames))
    result.update({"ticks": ticks, "late_ticks": late, "missed_ticks": missed})
    inside_errors = [abs(period - PERIOD_S) for period in inside]
    result["period_p99_error_inside_ms"] = percentile(inside_errors, 0.99) * 1e3
    for name, value in (ages or {}).items():  # trees before the input age have none
        result[f"input_age_{name}_ms"] = value
    host_ms = json.loads(host_out)["p99_late_ms"]
    result["host_sleep_p99_late_ms"] = host_ms
    # the goal of the far end's period error, from this run's host (docs: bench/README.md)
    result["period_p99_error_allowed_ms"] = 2 * host_ms + 0.5
    return result


# A plain Python sleep to absolute deadlines PERIOD_S apart on this host, at normal priority,
# for SECONDS: the p99 of how late it wakes, and the deadlines it missed (woke a whole period
# late or more), counted as a driver counts them: the host's own share of a daemon's timing
# figures.
HOST_SLEEP_PROBE = """
import json, os, sys, time
# a plain program: normal priority, whatever the bench's thread that starts it runs at (an
# in-process daemon makes its starter real-time: usb2rc/runtime/realtime.py)
os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
seconds, period = float(sys.argv[1]), float(sys.argv[2])
end = time.monotonic() + seconds
deadline, late, missed = time.monotonic(), [], 0
while deadline < end:
    deadline += period
    time.sleep(max(0.0, deadline - time.monotonic()))
    behind = time.monotonic() - deadline
    late.append(behind)
    if behind >= period:
        missed += int(behind // period)
        deadline += int(behind // period) * period
late.sort()
p99 = late[min(len(late) - 1, int(len(late) * 0.99))]
print(json.dumps({"p99_late_ms": p99 * 1e3, "missed": missed}))
"""


def host_sleep_probe(seconds: float, period_s: float) -> subprocess.Popen[str]:
    """HOST_SLEEP_PROBE started now, beside what the bench measures; `.communicate()` its
    JSON line."""
    return subprocess.Popen(
        [sys.executable, "-c", HOST_SLEEP_PROBE, str(seconds), str(period_s)],
        stdout=subprocess.PIPE,
        text=True,
    )


# --- CRSF at 500 Hz (ELRS's F500 packet rate), in-process -------------------------------------

CRSF500_HZ = 500
CRSF500_CONFIG = (
    "outputs:\n"
    "  - {{protocol: c2-16b, port: '{c2}'}}\n"
    "  - {{protocol: crsf, port: '{crsf}', rate_hz: 500, baudrate: 921600, channels: {channels}}}\n"
)


def resting_recording(seconds: float, name: str) -> str:
    """1000 reports/s of a stick at rest (X toggles one count, so every report is a new
    value): the neutral guard arms, so CRSF sends; a moving stick never arms, and CRSF's
    failsafe is silence (`frames_withheld`)."""
    states = [(i * 0.001, StickState(x=8192 + i % 2)) for i in range(int(seconds * 1000))]
    return timed_recording(states, name=name)


def driver_period_figures(
    periods: Sequence[float], period_s: float, prefix: str
) -> dict[str, float]:
    """p50/p99/max |period error| of one driver's own write-to-write periods."""
    errors = [abs(period - period_s) for period in periods]
    if not errors:
        raise RuntimeError(f"{prefix}: no write in the window")
    return {
        f"{prefix}_p50_error_ms": percentile(errors, 0.50) * 1e3,
        f"{prefix}_p99_error_ms": percentile(errors, 0.99) * 1e3,
        f"{prefix}_max_error_ms": max(errors) * 1e3,
    }


def run_crsf500(workdir: Path, warmup: float, window: float) -> dict[str, Any]:
    """C2-16B (50 Hz) plus CRSF at 500 Hz on ptys (921600 baud), 4 resting T.16000M at 1 kHz,
    the daemon in this process: each driver's own write periods over the window, and CRSF's
    missed and late ticks from its own counters."""
    from usb2rc.configfile import load_config_text
    from usb2rc.daemon import Daemon
    from usb2rc.hid.replay import ReplayBackend
    from usb2rc.runtime import realtime

    replay_dir = workdir / "crsf500"
    replay_dir.mkdir()
    for i in range(4):
        text = resting_recording(4.0, f"Thrustmaster T.16000M {i}")
        (replay_dir / f"device{i}.hid").write_text(text)
    # Every thread of this process at the daemon's priority, as in `usb2rc run`'s process
    # (the drain's thread shares the daemon's GIL here: at normal priority, preempted while
    # it holds it, it would hold the daemon's ticks back, which `usb2rc run` does not have)
    scheduling = realtime.request(realtime.DEFAULT_PRIORITY)
    drain = OutputDrain(["crsf", "crsf"])  # two ptys: C2-16B's and CRSF's far ends
    c2_port, crsf_port = drain.ports
    config = load_config_text(
        CRSF500_CONFIG.format(c2=c2_port, crsf=crsf_port, channels=EXTRA_CHANNELS)
    )
    daemon = Daemon(config, ReplayBackend(replay_dir, loop=True))
    daemon.start()
    try:
        c2, crsf = (output.driver for output in daemon.outputs)
        deadline = time.monotonic() + 20
        while crsf.stats.writes < CRSF500_HZ // 10:  # the nodes armed: CRSF sends
            if time.monotonic() > deadline:
                raise RuntimeError("CRSF at 500 Hz never sent (did the nodes arm?)")
            time.sleep(0.05)
        time.sleep(warmup)
        periods: dict[Any, list[float]] = {c2: [], crsf: []}
        for driver in periods:
            driver.stats.new_periods()  # the window starts now
        missed0, late0, ticks0 = crsf.stats.missed_ticks, crsf.stats.late_ticks, crsf.stats.ticks
        probe = host_sleep_probe(window, 1 / CRSF500_HZ)  # the host's own, same window
        end = time.monotonic() + window
        while (left := end - time.monotonic()) > 0:
            time.sleep(min(1.0, left))
            for driver, kept in periods.items():
                kept.extend(driver.stats.new_periods())  # keeps 6 s at 500 Hz: read each 1 s
        missed, late = crsf.stats.missed_ticks - missed0, crsf.stats.late_ticks - late0
        ticks = crsf.stats.ticks - ticks0
        figures = driver_period_figures(periods[crsf], 1 / CRSF500_HZ, "crsf500")
        took = crsf.stats.tick_durations()  # its last ticks (3000: 6 s), wake-up to written
        figures["crsf500_tick_p50_ms"] = percentile(took, 0.50) * 1e3
        figures["crsf500_tick_p99_ms"] = percentile(took, 0.99) * 1e3
        figures.update(driver_period_figures(periods[c2], PERIOD_S, "crsf500_c2"))
        host = json.loads(probe.communicate(timeout=window + 30)[0])
        figures["crsf500_host_p99_late_ms"] = host["p99_late_ms"]
        figures["crsf500_host_missed"] = host["missed"]
    finally:
        daemon.stop()
        drain.close()
        realtime.release(scheduling)
    return {**figures, "crsf500_ticks": ticks, "crsf500_missed_ticks": missed,
            "crsf500_late_ticks": late}  # fmt: skip


# --- the daemon as a subprocess ---------------------------------------------------------------

STATS_OUT_RE = re.compile(r"stats: (\S+) \S+: writes (\d+), ticks (\d+), late (\d+), missed (\d+)")
STATS_DEV_RE = re.compile(r"stats: device .*?\((replay-[^)]*)\): (\d+) reports")
STATS_BUSY_RE = re.compile(r"\((replay-[^)]*)\): .*, backend busy ([0-9.]+) ms")


class DaemonProcess:
    def __init__(
        self,
        replay_dir: Path,
        port: str,
        log_path: Path,
        extra: Sequence[str] = (),
        env: dict[str, str] | None = None,
    ) -> None:
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.spawned_at = time.monotonic()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "usb2rc", "run", "--replay", str(replay_dir),
             "--replay-loop", "--port", port, "--log-level", "info", *extra],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=ROOT,
            env=dict(env or os.environ, PYTHONUNBUFFERED="1"),
        )  # fmt: skip

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def cpu_s(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def memory_kb(self) -> dict[str, int]:
        out = {}
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                out[key] = int(value.split()[0])
        return out

    def stats(self, timeout: float = 5.0) -> tuple[float, dict[str, Any]]:
        """SIGUSR1, then wait for the new stats lines; (time sent, parsed)."""
        before = self.log().count("stats: ")
        sent = time.monotonic()
        self.proc.send_signal(signal.SIGUSR1)
        deadline = sent + timeout
        while time.monotonic() < deadline:
            text = self.log()
            lines = [ln for ln in text.splitlines() if "stats: " in ln][before:]
            devices = {m[1]: int(m[2]) for ln in lines if (m := STATS_DEV_RE.search(ln))}
            busy = {m[1]: float(m[2]) / 1000 for ln in lines if (m := STATS_BUSY_RE.search(ln))}
            outputs = [m for ln in lines if (m := STATS_OUT_RE.search(ln))]
            if outputs and len(lines) >= 1 + len(devices) and devices:
                out = outputs[0]
                return sent, {
                    "ticks": int(out[3]),
                    "late": int(out[4]),
                    "missed": int(out[5]),
                    "devices": devices,
                    "busy_s": busy,
                }
            time.sleep(0.02)
        raise RuntimeError("no stats lines after SIGUSR1; log:\n" + self.log()[-2000:])

    def terminate(self, timeout: float = 10.0) -> float:
        """SIGTERM; seconds until the process has exited (blocking waitpid, no polling)."""
        killer = threading.Timer(timeout, self.proc.kill)
        killer.start()
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait()
        took = time.monotonic() - t0
        killer.cancel()
        self._log.close()
        if self.proc.returncode != 0:
            raise RuntimeError(f"daemon exited {self.proc.returncode}; log:\n{self.log()[-2000:]}")
        return took


EXTRA_OUTPUTS = ("sumd", "crsf", "sbus", "mavlink")
EXTRA_CHANNELS = "[node0.x, node0.y, node0.rz, node0.slider, node0.button1]"


class OutputDrain:
    """Far ends for the extra outputs, read and dropped by one thread: a pty each for the
    serial protocols, a local UDP socket for MAVLink (`udpout:` to it)."""

    def __init__(self, protocols: Sequence[str]) -> None:
        pairs = [os.openpty() for p in protocols if p != "mavlink"]
        self.masters = [m for m, _ in pairs]
        self._slaves = [s for _, s in pairs]
        ttys = iter(os.ttyname(s) for s in self._slaves)
        self.udp: socket.socket | None = None
        if "mavlink" in protocols:
            self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.udp.bind(("127.0.0.1", 0))
        self.ports = [self._udp_url() if p == "mavlink" else next(ttys) for p in protocols]
        self.bytes_read = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="output drain", daemon=True)
        self._thread.start()

    def _udp_url(self) -> str:
        assert self.udp is not None
        return f"udpout:127.0.0.1:{self.udp.getsockname()[1]}"

    def _run(self) -> None:
        readable: list[Any] = [*self.masters, *([self.udp] if self.udp else [])]
        while not self._stop.is_set():
            ready, _, _ = select.select(readable, [], [], 0.1)
            for source in ready:
                if isinstance(source, socket.socket):
                    self.bytes_read += len(source.recv(65536))
                else:
                    self.bytes_read += len(os.read(source, 65536))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        for fd in self.masters + self._slaves:
            os.close(fd)
        if self.udp is not None:
            self.udp.close()


def extra_outputs_config(workdir: Path, protocols: Sequence[str], ports: Sequence[str]) -> Path:
    """C2-16B (its port from --port) plus each extra output at its default rate."""
    lines = ["outputs:", "  - protocol: c2-16b"]
    for protocol, port in zip(protocols, ports, strict=True):
        lines.append(f"  - {{protocol: {protocol}, port: '{port}', channels: {EXTRA_CHANNELS}}}")
    config = workdir / "outputs.yaml"
    config.write_text("\n".join(lines) + "\n")
    return config


def run_cpu(
    workdir: Path,
    warmup: float,
    window: float,
    extra_outputs: Sequence[str] = (),
    recordings: Sequence[str] = (),
) -> dict[str, Any]:
    """The daemon at 4 x 1 kHz: 4 T.16000M ramps, or `recordings` (each looped)."""
    replay_dir = workdir / "khz"
    replay_dir.mkdir()
    texts = recordings or [khz_recording(4.0, f"Thrustmaster T.16000M {i}") for i in range(4)]
    for i, text in enumerate(texts):
        (replay_dir / f"device{i}.hid").write_text(text)
    reader = PtyReader(workdir)
    drain = OutputDrain(extra_outputs)
    extra: list[str] = []
    if extra_outputs:
        extra = ["--config", str(extra_outputs_config(workdir, extra_outputs, drain.ports))]
    daemon = DaemonProcess(replay_dir, reader.path, workdir / "cpu.log", extra)
    try:
        nodes = set(range(len(texts)))
        reader.wait_for(lambda f: {x["n"] for x in f if x["k"] == "d"} >= nodes, 20,
                        f"data frames of {len(texts)} nodes")  # fmt: skip
        time.sleep(warmup)
        t0, s0 = daemon.stats()
        cpu0 = daemon.cpu_s()
        time.sleep(window)
        cpu1 = daemon.cpu_s()
        t1, s1 = daemon.stats()
        memory = daemon.memory_kb()
    finally:
        stop_s = daemon.terminate()
        drain.close()
    extra_bytes = {"extra_outputs_bytes": drain.bytes_read} if extra_outputs else {}
    frames = reader.data(t0)
    reader.close()
    times = [f["t"] for f in frames if f["t"] <= t1]
    rates = {k: (s1["devices"][k] - s0["devices"].get(k, 0)) / (t1 - t0) for k in s1["devices"]}
    period = period_figures(times, s1["missed"] - s0["missed"])
    cpu_pct = (cpu1 - cpu0) / window * 100
    replay_s = sum(s1["busy_s"][k] - s0["busy_s"].get(k, 0.0) for k in s1["busy_s"])
    reports = sum(s1["devices"][k] - s0["devices"].get(k, 0) for k in s1["devices"])
    replay_pct = replay_s / (t1 - t0) * 100
    return {
        "cpu_pct": cpu_pct,
        "cpu_replay_pct": replay_pct,
        "cpu_without_replay_pct": cpu_pct - replay_pct,
        "replay_read_us_per_report": replay_s / max(1, reports) * 1e6,
        "rss_mb": memory["VmRSS"] / 1024,
        "rss_peak_mb": memory["VmHWM"] / 1024,
        "devices": len(rates),
        "reports_per_s_min": min(rates.values()),
        "reports_per_s_total": sum(rates.values()),
        "load_period_p99_error_ms": period["period_p99_error_ms"],
        "load_late_ticks": s1["late"] - s0["late"],
        "load_missed_ticks": s1["missed"] - s0["missed"],
        "stop_s": stop_s,
        **extra_bytes,  # what the extra outputs' far ends read: proof they ran
    }


# --- plugging devices while a stick is live ---------------------------------------------------

PLUG_DEVICES = 5
PLUG_REPORT_HZ = 250  # the plugged devices' report rate (a typical full-speed HID stick)
# Enough room on the line for 6 nodes and the connect sequences (4 frames each) in every tick:
# at 115200 baud (6 frames a tick) a connect sequence defers other nodes' data frames, which
# is the protocol's bandwidth rule, not the delay this figure is after.
PLUG_CONFIG = "outputs:\n  - protocol: c2-16b\n    baudrate: 921600\n"


def frame_intervals(frames: Sequence[dict[str, Any]], start: float, end: float) -> list[float]:
    times = [f["t"] for f in frames if start <= f["t"] <= end]
    return [b - a for a, b in itertools.pairwise(times)]


def stick_breaks(frames: Sequence[dict[str, Any]]) -> int:
    """Node 0's frames that are not live or whose message code does not follow the last one
    (a frame lost on the line, or sent twice)."""
    breaks = 0
    for a, b in itertools.pairwise(frames):
        if b["s"] != c2_16b.LIVE or b["c"] != (a["c"] + 1) & 0xFF:
            breaks += 1
    return breaks


def plug_round(
    reader: PtyReader, replay_dir: Path, texts: Sequence[str], window: float
) -> list[float]:
    """Plug the devices one after another over `window` seconds (each once the last one's
    connect sequence is on the line); the plug -> `connected` times. Ends at `window`."""
    from usb2rc.hid.replay import install_file

    start = time.monotonic()
    connect_s: list[float] = []
    for k, text in enumerate(texts):
        plugged = time.monotonic()
        install_file(replay_dir / f"dev{k}.hid", text)
        seen = reader.wait_for(
            functools.partial(_connected_since, plugged), 20, f"device {k + 1}'s connect sequence"
        )
        connect_s.append(seen[0]["t"] - plugged)
        time.sleep(max(0.0, start + (k + 1) * window / (len(texts) + 1) - time.monotonic()))
    time.sleep(max(0.0, start + window - time.monotonic()))
    return connect_s


def unplug_all(reader: PtyReader, replay_dir: Path, count: int) -> None:
    since = time.monotonic()
    for k in range(count):
        (replay_dir / f"dev{k}.hid").unlink()
    reader.wait_for(
        lambda f: sum(1 for x in f if x.get("svc") == "disconnected" and x["t"] >= since) >= count,
        20, "the disconnects",
    )  # fmt: skip
    time.sleep(1.0)


def run_plug_while_live(workdir: Path, window: float, rounds: int) -> dict[str, Any]:
    """A 1 kHz stick live. Each round: a quiet window, then a window of the same length in
    which five devices (real descriptors, 250 reports/s) are plugged one after another, then
    they are unplugged. The longest interval between the stick's frames over the quiet
    windows against the same over the plug windows."""
    replay_dir = workdir / "plug"
    replay_dir.mkdir()
    (replay_dir / "stick.hid").write_text(khz_recording(4.0, "Thrustmaster T.16000M"))
    config = workdir / "plug.yaml"
    config.write_text(PLUG_CONFIG)
    texts = real_device_recordings(PLUG_DEVICES, 4.0, PLUG_REPORT_HZ)
    reader = PtyReader(workdir)
    daemon = DaemonProcess(replay_dir, reader.path, workdir / "plug.log", ["--config", str(config)])
    windows: list[tuple[float, float, bool]] = []  # start, end, plugging
    connect_s: list[float] = []
    try:
        reader.wait_for(lambda f: any(x["k"] == "d" and x["n"] == 0 for x in f), 20, "the stick")
        time.sleep(2.0)  # past start-up
        for _ in range(rounds):
            quiet = time.monotonic()
            time.sleep(window)
            plug = time.monotonic()
            connect_s += plug_round(reader, replay_dir, texts, window)
            windows += [(quiet, plug, False), (plug, time.monotonic(), True)]
            unplug_all(reader, replay_dir, len(texts))
    finally:
        daemon.terminate()
    stick = reader.data(windows[0][0])
    reader.close()
    quiet_dt = [d for a, b, p in windows if not p for d in frame_intervals(stick, a, b)]
    live_dt = [d for a, b, p in windows if p for d in frame_intervals(stick, a, b)]
    return {
        "plug_devices": len(texts) * rounds,
        "plug_quiet_max_interval_ms": max(quiet_dt) * 1e3,
        "plug_live_max_interval_ms": max(live_dt) * 1e3,
        "plug_live_excess_ms": (max(live_dt) - max(quiet_dt)) * 1e3,
        "plug_quiet_p99_interval_ms": percentile(quiet_dt, 0.99) * 1e3,
        "plug_live_p99_interval_ms": percentile(live_dt, 0.99) * 1e3,
        "plug_live_gaps": sum(1 for d in live_dt if d > 1.5 * PERIOD_S),
        "plug_live_stick_breaks": sum(
            stick_breaks([f for f in stick if a <= f["t"] <= b]) for a, b, p in windows if p
        ),
        "plug_connect_ms_median": statistics.median(connect_s) * 1e3,
        "plug_connect_ms_max": max(connect_s) * 1e3,
    }


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(len(ordered) * q))]


def installed_bytecode(workdir: Path) -> dict[str, str]:
    """The environment for a start timed as an installed usb2rc starts: with the bytecode
    written (pip compiles it when it installs the wheel), in a cache of this run's own, so
    the tree stays clean. PYTHONDONTWRITEBYTECODE, set in some shells and containers, made
    every timed start compile usb2rc's source first (+0.1 s)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(workdir / "bytecode")
    return env


def run_starts(workdir: Path, starts: int) -> dict[str, Any]:
    replay_dir = workdir / "start"
    replay_dir.mkdir()
    states = [StickState(x=8192 + i * 100) for i in range(50)]  # from the centre: the guard
    (replay_dir / "stick.hid").write_text(recording(states, hold_s=0.02))
    reader = PtyReader(workdir)
    firsts, datas, stops = [], [], []
    env = installed_bytecode(workdir)
    try:
        warm_up = DaemonProcess(replay_dir, reader.path, workdir / "start-warm-up.log", env=env)
        reader.wait_for(lambda f: f or None, 20, "a frame from the warm-up start")
        warm_up.terminate()
        for i in range(starts):
            daemon = DaemonProcess(replay_dir, reader.path, workdir / f"start{i}.log", env=env)
            t0 = daemon.spawned_at
            try:
                startup = reader.wait_for(
                    functools.partial(_first_since, t0, "startup"), 20, "the startup frame"
                )
                first = reader.wait_for(
                    functools.partial(_first_since, t0, None),
                    20,
                    "the first data frame",
                )
            finally:
                stops.append(daemon.terminate())
            firsts.append(startup["t"] - t0)
            datas.append(first["t"] - t0)
            time.sleep(0.1)
    finally:
        reader.close()
    return {
        "start_first_frame_s": statistics.median(firsts),
        "start_first_data_s": statistics.median(datas),
        "stop_s_median": statistics.median(stops),
        "stop_s_max": max(stops),
    }


# --- driver -----------------------------------------------------------------------------------

GOALS = {  # figure: (limit, "<=" | "abs<=", text)
    "period_p99_error_ms": (0.5, "<=", "≤ 0.5 ms"),
    "period_mean_error_pct": (0.02, "abs<=", "20.000 ms ± 0.02%"),
    "latency_mean_ms": (11.0, "<=", "≤ 11 ms"),
    "latency_max_ms": (21.0, "<=", "≤ 21 ms"),
    "cpu_pct": (5.0, "<=", "≤ 5% of a core"),
    "plug_live_excess_ms": (4.0, "<=", "≤ 4 ms"),
    "rss_mb": (40.0, "<=", "≤ 40 MB"),
    "crsf500_p99_error_ms": (0.3, "<=", "≤ 0.3 ms"),
    "crsf500_missed_ticks": (0, "<=", "none"),
    "stop_s_max": (1.0, "<", "< 1 s"),
}

# How runs are combined: median, except worst-case figures (max) and counts (sum).
WORST = {
    "period_max_error_ms",
    "latency_max_ms",
    "stop_s_max",
    "rss_peak_mb",
    "plug_live_max_interval_ms",
    "plug_live_excess_ms",
    "plug_connect_ms_max",
}
LOWEST = {"reports_per_s_min"}
SUMMED = {
    "late_ticks",
    "missed_ticks",
    "load_late_ticks",
    "load_missed_ticks",
    "gaps",
    "plug_live_gaps",
    "plug_live_stick_breaks",
    "crsf500_ticks",
    "crsf500_missed_ticks",
    "crsf500_late_ticks",
}

ROWS = [
    ("period_p99_error_ms", "period: p99 |period - 20 ms|", "ms", 3),
    ("period_p99_error_inside_ms", "... the driver's own write periods", "ms", 3),
    ("host_sleep_p99_late_ms", "host: p99 late, a plain 20 ms sleep", "ms", 3),
    ("period_p99_error_allowed_ms", "... far end p99 allowed (2x + 0.5)", "ms", 3),
    ("period_max_error_ms", "period: max |period - 20 ms|", "ms", 3),
    ("period_mean_ms", "period: mean", "ms", 5),
    ("period_mean_error_pct", "period: mean error (drift)", "%", 4),
    ("late_ticks", "late ticks (scheduler)", "", 0),
    ("missed_ticks", "missed ticks (scheduler)", "", 0),
    ("latency_mean_ms", "latency report -> frame: mean", "ms", 2),
    ("latency_p99_ms", "latency: p99", "ms", 2),
    ("latency_max_ms", "latency: max", "ms", 2),
    ("latency_unmatched", "latency: reports never carried", "", 0),
    ("input_age_p50_ms", "input age (read -> write): p50", "ms", 3),
    ("input_age_p99_ms", "input age: p99", "ms", 3),
    ("input_age_max_ms", "input age: max", "ms", 3),
    ("cpu_pct", "CPU, 4 devices x 1 kHz", "%", 2),
    ("cpu_replay_pct", "  of which the replay backend", "%", 2),
    ("cpu_without_replay_pct", "  without the replay backend", "%", 2),
    ("replay_read_us_per_report", "replay read per report", "µs", 2),
    ("rss_mb", "RSS, 4 x 1 kHz", "MB", 1),
    ("rss_peak_mb", "RSS peak (VmHWM)", "MB", 1),
    ("reports_per_s_min", "reports/s consumed (slowest dev)", "/s", 1),
    ("load_period_p99_error_ms", "p99 |period error| at 4 x 1 kHz", "ms", 3),
    ("load_missed_ticks", "missed ticks at 4 x 1 kHz", "", 0),
    ("cpu_idle_pct", "CPU, idle (no device)", "%", 2),
    ("cpu_real_pct", "CPU, 4 real descriptors x 1 kHz", "%", 2),
    ("cpu_real_replay_pct", "  of which the replay backend", "%", 2),
    ("cpu_real_without_replay_pct", "  without the replay backend", "%", 2),
    ("rss_real_mb", "  RSS", "MB", 1),
    ("real_reports_per_s_min", "  reports/s consumed (slowest dev)", "/s", 1),
    ("crsf500_p99_error_ms", "CRSF 500 Hz: p99 |period - 2 ms|", "ms", 3),
    ("crsf500_p50_error_ms", "  p50", "ms", 3),
    ("crsf500_tick_p99_ms", "  tick, wake-up to written: p99", "ms", 3),
    ("crsf500_missed_ticks", "  missed ticks", "", 0),
    ("crsf500_host_missed", "  host: a plain 2 ms sleep's missed", "", 0),
    ("crsf500_host_p99_late_ms", "  host: its p99 lateness", "ms", 3),
    ("crsf500_late_ticks", "  late ticks (> 1 ms)", "", 0),
    ("crsf500_c2_p99_error_ms", "  C2-16B beside it: p99 |period error|", "ms", 3),
    ("plug_quiet_max_interval_ms", "stick frames: max interval, quiet", "ms", 2),
    ("plug_live_max_interval_ms", "  ... while 5 devices are plugged", "ms", 2),
    ("plug_live_excess_ms", "  plugging - quiet", "ms", 2),
    ("plug_quiet_p99_interval_ms", "stick frames: p99 interval, quiet", "ms", 2),
    ("plug_live_p99_interval_ms", "  ... while plugging", "ms", 2),
    ("plug_live_gaps", "  stick gaps (> 30 ms) while plugging", "", 0),
    ("plug_live_stick_breaks", "  stick frames not live / out of order", "", 0),
    ("plug_connect_ms_median", "plug -> connect sequence, median", "ms", 1),
    ("plug_connect_ms_max", "plug -> connect sequence, max", "ms", 1),
    ("start_first_frame_s", "start -> startup frame (median)", "s", 3),
    ("start_first_data_s", "start -> first data frame", "s", 3),
    ("stop_s_median", "SIGTERM -> exit (median)", "s", 3),
    ("stop_s_max", "SIGTERM -> exit (max)", "s", 3),
]


def goal_met(name: str, value: float) -> bool | None:
    if name not in GOALS:
        return None
    limit, op, _ = GOALS[name]
    if op == "abs<=":
        return abs(value) <= limit
    if op == "<":
        return value < limit
    return value <= limit


def combine(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in runs[0]:
        values = [r[key] for r in runs if isinstance(r.get(key), int | float)]
        if len(values) != len(runs):
            continue
        if key in WORST:
            out[key] = max(values)
        elif key in LOWEST:
            out[key] = min(values)
        elif key in SUMMED:
            out[key] = sum(values)
        else:
            out[key] = statistics.median(values)
    return out


PARTS = ("period", "cpu", "cpu_real", "idle", "crsf500", "plug", "starts")
# Issue 22's second CPU figure: four real descriptors (BENCH_MODELS), random reports of every
# input report ID at 1 kHz each, 12 s looped (12,000 events per file, as the issue measured).
REAL_SECONDS = 12.0


def run_idle(workdir: Path, warmup: float, window: float) -> dict[str, Any]:
    """The daemon with no device (C2-16B only): what it costs to wait (`cpu_idle_pct`)."""
    idle_dir = workdir / "idle"
    idle_dir.mkdir()
    reader = PtyReader(workdir)
    daemon = DaemonProcess(idle_dir, reader.path, workdir / "idle.log")
    try:
        reader.wait_for(lambda f: next((x for x in f if x.get("svc") == "startup"), None), 20,
                        "the startup frame")  # fmt: skip
        time.sleep(warmup)
        cpu0 = daemon.cpu_s()
        time.sleep(window)
        cpu1 = daemon.cpu_s()
        memory = daemon.memory_kb()
    finally:
        daemon.terminate()
        reader.close()
    return {"cpu_idle_pct": (cpu1 - cpu0) / window * 100, "rss_idle_mb": memory["VmRSS"] / 1024}


def run_cpu_real(workdir: Path, warmup: float, window: float) -> dict[str, Any]:
    """`run_cpu` on the real descriptors; its figures renamed `cpu_real_*`, `rss_real_*`,
    `real_*`."""
    real_dir = workdir / "real"
    real_dir.mkdir()
    texts = named_device_recordings(BENCH_MODELS, REAL_SECONDS, 1000.0)
    figures = run_cpu(real_dir, warmup, window, recordings=texts)
    figures.pop("stop_s", None)
    renamed = {}
    for key, value in figures.items():
        if key.startswith("cpu_"):
            renamed["cpu_real_" + key.removeprefix("cpu_")] = value
        elif key.startswith("rss_"):
            renamed["rss_real_" + key.removeprefix("rss_")] = value
        else:
            renamed["real_" + key] = value
    return renamed


def one_run(args: argparse.Namespace) -> dict[str, Any]:
    parts = args.only or PARTS
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="usb2rc-bench-") as tmp:
        workdir = Path(tmp)
        if "period" in parts:
            result.update(run_period_latency(workdir, args.seconds, args.report_ms))
        if "cpu" in parts:
            result.update(run_cpu(workdir, args.warmup, args.cpu_seconds, args.extra_outputs))
        cpu_stop = result.pop("stop_s", 0.0)
        if "cpu_real" in parts:
            result.update(run_cpu_real(workdir, args.warmup, args.cpu_seconds))
        if "idle" in parts:
            result.update(run_idle(workdir, args.warmup, args.cpu_seconds))
        if "crsf500" in parts:
            result.update(run_crsf500(workdir, args.warmup, args.crsf_seconds))
        if "plug" in parts:
            result.update(run_plug_while_live(workdir, args.plug_seconds, args.plug_rounds))
        if "starts" in parts:
            starts = run_starts(workdir, args.starts)
            starts["stop_s_max"] = max(starts["stop_s_max"], cpu_stop)
            result.update(starts)
    return result


def print_table(figures: dict[str, Any]) -> None:
    print(f"{'figure':36} {'value':>12}  {'goal':20} met")
    for key, label, unit, digits in ROWS:
        if key not in figures:
            continue
        met = goal_met(key, figures[key])
        goal = GOALS[key][2] if key in GOALS else ""
        mark = "" if met is None else ("yes" if met else "NO")
        print(f"{label:36} {figures[key]:>9.{digits}f} {unit:2}  {goal:20} {mark}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="period/latency run (60)")
    parser.add_argument("--report-ms", type=float, default=23.0, help="ramp step (23 ms)")
    parser.add_argument("--cpu-seconds", type=float, default=30.0, help="CPU window (30)")
    parser.add_argument("--warmup", type=float, default=5.0, help="before the CPU window (5)")
    parser.add_argument(
        "--crsf-seconds", type=float, default=10.0, help="CRSF at 500 Hz window (10)"
    )
    parser.add_argument("--starts", type=int, default=5, help="start/stop trials (5)")
    parser.add_argument("--plug-seconds", type=float, default=5.0, help="plug windows (5)")
    parser.add_argument("--plug-rounds", type=int, default=3, help="plug rounds (3)")
    parser.add_argument("--only", nargs="+", choices=PARTS, help="run only these parts")
    parser.add_argument(
        "--extra-outputs",
        nargs="+",
        choices=EXTRA_OUTPUTS,
        default=(),
        help="the CPU run also drives these outputs at their default rates",
    )
    parser.add_argument("--runs", type=int, default=1, help="repeat; medians over runs")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON result here")
    parser.add_argument("--reader-fd", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.reader_fd is not None:
        reader_main(args.reader_fd)
        return
    logging.basicConfig(level=logging.ERROR, format="%(levelname)s %(message)s")
    runs = []
    for i in range(args.runs):
        runs.append(one_run(args))
        if args.runs > 1:
            print(f"run {i + 1}/{args.runs}: " + json.dumps(_rounded(runs[-1])), file=sys.stderr)
    figures = combine(runs)
    print(
        f"daemon bench: {args.runs} run(s), period/latency {args.seconds:g} s, CPU window "
        f"{args.cpu_seconds:g} s, plug windows {args.plug_rounds} x {args.plug_seconds:g} s, "
        f"{args.starts} starts, "
        f"outputs {' + '.join(('c2-16b', *args.extra_outputs))}, "
        "load average "
        f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
    )
    print_table(figures)
    result = {
        "bench": "daemon",
        "runs": args.runs,
        "seconds": args.seconds,
        "cpu_seconds": args.cpu_seconds,
        "loadavg": round(os.getloadavg()[0], 2),
        "figures": _rounded(figures),
        "goals_met": {k: goal_met(k, v) for k, v in figures.items() if k in GOALS},
    }
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))


def _rounded(figures: dict[str, Any]) -> dict[str, Any]:
    return {k: round(v, 6) if isinstance(v, float) else v for k, v in figures.items()}


if __name__ == "__main__":
    main()
