"""One owner per piece of shared state (issue 21): each test drives the two sides of a former
race explicitly through a seam, or checks which thread writes a field; none relies on luck.

- `Daemon._become_ready`: the check and the set are one step (READY=1 goes out once);
- `LineDriver.period_s`: written by the drivers' thread only, which follows a CRSF module;
- `CrsfModule.link`: the module's figures with their time, one value (tests/test_crsf_sbus.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import serial

from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.replay import ReplayBackend
from usb2rc.lines.driver import DriverThread, LineDriver
from usb2rc.lines.link import LineEvent
from usb2rc.lines.serial_link import SerialLink
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.session import CrsfSession

REAL_SERIAL_FOR_URL = serial.serial_for_url
WAIT_S = 5.0  # a safety net only: every wait below ends on its condition


def _daemon(tmp_path: Path, protocol: str = "c2-16b", **hooks: Any) -> Daemon:
    config = Config(outputs=(OutputConfig(protocol=protocol, port="loop://", rate_hz=50),))
    return Daemon(config, ReplayBackend(tmp_path), **hooks)


class _CheckSeam(threading.Event):
    """The ready flag, with a seam in its check: the first caller to find it unset stops
    there until `go`, as an output thread preempted between the check and the set."""

    def __init__(self) -> None:
        super().__init__()
        self.first_inside = threading.Event()
        self.go = threading.Event()

    def is_set(self) -> bool:
        unset = not super().is_set()
        if unset and not self.first_inside.is_set():
            self.first_inside.set()
            assert self.go.wait(WAIT_S)
        return not unset


class _SaysWhenWaited:
    """A lock that tells when a second thread waits for it."""

    def __init__(self, waited: threading.Event) -> None:
        self._lock = threading.Lock()
        self._waited = waited

    def __enter__(self) -> None:
        if not self._lock.acquire(blocking=False):
            self._waited.set()
            self._lock.acquire()

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


def test_two_outputs_becoming_ready_together_send_ready_once(tmp_path: Path) -> None:
    readies: list[str] = []
    daemon = _daemon(tmp_path, on_ready=lambda: readies.append(threading.current_thread().name))
    seam = _CheckSeam()
    second_came = threading.Event()  # the second output waits for the lock, or went past
    daemon._ready_once = seam
    daemon._ready_lock = _SaysWhenWaited(second_came)  # type: ignore[assignment]

    def become_ready(then: threading.Event | None) -> None:
        daemon._become_ready("ready")
        if then is not None:
            then.set()

    first = threading.Thread(target=become_ready, args=(None,), name="output1")
    second = threading.Thread(target=become_ready, args=(second_came,), name="output2")
    first.start()
    assert seam.first_inside.wait(WAIT_S)  # output1 checked: not ready yet
    second.start()
    assert second_came.wait(WAIT_S)  # output2 waits for output1's step (or, racy, went past)
    seam.go.set()
    first.join(WAIT_S)
    second.join(WAIT_S)
    assert readies == ["output1"]


def _watch_period(thread: LineDriver, writers: set[str]) -> None:
    """Notes in `writers` which threads assign the driver's `period_s`."""

    def setattr_watched(obj: Any, name: str, value: Any) -> None:
        if name == "period_s":
            writers.add(threading.current_thread().name)
        object.__setattr__(obj, name, value)

    thread.__class__ = type("Watched", (type(thread),), {"__setattr__": setattr_watched})


# every assignment to the driver's fields is watched (its class swapped for one with a
# `__setattr__`): a compiled LineDriver's fields are stored in C, past any `__setattr__`
@pytest.mark.interpreted
def test_only_the_drivers_thread_writes_the_period_and_follows_the_module(
    tmp_path: Path,
) -> None:
    daemon = _daemon(tmp_path, protocol="crsf")
    thread = daemon.outputs[0].driver
    assert isinstance(thread, LineDriver) and isinstance(thread.session, CrsfSession)
    writers: set[str] = set()
    _watch_period(thread, writers)
    # the module asks for 10 ms (0.1 µs units): next_due follows it from the first tick
    thread.session.received(crsf.encode_timing_sync(100_000, 0), time.monotonic())
    daemon.drivers.start()
    try:
        for _ in range(int(WAIT_S / 0.01)):
            if thread.stats.ticks >= 3:
                break
            threading.Event().wait(0.01)
    finally:
        daemon.drivers.stop()
        daemon.drivers.join(WAIT_S)
    assert thread.stats.ticks >= 3
    assert writers == {daemon.drivers.name}
    assert thread.period_s == 0.010


# --- SerialLink: one writer per field; a close waits for a read in progress -----------------


class _Seams:
    """Seams in one `loop://` port: a read that stops until `go` (or fails), and a log of
    what happened to the port in which order."""

    def __init__(self) -> None:
        self.ports: list[serial.SerialBase] = []
        self.order: list[str] = []
        self.reading = threading.Event()
        self.go = threading.Event()
        self.fail_reads = False
        self.closing = threading.Event()

    def open(self, url: str, **kwargs: Any) -> serial.SerialBase:
        port = REAL_SERIAL_FOR_URL("loop://", **kwargs)
        real_read, real_close = port.read, port.close

        def read(size: int = 1) -> bytes:
            self.reading.set()
            assert self.go.wait(WAIT_S)
            if self.fail_reads:
                raise serial.SerialException(
                    "device reports readiness to read but returned no data"
                )
            data: bytes = real_read(size)
            self.order.append("read done")
            return data

        def close() -> None:
            self.order.append("closed")
            self.closing.set()
            real_close()

        port.read, port.close = read, close  # type: ignore[method-assign]
        self.ports.append(port)
        return port


def test_a_port_lost_during_a_read_is_closed_after_the_read(monkeypatch: Any) -> None:
    """The writer finds the line lost while the RX thread is inside `port.read`: it closes
    the port only once the read is over (a read on a closed pyserial port raises TypeError
    or AttributeError, which the link no longer catches)."""
    seams = _Seams()
    monkeypatch.setattr(serial, "serial_for_url", seams.open)
    link = SerialLink("seams://")
    assert link.open_now() and link.line_event() is LineEvent.OPENED
    link.write(b"abc")
    link._port_lock = _SaysWhenWaited(seams.closing)  # type: ignore[assignment]
    got: list[bytes] = []
    rx = threading.Thread(target=lambda: got.append(link.read()), name="rx")
    rx.start()
    assert seams.reading.wait(WAIT_S)  # the RX thread is inside port.read
    writer = threading.Thread(target=link._lost, args=(OSError("write failed"),), name="w")
    writer.start()
    assert seams.closing.wait(WAIT_S)  # the writer waits for the read (racy: closes now)
    seams.go.set()
    rx.join(WAIT_S)
    writer.join(WAIT_S)
    assert seams.order == ["read done", "closed"]
    assert got == [b"abc"] and not link.is_open
    link.close()


# every assignment to the link's fields is watched (a SerialLink subclass with a
# `__setattr__`): a compiled class cannot be subclassed here, and stores past it
@pytest.mark.interpreted
def test_each_link_field_has_one_writer_thread(monkeypatch: Any) -> None:
    """A whole journey (open in the helper thread, adopt, write, a read fails in the RX
    thread, the writer closes and reopens) with every field assignment recorded: each
    field is written by one thread (`_offer`, the opener's handoff, only under its lock)."""
    seams = _Seams()
    monkeypatch.setattr(serial, "serial_for_url", seams.open)
    writers: dict[str, set[str]] = {}
    offers_unlocked: list[str] = []

    def record(link: Any, name: str, value: Any) -> None:
        object.__setattr__(link, name, value)
        who = threading.current_thread().name
        if who == "MainThread":  # the constructor; close() at stop
            return
        writers.setdefault(name, set()).add("opener" if who.startswith("open ") else who)
        if name == "_offer" and not link._lock.locked():
            offers_unlocked.append(who)

    watched = type("Watched", (SerialLink,), {"__setattr__": record})
    link = watched("seams://", reopen_interval_s=0.0)

    def until(condition: Callable[[], bool]) -> None:
        for _ in range(int(WAIT_S / 0.005)):
            if condition():
                return
            threading.Event().wait(0.005)
        raise AssertionError("never")

    def follow() -> LineEvent | None:
        """What `LineDriver._follow_link` does with the link each tick."""
        if not link.is_open:
            link.try_open()
        return link.line_event()

    def writer() -> None:
        until(lambda: follow() is LineEvent.OPENED)  # opened by the helper thread
        link.write(b"abc")
        seams.fail_reads = True
        seams.go.set()  # the RX thread's read fails now
        until(lambda: follow() is LineEvent.LOST)
        seams.fail_reads = False
        until(lambda: follow() is LineEvent.OPENED)  # the second port

    def reader() -> None:
        until(lambda: link.readable)
        link.read()  # fails: reported to the writer

    threads = [
        threading.Thread(target=writer, name="writer"),
        threading.Thread(target=reader, name="rx"),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(WAIT_S)
    assert len(seams.ports) == 2 and link.is_open
    link.close()
    assert offers_unlocked == []
    assert writers.pop("_offer") <= {"opener", "writer"}
    assert writers.pop("_broken") == {"rx"}
    assert all(who == {"writer"} for who in writers.values()), writers
    assert link.stats.bytes_read == 0 and link.stats.losses == 1 and link.stats.opens == 2


# --- a line session: the driver thread is its one writer -------------------------------------


# every assignment to the session's, its module's and its line's fields is watched
# (subclasses with a `__setattr__`): compiled classes cannot be subclassed here
@pytest.mark.interpreted
def test_a_session_its_module_and_its_line_are_written_by_the_driver_thread_only() -> None:
    """What a far end sends reaches the session on the driver's thread (the reader thread only
    queues bytes): every field of the session, its module and its line's state has that one
    writer, however the module's telemetry and the ticks interleave."""
    from usb2rc.lines.rx import LinkReader
    from usb2rc.lines.session import LineState
    from usb2rc.protocols.channels import OutputChannels
    from usb2rc.protocols.crsf.session import CrsfModule

    writers: dict[str, set[str]] = {}

    def record(obj: Any, name: str, value: Any) -> None:
        object.__setattr__(obj, name, value)
        who = threading.current_thread().name
        if who != "MainThread":  # the constructors
            writers.setdefault(f"{type(obj).__name__}.{name}", set()).add(who)

    module_type = type("Watched", (CrsfModule,), {"__setattr__": record})
    session_type = type("WatchedSession", (CrsfSession,), {"__setattr__": record})
    channels = OutputChannels([lambda nodes: (992, False)], crsf.RC_FRAME_LEN)  # live
    session = session_type("crsf", channels, module_type(0.004))
    session.line.__class__ = type("WatchedLine", (LineState,), {"__setattr__": record})
    link = SerialLink("loop://", 400000)
    from usb2rc.nodes.table import NodeTable

    driver = LineDriver("crsf", link, session, NodeTable().step_if_due, 0.004)
    thread = DriverThread("driver", [driver])
    reader = LinkReader("reader", link)
    assert link.open_now()
    thread.start()
    reader.start()
    try:
        for _ in range(int(WAIT_S / 0.01)):  # loop:// echoes the frames: the module "talks"
            if session.module.decoder.frames >= 20:
                break
            threading.Event().wait(0.01)
        link.received.put((crsf.encode_timing_sync(100_000, 0), time.monotonic()))
        for _ in range(int(WAIT_S / 0.01)):
            if session.module.timing_frames:
                break
            threading.Event().wait(0.01)
    finally:
        thread.stop()
        reader.stop()
        thread.join(WAIT_S)
        reader.join(WAIT_S)
    assert session.module.decoder.frames >= 20 and session.module.timing_frames == 1
    assert "WatchedLine.now" in writers  # the line opened: its state is watched too
    assert writers and all(who == {"driver"} for who in writers.values()), writers


def test_a_daemon_with_one_output_reads_on_its_deadline_and_beside_others_crsf_leads(
    tmp_path: Path,
) -> None:
    """`LineDriver.alone` is the daemon's: its only output has no lead (nothing else ticks, and
    a lead ages every frame's records). Beside others, a sending CRSF output makes its bytes
    ahead (its module times them to the microsecond); C2-16B and SUMD make theirs on their
    deadline (C2-16B leads too once the drivers' thread saw CRSF's lead: tests/test_driver.py)."""
    assert [o.driver.lead for o in _daemon(tmp_path).outputs] == [None]
    c2 = OutputConfig(protocol="c2-16b", port="loop://", rate_hz=50)
    channels = ("node0.x",)
    others = (
        OutputConfig(protocol="sumd", port="loop://", channels=channels),
        OutputConfig(protocol="crsf", port="loop://", channels=channels),
    )
    drivers = [
        o.driver for o in Daemon(Config(outputs=(c2, *others)), ReplayBackend(tmp_path)).outputs
    ]
    for driver in drivers:
        driver.plan(1.0, driver.period_s)
    assert [driver.leads for driver in drivers] == [False, False, True]
