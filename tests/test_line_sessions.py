"""All six line sessions driven through the one interface (`usb2rc.lines.session`) with random
line events, and each protocol's invariants checked on what leaves the session.

One harness, whatever the protocol: the line opens and is lost; the link reports its state as
its kind would (a serial port: queue counted and droppable; a pty: droppable, not counted; a
socket, UDP: neither; `loop://`: counted, not droppable) and the driver carries out what the
session asks; writes go out whole, cut short, unsure or not at all; the far end sends garbage;
devices come and go; snapshots are random; usb2rc stops. Checked:

- every byte a tick emits decodes with the protocol's own decoder, nothing skipped;
- failsafe as docs/ICD.md says per protocol: SUMD status 0x81, SBUS frame-lost + failsafe
  flags, CRSF and iBus silence, MAVLink the release of every channel or silence, C2-16B `!`;
- C2-16B: every invariant of tests/test_session.py's receiver model (startup first, `>` only
  after a whole 1,6,5,7, `2` before a node's next frame, codes never repeat);
- no tick adds bytes while the line is stalled; a C2-16B line is never asked to drop unread
  bytes (its frames carry state), a socket never flushed;
- a stop ends, on a line that takes bytes, with the protocol's failsafe and `stop_done`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from test_session import Receiver, Unsure, Written, dropped_frames

from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.hid.backend import DeviceInfo
from usb2rc.lines.session import Ask, LineSession, LinkState
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.step import NodeView
from usb2rc.nodes.table import (
    EVENTS_KEPT,
    EventKind,
    EventLog,
    NodeFrame,
    NodeSnapshot,
    ServiceEvent,
)
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.ibus import codec as ibus
from usb2rc.protocols.ibus.output import IBUS_SCALE
from usb2rc.protocols.ibus.session import IbusSession
from usb2rc.protocols.mavlink.codec import MavlinkDecoder
from usb2rc.protocols.mavlink.session import (
    MavlinkChannels,
    MavlinkEngine,
    MavlinkSession,
    heartbeat_bytes,
)
from usb2rc.protocols.mavlink.session import max_message_bytes as mavlink_bytes
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sbus import codec as sbus
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.protocols.sumd import codec as sumd
from usb2rc.protocols.sumd.channels import SumdChannels
from usb2rc.protocols.sumd.session import SumdSession

NODES = 3
SOURCES = [ChannelSource(0, "axis", 0), ChannelSource(1, "axis", 1), ChannelSource(2, "button", 1)]
RELEASED = 0  # MAVLink: channels 1-8 handed back to the RC radio


def sessions() -> dict[str, Callable[[], LineSession]]:
    def crsf_line() -> LineSession:
        channels = OutputChannels.scaled(SOURCES, RC11_SCALE, crsf.RC_FRAME_LEN)
        return CrsfSession("crsf", channels, CrsfModule(0.004))

    def mavlink_line() -> LineSession:
        tick_bytes = heartbeat_bytes() + mavlink_bytes("rc_channels_override")
        session = MavlinkEngine(MavlinkOptions())
        return MavlinkSession("mavlink", MavlinkChannels(SOURCES), session, tick_bytes, 50.0)

    return {
        "c2-16b": lambda: C2Session("c2", C2Settings(version="0.1.0")),
        "sumd": lambda: SumdSession("sumd", SumdChannels.of(SOURCES), sumd.frame_length(3), 100.0),
        "crsf": crsf_line,
        "sbus": lambda: SbusSession(
            "sbus", OutputChannels.scaled(SOURCES, RC11_SCALE, sbus.FRAME_LEN), 100.0
        ),
        "ibus": lambda: IbusSession(
            "ibus", OutputChannels.scaled(SOURCES, IBUS_SCALE, ibus.FRAME_LEN), 100.0
        ),
        "mavlink": mavlink_line,
    }


def decode(protocol: str, data: bytes) -> list[Any]:
    """Every frame of one tick's bytes; fails on a byte the protocol's decoder skips."""
    decoder: Any = {
        "c2-16b": c2_16b.Decoder,
        "sumd": sumd.SumdDecoder,
        "crsf": crsf.CrsfDecoder,
        "sbus": sbus.SbusDecoder,
        "ibus": ibus.IbusDecoder,
        "mavlink": MavlinkDecoder,
    }[protocol]()
    frames = list(decoder.feed(data))
    if protocol == "sbus":
        frames += decoder.flush()  # a frame is known whole at the next header
    assert decoder.bytes_skipped == 0, f"{protocol}: {data.hex()} does not decode"
    assert frames, f"{protocol}: {data.hex()} holds no frame"
    return frames


def failsafe_held(protocol: str, frames: list[Any], failsafe: bool) -> None:
    """The protocol's failsafe, as docs/ICD.md says, in one tick's frames."""
    if protocol == "sumd":
        assert all(f.failsafe == failsafe for f in frames)
    elif protocol == "sbus":
        assert all(f.failsafe == failsafe and f.frame_lost == failsafe for f in frames)
    elif protocol in ("crsf", "ibus"):
        assert not failsafe, f"{protocol} sent a frame in failsafe"
    elif protocol == "mavlink" and failsafe:
        overrides = [m for m in frames if m.get_type() == "RC_CHANNELS_OVERRIDE"]
        assert all(m.chan1_raw == RELEASED for m in overrides), "live values in failsafe"


# the link kinds: (queue counted, droppable, hides its queue)
LINKS = {
    "tty": (True, True, False),
    "pty": (False, True, True),
    "socket": (False, False, False),
    "loop": (True, False, False),
    "udp": (False, False, False),
}


@dataclass
class Line:
    """One session on one kind of link, the far end, and the devices."""

    protocol: str
    session: LineSession
    link: str
    receiver: Receiver = field(default_factory=Receiver)
    unread: list[Written | Unsure] = field(default_factory=list)
    present: dict[int, DeviceInfo] = field(default_factory=dict)
    known: set[int] = field(default_factory=set)
    log: EventLog = field(default_factory=EventLog)
    plugs: int = 0
    ticks: int = 0
    stopping: bool = False

    @property
    def c2(self) -> bool:
        return self.protocol == "c2-16b"

    # --- devices: the node table's event log ----------------------------------------------

    def _append(self, event: ServiceEvent) -> None:
        present = tuple(
            ServiceEvent(EventKind.CONNECTED, node, info, "JOYSTICK")
            for node, info in sorted(self.present.items())
        )
        self.log = self.log.appended(event, present)

    def plug(self, node: int) -> None:
        if node in self.present:
            return
        self.plugs += 1
        info = DeviceInfo(key=f"d{self.plugs}", path="p", vid=0x044F, pid=0xB10A, product="T")
        self.present[node] = info
        self.known.add(node)
        self._append(ServiceEvent(EventKind.CONNECTED, node, info, "JOYSTICK"))

    def unplug(self, node: int) -> None:
        info = self.present.pop(node, None)
        if info is None:
            return
        self._append(ServiceEvent(EventKind.DISCONNECTED, node, info))
        if self.c2 and self.receiver.line is not None:
            self.read()  # the far end judges the `2` by what it read before it
            self.receiver.device_left(node)

    def snapshot(self, live: list[bool], axis: int) -> NodeSnapshot:
        views = []
        for node in sorted(self.known):  # the session must make its own failsafe at a stop
            failsafe = node not in self.present or not live[node]
            frame = NodeFrame(node, failsafe, (axis,) + (0,) * 9, 1, 0)
            views.append(NodeView(frame))
        return NodeSnapshot(period=self.ticks, at=0.0, nodes=tuple(views), log=self.log)

    # --- the line ---------------------------------------------------------------------------

    def open(self) -> None:
        if not self.session.line_open:
            self.session.line_opened()
            self.receiver.opened()

    def lose(self) -> None:
        if self.session.line_open:
            self.read()
            self.session.line_lost()
            self.receiver.lost()
            self.unread = []

    def read(self) -> None:
        pieces, self.unread = self.unread, []
        for piece in pieces:
            if isinstance(piece, Unsure):
                self.receiver.unsure_writes += 1
            elif self.c2 and self.receiver.line is not None:
                self.receiver.deliver(piece.data, piece.cut)

    def follow_link(self, queued: int | None, writable: bool) -> None:
        """The driver's part: report the link, carry out what the session asks."""
        counted, droppable, hides = LINKS[self.link]
        state = LinkState(queued if counted else None, droppable, hides, writable)
        ask = self.session.link_state(state)
        if ask is Ask.DROP_UNREAD:
            assert not self.c2, "a C2-16B line drops no unread bytes: its frames carry state"
            assert hides, "only a pty's unread bytes are dropped each tick"
            self.unread = []
        elif ask is Ask.FLUSH:
            assert droppable, f"a {self.link} cannot be flushed"
            self.flush()
            self.session.flush_done(True)

    def flush(self) -> None:
        dropped: dict[int, int] = {}
        for piece in self.unread:
            if isinstance(piece, Written) and self.c2:
                for node, count in dropped_frames(piece.data, 0).items():
                    dropped[node] = dropped.get(node, 0) + count
        self.unread = [p for p in self.unread if isinstance(p, Unsure)]
        if self.c2 and self.receiver.line is not None:
            self.read()
            self.receiver.flushed(dropped)

    def tick(self, live: list[bool], axis: int, outcome: tuple[str, int, int]) -> bytes:
        self.ticks += 1
        snapshot = self.snapshot(live, axis)
        stalled = self.session.stalled
        out = self.session.tick(float(self.ticks) / 100, snapshot)
        assert not (stalled and out), "a tick added bytes while the line was stalled"
        if not out:
            return out
        self.check(out, snapshot)
        kind, first, second = outcome
        cut = first % (len(out) + 1)
        if kind == "all":
            sent, unsure = len(out), 0
        elif kind == "cut":
            sent, unsure = cut, 0
        else:
            sent, unsure = cut, second % (len(out) - cut + 1)
        if sent:
            self.unread.append(Written(out[:sent], cut=sent < len(out)))
        if unsure:
            self.unread.append(Unsure())
        self.session.wrote(sent, unsure)
        return out

    def check(self, out: bytes, snapshot: NodeSnapshot) -> None:
        frames = decode(self.protocol, out)
        if self.c2:
            failsafe = {v.frame.node_id for v in snapshot.nodes if v.frame.failsafe}
            for frame in frames:
                down = frame.node_id in failsafe or self.stopping
                if isinstance(frame, c2_16b.DataFrame) and down:
                    assert frame.status == c2_16b.FAILSAFE, f"node {frame.node_id} not `!`"
            return
        by_node = {v.frame.node_id: v.frame.failsafe for v in snapshot.nodes}
        failsafe = self.stopping or any(by_node.get(s.node_id, True) for s in SOURCES)
        failsafe_held(self.protocol, frames, failsafe)


positions = st.integers(0, 2**16)
outcomes = st.one_of(
    st.just(("all", 0, 0)),
    st.just(("all", 0, 0)),
    st.tuples(st.just("cut"), positions, st.just(0)),
    st.tuples(st.just("unsure"), positions, positions),
)
ticks = st.tuples(
    st.just("tick"),
    st.tuples(
        st.lists(st.booleans(), min_size=NODES, max_size=NODES),
        st.integers(-32768, 32767),
        outcomes,
        st.one_of(st.none(), st.integers(0, 400)),  # what the link holds (if it counts)
        st.booleans(),  # whether it takes bytes
    ),
)
actions = st.one_of(
    ticks,
    ticks,
    ticks,
    st.tuples(st.sampled_from(["open", "lose", "read", "stop"]), st.none()),
    st.tuples(st.sampled_from(["plug", "unplug"]), st.integers(0, NODES - 1)),
    st.tuples(st.just("garbage"), st.binary(max_size=64)),
)


def run(line: Line, action: tuple[str, Any]) -> None:
    name, arg = action
    if name == "tick":
        live, axis, outcome, queued, writable = arg
        line.follow_link(queued, writable)
        line.tick(live, axis, outcome)
    elif name == "open":
        line.open()
    elif name == "lose":
        line.lose()
    elif name == "read":
        line.read()
    elif name == "stop" and not line.stopping:
        line.stopping = True
        line.session.stopping()
    elif name == "plug":
        line.plug(arg)
    elif name == "unplug":
        line.unplug(arg)
    elif name == "garbage":
        line.session.received(arg, float(line.ticks) / 100)


def heal_and_stop(line: Line) -> None:
    """The line is well again, then usb2rc stops: it ends with the protocol's failsafe."""
    line.open()
    for _ in range(60):
        line.read()
        line.follow_link(0, True)
        line.tick([True] * NODES, 0, ("all", 0, 0))
    if not line.stopping:
        line.stopping = True
        line.session.stopping()
    for _ in range(60):
        if line.session.stop_done:
            break
        line.read()
        line.follow_link(0, True)
        line.tick([True] * NODES, 0, ("all", 0, 0))  # stopping: every node counts failsafe
    assert line.session.stop_done, f"{line.protocol}: the stop never ended"


@settings(max_examples=150, deadline=None)
@given(
    protocol=st.sampled_from(sorted(sessions())),
    link=st.sampled_from(sorted(LINKS)),
    actions=st.lists(actions, max_size=120),
)
def test_every_session_keeps_its_protocol_whatever_the_line_does(
    protocol: str, link: str, actions: list[tuple[str, Any]]
) -> None:
    line = Line(protocol, sessions()[protocol](), link)
    line.open()
    for node in range(NODES):
        line.plug(node)
    for action in actions:
        run(line, action)
    heal_and_stop(line)
    if line.c2:
        view = line.receiver.line
        assert view is not None and not view.owes_disconnect


def test_each_session_reports_its_stats_as_a_record() -> None:
    for name, make in sessions().items():
        record = make().stats(0.0)
        assert isinstance(record, dict) and "queue_full_ticks" in record, name


def test_a_c2_line_that_fell_behind_the_event_log_starts_over_from_the_startup_frame() -> None:
    line = Line("c2-16b", sessions()["c2-16b"](), "tty")
    line.open()
    line.plug(0)
    for _ in range(5):
        line.tick([True] * NODES, 0, ("all", 0, 0))
    line.read()
    assert line.receiver.line is not None and 0 in line.receiver.line.announced
    info = line.present[0]
    event = ServiceEvent(EventKind.ERROR, 0, info, "", 6)
    for _ in range(EVENTS_KEPT + 1):  # more than the log keeps between two of its ticks
        line._append(event)
    out = line.tick([True] * NODES, 0, ("all", 0, 0))
    names = [f.service for f in c2_16b.Decoder().feed(out) if isinstance(f, c2_16b.ServiceFrame)]
    assert names[:2] == [c2_16b.Service.STARTUP, c2_16b.Service.CONNECTED]
    assert line.session.stats(0.0)["event_log_gaps"] == 1


def test_the_event_log_keeps_its_bound_and_says_when_a_cursor_fell_behind() -> None:
    log = EventLog()
    event = ServiceEvent(EventKind.DISCONNECTED, 1)
    for _ in range(EVENTS_KEPT + 5):
        log = log.appended(event, ())
    assert len(log.events) == EVENTS_KEPT and log.end == EVENTS_KEPT + 5
    assert log.since(4) is None
    assert log.since(log.end - 2) == (event, event)
