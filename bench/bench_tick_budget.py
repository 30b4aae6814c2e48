"""The per-tick budget (issue 22): each protocol's session tick, the codecs' cached paths,
a reader's pulls, and what each allocates, so a regression shows in the figure that moved.

Session ticks (`tick_us_<case>`, `alloc_peak_b_<case>`, `retained_b_<case>`): the line
session of each protocol as the output thread drives it once a tick, its encoding included,
on an open line, fed values that change every tick (as at 1 kHz) from `--inputs` (64)
prepared ones, so the figure is the session's and the codec's, not the bench's:

- `c2_4_nodes`: `C2Engine.tick` with 4 node frames (4 data frames), then `wrote`;
- `sumd_16`, `crsf_16`, `sbus_16`, `ibus_14`: the channel sessions' `frame(values,
  failsafe)` with 16 (iBus 14) channel values;
- `mavlink_override`: `MavlinkEngine.tick` with RC_CHANNELS_OVERRIDE (pymavlink packs it).

`c2_encode_data_4`: 4 `encode_data` calls, the C2-16B codec alone.

`tick_us_*`: the mean over `--ticks` ticks back to back (thread CPU), median of `--runs`.
`alloc_peak_b_*`: tracemalloc, the most memory a tick held at once beyond what it started
with (its temporaries; median over ticks). `retained_b_*`: memory still held after
`--ticks` ticks, per tick (a leak shows here; ~0 expected).

Readers (`reader_*`): `--devices` replayed real descriptors (X52, T.16000M, TWCS, WingMan,
from tests/data/real-devices.json) with random reports of every input report ID at
`--rate` Hz each, read by pulled `DeviceReader`s that this thread pulls on a 20 ms grid (as
the node step of C2-16B alone does), for `--seconds`: `reader_pulls_per_s` (all readers),
`reader_reports_per_s`, `reader_us_per_pull` (the pulls' thread CPU, less the replay
backend's own `busy_s`, per pull) and `reader_cpu_pct` (the same as % of one core). A tree
whose readers are not pulled (an A/B against an older commit) leaves these rows out.

    .venv/bin/python bench/bench_tick_budget.py [--ticks 2000] [--runs 5] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import tempfile
import threading
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

from usb2rc.config import layout
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.ibus.session import IbusSession
from usb2rc.protocols.mavlink.session import ControlValues, MavlinkEngine
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.protocols.sumd import codec as sumd
from usb2rc.protocols.sumd.session import SumdSession

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from daemon_harness import BENCH_MODELS, named_device_recordings

from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import DeviceReader
from usb2rc.hid.replay import ReplayBackend, ReplayDevice, install_file
from usb2rc.nodes.step import NodeFrame
from usb2rc.protocols.c2_16b import codec as c2_16b

GRID_S = 0.020

Tick = Callable[[int], object]  # one tick of a case, given the tick's number
NO_CHANNELS = OutputChannels([])  # a channel session's values are given to `frame`


# --- session ticks --------------------------------------------------------------------------


def node_frames(count: int, inputs: int, rng: random.Random) -> list[list[NodeFrame]]:
    """`inputs` ticks' worth of `count` node frames, every axis and button new each tick."""

    def frame(node_id: int) -> NodeFrame:
        axes = tuple(rng.randint(-32768, 32767) for _ in range(layout.AXIS_COUNT))
        return NodeFrame(node_id, False, axes, rng.getrandbits(32), rng.getrandbits(32))

    return [[frame(node) for node in range(count)] for _ in range(inputs)]


def channel_lists(count: int, low: int, high: int, inputs: int, rng: random.Random) -> list[Any]:
    return [[rng.randint(low, high) for _ in range(count)] for _ in range(inputs)]


def c2_case(inputs: int, rng: random.Random) -> Tick:
    session = C2Engine(C2Settings(baudrate=921600))
    session.line_opened()
    frames = node_frames(4, inputs, rng)
    for k in range(4):  # the startup frame goes out; 4 data frames a tick from then on
        session.wrote(len(session.tick([], frames[k])))

    def tick(k: int) -> object:
        data = session.tick([], frames[k % inputs])
        return session.wrote(len(data))

    return tick


def channel_case(session: Any, values: list[Any]) -> Tick:
    session.line_opened()
    count = len(values)

    def tick(k: int) -> object:
        data = session.frame(values[k % count], False)
        return session.wrote(len(data))

    return tick


def mavlink_case(inputs: int, rng: random.Random) -> Tick:
    session = MavlinkEngine(MavlinkOptions())
    session.line_opened()
    values = [
        ControlValues(False, channels=tuple(rng.randint(1000, 2000) for _ in range(16)))
        for _ in range(inputs)
    ]

    def tick(k: int) -> object:
        messages = session.tick(k * 0.02, values[k % inputs])
        return [session.wrote(len(m)) for m in messages]

    return tick


def encode_data_case(inputs: int, rng: random.Random) -> Tick:
    frames = node_frames(4, inputs, rng)

    def tick(k: int) -> object:
        return [
            c2_16b.encode_data(c2_16b.LIVE, f.node_id, k & 0xFF, f.axes, f.group1, f.group2)
            for f in frames[k % inputs]
        ]

    return tick


def cases(inputs: int) -> dict[str, Tick]:
    rng = random.Random(22)
    return {
        "c2_4_nodes": c2_case(inputs, rng),
        "sumd_16": channel_case(
            SumdSession("bench", NO_CHANNELS, sumd.frame_length(16), 100.0),
            channel_lists(16, 0x2260, 0x3B60, inputs, rng),
        ),
        "crsf_16": channel_case(
            CrsfSession("bench", NO_CHANNELS, CrsfModule(0.004)),
            channel_lists(16, 172, 1811, inputs, rng),
        ),
        "sbus_16": channel_case(
            SbusSession("bench", NO_CHANNELS, 100.0), channel_lists(16, 172, 1811, inputs, rng)
        ),
        "ibus_14": channel_case(
            IbusSession("bench", NO_CHANNELS, 100.0), channel_lists(14, 1000, 2000, inputs, rng)
        ),
        "mavlink_override": mavlink_case(inputs, rng),
        "c2_encode_data_4": encode_data_case(inputs, rng),
    }


def tick_us(tick: Tick, ticks: int, runs: int) -> float:
    means = []
    for _ in range(runs):
        began = time.thread_time()
        for k in range(ticks):
            tick(k)
        means.append((time.thread_time() - began) / ticks)
    return statistics.median(means) * 1e6


def allocations(tick: Tick, ticks: int) -> tuple[float, float]:
    """(median transient peak of a tick, bytes retained per tick), tracemalloc: the peaks
    in one pass, what stays in a second one that records nothing (its own list would)."""
    peaks = [0] * ticks
    tracemalloc.start()
    try:
        tick(0)  # anything lazily built on the first tick is not the tick's
        for k in range(ticks):
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            tick(k + 1)
            peaks[k] = tracemalloc.get_traced_memory()[1] - before
        start = tracemalloc.get_traced_memory()[0]
        for k in range(ticks):
            tick(k + 1)
        end = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    return statistics.median(peaks), (end - start) / ticks


def session_figures(ticks: int, runs: int, inputs: int) -> dict[str, float]:
    figures: dict[str, float] = {}
    for name, tick in cases(inputs).items():
        figures[f"tick_us_{name}"] = tick_us(tick, ticks, runs)
    for name, tick in cases(inputs).items():  # fresh sessions: nothing left from the timing
        peak, retained = allocations(tick, min(ticks, 500))
        figures[f"alloc_peak_b_{name}"] = peak
        figures[f"retained_b_{name}"] = retained
    return figures


# --- readers ----------------------------------------------------------------------------------


def reader_figures(models: int, seconds: float, rate_hz: float) -> dict[str, float]:
    if not callable(getattr(DeviceReader, "pull", None)):
        # an older tree: its readers are not pulled (`pull` came with `pulled=`, 902b4a4; no
        # `inspect.signature`, which a class compiled at install need not have)
        return {}
    with tempfile.TemporaryDirectory() as tmp:
        # looped: the first lap's parse (the replay's cost) comes before the window
        recordings = named_device_recordings(BENCH_MODELS[:models], seconds + 2.0, rate_hz)
        for k, text in enumerate(recordings):
            install_file(Path(tmp) / f"device{k}.hid", text)
        backend = ReplayBackend(tmp, loop=True)
        readers = [pulled_reader(backend, info) for info in backend.enumerate()]
        for reader in readers:
            reader.start()
        try:
            pull_on_the_grid(readers, 1.0)  # started, first batches drained
            before = _reader_counts(readers)
            pulls, cpu_s = pull_on_the_grid(readers, seconds)
            after = _reader_counts(readers)
        finally:
            for reader in readers:
                reader.stop()
            for reader in readers:
                reader.join(1.0)
    reports, replay_s, window = (b - a for a, b in zip(before, after, strict=True))
    own_s = max(0.0, cpu_s - replay_s)
    return {
        "reader_devices": float(len(readers)),
        "reader_pulls_per_s": pulls / window,
        "reader_reports_per_s": reports / window,
        "reader_us_per_pull": own_s / max(1, pulls) * 1e6,
        "reader_cpu_pct": own_s / window * 100,
        "reader_replay_cpu_pct": replay_s / window * 100,
    }


def pulled_reader(backend: ReplayBackend, info: Any) -> Any:
    device = backend.open(info)
    decoder = parse_descriptor(device.report_descriptor()).make_decoder()
    return DeviceReader(device, decoder, lambda r, c: None, pulled=True)


def pull_on_the_grid(readers: list[Any], seconds: float) -> tuple[int, float]:
    """Every reader pulled once per GRID_S for `seconds`: (pulls, this thread's CPU in them)."""
    pulls, cpu_s = 0, 0.0
    started = time.monotonic()
    tick = started
    while tick - started < seconds:
        tick += GRID_S
        time.sleep(max(0.0, tick - time.monotonic()))
        began = time.thread_time()
        for reader in readers:
            reader.pull()
        cpu_s += time.thread_time() - began
        pulls += len(readers)
    return pulls, cpu_s


def _reader_counts(readers: list[Any]) -> tuple[float, ...]:
    reports = sum(reader.reports for reader in readers)
    replay = sum(r.device.busy_s for r in readers if isinstance(r.device, ReplayDevice))
    return float(reports), replay, time.monotonic()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per timed run")
    parser.add_argument("--runs", type=int, default=5, help="timed runs (the median counts)")
    parser.add_argument("--inputs", type=int, default=64, help="prepared inputs, cycled")
    parser.add_argument("--devices", type=int, default=4, help="replayed readers (1..4)")
    parser.add_argument("--rate", type=float, default=1000.0, help="reports/s per device")
    parser.add_argument("--seconds", type=float, default=5.0, help="the readers' window")
    args = parser.parse_args()
    figures = session_figures(args.ticks, args.runs, args.inputs)
    figures.update(reader_figures(args.devices, args.seconds, args.rate))
    for name, value in figures.items():
        unit = "µs" if "_us" in name else ("B" if "_b_" in name else "")
        print(f"{name:34s} {value:10.2f} {unit}")
    print(json.dumps({"bench": "tick_budget", "figures": figures}))


if __name__ == "__main__":
    threading.current_thread().name = "bench"
    main()
