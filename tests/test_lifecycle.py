"""DeviceLifecycle: one thread owns plug, unplug, reader exit, open retry and reload.

Each test forces an interleaving that once went wrong when these ran on three threads: a
reload during a plug, a late reader exit after a replug on the same path, an open that fails
until a permission changes.
"""

from __future__ import annotations

import errno
import threading
import time
from pathlib import Path

from daemon_harness import INVERT_X_CONFIG, StickState, install, timed_recording
from table_reader import TableReader

from usb2rc.configfile import load_config_text
from usb2rc.daemon import expected_nodes
from usb2rc.hid.backend import Device, DeviceGone, DeviceInfo, DevicePermissionError, ErrorCode
from usb2rc.hid.descriptor import DeviceLayout
from usb2rc.hid.reader import DeviceReader, OnExit
from usb2rc.hid.replay import ReplayBackend
from usb2rc.nodes.lifecycle import DeviceLifecycle
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import EventKind, NodeTable

WAIT_S = 10.0


def mapping_of(invert: str):
    config = load_config_text(INVERT_X_CONFIG.format(invert=invert))
    return compile_mapping(config), expected_nodes(config)


def make_reader(device: Device, layout: DeviceLayout, on_exit: OnExit) -> DeviceReader:
    return DeviceReader(device, layout.make_decoder(), on_exit, read_timeout_s=0.01)


class ScriptedBackend:
    """The replay backend, with opens that can be held at a gate or refused."""

    name = "replay"

    def __init__(self, folder: Path) -> None:
        self.replay = ReplayBackend(folder)
        self.refusals = 0  # this many opens fail with permission denied first
        self.opens = 0
        self.gate: threading.Event | None = None
        self.opening = threading.Event()

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        return self.replay.enumerate(all)

    def open(self, info: DeviceInfo) -> Device:
        self.opens += 1
        self.opening.set()
        if self.gate is not None:
            assert self.gate.wait(WAIT_S)
        if self.refusals:
            self.refusals -= 1
            raise DevicePermissionError(errno.EACCES, f"permission denied on {info.path}")
        return self.replay.open(info)


def plug_stick(folder: Path, name: str = "stick.hid") -> DeviceInfo:
    # plugged at rest for longer than the neutral guard's rest (guard.REST_S), then full right
    install(folder / name, timed_recording([(0.0, StickState()), (0.2, StickState(x=16383))]))
    return next(i for i in ReplayBackend(folder).enumerate() if i.path.endswith(name))


def wait_until(predicate, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.005)  # polls the condition; nothing waits on a fixed time


def refusing_setup(
    tmp_path: Path, refusals: int, retry_s: float
) -> tuple[NodeTable, TableReader, ScriptedBackend, DeviceLifecycle]:
    """A stick pin-mapped to node 4 whose first `refusals` opens are refused."""
    mapping, expected = mapping_of("false")
    table = NodeTable(expected)
    subscriber = TableReader(table)
    backend = ScriptedBackend(tmp_path)
    backend.refusals = refusals
    lifecycle = DeviceLifecycle(backend, table, mapping, make_reader, retry_s=retry_s)
    lifecycle.plugged(plug_stick(tmp_path))
    return table, subscriber, backend, lifecycle


def live_x(table: NodeTable) -> int | None:
    """Node 0's X while it is live (None while `!`)."""
    frame = table.frames()[0]
    return None if frame.failsafe else frame.axes[0]


def events_of(table: NodeTable, subscriber: TableReader) -> list[tuple[EventKind, int]]:
    events, _frames = subscriber.collect()
    return [(e.kind, e.node_id) for e in events]


def test_a_reload_during_a_plug_binds_the_device_with_the_new_mapping(tmp_path: Path) -> None:
    old, old_expected = mapping_of("false")
    new, new_expected = mapping_of("true")
    table = NodeTable(old_expected)
    backend = ScriptedBackend(tmp_path)
    lifecycle = DeviceLifecycle(backend, table, old, make_reader)
    lifecycle.start()
    try:
        backend.gate = threading.Event()
        lifecycle.plugged(plug_stick(tmp_path))
        assert backend.opening.wait(WAIT_S)  # the plug is half done: opening the device
        reloaded = threading.Thread(target=lifecycle.reload, args=(new, new_expected))
        reloaded.start()
        backend.gate.set()
        reloaded.join(WAIT_S)
        assert not reloaded.is_alive()
        bindings = [binding for _n, _i, binding, _p, _t in table.attachments()]
        assert len(bindings) == 1
        assert bindings[0] is not None and lifecycle.mapping is new
        # X at full right, inverted: the new mapping (the old one would send +32767)
        wait_until(lambda: live_x(table) == -32768)
    finally:
        for reader in lifecycle.shutdown(WAIT_S):
            reader.join(WAIT_S)


def test_a_late_exit_of_an_old_reader_leaves_the_new_device_alone(tmp_path: Path) -> None:
    mapping, expected = mapping_of("false")
    table = NodeTable(expected)
    lifecycle = DeviceLifecycle(ScriptedBackend(tmp_path), table, mapping, make_reader)
    info = plug_stick(tmp_path)
    lifecycle.plugged(info)
    lifecycle.handle_queued()
    (old_reader,) = lifecycle.readers
    lifecycle.unplugged(info)  # the monitor saw it go ...
    lifecycle.plugged(info)  # ... and a new device come on the same path
    lifecycle.handle_queued()
    (new_reader,) = lifecycle.readers
    assert new_reader is not old_reader
    lifecycle.reader_exited(old_reader, None)  # the old reader noticed its unplug late
    lifecycle.handle_queued()
    try:
        assert lifecycle.readers == (new_reader,)
        assert [present for _n, _i, _b, present, _t in table.attachments()] == [True]
    finally:
        for reader in lifecycle.shutdown(WAIT_S):
            reader.join(WAIT_S)


def test_an_open_refused_is_retried_while_plugged_and_reported_once(tmp_path: Path) -> None:
    table, subscriber, backend, lifecycle = refusing_setup(tmp_path, refusals=3, retry_s=0.01)
    lifecycle.start()
    seen: list[tuple[EventKind, int]] = []
    try:
        wait_until(lambda: bool(seen.extend(events_of(table, subscriber))) or len(seen) >= 2)
        assert backend.opens == 4
        assert seen == [(EventKind.ERROR, 4), (EventKind.CONNECTED, 4)]
        errors = [e for e in subscriber.collect()[0] if e.kind is EventKind.ERROR]
        assert errors == []
    finally:
        for reader in lifecycle.shutdown(WAIT_S):
            reader.join(WAIT_S)


def test_the_error_code_of_a_refused_open_is_permission_denied(tmp_path: Path) -> None:
    _table, subscriber, _backend, lifecycle = refusing_setup(tmp_path, refusals=1, retry_s=60)
    lifecycle.handle_queued()
    (error,) = subscriber.collect()[0]
    assert (error.kind, error.error_code) == (EventKind.ERROR, int(ErrorCode.PERMISSION_DENIED))


def test_an_unplug_ends_the_retries(tmp_path: Path) -> None:
    mapping, expected = mapping_of("false")
    backend = ScriptedBackend(tmp_path)
    backend.refusals = 1000
    lifecycle = DeviceLifecycle(backend, NodeTable(expected), mapping, make_reader, retry_s=0)
    info = plug_stick(tmp_path)
    lifecycle.plugged(info)
    lifecycle.unplugged(info)
    lifecycle.handle_queued()
    opens = backend.opens
    lifecycle._retry_due()
    assert backend.opens == opens == 1


def test_a_device_without_its_node_yet_is_looked_at_again(tmp_path: Path) -> None:
    """sysfs can list a device before its /dev node exists: the open finds it gone. It is
    not reported, but the monitor must report it again on its next scan, or it stays ignored
    for as long as it is plugged."""
    mapping, expected = mapping_of("false")
    table = NodeTable(expected)
    subscriber = TableReader(table)
    forgotten: list[str] = []

    class NoNodeYet(ScriptedBackend):
        def open(self, info: DeviceInfo) -> Device:
            raise DeviceGone(f"{info.path}: no node")

    lifecycle = DeviceLifecycle(
        NoNodeYet(tmp_path), table, mapping, make_reader, forget=forgotten.append
    )
    info = plug_stick(tmp_path)
    lifecycle.plugged(info)
    lifecycle.handle_queued()
    assert forgotten == [info.key]
    assert subscriber.collect()[0] == []


def test_a_daemon_that_never_started_stops_cleanly(tmp_path: Path) -> None:
    """`serve` stops the daemon whatever `start()` got to, so stop must cope with threads
    that never started."""
    from usb2rc.configfile import Config
    from usb2rc.daemon import Daemon

    daemon = Daemon(Config.default(), ReplayBackend(tmp_path), port_override="loop://")
    daemon.stop()
    assert not daemon.drivers.is_alive()
