"""A node step's pulls of real devices read on hidraw: what the read path costs.

    .venv/bin/python bench/bench_fd_pull.py [--samples 200]

Four pulled readers (the real descriptors of tests/data: X52, T.16000M, P-series, a gamepad),
each on a `HidapiDevice` whose reads come from one end of a SOCK_SEQPACKET pair, which gives
one whole report a `read()` as a hidraw node does (no hidraw here: /dev/uhid is not
reachable). Before each sleep of 10 or 20 ms the bench sends every device the random reports
of that time at 1 kHz (10 or 20 each); after it the four pulls run, and their thread CPU is
taken (median over --samples). Three read paths:

- c: the compiled pull on the device's own fd (`_speedups.pull_fd`): one read() a report in
  C, no Python object a report;
- python: the Python pull on the same fd (`HidapiDevice.read(0.0)`: `os.read` a report);
- hidapi: the Python pull over a handle that reads as cython-hidapi's `read()` does on a
  non-blocking hidraw handle (hid_read: a `poll()` of 0 ms, then the `read()`; then a list of
  ints, which the device turns into bytes), emulated here in Python: the read path before
  the device had an fd of its own.

Prints one line per path and sleep (median µs of the four pulls), then one JSON line (with no
figures, and why, where the C loops are not built).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import select
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from usb2rc.hid import speedups
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import DeviceReader

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from seqpacket_device import SeqpacketDevice  # noqa: E402 - a test helper, found there

DEVICES = ("Saitek/Logitech X52", "Thrustmaster T.16000M", "Saitek P-series", "Asus gamepad")
REPORT_HZ = 1000.0
PATHS = ("c", "python", "hidapi")


def descriptors() -> list[bytes]:
    real = json.loads((ROOT / "tests/data/real-devices.json").read_text())
    by_name = {d["name"]: bytes.fromhex(d["hex"]) for d in real}
    return [next(v for k, v in by_name.items() if k.startswith(name)) for name in DEVICES]


class Handle:
    """A hidapi handle: the descriptor; `read(n)` as cython-hidapi's on a non-blocking
    hidraw handle (a poll of 0 ms, the read, a list of ints)."""

    def __init__(self, desc: bytes, fd: int) -> None:
        self.desc, self.fd = desc, fd
        self.poller = select.poll()
        self.poller.register(fd, select.POLLIN)

    def get_report_descriptor(self) -> list[int]:
        return list(self.desc)

    def get_input_report(self, report_id: int, length: int) -> list[int]:
        raise OSError("not asked here")

    def read(self, size: int, timeout_ms: int = 0) -> list[int]:
        if not self.poller.poll(timeout_ms):
            return []
        return list(os.read(self.fd, size))

    def close(self) -> None:
        pass


class Device:
    """One device: the reader on its end of the pair, the sender on the other, its reports."""

    def __init__(self, node: Path, desc: bytes, path: str, rng: random.Random) -> None:
        self.pair = SeqpacketDevice(node, lambda fd: Handle(desc, fd), own_fd=path != "hidapi")
        self.sender, self.device = self.pair.sender, self.pair.device
        layout = parse_descriptor(desc)
        decoder = layout.make_decoder()
        self.reader = DeviceReader(self.device, decoder, lambda r, c: None, pulled=True)
        if path != "c":
            self.reader._c_pull = None
        plans = layout.report_plans
        self.kinds = [
            (b"" if rid == 0 else bytes([rid]), plan.length - (0 if rid == 0 else 1))
            for rid, plan in plans.items()
        ]
        self.rng = rng

    def send(self, count: int) -> None:
        for _ in range(count):
            head, size = self.rng.choice(self.kinds)
            self.sender.send(head + self.rng.randbytes(size))

    def close(self) -> None:
        self.pair.close()


@contextmanager
def devices(tmp: Path, path: str) -> Iterator[list[Device]]:
    with ExitStack() as stack:
        made = []
        for k, desc in enumerate(descriptors()):
            node = tmp / f"hidraw{k}-{path}"
            node.touch()
            made.append(Device(node, desc, path, random.Random(k)))
            stack.callback(made[-1].close)
        yield made


def pulls_us(made: list[Device], seconds: float, samples: int) -> float:
    costs = []
    count = round(seconds * REPORT_HZ)
    for _ in range(samples):
        for device in made:
            device.send(count)
        time.sleep(seconds)
        began = time.thread_time_ns()
        for device in made:
            device.reader.pull()
        costs.append((time.thread_time_ns() - began) / 1000)
    assert all(d.reader.record.reports >= samples * count for d in made), "reports lost"
    return statistics.median(costs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=200, help="steps per path and sleep")
    args = parser.parse_args()
    figures: dict[str, Any] = {}
    if speedups.compiled() is None:
        print("the C loops are not built here (or switched off): no compiled pull to compare")
        print(json.dumps({"bench": "fd_pull", "samples": args.samples, "figures": figures}))
        return
    with tempfile.TemporaryDirectory() as tmp:
        for seconds in (0.010, 0.020):
            for path in PATHS:
                with devices(Path(tmp), path) as made:
                    us = pulls_us(made, seconds, args.samples)
                figures[f"{path}_after_sleep_{seconds * 1000:g}ms_us"] = round(us, 1)
                print(f"{path:7s} 4 pulls, {seconds * REPORT_HZ:g} reports each, after a sleep "
                      f"of {seconds * 1000:g} ms: {us:6.1f} µs", flush=True)  # fmt: skip
    print(json.dumps({"bench": "fd_pull", "samples": args.samples, "figures": figures}))


if __name__ == "__main__":
    main()
