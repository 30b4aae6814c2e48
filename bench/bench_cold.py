"""How the host cools what the daemon touches: the same small piece of work, repeated after a
pause of each length, its thread CPU.

    .venv/bin/python bench/bench_cold.py [--samples 100] [--due] [--touch]

The work is a pulled reader's pull of a replay device that has nothing due (the replay's
checks, the reader's fields, the device lock: a few dozen Python objects), compiled
(`_speedups.pull`, where built) and in Python; the pause is either a sleep or a spin (the
thread never leaves the CPU: it reads the clock in a loop). Back to back the pull costs a few
µs; the figure that matters is how it grows with the pause, at the periods the daemon works
at (2-20 ms). Where it grows in a spin as it does in a sleep, what cools the caches is not
the daemon's own sleep nor its other work but the host (its own ticks and guests), and a
tick's cost follows the memory it touches more than the code it runs (bench/README.md,
"Issue 40: a replay device's pull compiled").

With --due it also pulls what a node step pulls: four real devices (tests/data) replaying
random reports at 1 kHz, every reader pulled after each sleep of 10 and 20 ms (~10 and ~20
reports due each), the four pulls' thread CPU together, compiled and in Python.

With --touch it also builds `cold_touch.c` (gcc, this interpreter's headers) and measures
one call from Python after each sleep, by what the call touches: nothing (the call alone),
sixteen fields of one small C struct (state kept compact, as a C engine would keep it), and
eighteen names looked up on six Python objects in turn (state kept in Python objects, as the
compiled pull and step keep it). Skipped, and said, without a compiler.

Prints one line per pause and path (median µs of thread CPU), then one JSON line.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from daemon_harness import StickState, real_device_recordings, recording

from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import DeviceReader
from usb2rc.hid.replay import ReplayBackend, install_file

HERE = Path(__file__).resolve().parent
PAUSES_S = (0.0001, 0.001, 0.003, 0.010, 0.020)


def spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def pulled_readers(directory: str, compiled: bool) -> list[DeviceReader]:
    """A pulled reader on each replay device of `directory` (`compiled`: with the C pull,
    where built; else the Python pull only), pulled once."""
    backend = ReplayBackend(directory)
    readers = []
    for info in backend.enumerate():
        device = backend.open(info)
        decoder = parse_descriptor(device.report_descriptor()).make_decoder()
        reader = DeviceReader(device, decoder, lambda r, c: None, pulled=True)
        if not compiled:
            reader._c_pull = None
        reader.pull()
        readers.append(reader)
    return readers


def idle_reader(directory: str, compiled: bool) -> DeviceReader:
    """A pulled reader on a replay device whose reports are a minute apart: every pull
    finds nothing due (after the first)."""
    (reader,) = pulled_readers(directory, compiled)
    return reader


def due_costs(samples: int) -> dict[str, float]:
    """A step's four pulls after each sleep, with the reports of that sleep due."""
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        # long enough for either path's pulls (samples x 30 ms of sleeps), each on devices
        # opened anew: a replay plays from its open
        recordings = real_device_recordings(4, 3 * samples * 0.020 + 10.0, 1000.0)
        for k, text in enumerate(recordings):
            install_file(Path(tmp) / f"device{k}.hid", text)
        for compiled in (True, False):
            readers = pulled_readers(tmp, compiled)
            if compiled and readers[0]._c_pull is None:
                continue  # the C loops are not built here
            path = "c" if compiled else "python"
            for seconds in (0.010, 0.020):

                def pulls(readers: list[DeviceReader] = readers) -> None:
                    for reader in readers:
                        reader.pull()

                us = cost_us(pulls, time.sleep, seconds, samples)
                figures[f"due_{path}_after_sleep_{seconds * 1000:g}ms_us"] = round(us, 1)
                print(f"{path:7s} 4 pulls, reports due, after a sleep of {seconds * 1000:g} ms: "
                      f"{us:6.1f} µs")  # fmt: skip
    return figures


def cost_us(
    work: Callable[[], None], pause: Callable[[float], None], seconds: float, n: int
) -> float:
    costs = []
    for _ in range(n):
        pause(seconds)
        began = time.thread_time_ns()
        work()
        costs.append((time.thread_time_ns() - began) / 1000)
    return statistics.median(costs)


def build_touch(workdir: Path) -> ModuleType | None:
    """cold_touch.c built and imported; None without a compiler or Python's headers."""
    gcc = shutil.which("gcc")
    include = Path(sysconfig.get_paths()["include"])
    if gcc is None or not (include / "Python.h").exists():
        return None
    target = workdir / f"cold_touch{sysconfig.get_config_var('EXT_SUFFIX')}"
    command = [gcc, "-O2", "-fPIC", "-shared", f"-I{include}", str(HERE / "cold_touch.c")]
    subprocess.run([*command, "-o", str(target)], check=True)
    spec = importlib.util.spec_from_file_location("cold_touch", target)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Holder:
    """A Python object with eight float fields, as the readers and replays hold theirs."""

    def __init__(self, base: float) -> None:
        for i in range(8):
            setattr(self, f"field{i}", base + i)


def touch_costs(touch: ModuleType, samples: int) -> dict[str, float]:
    """One call after each sleep, by what it touches (see the module docstring)."""
    compact = touch.Compact()
    objects = tuple(Holder(k) for k in range(6))
    names = tuple(f"field{i % 8}" for i in range(18))
    works: dict[str, Callable[[], None]] = {
        "call": lambda: touch.nothing(None),
        "compact_fields": lambda: touch.fields(compact),
        "object_attrs": lambda: touch.attrs(objects, names),
    }
    figures = {}
    for seconds in PAUSES_S:
        for name, work in works.items():
            us = cost_us(work, time.sleep, seconds, samples)
            figures[f"touch_{name}_after_sleep_{seconds * 1000:g}ms_us"] = round(us, 1)
            print(f"{name:15s} after a sleep of {seconds * 1000:5g} ms: {us:6.1f} µs")
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=100, help="pulls per pause and path")
    parser.add_argument("--touch", action="store_true", help="also one call, by what it touches")
    parser.add_argument("--due", action="store_true", help="also a step's pulls, reports due")
    args = parser.parse_args()
    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        states = [StickState(x=i, y=i) for i in range(3)]
        install_file(Path(tmp) / "s.hid", recording(states, 60.0, rest_s=60.0))
        readers = {"c": idle_reader(tmp, True), "python": idle_reader(tmp, False)}
        if readers["c"]._c_pull is None:
            del readers["c"]  # the C loops are not built here
        for pause_name, pause in (("spin", spin), ("sleep", time.sleep)):
            for seconds in PAUSES_S:
                for path, reader in readers.items():
                    us = cost_us(reader.pull, pause, seconds, args.samples)
                    key = f"{path}_after_{pause_name}_{seconds * 1000:g}ms_us"
                    figures[key] = round(us, 1)
                    after = f"{pause_name:5s} of {seconds * 1000:5g} ms"
                    print(f"{path:7s} pull after a {after}: {us:6.1f} µs")
        if args.due:
            figures.update(due_costs(args.samples))
        if args.touch:
            touch = build_touch(Path(tmp))
            if touch is None:
                print("--touch: no gcc or no Python headers here: not measured")
            else:
                figures.update(touch_costs(touch, args.samples))
    print(json.dumps({"bench": "cold", "samples": args.samples, "figures": figures}))


if __name__ == "__main__":
    main()
