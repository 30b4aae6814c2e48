"""A pulled reader's compiled pull of a device read on an fd of its own
(`usb2rc.hid._speedups.pull_fd`) against the Python pull (`DeviceReader.pull` over
`HidapiDevice.read(0.0)`).

Each side is a real `HidapiDevice` (its constructor and its reads), its hidapi handle a fake
that answers the descriptor and the reports asked for at open, its `read_fd` one end of a
SOCK_SEQPACKET pair: like a hidraw node, it gives one whole report a `read()`. The test sends
both sides the same reports between pulls; after every pull both must have published the
same record (state, counts, time, press log, bad runs, repeats), told `on_bad_reports` the
same edges, and left their decoders with the same values; a read that fails must fail
alike (the reports of that pull dropped, the same error said). The reports: real
descriptors with and without report IDs, short ones, unknown IDs, refused runs long enough
to put the device in error, repeats, presses, more queued than one pull takes, reports
pending from the open.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from daemon_harness import wait_until
from hypothesis import given, settings
from hypothesis import strategies as st
from seqpacket_device import SeqpacketDevice
from test_compiled_pull import PLAYED, WatchedReader, descriptor, random_reports, stopped_clock

from usb2rc.daemon import Daemon
from usb2rc.hid import hidapi_backend, reader, speedups
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.runtime import stats_text

if not speedups.built():
    if os.environ.get("CI"):
        pytest.fail("the C loops were not built (setup.py; needs a C compiler and Python headers)")
    pytest.skip(
        "the C loops are not built here: only the Python pull runs", allow_module_level=True
    )


class FakeHandle:
    """What a hidapi handle answers at open: the descriptor, and each input report asked for
    (`pending`: report ID -> the report hidapi returns, its ID first)."""

    def __init__(self, desc: bytes, pending: dict[int, bytes]) -> None:
        self.desc, self.pending = desc, pending

    def get_report_descriptor(self) -> list[int]:
        return list(self.desc)

    def get_input_report(self, report_id: int, length: int) -> list[int]:
        if report_id not in self.pending:
            raise OSError("no such report")
        return list(self.pending[report_id])

    def close(self) -> None:
        pass


class Side(WatchedReader):
    """One reader on its own device and socket pair; `c`: the compiled pull, else Python."""

    def __init__(self, node: Path, desc: bytes, pending: dict[int, bytes], c: bool) -> None:
        self.pair = SeqpacketDevice(node, lambda fd: FakeHandle(desc, pending))
        self.sender, self._theirs = self.pair.sender, self.pair.theirs
        self.device = self.pair.device
        c_loops = speedups.compiled()
        assert c_loops is not None
        assert reader._compiled_pull(self.device, False) is c_loops.pull_fd
        super().__init__(self.device, c)

    def send(self, reports: list[bytes]) -> None:
        for report in reports:
            self.sender.send(report)  # a few hundred fit in the queue: the pulls read them

    def seen(self) -> tuple[object, ...]:
        reader, decoder = self.reader, self.reader.decoder
        return (
            reader.record,
            tuple(self.edges),
            repr(reader._pull_error).replace(self.device.info.hidraw, "<node>"),
            reader._last_report,
            list(decoder._values),  # type: ignore[attr-defined]
            decoder._buttons,  # type: ignore[attr-defined]
            decoder.reports,  # type: ignore[attr-defined]
            decoder.bad_reports,  # type: ignore[attr-defined]
            len(self.device._pending),
            self.device.queue_full,
            self.device._drained,
        )

    def close(self) -> None:
        self.pair.close()


@contextmanager
def two_sides(tmp: Path, desc: bytes, pending: dict[int, bytes]) -> Iterator[tuple[Side, Side]]:
    with ExitStack() as stack:
        sides = []
        for name in ("c", "py"):
            node = tmp / f"hidraw-{name}"
            node.touch()  # the node's path: there while plugged (HidapiDevice._gone)
            side = Side(node, desc, pending, c=name == "c")
            stack.callback(side.close)
            sides.append(side)
        yield sides[0], sides[1]


def pull_both(c_side: Side, py_side: Side, clock: Any, step_s: float, label: str) -> None:
    clock.now += step_s
    c_side.reader.pull()
    py_side.reader.pull()
    assert c_side.seen() == py_side.seen(), label


def at_open(rng: random.Random, desc: bytes) -> dict[int, bytes]:
    """The reports the device answers at open (hidapi puts the report ID first, 0: none)."""
    layout = parse_descriptor(desc)
    pending = {}
    for report_id, length in layout.input_report_lengths.items():
        if rng.random() < 0.5:
            body = rng.randbytes(length if report_id == 0 else length - 1)
            pending[report_id] = bytes([report_id]) + body
    return pending


@st.composite
def plays(draw: st.DrawFn) -> dict[str, Any]:
    rng = random.Random(draw(st.integers(0, 2**32)))
    desc = descriptor(draw(st.sampled_from(PLAYED)))
    count = draw(st.sampled_from([1, 5, 40, 400]))
    reports = random_reports(rng, desc, count)
    chunks, at = [], 0
    while at < len(reports):  # sent between two pulls: none, one, a few, more than a pull
        size = rng.choice([0, 1, 3, 20, 120])
        chunks.append(reports[at : at + size])
        at += size
    fail_at = draw(st.integers(0, len(chunks))) if draw(st.integers(0, 3)) == 0 else None
    return {"desc": desc, "pending": at_open(rng, desc), "chunks": chunks, "fail_at": fail_at}


@settings(max_examples=100, deadline=None)
@given(plays())
def test_the_compiled_fd_pull_leaves_what_the_python_pull_leaves(
    tmp_path_factory: pytest.TempPathFactory, played: dict[str, Any]
) -> None:
    tmp = tmp_path_factory.mktemp("fd")
    with stopped_clock() as clock, two_sides(tmp, played["desc"], played["pending"]) as sides:
        c_side, py_side = sides
        for k, chunk in enumerate(played["chunks"]):
            if py_side.reader._pull_error is not None:
                break  # nothing reads any more: the socket's queue would fill
            c_side.send(chunk)
            py_side.send(chunk)
            if k == played["fail_at"]:
                # a read that fails: a directory's fd (EISDIR) where the node's was
                for side in sides:
                    side.device.read_fd = os.open(tmp, os.O_RDONLY)
            pull_both(c_side, py_side, clock, 0.02, f"pull {k}")
        pull_both(c_side, py_side, clock, 0.02, "the last pull")
        for side in sides:
            if side.device.read_fd != side._theirs.fileno():
                os.close(side.device.read_fd)  # type: ignore[arg-type]


def test_the_c_path_takes_every_pull_once_the_open_reports_are_handed_over(
    tmp_path: Path,
) -> None:
    desc = descriptor("Thrustmaster T.16000M")
    rng = random.Random(3)
    with stopped_clock() as clock, two_sides(tmp_path, desc, {0: bytes(65)}) as (c_side, py):
        for k in range(30):
            reports = [rng.randbytes(64) for _ in range(rng.choice([0, 1, 20]))]
            c_side.send(reports)
            py.send(reports)
            pull_both(c_side, py, clock, 0.02, f"pull {k}")
        assert c_side.compiled_pulls == 29  # the first handed back: the report from the open
        assert c_side.reader.record.reports == py.reader.record.reports > 30


def test_more_queued_than_a_pull_takes_is_left_for_the_next(tmp_path: Path) -> None:
    desc = descriptor("Thrustmaster T.16000M")
    with (
        mock.patch.object(reader, "MAX_BATCH", 7),
        stopped_clock() as clock,
        two_sides(tmp_path, desc, {}) as (c_side, py),
    ):
        reports = [bytes([k]) * 64 for k in range(10)]
        c_side.send(reports)
        py.send(reports)
        pull_both(c_side, py, clock, 0.02, "seven")
        assert c_side.reader.record.reports == 7
        pull_both(c_side, py, clock, 0.02, "three")
        assert c_side.reader.record.reports == 10
        assert c_side.compiled_pulls == 2


def test_a_failed_read_is_said_as_the_python_read_says_it(tmp_path: Path) -> None:
    desc = descriptor("Thrustmaster T.16000M")
    with stopped_clock() as clock, two_sides(tmp_path, desc, {}) as (c_side, py):
        for side in (c_side, py):
            side.send([bytes(64)] * 3)
            side.device.read_fd = os.open(tmp_path, os.O_RDONLY)
        pull_both(c_side, py, clock, 0.02, "the failed read")
        error = c_side.reader._pull_error
        assert isinstance(error, OSError) and "read failed" in str(error)
        assert c_side.reader.record.reports == 0  # the pull's reports dropped, as in Python
        (tmp_path / "hidraw-c").unlink()  # the node gone: unplugged
        c_side.reader._pull_error = None
        c_side.device.failed_read = None
        c_side.reader.pull()
        assert "unplugged" in str(c_side.reader._pull_error)
        for side in (c_side, py):
            os.close(side.device.read_fd)  # type: ignore[arg-type]


def test_a_node_that_hung_up_is_unplugged_on_either_path(tmp_path: Path) -> None:
    """A read of nothing (a node whose far end hung up, as umockdev's pty after an unplug)
    is an error, as hidapi's read makes it; with the node gone it says unplugged."""
    desc = descriptor("Thrustmaster T.16000M")
    with stopped_clock() as clock, two_sides(tmp_path, desc, {}) as (c_side, py):
        for side in (c_side, py):
            side.send([bytes(64)] * 2)
        pull_both(c_side, py, clock, 0.02, "before")
        for side in (c_side, py):
            side.sender.close()
            Path(side.device.info.hidraw).unlink()
        pull_both(c_side, py, clock, 0.02, "hung up")
        assert "unplugged" in str(c_side.reader._pull_error)
        assert c_side.compiled_pulls == 1


def test_a_drain_of_a_full_kernel_queue_is_counted_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """As many reports as the kernel queues for an fd, read in one drain: the kernel dropped
    those sent after them. Counted on either path (a drain cut by the pull's limit goes on
    in the next pull), said in the log the first time, shown in the device's stats line
    with how often its reader pulls it since."""
    desc = descriptor("Thrustmaster T.16000M")
    full = hidapi_backend.KERNEL_QUEUE_REPORTS
    with (
        mock.patch.object(reader, "MAX_BATCH", 40),
        stopped_clock() as clock,
        two_sides(tmp_path, desc, {}) as (c_side, py),
    ):
        for k, count in enumerate([full - 1, full, 10, full + 30, 2 * full]):
            for side in (c_side, py):
                side.send([bytes([k]) * 64] * count)
            for _ in range(4):  # the limit: up to four pulls a drain
                pull_both(c_side, py, clock, 0.02, f"{count} reports")
        assert c_side.device.queue_full == py.device.queue_full == 3
        assert c_side.compiled_pulls == 20
    said = [r.message for r in caplog.records if "as many as the kernel keeps" in r.message]
    assert len(said) == 2  # the first time, for each device
    line = stats_text.device_line(
        {"name": "T", "port_path": "1-1", "reports": 1, "reports_per_s": 1.0,
         "bad_reports": 0, "last_report_age_s": 0.1, "kernel_queue_full": 3,
         "pulled_between_steps_ms": 3.94}
    )  # fmt: skip
    assert line.endswith(
        "kernel queue full 3 times (reports dropped), its reader pulls it every 3.9 ms"
    )


@pytest.mark.parametrize("c", [True, False], ids=["compiled", "python"])
def test_a_device_whose_queue_filled_is_pulled_by_its_own_thread_between_the_steps(
    tmp_path: Path, c: bool
) -> None:
    """Once a step's pull finds the kernel's queue full, the reader's thread pulls the device
    too, between the steps: what it sends later is read, its presses noted, with no step at
    all, and the record is the one a single late pull of every report makes (which thread
    pulled changes nothing but the time). With nothing more to read it pulls at the
    slowest pace."""
    desc = descriptor("Thrustmaster T.16000M")
    rng = random.Random(7)
    full = hidapi_backend.KERNEL_QUEUE_REPORTS
    first, later = random_reports(rng, desc, full), random_reports(rng, desc, 90)
    (tmp_path / "kept").mkdir()
    (tmp_path / "twin").mkdir()
    kept_node, twin_node = tmp_path / "kept" / "hidraw0", tmp_path / "twin" / "hidraw0"
    kept_node.touch()
    twin_node.touch()
    with ExitStack() as stack:
        kept, twin = Side(kept_node, desc, {}, c), Side(twin_node, desc, {}, c)
        for side in (kept, twin):
            stack.callback(side.close)
        # the thread closes its device when it ends: a descriptor of its own to close
        kept.device.read_fd = os.dup(kept.device.read_fd)  # type: ignore[arg-type]
        kept.reader.start()
        stack.callback(kept.reader.join, 5.0)
        stack.callback(kept.reader.stop)
        kept.send(first)
        kept.reader.pull()  # the step's: the queue was full
        assert kept.device.queue_full == 1
        assert kept.reader.keep_every_s == reader.KEEP_FIRST_S
        sent = full
        for at in range(0, len(later), 30):  # never a full queue again: no step pulls
            kept.send(later[at : at + 30])
            sent += len(later[at : at + 30])
            wait_until(lambda: kept.reader._taken() == sent, "the reader's own pulls")  # noqa: B023
        twin.send(first + later)  # more than the kernel would keep: a socket keeps them
        twin.reader.pull()
        assert kept.reader.record._replace(at=0) == twin.reader.record._replace(at=0)
        assert kept.reader.record.press_serial > 0
        wait_until(lambda: kept.reader.keep_every_s == reader.KEEP_MAX_S, "the slowest pace")
        assert kept.device.queue_full == 1
        # what the daemon's stats say of it (the log's and `monitor`'s device line)
        line = stats_text.device_line(Daemon._device_stats(kept.reader, 0.0, 1.0))
        assert line.endswith(
            "kernel queue full 1 times (reports dropped), its reader pulls it every 20.0 ms"
        )
        kept.reader.stop()  # a stop ends the thread between two of its pulls
        assert kept.reader.join(5.0) and not kept.reader.is_alive()


@pytest.mark.parametrize(
    ("reports_per_s", "every_s"),
    [
        (8000, 31.5 / 8000),
        (4000, 31.5 / 4000),
        (1000, reader.KEEP_MAX_S),
        (10**6, reader.KEEP_MIN_S),
    ],
)
def test_the_reader_pulls_a_filling_queue_at_half_of_it_at_the_rate_it_reports(
    tmp_path: Path, reports_per_s: int, every_s: float
) -> None:
    node = tmp_path / "hidraw0"
    node.touch()
    side = Side(node, descriptor("Thrustmaster T.16000M"), {}, c=True)
    try:
        side.reader._queue_filled(hidapi_backend.KERNEL_QUEUE_REPORTS)
        side.reader._kept_at = (0, 10.0)
        side.reader.record = side.reader.record._replace(reports=reports_per_s // 2)
        with mock.patch.object(side.reader, "pull"):
            assert side.reader._keep_queue(10.5) == pytest.approx(every_s)
    finally:
        side.close()


def test_a_wrong_call_of_either_compiled_pull_names_the_function_called() -> None:
    c_loops = speedups.compiled()
    assert c_loops is not None
    for name in ("pull", "pull_fd"):
        function = getattr(c_loops, name)
        with pytest.raises(TypeError, match=rf"^{name}\(reader, device, now"):
            function(None)
        with pytest.raises(ValueError, match=rf"^{name}: limit 1\.\.1024"):
            function(None, None, 0.0, 0, 1, 1)
