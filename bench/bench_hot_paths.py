"""CPU of the daemon's hot paths: an output tick (and its parts), a reader's pull.

The daemon's CPU at 4 devices x 1000 reports/s is the scheduler's tick, 50 times a second,
and each reader's pulls by the node step, each draining what the device queued since.
Thread CPU time (`time.thread_time`), so other load on the machine changes the figures less
than it changes wall-clock ones (it still evicts caches: compare runs made back to back).

Tick: the real `lines.driver.LineDriver.tick()` of a C2-16B output (follow the link, the node
snapshot `NodeTable.step_if_due` ("collect"), `C2Session.tick` with one data frame per node,
the write) on a pty that a `cat` subprocess
drains, `--nodes` T.16000M devices whose readers' records change every tick (as at 1 kHz):
- `tick_hot_us`: ticks back to back, the best of `--runs` means (the code's own cost);
- `tick_paced_us`: one tick every 20 ms, as the daemon runs it (median): code and data are
  cold in the CPU's caches after 20 ms of other work, which costs several times more;
- `collect_`, `session_`, `write_paced_us`: its parts, measured the same way.

Reader: a pulled `DeviceReader`'s `pull()` (its drain and publish) of `--batch` queued
T.16000M reports (a device whose `read` costs nothing, so this is the reader's and the
decoder's share):
- `reader_pull_hot_us` (best of `--runs` means), `reader_pull_paced_us` (one every 10 ms);
- `replay_pull_c_paced_us`, `replay_pull_python_paced_us`: the pull of a real replay device
  playing at 1 kHz, one every 10 ms, compiled (`_speedups.pull`) and in Python.

    .venv/bin/python bench/bench_hot_paths.py [--nodes 4] [--ticks 2000] [--paced 250]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from daemon_harness import StickState, recording

from usb2rc.configfile import Config
from usb2rc.hid.backend import DeviceGone, DeviceInfo, OutputPort
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import DeviceReader, ReaderRecord
from usb2rc.hid.replay import ReplayBackend, install_file
from usb2rc.lines.driver import LineDriver
from usb2rc.lines.serial_link import SerialLink
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session

PERIOD_S = 0.020


class Source:
    """A reader as the table sees it: one record, replaced as a reader replaces it."""

    def __init__(self, record: ReaderRecord) -> None:
        self.record = record

    def pull(self) -> None:
        """The step's pull: the bench replaces the record itself."""


class Rig:
    def __init__(self, nodes: int, directory: Path, port: str) -> None:
        states = [StickState(x=(7 * i) % 16384, y=(13 * i) % 16384) for i in range(64)]
        for k in range(nodes):
            install_file(directory / f"stick{k}.hid", recording(states, 0.001, f"Stick {k}"))
        backend = ReplayBackend(directory)
        mapping = compile_mapping(Config.default())
        self.table = NodeTable()
        self.feeds: list[tuple[Source, Callable[[bytes], bool], Callable[[], object]]] = []
        self.reports: list[bytes] = [state.report() for state in states]
        for node_id, info in enumerate(backend.enumerate()):
            device = backend.open(info)
            layout = parse_descriptor(device.report_descriptor())
            device.close()
            binding = mapping.bind(info, layout)
            assert binding is not None
            decoder = layout.make_decoder()
            decoder.feed(self.reports[0])
            source = Source(ReaderRecord(decoder.state(), 1, 0, time.monotonic()))
            self.table.add_device(node_id, info, binding, source, "JOYSTICK")
            self.feeds.append((source, decoder.feed, decoder.state))
        session = C2Session("bench", C2Settings())
        link = SerialLink(port, 921600)
        self.output = LineDriver("bench", link, session, self.table.step_if_due, PERIOD_S)
        self.output.link.open_now()
        self._count = 0
        for _ in range(10):  # the startup frame and the connect sequences go out
            self.tick()

    def new_reports(self) -> None:
        """What the readers do between two ticks: a new record per device."""
        self._count += 1
        report = self.reports[self._count % len(self.reports)]
        for source, feed, state in self.feeds:
            feed(report)
            last = source.record
            source.record = ReaderRecord(state(), last.reports + 1, 0, time.monotonic())  # type: ignore[arg-type]

    def tick(self) -> None:
        self.output.tick()


def hot(rig: Rig, ticks: int, runs: int) -> float:
    best = float("inf")
    for _ in range(runs):
        took = 0.0
        for _ in range(ticks):
            rig.new_reports()
            began = time.thread_time()
            rig.tick()
            took += time.thread_time() - began
        best = min(best, took / ticks)
    return best * 1e6


def paced(rig: Rig, ticks: int) -> dict[str, float]:
    """One tick per period; thread CPU per tick and per part (medians, µs)."""
    output, table, session = rig.output, rig.table, rig.output.session
    parts: dict[str, list[float]] = {"tick": [], "collect": [], "session": [], "write": []}
    deadline = time.monotonic()
    for i in range(ticks):
        deadline += PERIOD_S
        rig.new_reports()
        time.sleep(max(0.0, deadline - time.monotonic()))
        if i % 2 == 0:  # the whole tick
            began = time.thread_time()
            rig.tick()
            parts["tick"].append(time.thread_time() - began)
            continue
        # the same work in parts (without the link's follow-up and stats, a few µs)
        t0 = time.thread_time()
        snapshot = table.step_if_due()
        t1 = time.thread_time()
        data = session.tick(time.monotonic(), snapshot)
        t2 = time.thread_time()
        output._send(data)
        t3 = time.thread_time()
        parts["collect"].append(t1 - t0)
        parts["session"].append(t2 - t1)
        parts["write"].append(t3 - t2)
    return {name: statistics.median(values) * 1e6 for name, values in parts.items()}


class QueuedDevice:
    """A device whose reports are already queued: `read` costs a deque pop."""

    def __init__(self) -> None:
        self.info = DeviceInfo(key="bench", path="bench", vid=0x044F, pid=0xB10A)
        self.queue: collections.deque[bytes] = collections.deque()

    def report_descriptor(self) -> bytes:
        return b""

    def read(self, timeout_s: float) -> bytes | None:
        return self.queue.popleft() if self.queue else None

    def open_output(self) -> OutputPort:
        raise DeviceGone("the bench's device has no outputs")

    def close(self) -> None:
        pass


def reader_figures(batch: int, pulls: int, runs: int, paced_pulls: int) -> dict[str, float]:
    """A pulled reader's work per pull (the node step's call: the drain of what is queued,
    one publish)."""
    states = [StickState(x=(7 * i) % 16384, y=(13 * i) % 16384, buttons=i) for i in range(64)]
    reports = [state.report() for state in states]
    device = QueuedDevice()
    with tempfile.TemporaryDirectory() as tmp:
        install_file(Path(tmp) / "s.hid", recording(states[:1], 0.001))
        backend = ReplayBackend(tmp)
        replayed = backend.open(backend.enumerate()[0])
        layout = parse_descriptor(replayed.report_descriptor())
        replayed.close()
    # its thread is not started: it only holds the device, and a pull does not need it
    reader = DeviceReader(device, layout.make_decoder(), lambda r, c: None, pulled=True)

    def pull(k: int) -> float:
        device.queue.extend(reports[(k + i) % len(reports)] for i in range(batch))
        began = time.thread_time()
        reader.pull()
        return time.thread_time() - began

    best = min(sum(pull(k) for k in range(pulls)) / pulls for _ in range(runs))
    paced: list[float] = []
    for k in range(paced_pulls):
        time.sleep(0.01)
        paced.append(pull(k))
    return {
        "reader_pull_hot_us": best * 1e6,
        "reader_pull_paced_us": statistics.median(paced) * 1e6,
    }


def replay_pull_figures(paced_pulls: int) -> dict[str, float]:
    """A pulled reader's pull of a real replay device playing a T.16000M at 1 kHz (random
    axes and buttons), one every 10 ms (about ten reports each), compiled
    (`_speedups.pull`, where built) and in Python: the replay backend's share included."""
    states = [
        StickState(x=(7 * i) % 16384, y=(13 * i) % 16384, buttons=(37 * i) % 256)
        for i in range(int(paced_pulls * 10 * 1.5) + 100)
    ]
    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        install_file(Path(tmp) / "s.hid", recording(states, 0.001, rest_s=0.001))
        for path in ("c", "python"):
            backend = ReplayBackend(tmp)
            device = backend.open(backend.enumerate()[0])
            decoder = parse_descriptor(device.report_descriptor()).make_decoder()
            reader = DeviceReader(device, decoder, lambda r, c: None, pulled=True)
            if path == "python":
                reader._c_pull = None
            elif reader._c_pull is None:
                continue  # the C loops are not built here
            costs = []
            for _ in range(paced_pulls):
                time.sleep(0.01)
                began = time.thread_time()
                reader.pull()
                costs.append(time.thread_time() - began)
            device.close()
            figures[f"replay_pull_{path}_paced_us"] = statistics.median(costs) * 1e6
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, default=4)
    parser.add_argument("--ticks", type=int, default=2000, help="hot ticks")
    parser.add_argument("--paced", type=int, default=250, help="paced ticks (20 ms each)")
    parser.add_argument("--runs", type=int, default=5, help="hot runs (the best counts)")
    parser.add_argument("--batch", type=int, default=10, help="reports per reader pull")
    args = parser.parse_args()
    master, slave = os.openpty()
    drain = subprocess.Popen(["cat"], stdin=master, stdout=subprocess.DEVNULL)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            rig = Rig(args.nodes, Path(tmp), os.ttyname(slave))
            figures = {"tick_hot_us": hot(rig, args.ticks, args.runs)}
            for name, value in paced(rig, args.paced).items():
                figures[f"{name}_paced_us"] = value
            rig.output.link.close()
    finally:
        drain.kill()
        drain.wait()
        os.close(master)
        os.close(slave)
    figures.update(reader_figures(args.batch, args.ticks, args.runs, args.paced))
    figures.update(replay_pull_figures(args.paced))
    for name, value in figures.items():
        print(f"{name:28s} {value:8.1f} µs")
    print(json.dumps({"bench": "hot_paths", "nodes": args.nodes, "figures": figures}))


if __name__ == "__main__":
    main()
