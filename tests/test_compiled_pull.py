"""A pulled reader's compiled pull of a replay device (`usb2rc.hid._speedups.pull`) against
the Python pull (`DeviceReader.pull` over `ReplayDevice.read_due`).

Two readers play the same recording on two replay devices that started at the same moment,
under one stopped clock that the test moves: one pulls in C, the other in Python only. After
every pull both must have published the same record (state, counts, time, press log, bad
runs, repeats), told `on_bad_reports` the same edges, left their decoders with the same
values, and their devices at the same report; a pull that fails must fail alike. The plays
use real descriptors with and without report IDs, reports that are short or carry an unknown
ID, runs of refused reports long enough to put the device in error, repeated reports, button
presses, recordings longer than one block of the file (a pull that spans two blocks),
blocks the Python parse reads (a line in another spelling), looped plays, an injected read
error and a file removed or replaced while it plays (the gone check, made in C while the
file is there). Deterministic tests
check that the C path takes the pulls (not only hands them back to Python) and hands back
what it must.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from daemon_harness import timed_recording
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid import speedups
from usb2rc.hid.descriptor import ReportDecoder, parse_descriptor
from usb2rc.hid.reader import DeviceReader, ReaderRecord
from usb2rc.hid.replay import ReplayBackend, ReplayDevice, install_file

if not speedups.built():
    if os.environ.get("CI"):
        pytest.fail("the C loops were not built (setup.py; needs a C compiler and Python headers)")
    pytest.skip(
        "the C loops are not built here: only the Python pull runs", allow_module_level=True
    )

REAL = {
    d["name"]: d for d in json.loads((Path(__file__).parent / "data/real-devices.json").read_text())
}
# without report IDs (14 and 64 bytes), and with them (two IDs, one of them 3 bytes long)
PLAYED = ["Saitek/Logitech X52", "Thrustmaster T.16000M", "Saitek P-series", "Asus gamepad"]


def descriptor(prefix: str) -> bytes:
    (name,) = [name for name in REAL if name.startswith(prefix)]
    return bytes.fromhex(REAL[name]["hex"])


class Raw:
    """A report as `timed_recording` writes it."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    def report(self) -> bytes:
        return self.data


def random_reports(rng: random.Random, desc: bytes, count: int) -> list[bytes]:
    """Mostly valid reports (buttons pressed and released at random), some repeated, some
    short or of an unknown ID, and now and then a run of refused ones."""
    layout = parse_descriptor(desc)
    plans = dict(layout.report_plans) if layout.uses_report_ids else {None: layout.report_plans[0]}
    reports: list[bytes] = []
    while len(reports) < count:
        kind = rng.choices(["valid", "repeat", "short", "unknown", "bad run"], [80, 10, 4, 3, 2])[0]
        rid = rng.choice(list(plans))
        length = plans[rid].length
        head = b"" if rid is None else bytes([rid])
        if kind == "repeat" and reports:
            reports.append(reports[-1])
        elif kind == "short":
            reports.append((head + rng.randbytes(length))[: rng.randrange(1, length)])
        elif kind == "unknown" and layout.uses_report_ids:
            unknown = next(i for i in range(1, 256) if i not in plans)
            reports.append(bytes([unknown]) + rng.randbytes(length - 1))
        elif kind == "bad run":
            reports += [head[:1] or b"\x00"] * rng.randrange(15, 45)
        else:
            body = rng.randbytes(length - len(head))
            reports.append(head + body)
    return reports[:count]


class Clock:
    """time.monotonic, stopped: both pulls of a step see the same now."""

    def __init__(self) -> None:
        self.now = 5000.0

    def __call__(self) -> float:
        return self.now


@contextmanager
def stopped_clock() -> Iterator[Clock]:
    clock = Clock()
    with mock.patch("time.monotonic", clock):
        yield clock


class WatchedReader:
    """A pulled reader on `device`, the edges it told kept; `c`: its compiled pull, counted,
    else the Python pull only."""

    def __init__(self, device: Any, c: bool) -> None:
        layout = parse_descriptor(device.report_descriptor())
        self.edges: list[ReaderRecord] = []
        self.reader = DeviceReader(device, layout.make_decoder(), lambda r, c: None, pulled=True)
        self.reader.on_bad_reports = lambda reader, record: self.edges.append(record)
        self.compiled_pulls = 0
        if c:
            real = self.reader._c_pull
            assert real is not None

            def counted(*args: Any) -> bool | None:
                pulled = real(*args)
                self.compiled_pulls += pulled is True
                return pulled

            self.reader._c_pull = counted
        else:
            self.reader._c_pull = None


class Side(WatchedReader):
    """One reader on its own replay device; `c`: the compiled pull, else Python only."""

    def __init__(self, backend: ReplayBackend, c: bool) -> None:
        self.device: ReplayDevice = backend.open(backend.enumerate()[0])
        super().__init__(self.device, c)

    def pull(self) -> None:
        self.reader.pull()

    def seen(self) -> tuple[object, ...]:
        reader, decoder = self.reader, self.reader.decoder
        return (
            reader.record,
            tuple(self.edges),
            repr(reader._pull_error),
            reader._last_report,
            list(decoder._values),  # type: ignore[attr-defined]
            decoder._buttons,  # type: ignore[attr-defined]
            decoder.reports,  # type: ignore[attr-defined]
            decoder.bad_reports,  # type: ignore[attr-defined]
            self.device._batch.left,
            self.device._batch.next_due,
            self.device._lap,
            self.device._next_gone_check,
            self.device._quiet_until,
            self.device._gone,
        )


def change_file(path: Path, how: str) -> None:
    """The played file removed, or made another file at its path: renamed over by a copy
    (a new inode: its time and size the same), touched (a new time only), grown (a new
    size only)."""
    if how == "remove":
        path.unlink()
    elif how == "replace":
        copy = path.with_name(".copy")
        shutil.copy2(path, copy)
        copy.replace(path)
    elif how == "touch":
        st = path.stat()
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1))
    else:  # grown, its time kept: only its size tells
        st = path.stat()
        with path.open("a") as file:
            file.write("# grown\n")
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def play(
    tmp: Path,
    text: str,
    steps: list[float],
    loop: bool = False,
    change_at: int | None = None,
    change: str = "remove",
) -> tuple[Side, Side]:
    """Both sides pulled after each of `steps` (seconds the clock moves first); the file
    changed before step `change_at` (`change_file`). Their views compared at every step."""
    path = install_file(tmp / "dev.hid", text)
    with stopped_clock() as clock:
        backend = ReplayBackend(tmp, loop=loop)
        c_side, py_side = Side(backend, c=True), Side(backend, c=False)
        for k, step in enumerate(steps):
            if k == change_at:
                change_file(path, change)
            clock.now += step
            c_side.pull()
            py_side.pull()
            assert c_side.seen() == py_side.seen(), f"step {k} at +{clock.now - 5000.0:.4f} s"
    return c_side, py_side


@st.composite
def plays(draw: st.DrawFn) -> dict[str, Any]:
    rng = random.Random(draw(st.integers(0, 2**32)))
    desc = descriptor(draw(st.sampled_from(PLAYED)))
    count = draw(st.sampled_from([1, 5, 40, 400, 1500]))
    reports = random_reports(rng, desc, count)
    gap = draw(st.sampled_from([0.0, 0.0005, 0.001, 0.004]))
    at, events = 0.0, []
    for report in reports:
        at += gap * rng.random() * 2
        events.append((at, Raw(report)))
    extra = ""
    if draw(st.integers(0, 3)) == 0:  # a quarter of the plays end in a read error
        extra = f"# usb2rc-fault: read-error at {draw(st.floats(0.0, at + 0.1)):.4f}"
    steps = draw(
        st.lists(st.sampled_from([0.0, 0.0003, 0.002, 0.01, 0.02, 0.06]), min_size=10, max_size=120)
    )
    text = timed_recording(events, descriptor=desc, extra=extra)
    if draw(st.booleans()):  # lines in another spelling: blocks the Python parse reads
        lines = text.split("\n")
        for k in range(len(lines)):
            if lines[k].startswith("E: ") and rng.random() < 0.05:
                lines[k] = "E:  " + lines[k][3:]
        text = "\n".join(lines)
    return {
        "text": text,
        "steps": [0.0, *steps, 0.5, 2.0],  # and the rest of the play, in two pulls
        "loop": draw(st.booleans()),
        "change_at": draw(st.integers(1, 120)) if draw(st.integers(0, 3)) == 0 else None,
        "change": draw(st.sampled_from(["remove", "replace", "touch", "grow"])),
    }


@settings(max_examples=150, deadline=None)
@given(plays())
def test_the_compiled_pull_leaves_what_the_python_pull_leaves(
    tmp_path_factory: pytest.TempPathFactory, played: dict[str, Any]
) -> None:
    play(tmp_path_factory.mktemp("play"), **played)


def steady_text(reports: int, rid: int | None = None) -> str:
    desc = descriptor("Saitek P-series" if rid else "Thrustmaster T.16000M")
    length = 7 if rid else 64
    rng = random.Random(7)
    head = bytes([rid]) if rid else b""
    events = [(k * 0.001, Raw(head + rng.randbytes(length - len(head)))) for k in range(reports)]
    return timed_recording(events, descriptor=desc)


@pytest.mark.parametrize("rid", [None, 1])
def test_the_c_path_takes_a_streaming_devices_pulls(tmp_path: Path, rid: int | None) -> None:
    """Across the file's blocks and every gone check: not one pull handed back."""
    steps = [0.0] + [0.01] * 150
    c_side, py_side = play(tmp_path, steady_text(1600, rid), steps)
    assert c_side.compiled_pulls == len(steps)
    assert c_side.reader.record.reports == py_side.reader.record.reports == 1501  # 0 to 1.5 s


def test_refused_runs_and_their_edges_are_pulled_in_c(tmp_path: Path) -> None:
    desc = descriptor("Thrustmaster T.16000M")
    good = Raw(bytes(64))
    events = [(0.0, good)] + [(0.001 * k, Raw(b"\x01")) for k in range(1, 30)] + [(0.05, good)]
    steps = [0.0, 0.01, 0.01, 0.01, 0.03]
    c_side, _ = play(tmp_path, timed_recording(events, descriptor=desc), steps)
    assert [record.in_error for record in c_side.edges] == [True, False]
    assert c_side.compiled_pulls == len(steps)


def test_a_fault_and_a_changed_file_are_the_python_reads_to_raise(tmp_path: Path) -> None:
    text = steady_text(400)
    c_side, _ = play(
        tmp_path,
        text.replace("\nE:", "\n# usb2rc-fault: read-error at 0.1\nE:", 1),
        [0.0, 0.05, 0.1],
    )
    assert isinstance(c_side.reader._pull_error, OSError)
    for how in ("remove", "replace", "touch", "grow"):
        (tmp_path / how).mkdir()
        c_side, _ = play(tmp_path / how, text, [0.0, 0.05, 0.1, 0.1], change_at=2, change=how)
        assert "removed or replaced" in str(c_side.reader._pull_error), how


def test_a_close_in_progress_hands_the_pull_back(tmp_path: Path) -> None:
    install_file(tmp_path / "dev.hid", steady_text(10))
    side = Side(ReplayBackend(tmp_path), c=True)
    with side.reader._device_lock:
        assert (
            side.reader._c_pull(side.reader, side.device, time.monotonic(), 1000, 32, 20) is False
        )


def test_a_decoder_without_the_c_drain_is_never_pulled_in_c(tmp_path: Path) -> None:
    install_file(tmp_path / "dev.hid", steady_text(10))
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    decoder = ReportDecoder(parse_descriptor(device.report_descriptor()), compiled=False)
    reader = DeviceReader(device, decoder, lambda r, c: None, pulled=True)
    assert reader._c_pull is not None
    reader.pull()
    assert reader._c_pull is None
