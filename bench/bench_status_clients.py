"""The output tick with status-socket clients connected, in one daemon run.

    .venv/bin/python bench/bench_status_clients.py [--seconds 10] [--rounds 3] [--json PATH]

The daemon (zero config, `--status-socket S`) runs in this process, on one replayed
T.16000M; a reader subprocess stamps the C2-16B frames at the far end of the pty
(bench_daemon.PtyReader), and the clients live in a subprocess of their own, so that they
never take the daemon's GIL. The run alternates windows of --seconds each, --rounds times:

- none: no client on the status socket;
- reading: 5 clients that read every line (what 5 pages through `usb2rc web` cost);
- stuck: 5 clients that connect and never read (each is dropped once its buffer is full).

Per kind of window (its first EDGE_S left out):
- tick p50/p99: how long the C2-16B driver's ticks took, wake-up to written (the driver's
  own `ticks_s`). What a client could add to a tick shows here, and not the wake-up's jitter,
  which on a VM is set by the host (the issue's "tick p99 with 5 clients within 0.1 ms of
  none");
- inside p99: |period - 20 ms| of the driver's own write-to-write periods;
- p99 and max of |period - 20 ms| of node 0's data frames at the far end of the pty.

And the daemon's status counters at the end. Alternating the windows puts any drift of the
machine's load into every kind alike.

Then what one status line costs the daemon, in this process (a `Daemon` on the two demo
recordings, input side only): the whole line (`StatusSource()` + `json.dumps`) and the
`json.dumps` alone, median and max of --calls. The Python part gives the GIL up every
switch interval (0.5 ms in the daemon); `json.dumps` is one C call that holds it throughout,
so its max bounds how late one line can make a tick.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_daemon import PERIOD_S, PtyReader, percentile, ramp_recording

CLIENTS = 5
KINDS = ("none", "reading", "stuck")
EDGE_S = 0.2  # frames this close to a window's change are left out


class Clients:
    """`count` connections to the socket; `reading` ones drain it in a thread of their own."""

    def __init__(self, path: str, count: int, reading: bool) -> None:
        self.socks = []
        for _ in range(count):
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.connect(path)
            self.socks.append(sock)
        self.bytes_read = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain) if reading else None
        if self._thread:
            self._thread.start()

    def _drain(self) -> None:
        selector = selectors.DefaultSelector()
        for sock in self.socks:
            selector.register(sock, selectors.EVENT_READ)
        while not self._stop.is_set():
            for key, _ in selector.select(0.05):
                data = key.fileobj.recv(65536)  # type: ignore[union-attr]
                self.bytes_read += len(data)
                if not data:
                    selector.unregister(key.fileobj)
        selector.close()

    def close(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join()
        for sock in self.socks:
            sock.close()


def last_status(path: str) -> dict[str, Any]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.connect(path)
        status: dict[str, Any] = json.loads(sock.makefile("rb").readline())
        return status


def window_errors(frames: list[dict[str, Any]], start: float, end: float) -> list[float]:
    """|period - 20 ms| of consecutive data frames inside (start, end), edges left out."""
    times = [f["t"] for f in frames if start + EDGE_S <= f["t"] <= end - EDGE_S]
    return [abs(b - a - PERIOD_S) for a, b in itertools.pairwise(times)]


def clients_main() -> None:
    """The clients' own process (so that they never take the daemon's GIL): one command a
    line on stdin, `reading PATH`, `stuck PATH` or `none`; the clients before it are closed,
    the new ones connected, then `ok`."""
    clients: Clients | None = None
    for line in sys.stdin:
        kind, *path = line.split()
        if clients:
            clients.close()
            clients = None
        if kind != "none":
            clients = Clients(path[0], CLIENTS, kind == "reading")
        print("ok", flush=True)
    if clients:
        clients.close()


class ClientsProcess:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--clients"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def become(self, kind: str, path: str) -> None:
        assert self.proc.stdin and self.proc.stdout
        self.proc.stdin.write(f"{kind} {path}\n")
        self.proc.stdin.flush()
        if self.proc.stdout.readline().strip() != "ok":
            raise RuntimeError(f"the clients' process did not become {kind}")

    def close(self) -> None:
        assert self.proc.stdin
        self.proc.stdin.close()
        self.proc.wait(10)


def run(seconds: float, rounds: int) -> dict[str, Any]:
    from usb2rc.configfile import Config
    from usb2rc.daemon import Daemon
    from usb2rc.hid.replay import ReplayBackend

    logging.getLogger("usb2rc").setLevel(logging.ERROR)
    inside: dict[str, list[tuple[list[float], list[float]]]] = {kind: [] for kind in KINDS}
    with tempfile.TemporaryDirectory(prefix="usb2rc-bench-status-") as tmp:
        workdir = Path(tmp)
        replay = workdir / "replay"
        replay.mkdir()
        (replay / "stick.hid").write_text(ramp_recording(2000, 0.023))
        sock = str(workdir / "status.sock")
        reader = PtyReader(workdir)
        clients = ClientsProcess()
        backend = ReplayBackend(replay, loop=True)
        daemon = Daemon(Config.default(), backend, port_override=reader.path, status_socket=sock)
        daemon.start()
        try:
            stats = daemon.outputs[0].driver.stats
            reader.wait_for(lambda f: reader.data(), timeout=20, what="the first data frames")
            windows: list[tuple[str, float, float]] = []
            for kind in [k for _ in range(rounds) for k in KINDS]:
                clients.become(kind, sock)
                time.sleep(EDGE_S)
                stats.new_tick_durations(), stats.new_periods()  # the window starts now
                start = time.monotonic()
                time.sleep(seconds)
                end = time.monotonic()
                inside[kind].append((stats.new_tick_durations(), stats.new_periods()))
                windows.append((kind, start, end))
            clients.become("none", sock)
            status = last_status(sock)["status_socket"]
            reader.wait_for(lambda f: f and f[-1]["t"] > windows[-1][2], 5, "the last frames")
            frames = reader.data()
        finally:
            daemon.stop()
            clients.close()
            reader.close()
    figures: dict[str, Any] = {}
    for kind in KINDS:
        errors = [e for k, a, b in windows if k == kind for e in window_errors(frames, a, b)]
        ticks = [t for took, _ in inside[kind] for t in took]
        periods = [abs(p - PERIOD_S) for _, kept in inside[kind] for p in kept]
        figures[f"{kind}_frames"] = len(errors) + 1
        figures[f"{kind}_p99_error_ms"] = round(percentile(errors, 0.99) * 1e3, 4)
        figures[f"{kind}_max_error_ms"] = round(max(errors) * 1e3, 4)
        figures[f"{kind}_tick_p50_ms"] = round(percentile(ticks, 0.50) * 1e3, 4)
        figures[f"{kind}_tick_p99_ms"] = round(percentile(ticks, 0.99) * 1e3, 4)
        figures[f"{kind}_inside_p99_error_ms"] = round(percentile(periods, 0.99) * 1e3, 4)
    for kind in ("reading", "stuck"):
        for figure in ("p99_error_ms", "tick_p99_ms", "inside_p99_error_ms"):
            difference = figures[f"{kind}_{figure}"] - figures[f"none_{figure}"]
            figures[f"{kind}_minus_none_{figure.removesuffix('_ms')}_ms"] = round(difference, 4)
    figures["clients_dropped"] = status["clients_dropped"]
    return figures


def line_cost(calls: int) -> dict[str, float]:
    """µs per status line and per json.dumps of it (median, max), on the demo recordings."""
    from usb2rc.configfile import Config
    from usb2rc.daemon import Daemon
    from usb2rc.examples import data_dir
    from usb2rc.hid.replay import ReplayBackend
    from usb2rc.status_socket import StatusSource

    logging.getLogger("usb2rc").setLevel(logging.ERROR)  # the plugs' lines: not figures
    backend = ReplayBackend(str(data_dir("demo")), loop=True)
    daemon = Daemon(Config.default(), backend, outputs=False)
    daemon.start()
    try:
        source = StatusSource(daemon.table, daemon.stats_record, daemon.checked)
        time.sleep(0.5)  # the devices plugged and reporting
        whole, dumps = [], []
        for _ in range(calls):
            t0 = time.perf_counter()
            record = source()
            t1 = time.perf_counter()
            json.dumps(record, separators=(",", ":"))
            t2 = time.perf_counter()
            whole.append(t2 - t0)
            dumps.append(t2 - t1)
            time.sleep(0.002)
    finally:
        daemon.stop()
    return {
        "line_us_median": round(statistics.median(whole) * 1e6, 1),
        "line_us_max": round(max(whole) * 1e6, 1),
        "json_dumps_us_median": round(statistics.median(dumps) * 1e6, 1),
        "json_dumps_us_max": round(max(dumps) * 1e6, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="each window (10)")
    parser.add_argument("--rounds", type=int, default=3, help="none/reading/stuck rounds (3)")
    parser.add_argument("--calls", type=int, default=500, help="status lines timed (500)")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON line here")
    parser.add_argument("--clients", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.clients:
        clients_main()
        return
    figures = run(args.seconds, args.rounds)
    figures.update(line_cost(args.calls))
    print(
        f"{'clients':10} {'frames':>7} {'p99 |err| ms':>13} {'max |err| ms':>13} "
        f"{'inside p99':>11} {'tick p50':>9} {'tick p99':>9}"
    )
    for kind in KINDS:
        print(
            f"{kind:10} {figures[f'{kind}_frames']:>7} {figures[f'{kind}_p99_error_ms']:>13.3f}"
            f" {figures[f'{kind}_max_error_ms']:>13.3f}"
            f" {figures[f'{kind}_inside_p99_error_ms']:>11.3f}"
            f" {figures[f'{kind}_tick_p50_ms']:>9.3f} {figures[f'{kind}_tick_p99_ms']:>9.3f}"
        )
    for kind in ("reading", "stuck"):
        print(
            f"5 {kind} clients - none: tick p99 "
            f"{figures[f'{kind}_minus_none_tick_p99_ms']:+.3f} ms, p99 |period error| "
            f"{figures[f'{kind}_minus_none_p99_error_ms']:+.3f} ms at the far end, "
            f"{figures[f'{kind}_minus_none_inside_p99_error_ms']:+.3f} ms inside"
        )
    print(
        f"one status line: {figures['line_us_median']:.0f} µs median, "
        f"{figures['line_us_max']:.0f} µs max; its json.dumps (holds the GIL): "
        f"{figures['json_dumps_us_median']:.0f} µs median, "
        f"{figures['json_dumps_us_max']:.0f} µs max"
    )
    line = json.dumps({"bench": "status_clients", "figures": figures})
    print(line)
    if args.json:
        Path(args.json).write_text(line + "\n")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
