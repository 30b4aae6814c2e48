"""DeviceLifecycle driven by random event sequences (hypothesis), no threads.

The lifecycle is fed plugs, unplugs, reader exits (the current reader's and late ones from
readers already replaced), reloads, permission changes and retries in any order. After every
event the node table and the lifecycle must agree on what is plugged, and the rules the
daemon promises must hold whatever the order was.
"""

from __future__ import annotations

import errno
import threading
from dataclasses import dataclass, field

from daemon_harness import INVERT_X_CONFIG, T16000M_DESCRIPTOR
from hypothesis import given, settings
from hypothesis import strategies as st
from output_fakes import RecordingPort
from table_reader import TableReader

from usb2rc.configfile import Config, load_config_text
from usb2rc.daemon import expected_nodes
from usb2rc.hid.backend import DeviceInfo, DevicePermissionError, ErrorCode
from usb2rc.hid.descriptor import DeviceLayout, InputState
from usb2rc.hid.reader import OnExit, ReaderRecord
from usb2rc.nodes.lifecycle import DeviceLifecycle, Reload
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import EventKind, NodeTable

PORTS = ("1-1.2", "1-1.3", "1-1.4")
# Zero config (automatic Node-IDs), and every T.16000M pinned to node 4 (a second one clashes).
CONFIGS = [Config.default(), load_config_text(INVERT_X_CONFIG.format(invert="true"))]
MAPPINGS = [(compile_mapping(c), expected_nodes(c)) for c in CONFIGS]


class FakeDevice:
    def __init__(self, info: DeviceInfo) -> None:
        self.info = info
        self.closed = False

    def report_descriptor(self) -> bytes:
        return T16000M_DESCRIPTOR

    def read(self, timeout_s: float) -> bytes | None:
        return None

    def open_output(self) -> RecordingPort:
        return RecordingPort()

    def close(self) -> None:
        self.closed = True


class FakeReader:
    """A DeviceReader without a thread: the test decides when it exits."""

    def __init__(self, device: FakeDevice, layout: DeviceLayout, on_exit: OnExit) -> None:
        self.device = device
        self.info = device.info
        self.on_exit = on_exit
        self.record = ReaderRecord(InputState((0,) * len(layout.inputs), 0), reports=1)
        self.started = self.stopped = self.exited = False

    def start(self) -> None:
        self.started = True

    def pull(self) -> None:
        """The step's pull: its record is fixed."""

    def stop(self) -> None:
        self.stopped = True


@dataclass
class World:
    """What is really plugged, and a backend over it."""

    name = "fake"
    plugged: dict[int, DeviceInfo] = field(default_factory=dict)  # port index -> device
    refused: set[int] = field(default_factory=set)  # ports whose node is not readable
    generation: int = 0
    readers: list[FakeReader] = field(default_factory=list)

    def plug(self, port: int) -> DeviceInfo:
        # Two identical sticks without serial numbers; the kernel reuses hidraw paths.
        self.generation += 1
        info = DeviceInfo(
            key=f"/dev/hidraw{port}",
            path=f"/dev/hidraw{port}#{self.generation}",
            vid=0x044F,
            pid=0xB10A,
            product="T.16000M",
            port_path=PORTS[port],
            usage_page=1,
            usage=4,
        )
        self.plugged[port] = info
        return info

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        return list(self.plugged.values())

    def open(self, info: DeviceInfo) -> FakeDevice:
        port = PORTS.index(info.port_path)
        if self.plugged.get(port) != info:
            from usb2rc.hid.backend import DeviceGone

            raise DeviceGone(f"{info.path}: gone")
        if port in self.refused:
            raise DevicePermissionError(errno.EACCES, f"permission denied on {info.key}")
        return FakeDevice(info)

    def make_reader(self, device: FakeDevice, layout: DeviceLayout, on_exit: OnExit):
        reader = FakeReader(device, layout, on_exit)
        self.readers.append(reader)
        return reader


ports = st.integers(0, len(PORTS) - 1)
events = st.one_of(
    st.tuples(st.just("plug"), ports),
    st.tuples(st.just("unplug"), ports),
    st.tuples(st.just("read-error"), ports),
    st.tuples(st.just("late-exit"), st.integers(0, 20)),
    st.tuples(st.just("reload"), st.integers(0, 1)),
    st.tuples(st.just("refuse"), ports),
    st.tuples(st.just("allow"), ports),
    st.tuples(st.just("retry"), st.just(0)),
)


def apply(world: World, lifecycle: DeviceLifecycle, kind: str, arg: int) -> None:
    if kind == "plug":
        if arg in world.plugged:
            lifecycle.unplugged(world.plugged.pop(arg))
        lifecycle.plugged(world.plug(arg))
    elif kind == "unplug" and arg in world.plugged:
        lifecycle.unplugged(world.plugged.pop(arg))
    elif kind == "read-error":
        current = [r for r in world.readers if r.info.port_path == PORTS[arg]]
        if current and not current[-1].exited:
            current[-1].exited = True
            current[-1].on_exit(current[-1], ErrorCode.READ_FAILED)  # type: ignore[arg-type]
    elif kind == "late-exit" and world.readers:
        old = world.readers[arg % len(world.readers)]
        if old.stopped and not old.exited:  # a replaced reader that noticed its end late
            old.exited = True
            old.on_exit(old, None)  # type: ignore[arg-type]
    elif kind == "reload":
        mapping, expected = MAPPINGS[arg]
        lifecycle.post(Reload(mapping, expected, threading.Event()))
    elif kind == "refuse":
        world.refused.add(arg)
    elif kind == "allow":
        world.refused.discard(arg)
    lifecycle.handle_queued()
    if kind == "retry":
        lifecycle._retry_due()


def check(world: World, lifecycle: DeviceLifecycle, table: NodeTable) -> None:
    present = {info.key: (node, info) for node, info, _b, on, _t in table.attachments() if on}
    readers = {r.info.key: r for r in lifecycle.readers}
    # The table and the lifecycle agree on what is plugged, reader for reader.
    assert set(present) == set(readers)
    for key, (_node, info) in present.items():
        assert readers[key].info == info
        assert readers[key].started and not readers[key].stopped
    # Only devices that are really plugged are present; each on its own node.
    assert all(info in world.plugged.values() for _n, info in present.values())
    nodes = [node for node, _info in present.values()]
    assert len(nodes) == len(set(nodes)), "two present devices on one node"
    # Every reader that is not present was stopped or ended by itself.
    for reader in world.readers:
        if readers.get(reader.info.key) is not reader:
            assert reader.stopped or reader.exited


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 1), st.lists(events, max_size=40))
def test_random_event_orders_keep_table_and_lifecycle_in_step(config: int, steps) -> None:
    world = World()
    mapping, expected = MAPPINGS[config]
    table = NodeTable(expected)
    subscriber = TableReader(table)
    lifecycle = DeviceLifecycle(world, table, mapping, world.make_reader, retry_s=0)
    for kind, arg in steps:
        apply(world, lifecycle, kind, arg)
        check(world, lifecycle, table)
    # Every device that left a present node was announced as gone: `2` for each removal.
    services, _frames = subscriber.collect()
    connects = sum(e.kind is EventKind.CONNECTED for e in services)
    disconnects = sum(e.kind is EventKind.DISCONNECTED for e in services)
    still_present = len(lifecycle.readers)
    assert connects - disconnects == still_present
