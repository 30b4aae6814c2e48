"""The data statuses `!`, `&`, `%`, `>` of a C2Engine (docs/ICD.md, "Status priority",
"Handover", "Low battery"), driven by random event sequences.

The world of tests/test_session.py (plugs, unplugs, stalls, flushes, cut and unsure writes,
`<` and `4` requests, a receiver checking every invariant of the line) gets handover buttons
and batteries: node 0 hands over to 9 while its button is held, node 1 sends K `&` frames to
7 per press, node 2 has no handover. A model checks the status of every data frame the session
composes: `!` for a node that is not live (and such a `!` ends a burst), else `&` while held
or while a burst owes frames, else `%` while the battery is low, else `>`; a `&` carries the
destination and uses no message code (the receiver checks the codes of the others).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from test_session import NODES, Receiver, World, actions, run

from usb2rc.config.model import HandoverConfig
from usb2rc.lines.session import Delivered
from usb2rc.nodes.table import NodeFrame
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings

HOLD = HandoverConfig(button=5, destination=9)
AXES = (0,) * 10


@dataclass
class StatusModel:
    """What the statuses must be, from the frames the table gave and what went out."""

    owed: dict[int, int] = field(default_factory=dict)  # `&` frames a burst still owes
    pressed: set[int] = field(default_factory=set)  # handover down at the last tick
    composed: list[tuple[int, int, int]] = field(default_factory=list)  # (end, node, status)
    handovers: int = 0  # `&` frames composed, to show the test reaches them
    low_batteries: int = 0

    def tick(self, frames: Sequence[NodeFrame], out: bytes, frame_len: int) -> None:
        for frame in frames:
            handover = frame.handover
            edge = handover is not None and frame.node_id not in self.pressed
            if edge and handover.frames and not self.owed.get(frame.node_id):
                self.owed[frame.node_id] = handover.frames
        self.pressed = {f.node_id for f in frames if f.handover is not None}
        by_node = {f.node_id: f for f in frames}
        self.composed = []
        for i, decoded in enumerate(c2_16b.Decoder().feed(out)):
            if isinstance(decoded, c2_16b.DataFrame):
                self._check(by_node[decoded.node_id], decoded)
                end = i * frame_len + c2_16b.FRAME_LEN
                self.composed.append((end, decoded.node_id, decoded.status))

    def _check(self, given: NodeFrame, frame: c2_16b.DataFrame) -> None:
        node = frame.node_id
        if frame.status == c2_16b.FAILSAFE:
            self.owed.pop(node, None)  # a `!` ends a burst: no handover on stale values
            return
        assert not given.failsafe, f"node {node}: `{chr(frame.status)}` while in failsafe"
        held = given.handover is not None and given.handover.frames is None
        if self.owed.get(node) or held:
            assert frame.status == c2_16b.HANDOVER, f"node {node}: `{chr(frame.status)}`"
            assert given.handover is not None or self.owed.get(node)
            assert frame.code == HANDOVERS[node].destination
            self.handovers += 1
        elif given.low_battery:
            assert frame.status == c2_16b.LOW_BATTERY, f"node {node}: `{chr(frame.status)}`"
            self.low_batteries += 1
        else:
            assert frame.status == c2_16b.LIVE, f"node {node}: `{chr(frame.status)}`"

    def wrote(self, sent: int, unsure: int) -> None:
        for end, node, status in self.composed:
            if status == c2_16b.HANDOVER and end <= sent + unsure and self.owed.get(node):
                self.owed[node] -= 1
        self.composed = []


class CheckedSession:
    """A C2Engine whose every tick is checked against the model (around it: the engine's
    class is compiled with the hot path, and an interpreted class cannot subclass it)."""

    def __init__(self, settings: C2Settings) -> None:
        self.engine = C2Engine(settings)
        self.model = StatusModel()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.engine, name)

    def line_opened(self) -> None:
        self.engine.line_opened()
        self.model.owed.clear()  # a press nobody saw

    def line_lost(self) -> None:
        self.engine.line_lost()
        self.model.owed.clear()

    def tick(self, events, frames, room_frames=None):  # C2Engine.tick's
        out = self.engine.tick(events, frames, room_frames)
        self.model.tick(frames, out, self.engine.frame_len)
        return out

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        self.model.wrote(sent, unsure)
        return self.engine.wrote(sent, unsure)


HANDOVERS: dict[int, HandoverConfig] = {0: HOLD}  # node 1's is drawn per example


@dataclass
class StatusWorld(World):
    pressed: set[int] = field(default_factory=set)
    low: set[int] = field(default_factory=set)

    def frames(self) -> list[NodeFrame]:
        return [
            frame._replace(
                handover=HANDOVERS.get(frame.node_id) if frame.node_id in self.pressed else None,
                low_battery=frame.node_id in self.low,
            )
            for frame in super().frames()
        ]


status_actions = st.one_of(
    actions,
    st.tuples(st.sampled_from(["press", "release", "low", "high"]), st.integers(0, NODES - 1)),
)


def run_status(world: StatusWorld, action: tuple[str, object]) -> None:
    name, node = action
    if name == "press":
        world.pressed.add(node)  # type: ignore[arg-type]
    elif name == "release":
        world.pressed.discard(node)  # type: ignore[arg-type]
    elif name == "low":
        world.low.add(node)  # type: ignore[arg-type]
    elif name == "high":
        world.low.discard(node)  # type: ignore[arg-type]
    else:
        run(world, action)


def status_world(burst: int, baudrate: int = 115200) -> StatusWorld:
    HANDOVERS[1] = HandoverConfig(button=2, destination=7, frames=burst)
    session = CheckedSession(C2Settings(baudrate=baudrate, version="0.1.0"))
    world = StatusWorld(session, Receiver())
    world.open()
    return world


def heard(world: StatusWorld, ticks: int) -> list[c2_16b.DataFrame]:
    """The data frames of `ticks` whole ticks, as the far end reads them."""
    frames = []
    for _ in range(ticks):
        world.tick(("all", 0, 0))
        pending = [p.data for p in world.unread if hasattr(p, "data")]
        world.read()
        for data in pending:
            frames += [f for f in c2_16b.Decoder().feed(data) if isinstance(f, c2_16b.DataFrame)]
    return frames


@settings(max_examples=600, deadline=None)
@given(
    burst=st.integers(1, 4),
    baudrate=st.sampled_from([57600, 115200]),
    steps=st.lists(status_actions, max_size=150),
)
def test_statuses_follow_the_priority_whatever_the_line_does(burst, baudrate, steps):
    world = status_world(burst, baudrate)
    for action in steps:
        run_status(world, action)
    world.heal()
    # once the line is well, a press of node 1 gives exactly `burst` `&` frames, held or not
    for node in (0, 1, 2):
        world.plug(node)
        world.report(node)
    world.pressed.clear()
    world.heal()
    world.low = {2}
    world.pressed = {0, 1}
    frames = heard(world, burst + 3)
    statuses = {n: [chr(f.status) for f in frames if f.node_id == n] for n in (0, 1, 2)}
    assert set(statuses[0]) == {"&"}
    assert statuses[1] == ["&"] * burst + [">"] * 3
    assert set(statuses[2]) == {"%"}
    assert {f.code for f in frames if f.status == c2_16b.HANDOVER and f.node_id == 1} == {7}


def test_a_press_sends_k_frames_and_the_codes_go_on_after_them():
    world = status_world(burst=3)
    world.plug(1)
    world.report(1)
    before = heard(world, 3)
    assert [chr(f.status) for f in before] == [">", ">", ">"]
    world.pressed.add(1)
    during = heard(world, 5)
    assert [(chr(f.status), f.code) for f in during] == [
        ("&", 7),
        ("&", 7),
        ("&", 7),
        (">", before[-1].code + 1),  # `&` frames used no message code
        (">", before[-1].code + 2),
    ]
    world.pressed.clear()
    world.pressed.add(1)  # released and pressed again between two ticks: not a press
    assert [chr(f.status) for f in heard(world, 1)] == [">"]
    world.pressed.clear()
    heard(world, 1)
    world.pressed.add(1)
    assert [chr(f.status) for f in heard(world, 4)] == ["&", "&", "&", ">"]


def test_failsafe_wins_and_ends_a_burst():
    world = status_world(burst=10)
    world.plug(1)
    world.report(1)
    world.plug(0)
    world.report(0)
    heard(world, 2)
    world.pressed = {0, 1}
    world.low = {0, 1}
    assert {chr(f.status) for f in heard(world, 2)} == {"&"}
    world.live.discard(1)  # its device is live no more: failsafe, whatever it asks
    assert [chr(f.status) for f in heard(world, 2) if f.node_id == 1] == ["!", "!"]
    statuses = world.session.statuses
    assert (statuses.handovers_cut, statuses.handover_frames) == (8, 6)  # node 0 still held
    world.live.add(1)  # back: the burst was ended by the `!`, the battery is still low
    assert [chr(f.status) for f in heard(world, 2) if f.node_id == 1] == ["%", "%"]
    world.pressed = set()
    assert [chr(f.status) for f in heard(world, 1)] == ["%", "%"]  # node 0 released too
    world.low = set()
    assert [chr(f.status) for f in heard(world, 1)] == [">", ">"]


def test_low_battery_frames_use_message_codes():
    world = status_world(burst=1)
    world.plug(2)
    world.report(2)
    heard(world, 2)
    world.low.add(2)
    frames = heard(world, 3)
    assert [chr(f.status) for f in frames] == ["%"] * 3
    assert world.session.statuses.low_battery_frames == 3
    codes = [f.code for f in frames]
    assert codes == [codes[0], codes[0] + 1, codes[0] + 2]
