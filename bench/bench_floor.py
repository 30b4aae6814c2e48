"""The floor of the drivers' loop: what its bare shape costs compiled and interpreted.

    .venv/bin/python bench/bench_floor.py [--rounds 3] [--seconds 10] [--lead-us 500]

How far could a C engine go? `floor_loop.c` (built here with `gcc -O2`) and its line-for-line
Python twin `floor_loop.py` run the shape of usb2rc's drivers' thread with none of its
work: bench_hot_path.py's five outputs at their default rates (C2-16B 50 Hz 35 bytes, SUMD
100 Hz, SBUS 100 Hz, CRSF 250 Hz on ptys, MAVLink 50 Hz on a UDP socket), each tick started
a lead before its deadline, 4 devices pulled at each start (a read(2) per report until
EAGAIN, as hidraw gives them), a frame made of the last report with a CRC, and written on
the deadline: 300 starts and 300 write moments a second, as the daemon with every node
live. The devices are SOCK_SEQPACKET socket pairs (one report per read, as hidraw) fed at
1 kHz each by a thread here; the far ends are read and dropped here too.

Each round runs the two in turn (the order alternating); the CPU of all the child's threads
(schedstat) over the window, its voluntary context switches, and the reports it read.
Prints the medians over the rounds, then one JSON line ({"bench": "floor", ...}).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_daemon import OutputDrain  # noqa: E402
from bench_hot_path import FIVE, threads_now  # noqa: E402

# protocol -> (period µs, frame bytes) at its default rate
OUTPUTS = {
    "c2-16b": (20000, 35),
    "sumd": (10000, 21),
    "sbus": (10000, 25),
    "crsf": (4000, 26),
    "mavlink": (20000, 50),
}
DEVICES = 4
REPORT_HZ = 1000.0
REPORT_BYTES = 20
WARMUP_S = 2.0


class Feeder:
    """Reports into each device's socket pair at REPORT_HZ, on absolute deadlines."""

    def __init__(self, devices: int) -> None:
        pairs = [socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET) for _ in range(devices)]
        self.ends = [theirs for _, theirs in pairs]
        self._ours = [ours for ours, _ in pairs]
        for end in self.ends:
            end.setblocking(False)
        self._stop = threading.Event()
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="feeder", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        due = time.monotonic()
        while not self._stop.is_set():
            report = os.urandom(REPORT_BYTES)
            for sock in self._ours:
                try:
                    sock.send(report)
                    self.sent += 1
                except BlockingIOError:  # the child is not reading: dropped, as a full queue
                    pass
            due += 1.0 / REPORT_HZ
            time.sleep(max(0.0, due - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        for sock in self._ours + self.ends:
            sock.close()


def build(workdir: Path) -> Path | None:
    """floor_loop.c built with gcc -O2; None without a compiler."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    binary = workdir / "floor_loop"
    subprocess.run([gcc, "-O2", "-o", str(binary), str(HERE / "floor_loop.c")], check=True)
    return binary


def run_one(command: list[str], fds: list[int], seconds: float) -> dict[str, float]:
    """The loop started, warmed up, measured over `seconds`, stopped."""
    proc = subprocess.Popen(command, pass_fds=fds, stdin=subprocess.DEVNULL)
    try:
        time.sleep(WARMUP_S)
        if proc.poll() is not None:
            raise RuntimeError(f"{command[0]} exited {proc.returncode}")
        a, t0 = threads_now(proc.pid), time.monotonic()
        time.sleep(seconds)
        b, t1 = threads_now(proc.pid), time.monotonic()
    finally:
        proc.terminate()
        proc.wait(10)
    cpu_s = sum(ns - a.get(tid, (0, 0))[0] for tid, (ns, _) in b.items()) / 1e9
    wakes = sum(n - a.get(tid, (0, 0))[1] for tid, (_, n) in b.items())
    return {"cpu_pct": cpu_s / (t1 - t0) * 100, "wakes_per_s": wakes / (t1 - t0)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--lead-us", type=int, default=500)
    parser.add_argument("--devices", type=int, default=DEVICES, help="0: no pull at all")
    parser.add_argument(
        "--outputs", nargs="+", default=list(FIVE), choices=FIVE, help="which of the five"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        binary = build(Path(tmp))
        protocols = [p for p in FIVE if p in args.outputs]
        drain = OutputDrain(protocols)
        feeder = Feeder(args.devices)
        fds: list[int] = []
        try:
            argv = [str(args.lead_us)]
            for end in feeder.ends:
                argv += ["--dev", str(end.fileno())]
                fds.append(end.fileno())
            udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            for protocol, port in zip(protocols, drain.ports, strict=True):
                if protocol == "mavlink":
                    host, _, number = port.removeprefix("udpout:").rpartition(":")
                    udp.connect((host, int(number)))
                    udp.setblocking(False)
                    fd = udp.fileno()
                else:
                    fd = os.open(port, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
                fds.append(fd)
                period_us, length = OUTPUTS[protocol]
                argv += ["--out", str(fd), str(period_us), str(length)]
            loops = {"python": [sys.executable, str(HERE / "floor_loop.py"), *argv]}
            if binary is not None:
                loops["c"] = [str(binary), *argv]
            results: dict[str, list[dict[str, float]]] = {name: [] for name in loops}
            for round_ in range(args.rounds):
                order = list(loops) if round_ % 2 == 0 else list(reversed(loops))
                for name in order:
                    figures = run_one(loops[name], fds, args.seconds)
                    results[name].append(figures)
                    print(f"round {round_ + 1}/{args.rounds} {name}: {json.dumps(figures)}")
        finally:
            feeder.close()
            drain.close()
            for fd in fds[args.devices :]:
                with contextlib.suppress(OSError):
                    os.close(fd)
    print(f"floor of the drivers' loop: {args.rounds} round(s) of {args.seconds:g} s, outputs "
          f"{' '.join(protocols)}, {args.devices} devices x {REPORT_HZ:g} Hz, lead "
          f"{args.lead_us} µs, load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    medians = {}
    for name, rounds in results.items():
        cpu = [r["cpu_pct"] for r in rounds]
        wakes = [r["wakes_per_s"] for r in rounds]
        medians[name] = {"cpu_pct": statistics.median(cpu), "wakes_per_s": statistics.median(wakes)}
        shown = " ".join(f"{c:.2f}" for c in cpu)
        print(f"  {name:7} CPU {medians[name]['cpu_pct']:.2f} % of a core ({shown}), "
              f"wake-ups {medians[name]['wakes_per_s']:.0f}/s")  # fmt: skip
    print(json.dumps({"bench": "floor", "rounds": results, "medians": medians}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
