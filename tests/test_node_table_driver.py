"""NodeTable and a C2-16B driver in one process, ticked by hand: the safety rules, exactly.

Each test here pins down one rule a reviewer found broken once: identical devices without a
serial number, a device that has not reported yet, a far end flooding `<`, a write that
fails, a node that a reload left empty, SUMD reading unsigned axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from daemon_harness import T16000M_DESCRIPTOR, StickState

from usb2rc.configfile import load_config_text
from usb2rc.daemon import expected_nodes
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.lines.driver import LineDriver
from usb2rc.lines.link import LineEvent, LinkStats, Written
from usb2rc.lines.session import LinkState
from usb2rc.nodes.binding import default_binding, unsigned_slots
from usb2rc.nodes.guard import NO_GUARD
from usb2rc.nodes.mapping import ChannelSource, compile_mapping
from usb2rc.nodes.table import NodeFrame, NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session
from usb2rc.protocols.sumd.channels import SumdChannels, sumd_channel

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)


@dataclass
class Source:
    """Stands in for a DeviceReader: its published record (state and reports decoded)."""

    record: ReaderRecord

    def pull(self) -> None:
        """The step's pull: a test sets the record itself."""

    @classmethod
    def of(cls, state: StickState, reports: int = 1) -> Source:
        decoder = LAYOUT.make_decoder()
        decoder.feed(state.report())
        return cls(ReaderRecord(decoder.state(), reports))


def info(key: str, port: str, serial: str = "") -> DeviceInfo:
    return DeviceInfo(
        key=key, path=key, vid=0x044F, pid=0xB10A, serial=serial, product="T.16000M", port_path=port
    )


BINDING = default_binding(LAYOUT, "T.16000M")
# These rules hold whatever the sticks do: the neutral guard (tests/test_guard.py) is off
# here, so a stick at full deflection goes live at its first report.
BINDING.guard = NO_GUARD
LEFT, RIGHT = StickState(x=0), StickState(x=16383)


def frame_of(table: NodeTable, node_id: int) -> NodeFrame:
    return next(f for f in table.frames() if f.node_id == node_id)


def test_identical_devices_without_serial_are_told_apart_by_port():
    table = NodeTable()
    a, b = info("hidraw0", "1-1"), info("hidraw1", "1-2")
    table.add_device(0, a, BINDING, Source.of(LEFT), "JOYSTICK")
    table.add_device(1, b, BINDING, Source.of(RIGHT), "JOYSTICK")
    table.remove_device(a.key)
    table.remove_device(b.key)
    # B comes back on its own port: node 1, never A's node 0
    b_again = info("hidraw2", "1-2")
    assert table.lost_node_of(b_again, BINDING) == 1
    # the same model on another port with no serial is another device
    assert table.lost_node_of(info("hidraw3", "1-3"), BINDING) is None
    # with a serial number, the serial identifies it whatever the port
    table.add_device(2, info("hidraw4", "1-4", "SN1"), BINDING, Source.of(LEFT), "JOYSTICK")
    table.remove_device("hidraw4")
    assert table.lost_node_of(info("hidraw5", "1-9", "SN1"), BINDING) == 2


def test_a_device_is_not_live_before_its_first_report():
    table = NodeTable()
    throttle = info("hidraw0", "1-1")
    table.add_device(0, throttle, BINDING, Source.of(LEFT), "JOYSTICK")
    assert not frame_of(table, 0).failsafe
    table.remove_device(throttle.key)
    held = frame_of(table, 0)
    assert held.failsafe and held.axes[0] == -32768
    # re-plugged, nothing reported yet (its snapshot is the descriptor's centre)
    silent = Source(ReaderRecord(LAYOUT.initial_state(), reports=0))
    table.add_device(0, info("hidraw1", "1-1"), BINDING, silent, "JOYSTICK")
    waiting = frame_of(table, 0)
    assert waiting.failsafe and waiting.axes[0] == -32768  # held, not mid-scale
    silent.record = Source.of(RIGHT).record
    live = frame_of(table, 0)
    assert not live.failsafe and live.axes[0] == 32767


class PublishesOnSecondRead:
    """A reader that publishes its first report right after the table read its record once:
    the interleaving where a frame could be marked live yet carry the held values."""

    def __init__(self, before: ReaderRecord, after: ReaderRecord) -> None:
        self._records = [before, after]

    @property
    def record(self) -> ReaderRecord:
        return self._records.pop(0) if len(self._records) > 1 else self._records[0]

    def pull(self) -> None:
        """The step's pull: the records are scripted."""


def test_a_record_published_mid_frame_never_gives_live_held_values():
    table = NodeTable()
    table.add_device(0, info("hidraw0", "1-1"), BINDING, Source.of(LEFT), "JOYSTICK")
    table.remove_device("hidraw0")  # held at full left
    racing = PublishesOnSecondRead(
        ReaderRecord(LAYOUT.initial_state(), reports=0), Source.of(RIGHT).record
    )
    table.add_device(0, info("hidraw1", "1-1"), BINDING, racing, "JOYSTICK")
    first = frame_of(table, 0)
    # the values and the live flag come from the same record: held and `!`, not held and live
    assert first.failsafe and first.axes[0] == -32768
    second = frame_of(table, 0)
    assert not second.failsafe and second.axes[0] == 32767


def test_a_node_that_a_reload_left_empty_is_failsafe_not_live():
    table = NodeTable({3: {}})
    assert frame_of(table, 3).failsafe


@dataclass
class FakeLink:
    """A serial line that records writes; `accept` decides whether a write goes out."""

    url: str = "fake://"
    baudrate: int = 115200
    last_error: str = ""
    stats: LinkStats = field(default_factory=LinkStats)
    is_open: bool = True
    accept: bool = True
    writes: list[bytes] = field(default_factory=list)
    _adopted: bool = False

    def try_open(self) -> bool:
        return True

    def line_event(self) -> LineEvent | None:
        if self._adopted:
            return None
        self._adopted = True
        return LineEvent.OPENED

    def write(self, data: bytes) -> Written:
        if self.accept:
            self.writes.append(data)
            return Written(len(data))
        return Written(0)

    def state(self, probe_writable: bool) -> LinkState:
        return LinkState(writable=self.accept)  # a socket's: nothing counted nor dropped

    def wait_writable(self, timeout_s: float) -> bool:
        return self.accept

    def flush(self, counted: bool = True) -> bool:
        return False  # nothing stale to drop, nothing lost

    def take_received(self) -> list[tuple[bytes, float]]:
        return []

    def counters(self) -> dict[str, int | str]:
        return {}

    def close(self) -> None:
        pass


def decode(chunks: list[bytes]) -> list:
    decoder = c2_16b.Decoder()
    return [f for chunk in chunks for f in decoder.feed(chunk)]


def c2_output(table: NodeTable, link: FakeLink, baudrate: int = 115200) -> LineDriver:
    session = C2Session("test", C2Settings(baudrate=baudrate, version="0.1.0"))
    return LineDriver("test", link, session, table.step_if_due, 0.02)


CONFIG_REQUEST = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0x10, 0, (0,) * 10, 0, 0)


def test_a_flood_of_config_requests_never_starves_the_data():
    table = NodeTable()
    link = FakeLink()
    out = c2_output(table, link)
    for n in range(2):
        table.add_device(n, info(f"k{n}", f"1-{n}"), BINDING, Source.of(LEFT), "JOYSTICK")
    for _ in range(100):  # the far end asks `<` every tick
        out.session.received(CONFIG_REQUEST, 0.0)
        out.tick()
    frames = decode(link.writes)
    data = [f for f in frames if isinstance(f, c2_16b.DataFrame)]
    per_node = {n: sum(f.node_id == n for f in data) for n in range(2)}
    assert min(per_node.values()) >= 40, per_node  # each node at least every other tick
    assert all(len(decode([w])) <= out.session.engine.capacity for w in link.writes)


def test_a_failed_write_keeps_the_service_frames_and_the_codes():
    table = NodeTable()
    link = FakeLink(accept=False)
    out = c2_output(table, link)
    table.add_device(0, info("k0", "1-1"), BINDING, Source.of(LEFT), "JOYSTICK")
    for _ in range(3):
        out.tick()  # nothing goes out
    link.accept = True
    out.tick()
    out.tick()
    frames = decode(link.writes)
    names = [f.service.service_name for f in frames if isinstance(f, c2_16b.ServiceFrame)]
    assert names == ["startup", "connected", "vid-pid", "device-string", "device-type"]
    assert [f.code for f in frames if isinstance(f, c2_16b.DataFrame)] == [0, 1]


def test_sumd_reads_unsigned_from_the_binding_not_from_a_guess():
    config_text = (
        "devices:\n  - name: pedal\n    match: {vid: 0x044f}\n"
        "    axes:\n      x: {usage: X, unsigned: true, arm: any}\n"
    )
    config = load_config_text(config_text, "t.yaml")
    binding = compile_mapping(config).bind(info("k", "1-1"), LAYOUT)
    assert binding is not None and binding.node_id is None  # automatic: no pin to guess from
    table = NodeTable()
    table.add_device(0, info("k", "1-1"), binding, Source.of(StickState(x=16383)), "JOYSTICK")
    nodes = {f.node_id: f for f in table.frames()}
    assert nodes[0].axes[0] == 65535
    channel = sumd_channel(ChannelSource(0, "axis", 0, unsigned=False), extended=False)
    assert channel(nodes) == (15200, False)  # full travel: 1900 µs, never an exception


def test_a_node_being_re_announced_keeps_sending_but_never_live_before_its_sequence():
    table = NodeTable()
    link = FakeLink()
    # 57600 baud: 3 frames a tick, so a re-announcement spreads over several ticks
    out = c2_output(table, link, baudrate=57600)
    stick = info("k0", "1-1")
    table.add_device(0, stick, BINDING, Source.of(LEFT), "JOYSTICK")
    for _ in range(4):
        out.tick()
    table.remove_device(stick.key)
    table.add_device(0, info("k1", "1-1"), BINDING, Source.of(RIGHT), "JOYSTICK")
    link.writes.clear()
    for _ in range(5):
        out.tick()
    per_tick = [decode([w]) for w in link.writes]
    assert len(per_tick) == 5
    assert all(any(isinstance(f, c2_16b.DataFrame) for f in tick) for tick in per_tick)  # no gap
    frames = [f for tick in per_tick for f in tick]
    names = [
        f.service.service_name if isinstance(f, c2_16b.ServiceFrame) else chr(f.status)
        for f in frames
    ]
    last_of_sequence = names.index("device-type")
    assert ">" not in names[:last_of_sequence]
    assert names[0] == "disconnected" and names[last_of_sequence + 1 :][-1] == ">"


def test_this_version_fits_the_startup_frame():
    from usb2rc import __version__

    frame = decode([c2_16b.startup(__version__)])[0]
    assert frame.node_id == 0xFF and frame.text == f"usb2rc {__version__}"


# compiled, `period_p99_error_ms` takes the nominal period as a C double (the float
# subclass's `__rsub__` never runs) and its loop lets no other thread in: the append
# mid-iteration this test makes happens only where the hot path is interpreted
@pytest.mark.interpreted
def test_stats_are_read_while_the_output_thread_adds_periods():
    """`stats_lines` (another thread) once died with 'deque mutated during iteration'. Here
    the writer appends exactly while the reader goes through the periods: the reader works
    on a copy, so the append neither waits for it nor breaks it."""
    import threading

    from usb2rc.lines.driver import OutputStats

    stats = OutputStats()
    appended = threading.Event()

    def writer() -> None:
        stats.add_period(0.02)
        appended.set()

    class Nominal(float):
        """A nominal period whose arithmetic lets the writer thread in, mid-iteration (a
        period minus it asks it first: it is a float's subclass)."""

        def __rsub__(self, other: float) -> float:
            if not appended.is_set():
                threading.Thread(target=writer).start()
                assert appended.wait(5), "the writer was kept waiting by the reader"
            return other - float(self)

    for _ in range(10):
        stats.add_period(0.02)
    stats.add_period(0.021)
    assert stats.period_p99_error_ms(Nominal(0.02)) == pytest.approx(1.0)
    assert appended.is_set() and len(stats.periods()) == 12


def test_every_consumer_gets_the_same_unsigned_slots():
    """Whether a slot is unsigned is answered once (`binding.unsigned_slots`): the binding,
    the pinned entry before its device comes, the node's frame, the SUMD channel list of
    `icd` / `check` and the SUMD output's values all agree."""
    config = load_config_text(
        "outputs:\n  - protocol: sumd\n    channels: [node2.x, node2.rz, node2.slider]\n"
        "devices:\n"
        "  - name: pedals\n    match: {vid: 0x044f}\n    node_id: 2\n"
        "    axes: {x: X, rz: {usage: Rz, unsigned: true, arm: any}}\n"
        "  - name: throttle\n    match: {vid: 0x1234}\n    node_id: 2\n"
        "    axes: {slider: {usage: Slider, unsigned: true}}\n",
        "t.yaml",
    )
    mapping = compile_mapping(config)
    rz, slider = 1 << 6, 1 << 3
    pedals, throttle = mapping.entries
    assert (pedals.unsigned_slots, throttle.unsigned_slots) == (rz, slider)
    binding = mapping.bind(info("k", "1-1"), LAYOUT)
    assert binding is not None and binding.unsigned_slots == rz
    per_slot = [info is not None and info.unsigned for info in binding.axis_info]
    assert binding.unsigned_slots == sum(1 << k for k, u in enumerate(per_slot) if u)
    assert unsigned_slots(binding.axis_info) == unsigned_slots(config.devices[0].axes) == rz

    expected = expected_nodes(mapping)
    assert {n: e.unsigned_slots for n, e in expected[2].items()} == {
        "pedals": rz,
        "throttle": slider,
    }
    table = NodeTable(expected)
    assert frame_of(table, 2).unsigned_slots == rz | slider
    table.add_device(2, info("k", "1-1"), binding, Source.of(StickState(rz=255)), "JOYSTICK")
    frame = frame_of(table, 2)
    assert frame.unsigned_slots == rz | slider  # the throttle is still expected

    sources = mapping.sumd_channels(config.outputs[0])
    assert [s.unsigned for s in sources] == [False, True, True]
    assert [bool(frame.unsigned_slots >> s.index & 1) for s in sources] == [False, True, True]
    values, failsafe = SumdChannels.of(sources).evaluate([frame])
    # rz full travel (uint16 65535), slider at its failsafe 0 (uint16: the low end)
    assert (values[1:], failsafe) == ([15200, 8800], True)


@dataclass
class PtyLink(FakeLink):
    """A pty as the driver sees it: what it holds is hidden but can be dropped; counts the
    drops."""

    drops: int = 0

    def state(self, probe_writable: bool) -> LinkState:
        return LinkState(None, flushable=True, hides_queue=True, writable=True)

    def flush(self, counted: bool = True) -> bool:
        self.drops += 1
        return True


def crsf_output(table: NodeTable, link: FakeLink) -> LineDriver:
    from usb2rc.protocols.channels import OutputChannels
    from usb2rc.protocols.crsf import codec as crsf
    from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
    from usb2rc.protocols.rc11_channels import RC11_SCALE

    source = ChannelSource(0, "axis", 0, unsigned=False)
    channels = OutputChannels.scaled([source], RC11_SCALE, crsf.RC_FRAME_LEN)
    return LineDriver(
        "crsf", link, CrsfSession("crsf", channels, CrsfModule(0.004)), table.step_if_due, 0.004
    )


def test_a_silent_line_on_a_pty_is_not_dropped_at_each_tick_but_what_it_wrote_is():
    """A channel output drops what the far end of a pty left unread before each tick; a
    tick after one that wrote nothing has nothing of its own to drop (a CRSF line is
    silent while its node waits), and the first tick on a port drops whatever it holds.
    A silent CRSF line makes no frame ahead of its deadline; a sending one does."""
    table = NodeTable()
    link = PtyLink()
    out = crsf_output(table, link)
    for _ in range(5):  # node 0 has no device: CRSF's failsafe is silence
        out.tick()
    assert link.writes == [] and link.drops == 1  # the new port's, once
    assert not out.session.makes_ahead()  # no frame to time: it starts on its deadline
    table.add_device(0, info("k0", "1-1"), BINDING, Source.of(LEFT), "JOYSTICK")
    out.tick()  # the first frame
    assert len(link.writes) == 1 and link.drops == 1
    assert out.session.makes_ahead()  # sending: its module times the frames
    out.tick()  # the frame before may be unread: dropped before the next one
    assert len(link.writes) == 2 and link.drops == 2
