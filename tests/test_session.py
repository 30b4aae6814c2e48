"""C2Engine driven by random event sequences against a receiver model.

A fake world plugs, unplugs and fails devices, opens and loses the line, asks `<` and `4`,
and decides for every write how much of it went out (all, nothing, a cut anywhere, a cut
with an unsure piece, a failure). What went out waits in the OS until the far end reads it;
a flush (`line_flushed()`, what `SerialLink.discard_stale` does on a pty) drops any suffix
of what is still unread, perhaps in the middle of a frame. The receiver decodes what it
reads with the C2-16B stream decoder, a fresh one per line opening, and checks every
invariant of docs/ICD.md, "A stalled line":

- the startup frame is the first frame on every (re)opened line, and the first frame after
  a flush; after it nothing is announced until its next whole `1,6,5,7`;
- a node's `>` comes only after its whole `1,6,5,7` on the current line (and no `2` and no
  startup since);
- a device that left a node live has its `2` out before the node's next frame of any kind,
  across flushes too (the receiver's last `>` may be older than the flush);
- a node's message code advances by one per data frame that went out whole (an unsure
  write may skip codes, a flush skips the codes of the frames it dropped; never a repeat);
- a service frame cut short is sent again: once the line is well, every owed `2` arrives
  and every live node is announced and `>`;
- a request flood (`<` and `4`, many a tick) never costs a live announced node a `>` (no `!`
  while it is announced again), and what it leaves owed is one answer per node at most.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid.backend import DeviceInfo
from usb2rc.nodes.table import EventKind, NodeFrame, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings

Service = c2_16b.Service
CONNECT = (Service.CONNECTED, Service.VID_PID, Service.DEVICE_STRING, Service.DEVICE_TYPE)
CONNECT_NAMES = ["connected", "vid-pid", "device-string", "device-type"]
NODES = 3
LIVE = c2_16b.LIVE


@dataclass
class LineView:
    """What a receiver knows about one line opening."""

    decoder: c2_16b.Decoder = field(default_factory=c2_16b.Decoder)
    frames: int = 0
    startup_next: bool = True  # the next frame must be the startup frame
    announced: set[int] = field(default_factory=set)
    progress: dict[int, tuple[int, Service | None]] = field(default_factory=dict)
    owes_disconnect: set[int] = field(default_factory=set)
    last_status: dict[int, int] = field(default_factory=dict)
    sequences: dict[int, int] = field(default_factory=dict)  # whole 1,6,5,7 seen per node
    disconnects: dict[int, int] = field(default_factory=dict)  # `2` seen per node


class Receiver:
    """The far end: decodes what went out and checks the invariants frame by frame."""

    def __init__(self) -> None:
        self.line: LineView | None = None
        self.codes: dict[int, int] = {}  # across lines: codes keep counting
        self.unsure_writes = 0
        self.unsure_at_code: dict[int, int] = {}
        self.dropped: dict[int, int] = {}  # data frames flushes dropped, per node (a total)
        self.dropped_at_code: dict[int, int] = {}
        self.lines = 0

    def opened(self) -> None:
        self.line = LineView()
        self.lines += 1

    def lost(self) -> None:
        self.line = None

    def deliver(self, data: bytes, cut: bool) -> None:
        assert self.line is not None, "bytes on a line that is not open"
        for frame in self.line.decoder.feed(data):
            self._check(self.line, frame)
        if cut:  # a frame cut short fails the receiver's CRC: model it without 2^-16 luck
            self.line.decoder.flush()

    def flushed(self, dropped: dict[int, int]) -> None:
        """What was unread after the kept part is gone: the line starts over."""
        assert self.line is not None
        self.line.decoder.flush()  # a frame the flush cut fails the CRC
        self.line.startup_next = True
        for node, count in dropped.items():
            self.dropped[node] = self.dropped.get(node, 0) + count

    def device_left(self, node: int) -> None:
        line = self.line
        if line is not None and line.last_status.get(node) == c2_16b.LIVE:
            line.owes_disconnect.add(node)

    def _check(self, line: LineView, frame: c2_16b.Frame) -> None:
        line.frames += 1
        if line.startup_next:
            assert isinstance(frame, c2_16b.ServiceFrame), f"first frame {frame}"
            assert frame.service is Service.STARTUP, f"first frame {frame}"
            line.startup_next = False
        if isinstance(frame, c2_16b.ServiceFrame):
            self._service(line, frame)
        else:
            self._data(line, frame)

    def _service(self, line: LineView, frame: c2_16b.ServiceFrame) -> None:
        node, service = frame.node_id, frame.service
        if service is Service.STARTUP:  # the line starts over: announced again from `1`
            line.announced.clear()
            line.progress.clear()
            return
        if node in line.owes_disconnect and service is not Service.ERROR:
            assert service is Service.DISCONNECTED, f"node {node}: {service} before its `2`"
            line.owes_disconnect.discard(node)
        if service is Service.DISCONNECTED:
            line.disconnects[node] = line.disconnects.get(node, 0) + 1
            line.last_status.pop(node, None)  # not live any more until its next `>`
        if service is Service.DISCONNECTED:
            line.announced.discard(node)  # a `2` ends it; a request's `1` does not (ICD)
        step, previous = line.progress.get(node, (0, None))
        if service is previous and step:
            return  # a frame sent again (its first copy may or may not have gone whole)
        if service is CONNECT[0]:
            step = 1
        elif step and service is CONNECT[step]:
            step += 1
        else:
            step = 0
        if step == len(CONNECT):
            line.announced.add(node)
            line.sequences[node] = line.sequences.get(node, 0) + 1
            step = 0
        line.progress[node] = (step, service)

    def _data(self, line: LineView, frame: c2_16b.DataFrame) -> None:
        node = frame.node_id
        assert node not in line.owes_disconnect, f"node {node} sent data before its `2`"
        if frame.status != c2_16b.FAILSAFE:  # `>`, and `&` / `%`, which are live too
            assert node in line.announced, f"node {node} `{chr(frame.status)}` before 1,6,5,7"
        line.last_status[node] = c2_16b.FAILSAFE if frame.status == c2_16b.FAILSAFE else LIVE
        if frame.status == c2_16b.HANDOVER:
            return  # byte 4 is the destination: `&` frames use no message code
        dropped = self.dropped.get(node, 0)
        if node in self.codes:
            skipped = (frame.code - self.codes[node] - 1) & 0xFF
            allowed = self.unsure_writes - self.unsure_at_code[node]
            allowed += dropped - self.dropped_at_code[node]
            assert skipped <= allowed, f"node {node}: code {frame.code} after {self.codes[node]}"
        self.codes[node] = frame.code
        self.unsure_at_code[node] = self.unsure_writes
        self.dropped_at_code[node] = dropped


@dataclass(frozen=True)
class Written:
    """Bytes the OS took, not read yet; `cut`: they end in the middle of a frame."""

    data: bytes
    cut: bool


@dataclass(frozen=True)
class Left:
    """A device left its node here in the stream (the receiver judges it by what it read
    before: was the node live?). A flush drops bytes, never this."""

    node: int


@dataclass(frozen=True)
class Unsure:
    """An unsure write here in the stream: the codes read after it may skip one."""


Unread = Written | Left | Unsure


def data_statuses(data: bytes) -> dict[int, int]:
    """Each node's data frame status in a write that starts at a frame boundary."""
    frames = c2_16b.Decoder().feed(data)
    return {f.node_id: f.status for f in frames if isinstance(f, c2_16b.DataFrame)}


def data_frames_in(data: bytes) -> dict[int, int]:
    """Data frames per node in a piece that starts at a frame boundary."""
    decoder = c2_16b.Decoder()
    counts: dict[int, int] = {}
    for frame in [*decoder.feed(data), *decoder.flush()]:
        if isinstance(frame, c2_16b.DataFrame):
            counts[frame.node_id] = counts.get(frame.node_id, 0) + 1
    return counts


def dropped_frames(whole: bytes, kept: int) -> dict[int, int]:
    """The data frames of `whole` that keeping only its first `kept` bytes loses."""
    before, after = data_frames_in(whole), data_frames_in(whole[:kept])
    return {node: count - after.get(node, 0) for node, count in before.items()}


@dataclass
class World:
    """The node table's side, kept tiny: one device at most per node."""

    session: C2Engine
    receiver: Receiver
    present: dict[int, DeviceInfo] = field(default_factory=dict)
    live: set[int] = field(default_factory=set)
    known: set[int] = field(default_factory=set)
    events: list[ServiceEvent] = field(default_factory=list)
    unread: list[Unread] = field(default_factory=list)  # in the OS, in order
    plugs: int = 0
    ticks: int = 0
    last_out: bytes = b""  # what the last tick's write held

    def plug(self, node: int) -> None:
        if node in self.present:
            return
        self.plugs += 1
        key = f"dev{self.plugs}"
        info = DeviceInfo(key=key, path=key, vid=0x044F, pid=0xB10A, product="T.16000M")
        self.present[node] = info
        self.known.add(node)
        self.events.append(ServiceEvent(EventKind.CONNECTED, node, info, "JOYSTICK"))

    def unplug(self, node: int, failed: bool) -> None:
        info = self.present.pop(node, None)
        if info is None:
            return
        self.live.discard(node)
        if failed:
            self.events.append(ServiceEvent(EventKind.ERROR, node, info, "", 1))
        self.events.append(ServiceEvent(EventKind.DISCONNECTED, node, info))
        if self.receiver.line is not None:
            self.unread.append(Left(node))

    def report(self, node: int) -> None:
        if node in self.present:
            self.live.add(node)

    def open(self) -> None:
        if self.session.line.is_open:
            return
        self.session.line_opened()
        self.receiver.opened()
        # NodeTable: what was queued is superseded by the connect events of every device
        self.events = [
            ServiceEvent(EventKind.CONNECTED, node, info, "JOYSTICK")
            for node, info in sorted(self.present.items())
        ]

    def lose(self) -> None:
        if self.session.line.is_open:
            self.read()
            self.session.line_lost()
            self.receiver.lost()

    def read(self) -> None:
        """The far end reads all the OS holds."""
        pieces, self.unread = self.unread, []
        for piece in pieces:
            if isinstance(piece, Left):
                self.receiver.device_left(piece.node)
            elif isinstance(piece, Unsure):
                self.receiver.unsure_writes += 1
            else:
                self.receiver.deliver(piece.data, piece.cut)

    def flush(self, position: int) -> None:
        """The link drops what the OS holds after the first `keep` unread bytes (the part the
        far end's line discipline already had): the session starts the line over."""
        if not self.session.line.is_open:
            return
        total = sum(len(p.data) for p in self.unread if isinstance(p, Written))
        keep = position % (total + 1)
        kept: list[Unread] = []
        dropped: dict[int, int] = {}
        for piece in self.unread:
            if not isinstance(piece, Written) or len(piece.data) <= keep:
                kept.append(piece)
                keep -= len(piece.data) if isinstance(piece, Written) else 0
                continue
            for node, count in dropped_frames(piece.data, keep).items():
                dropped[node] = dropped.get(node, 0) + count
            if keep:
                kept.append(Written(piece.data[:keep], cut=True))
            keep = 0
        self.unread = kept
        self.read()
        self.receiver.flushed(dropped)
        self.session.line_flushed()

    def frames(self) -> list[NodeFrame]:
        axes = (self.ticks % 1000,) + (0,) * 9
        return [NodeFrame(node, node not in self.live, axes, 0, 0) for node in sorted(self.known)]

    def tick(self, outcome: tuple[str, int, object]) -> None:
        self.ticks += 1
        events, self.events = self.events, []
        out = self.last_out = self.session.tick(events, self.frames())
        if not out:
            return
        kind, first, second = outcome
        cut = first % (len(out) + 1)
        if kind == "all":
            self._went(out, len(out), len(out), 0)
        elif kind == "cut":
            self._went(out, cut, cut, 0)
        elif kind == "unsure":  # `cut` bytes surely, some of the next `unsure` really
            length, really = second  # type: ignore[misc]
            unsure = length % (len(out) - cut + 1)
            self._went(out, cut + really % (unsure + 1), cut, unsure)
            if self.receiver.line is not None:
                self.unread.append(Unsure())
        else:  # the write failed: what went before the failure, then the line is gone
            self._went(out, cut, cut, 0)
            self.lose()

    def _went(self, out: bytes, really: int, sent: int, unsure: int) -> None:
        if self.receiver.line is not None and really:
            self.unread.append(Written(out[:really], cut=really < len(out)))
        self.session.wrote(sent, unsure)

    def request(self, node: int | None) -> None:
        if node is None:
            frame = c2_16b.DataFrame(c2_16b.CONFIG_REQUEST, 0x10, 0, (0,) * 10, 0, 0)
            assert self.session.received(frame)
        else:
            assert self.session.received(c2_16b.ServiceFrame(Service.POLL, node))

    def flood(self, asked: list[int | None], repeats: int, ticks: int) -> None:
        """The far end asks `asked` `repeats` times before each of `ticks` whole ticks. A
        node live and `>` before it stays `>` in every data frame meanwhile; the requests
        wait coalesced and leave at most one answer per node owed."""
        self.whole_tick()
        steady = {node for node, status in data_statuses(self.last_out).items() if status == LIVE}
        owed_before = self.session.owed_frames
        absent = {node for node in asked if node is not None and node not in self.present}
        most_owed = owed_before + len(CONNECT) * len(self.present) + len(absent)
        for _ in range(ticks):
            for _ in range(repeats):
                for node in asked:
                    self.request(node)
            assert self.session.pending_requests <= len(set(asked))
            self.whole_tick()
            for node, status in data_statuses(self.last_out).items():
                assert node not in steady or status == LIVE, f"node {node} `{chr(status)}`"
            assert self.session.owed_frames <= most_owed

    def whole_tick(self) -> None:
        """A tick on a line that is well: drained, written whole, read."""
        if self.session.line.stalled:
            self.session.line_drained()
        self.tick(("all", 0, 0))
        self.read()

    def heal(self) -> None:
        """The line is well again: open, drained, every write goes out whole."""
        self.open()
        for _ in range(80):
            if self.session.line.stalled:
                self.session.line_drained()
            self.tick(("all", 0, 0))
            self.read()


# Where a write is cut: a number taken modulo the write's length + 1, so every position is
# as likely (hypothesis favours the ends of a float range).
positions = st.integers(min_value=0, max_value=2**20)
outcomes = st.one_of(
    st.tuples(st.just("cut"), positions, st.just(0)),
    st.tuples(st.just("unsure"), positions, st.tuples(positions, positions)),
    st.tuples(st.just("fail"), positions, st.just(0)),
)
nodes = st.integers(min_value=0, max_value=NODES - 1)
asked = st.one_of(st.none(), st.integers(min_value=0, max_value=NODES))  # NODES: never present
floods = st.tuples(st.integers(1, 50), st.integers(1, 4))  # requests per tick, ticks
whole = st.tuples(st.just("tick"), st.just(("all", 0, 0)))
# A stall as a pty sees it: the far end read until now and stops, ticks go out unread while
# devices come and go, then the link drops what the OS holds (all of it, or all but a prefix).
device_events = st.tuples(st.sampled_from(["plug live", "unplug", "replug", "fail"]), nodes)
stall = st.tuples(
    st.just("stall"),
    st.tuples(st.integers(0, 6), st.lists(device_events, max_size=3), st.integers(0, 6), positions),
)
actions = st.one_of(
    whole,  # most writes go out whole: the others interleave with real progress
    whole,
    whole,
    st.tuples(st.just("tick"), outcomes),
    st.tuples(st.just("plug"), nodes),
    st.tuples(st.just("plug live"), nodes),
    st.tuples(st.just("unplug"), nodes),
    st.tuples(st.just("replug"), nodes),
    st.tuples(st.just("fail"), nodes),
    st.tuples(st.just("report"), nodes),
    st.tuples(st.sampled_from(["open", "lose", "drain"]), st.none()),
    st.tuples(st.just("read"), st.none()),  # the far end reads what the OS holds
    st.tuples(st.just("read"), st.none()),
    st.tuples(st.just("flush"), positions),  # ... or the link drops a suffix of it
    st.tuples(st.just("request"), st.one_of(st.none(), nodes)),
    st.tuples(st.just("flood"), st.tuples(st.lists(asked, min_size=1, max_size=5), floods)),
    stall,
)


def run(world: World, action: tuple[str, object]) -> None:
    name, arg = action
    if name == "tick":
        world.tick(arg)  # type: ignore[arg-type]
    elif name == "plug":
        world.plug(arg)  # type: ignore[arg-type]
    elif name == "plug live":  # plugged and its state known at once (hidapi reads it)
        world.plug(arg)  # type: ignore[arg-type]
        world.report(arg)  # type: ignore[arg-type]
    elif name in ("unplug", "fail"):
        world.unplug(arg, failed=name == "fail")  # type: ignore[arg-type]
    elif name == "replug":  # unplugged and back between two ticks
        world.unplug(arg, failed=False)  # type: ignore[arg-type]
        world.plug(arg)  # type: ignore[arg-type]
        world.report(arg)  # type: ignore[arg-type]
    elif name == "report":
        world.report(arg)  # type: ignore[arg-type]
    elif name == "open":
        world.open()
    elif name == "lose":
        world.lose()
    elif name == "drain":
        if world.session.line.stalled:
            world.session.line_drained()
    elif name == "read":
        world.read()
    elif name == "flush":
        world.flush(arg)  # type: ignore[arg-type]
    elif name == "stall":
        before, events, after, position = arg  # type: ignore[misc]
        world.read()  # the far end read until then
        for _ in range(before):
            world.tick(("all", 0, 0))
        for event in events:
            run(world, event)
        for _ in range(after):
            world.tick(("all", 0, 0))
        world.flush(position)
    elif name == "request" and world.session.line.is_open:
        world.request(arg)  # type: ignore[arg-type]
    elif name == "flood" and world.session.line.is_open:
        requests, (repeats, ticks) = arg  # type: ignore[misc]
        world.flood(requests, repeats, ticks)


@settings(max_examples=1000, deadline=None)
@given(
    baudrate=st.sampled_from([19200, 57600, 115200]),
    line_feed=st.booleans(),
    actions=st.lists(actions, max_size=200),
)
def test_every_invariant_holds_whatever_the_line_does(baudrate, line_feed, actions):
    session = C2Engine(C2Settings(baudrate=baudrate, line_feed=line_feed, version="0.1.0"))
    world = World(session, Receiver())
    world.open()
    for action in actions:
        run(world, action)
    world.heal()
    line = world.receiver.line
    assert line is not None
    assert not line.owes_disconnect, f"`2` never sent for {line.owes_disconnect}"
    for node in world.live:
        assert line.last_status.get(node) == c2_16b.LIVE, f"node {node} never back to `>`"
    # the far end asks: every device present is announced again, an empty node says `2`
    sequences, disconnects = dict(line.sequences), dict(line.disconnects)
    world.request(None)
    world.request(NODES)
    world.heal()
    for node in world.present:
        assert line.sequences[node] == sequences[node] + 1, f"`<` not answered for {node}"
    assert line.disconnects.get(NODES, 0) == disconnects.get(NODES, 0) + 1


def ticked(world: World, outcome: tuple[str, int, int] = ("all", 0, 0)) -> None:
    world.tick(outcome)


def names(data: bytes) -> list[str]:
    decoder = c2_16b.Decoder()
    return [
        f.service.service_name if isinstance(f, c2_16b.ServiceFrame) else chr(f.status)
        for f in decoder.feed(data)
    ]


def fresh_world(baudrate: int = 115200) -> World:
    session = C2Engine(C2Settings(baudrate=baudrate, version="0.1.0"))
    world = World(session, Receiver())
    world.open()
    return world


def test_a_stall_holds_the_frames_and_resumes_with_what_is_owed():
    world = fresh_world()
    world.plug(0)
    world.report(0)
    for _ in range(3):
        ticked(world)
    world.tick(("cut", 0, 0))  # nothing went out: a stall
    assert world.session.line.stalled
    world.unplug(0, failed=False)
    world.plug(1)
    world.report(1)
    assert world.session.tick(world.events, world.frames()) == b""  # held while stalled
    world.events = []
    world.session.line_drained()
    out = world.session.tick([], world.frames())
    # the `2` first, then node 1's sequence (service frames leave a slot per node for
    # data: 4 of 6 here); node 1 waits for the rest of it; node 0 sends `!`
    assert names(out) == ["disconnected", "connected", "vid-pid", "device-string", "!"]
    world.session.wrote(len(out))
    assert names(world.session.tick([], world.frames())) == ["device-type", "!", ">"]


def test_a_service_frame_cut_short_is_sent_again_and_a_cut_data_frame_keeps_its_code():
    world = fresh_world()
    world.plug(0)
    world.report(0)
    out = world.session.tick(world.events, world.frames())
    world.events = []
    assert names(out)[:2] == ["startup", "connected"]
    world.session.wrote(c2_16b.FRAME_LEN + 1 + 10)  # the startup whole, `1` cut short
    world.session.line_drained()
    again = world.session.tick([], world.frames())
    assert names(again)[:4] == ["connected", "vid-pid", "device-string", "device-type"]
    data_at = len(again) - 36
    world.session.wrote(data_at + 20)  # the data frame cut short: its code is not used
    world.session.line_drained()
    third = c2_16b.Decoder().feed(world.session.tick([], world.frames()))
    assert [(chr(f.status), f.code) for f in third] == [(">", 0)]


def test_a_live_node_not_announced_on_this_line_sends_failsafe():
    world = fresh_world()
    world.plug(0)
    world.report(0)
    ticked(world)
    world.lose()
    world.session.line_opened()  # a line whose connect events never came (a table bug)
    out = world.session.tick([], world.frames())
    assert names(out) == ["startup", "!"]


def test_frames_of_a_line_that_is_gone_are_never_written_on_the_next():
    world = fresh_world()
    world.plug(0)
    world.report(0)
    ticked(world)
    world.session.tick([], world.frames())  # composed, then the port fails before writing
    world.lose()
    world.open()
    out = world.session.tick(world.events, world.frames())
    assert names(out)[:5] == ["startup", "connected", "vid-pid", "device-string", "device-type"]


@pytest.mark.parametrize("binary", [False, True])
def test_requests_are_answered_from_the_devices_present(binary):
    session = C2Engine(C2Settings(version="0.1.0", binary_status=binary))
    world = World(session, Receiver())
    world.open()
    world.plug(2)
    ticked(world)
    world.request(None)
    world.request(None)  # asked twice before the answer went: answered once
    world.request(3)  # nobody on node 3
    out = session.tick([], world.frames())
    sequence = ["connected", "vid-pid", "device-string", "device-type"]
    assert names(out) == [*sequence, "disconnected", "!"]
    session.wrote(len(out))
    world.request(2)  # asked again once the answer went: answered again
    assert names(session.tick([], world.frames())) == [*sequence, "!"]


def test_a_live_node_stays_live_while_the_far_end_asks_every_tick():
    """Issue 19 point 8: a `<` every tick cost each live node its `>` (74 % `!`); now its
    frames stay `>` while it is announced again, and the requests wait coalesced."""
    world = fresh_world()
    for node in (0, 1):
        world.plug(node)
        world.report(node)
    world.heal()
    statuses: list[int] = []
    for _ in range(50):
        for _ in range(100):  # a flood: 100 `<` and a `4` for each node, present or not
            world.request(None)
            for node in range(NODES + 1):
                world.request(node)
        assert world.session.pending_requests == 1 + NODES + 1
        world.whole_tick()
        statuses += data_statuses(world.last_out).values()
        assert world.session.owed_frames <= 2 * len(CONNECT) + 2  # one answer per node
    assert statuses and set(statuses) == {LIVE}
    line = world.receiver.line
    assert line is not None and line.sequences[0] > 10  # and every answer went out whole


def test_round_robin_serves_every_node_and_warns_once_per_node_count(caplog):
    world = fresh_world(baudrate=57600)  # 3 frames a tick
    for node in range(NODES + 2):
        world.plug(node)
        world.report(node)
    seen: dict[int, int] = {}
    for tick in range(60):  # 5 sequences at one service frame a tick, then data only
        out = world.session.tick(world.events, world.frames())
        world.events = []
        world.session.wrote(len(out))
        for frame in c2_16b.Decoder().feed(out):
            if isinstance(frame, c2_16b.DataFrame) and tick >= 30:
                seen[frame.node_id] = seen.get(frame.node_id, 0) + 1
    assert world.session.owed_frames == 0
    assert seen == {node: 18 for node in range(NODES + 2)}  # 30 ticks x 3 frames / 5 nodes
    warnings = [r.message for r in caplog.records if "round-robin" in r.message]
    assert len(warnings) == 1 and "nodes 0, 1, 2, 3, 4" in warnings[0]
    assert "115200 baud would carry them all" in warnings[0]


def test_a_stalled_sumd_line_gets_no_frames_until_it_drains():

    from usb2rc.protocols.channels import OutputChannels
    from usb2rc.protocols.sumd import codec as sumd
    from usb2rc.protocols.sumd.session import SumdSession

    session = SumdSession("sumd", OutputChannels([]), sumd.frame_length(8), 100.0)
    assert session.frame([12000] * 8, False) == b""  # no line yet
    session.line_opened()
    frame = session.frame([12000] * 8, False)
    assert sumd.SumdDecoder().feed(frame)
    assert session.wrote(len(frame)).data_frames == 1
    cut = session.frame([12000] * 8, False)
    delivered = session.wrote(len(cut) // 2)
    assert delivered.stalled and delivered.data_frames == 0 and session.line.stalled
    assert session.frame([12000] * 8, True) == b""
    session.line_drained()
    assert sumd.SumdDecoder().feed(session.frame([9000] * 8, True))[0].failsafe


def test_a_flush_starts_the_line_over_and_the_lost_stick_still_gets_its_2():
    """Issue 11's Done-when at the session: the far end read node 0's `>`; its stick left
    and the `2` went out, but a flush dropped it (and everything after the `>`)."""
    world = fresh_world()
    world.plug(0)
    world.report(0)
    world.plug(1)
    world.report(1)
    for _ in range(4):
        ticked(world)
    world.read()
    assert world.receiver.line is not None
    assert world.receiver.line.last_status == {0: c2_16b.LIVE, 1: c2_16b.LIVE}
    world.unplug(0, failed=False)
    ticked(world)  # the `2` goes out into the OS ...
    world.flush(0)  # ... and is dropped, unread
    out = world.session.tick(world.events, world.frames())
    # room for 4 service frames of 6 (2 nodes): node 1 is announced again from its `1`
    assert names(out) == ["startup", "disconnected", "connected", "vid-pid", "!", "!"]
    world.unread.append(Written(out, cut=False))
    world.session.wrote(len(out))
    world.read()  # the receiver model checks the `2` came before node 0's `!`
    world.heal()
    assert world.receiver.line.last_status == {0: c2_16b.FAILSAFE, 1: c2_16b.LIVE}


def test_a_flushed_sumd_line_goes_on_with_fresh_frames():

    from usb2rc.protocols.channels import OutputChannels
    from usb2rc.protocols.sumd import codec as sumd
    from usb2rc.protocols.sumd.session import SumdSession

    session = SumdSession("sumd", OutputChannels([]), sumd.frame_length(8), 100.0)
    session.line_opened()
    cut = session.frame([12000] * 8, False)
    assert session.wrote(len(cut) // 2).stalled
    session.line_flushed()
    frames = sumd.SumdDecoder().feed(session.frame([9000] * 8, True))
    assert frames[0].failsafe and frames[0].channels == (9000,) * 8
