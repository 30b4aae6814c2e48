"""What one plug costs the daemon's other threads: CPU, the longest C call, GC pauses.

A plug runs Python on the hot-plug thread (the directory scan that finds the file) and on the
lifecycle thread (open, descriptor, decode plan, binding, attach), while the scheduler thread
wants the GIL on time. A thread waiting for the GIL gets it within the switch interval
(`daemon.GIL_SWITCH_S`) *unless* the holder is inside one C call (a regex over a whole file,
`compile()`) or a garbage collection: those are not interrupted. So this prints, per plug and
per thread, the CPU time (`time.thread_time`), the longest single C call in thread CPU time
(a second pass under `sys.setprofile`; calls that block, such as a lock or a read, cost no
CPU and do not show), and the collections the plug set off. Each of `--devices` real
descriptors (tests/data/real-devices.json, `--seconds` of reports at `--rate` Hz, replayed)
is plugged twice: "first" (a model the process has not seen) and "replug" (the same file
written again: a new plug of a known model).

Then the replay device's own cost per report (its `busy_s`): the first lap parses each event
as it is played, later laps replay them.

    .venv/bin/python bench/bench_plug_cost.py [--devices 5] [--seconds 4] [--rate 250]

Runs synchronously in one thread (the readers of the plugged devices run meanwhile, so the
figures include their competition for CPU caches, not for the GIL: thread CPU time).
"""

from __future__ import annotations

import argparse
import gc
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from daemon_harness import real_device_recordings

from usb2rc.configfile import Config
from usb2rc.hid import descriptor
from usb2rc.hid.backend import Device
from usb2rc.hid.descriptor import DeviceLayout
from usb2rc.hid.hotplug import HotplugMonitor
from usb2rc.hid.reader import DeviceReader, OnExit
from usb2rc.hid.replay import ReplayBackend, install_file
from usb2rc.nodes.lifecycle import DeviceLifecycle
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeTable


class LongestCall:
    """sys.setprofile hook: the longest C call (thread CPU time) while enabled."""

    def __init__(self) -> None:
        self.longest = (0.0, "")
        self._started: tuple[float, Any] | None = None

    def __call__(self, frame: FrameType, event: str, arg: Any) -> None:
        if event == "c_call":
            self._started = (time.thread_time(), arg)
        elif event in ("c_return", "c_exception") and self._started is not None:
            began, func = self._started
            self._started = None
            took = time.thread_time() - began
            if took > self.longest[0]:
                self.longest = (took, getattr(func, "__qualname__", repr(func)))


class GcPauses:
    """gc.callbacks: the collections (generation, seconds) between two `take()`s."""

    def __init__(self) -> None:
        self.pauses: list[tuple[int, float]] = []
        self._began = 0.0
        gc.callbacks.append(self._callback)

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._began = time.perf_counter()
        else:
            self.pauses.append((info["generation"], time.perf_counter() - self._began))

    def take(self) -> list[tuple[int, float]]:
        pauses, self.pauses = self.pauses, []
        return pauses


def cpu_of(step: Callable[[], object], profiled: bool) -> tuple[float, float, str]:
    """(thread CPU s, longest C call s, its name) of one call; the C call only if profiled."""
    hook = LongestCall()
    if profiled:
        sys.setprofile(hook)
    began = time.thread_time()
    try:
        step()
    finally:
        took = time.thread_time() - began
        sys.setprofile(None)
    return took, hook.longest[0], hook.longest[1]


class Rig:
    """A replay directory, its monitor and lifecycle, driven from this thread."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.backend = ReplayBackend(directory, loop=True)
        self.readers: list[DeviceReader] = []
        self.lifecycle = DeviceLifecycle(
            self.backend, NodeTable(), compile_mapping(Config.default()), self._make_reader
        )
        self.monitor = HotplugMonitor(
            self.backend, self.lifecycle.plugged, self.lifecycle.unplugged
        )
        self.monitor.initial_devices()

    def _make_reader(self, device: Device, layout: DeviceLayout, on_exit: OnExit) -> DeviceReader:
        reader = DeviceReader(device, layout.make_decoder(), on_exit)
        self.readers.append(reader)
        return reader

    def plug(self, name: str, text: str, profiled: bool) -> dict[str, Any]:
        install_file(self.directory / name, text)
        scan = cpu_of(self.monitor.scan, profiled)
        lifecycle = cpu_of(self.lifecycle.handle_queued, profiled)
        return {"scan": scan, "lifecycle": lifecycle}

    def unplug_all(self) -> None:
        for path in self.directory.glob("*.hid"):
            path.unlink()
        self.monitor.scan()
        self.lifecycle.handle_queued()
        for reader in self.readers:
            reader.stop()
            reader.join(1.0)
        self.readers.clear()


def plug_figures(texts: list[str]) -> dict[str, Any]:
    clear = getattr(getattr(descriptor, "_parse_cached", None), "cache_clear", None)
    if clear is not None:
        clear()  # the recordings were made with parse_descriptor: start with no model known
    pauses = GcPauses()
    rows: dict[str, list[dict[str, Any]]] = {"first": [], "replug": []}
    with tempfile.TemporaryDirectory() as tmp:
        rig = Rig(Path(tmp))
        for kind in ("first", "replug"):
            for k, text in enumerate(texts):
                pauses.take()
                row = rig.plug(f"dev{k}.hid", text, profiled=False)
                row["gc"] = pauses.take()
                rows[kind].append(row)
            rig.unplug_all()
        # the longest C calls, in a pass of its own (the profile hook slows Python down)
        if clear is not None:
            clear()
        longest: dict[str, list[tuple[float, str]]] = {"scan": [], "lifecycle": []}
        for _ in range(2):
            for k, text in enumerate(texts):
                row = rig.plug(f"dev{k}.hid", text, profiled=True)
                for step in longest:
                    longest[step].append(row[step][1:])
            rig.unplug_all()
    gc.callbacks.remove(pauses._callback)
    out: dict[str, Any] = {}
    for kind, kind_rows in rows.items():
        for step in ("scan", "lifecycle"):
            cpu = [row[step][0] * 1e3 for row in kind_rows]
            out[f"plug_{kind}_{step}_cpu_ms_median"] = statistics.median(cpu)
            out[f"plug_{kind}_{step}_cpu_ms_max"] = max(cpu)
        collections = [p for row in kind_rows for p in row["gc"]]
        out[f"plug_{kind}_gc_collections"] = len(collections)
        out[f"plug_{kind}_gc_max_ms"] = max((s * 1e3 for _, s in collections), default=0.0)
    for step, calls in longest.items():
        took, name = max(calls)
        out[f"plug_{step}_longest_c_call_ms"] = took * 1e3
        out[f"plug_{step}_longest_c_call"] = name
    return out


def replay_figures(text: str, reports: int) -> dict[str, float]:
    """µs of replay `read` per report: the first lap (parsing as it plays), later laps."""
    with tempfile.TemporaryDirectory() as tmp:
        install_file(Path(tmp) / "dev.hid", text)
        backend = ReplayBackend(tmp, loop=True, speed=1e6)  # every report is due at once
        device = backend.open(backend.enumerate()[0])
        per_lap = []
        for _ in range(3):
            before = device.busy_s
            for _ in range(reports):
                device.read(1.0)
            per_lap.append((device.busy_s - before) / reports * 1e6)
        device.close()
    return {"replay_first_lap_us_per_report": per_lap[0], "replay_later_us_per_report": per_lap[2]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--rate", type=float, default=250.0)
    args = parser.parse_args()
    texts = real_device_recordings(args.devices, args.seconds, args.rate)
    figures = plug_figures(texts)
    figures.update(replay_figures(texts[0], int(args.seconds * args.rate)))
    for key, value in figures.items():
        shown = f"{value:.3f}" if isinstance(value, float) else str(value)
        print(f"{key:40s} {shown}")
    print(json.dumps({"bench": "plug_cost", "figures": figures}))


if __name__ == "__main__":
    main()
