"""Hot-plug latency over the replay backend.

- plug: a recording renamed into the replay directory -> HotplugMonitor's on_added; each
  plug at a random moment of the monitor's poll period, as a user's plug comes (right after
  the unplug, the plug's phase followed how fast the unplug was seen: a faster unplug put
  every plug just after a poll, and showed a whole poll period)
- unplug: the file removed -> the DeviceReader's on_exit (the reader notices it, not the monitor)

    .venv/bin/python bench/bench_hotplug.py [--trials 20] [--poll 0.1]
"""

from __future__ import annotations

import argparse
import random
import statistics
import tempfile
import threading
import time
from pathlib import Path

from usb2rc.hid.backend import DeviceInfo, ErrorCode
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.hotplug import HotplugMonitor
from usb2rc.hid.reader import DeviceReader
from usb2rc.hid.replay import ReplayBackend, install_file

DEMO = Path(__file__).resolve().parent.parent / "usb2rc" / "data" / "demo" / "stick.hid"


class Timings:
    def __init__(self) -> None:
        self.added = threading.Event()
        self.added_at = 0.0
        self.info: DeviceInfo | None = None

    def on_added(self, info: DeviceInfo) -> None:
        self.added_at = time.monotonic()
        self.info = info
        self.added.set()

    def on_removed(self, info: DeviceInfo) -> None:
        pass


def one_trial(
    directory: Path, backend: ReplayBackend, timings: Timings, text: str, phase_s: float
) -> tuple[float, float]:
    timings.added.clear()
    time.sleep(phase_s)  # the plug's moment within the monitor's poll period
    t_plug = time.monotonic()
    path = install_file(directory / "stick.hid", text)
    if not timings.added.wait(10):
        raise RuntimeError("plug not seen within 10 s")
    plug_s = timings.added_at - t_plug
    assert timings.info is not None
    device = backend.open(timings.info)
    layout = parse_descriptor(device.report_descriptor())
    exited = threading.Event()
    exit_at = [0.0]

    def on_exit(reader: DeviceReader, code: ErrorCode | None) -> None:
        exit_at[0] = time.monotonic()
        exited.set()

    reader = DeviceReader(device, layout.make_decoder(), on_exit)
    reader.start()
    t_unplug = time.monotonic()
    path.unlink()
    if not exited.wait(10):
        raise RuntimeError("unplug not seen within 10 s")
    reader.join()
    return plug_s, exit_at[0] - t_unplug


def summary(name: str, values: list[float]) -> str:
    ms = [v * 1000 for v in values]
    return f"{name:<22} median {statistics.median(ms):6.1f} ms   max {max(ms):6.1f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--poll", type=float, default=0.1, help="HotplugMonitor poll_s")
    args = parser.parse_args()
    text = DEMO.read_text()
    plugs, unplugs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        backend = ReplayBackend(directory)
        timings = Timings()
        monitor = HotplugMonitor(backend, timings.on_added, timings.on_removed, args.poll)
        monitor.start()
        phases = random.Random(21)
        try:
            for _ in range(args.trials):
                phase_s = phases.uniform(0.0, args.poll)
                plug_s, unplug_s = one_trial(directory, backend, timings, text, phase_s)
                plugs.append(plug_s)
                unplugs.append(unplug_s)
        finally:
            monitor.stop()
            monitor.join()
    print(f"{args.trials} trials, poll_s={args.poll}")
    print(summary("plug -> on_added", plugs))
    print(summary("unplug -> on_exit", unplugs))


if __name__ == "__main__":
    main()
