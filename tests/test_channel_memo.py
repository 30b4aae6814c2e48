"""An output's channels evaluated again on frames equal to the last ones give what a fresh
evaluation gives (usb2rc/protocols/channels.py, `OutputChannels.evaluate`: the last result is
kept, and a tick whose nodes did not change does not evaluate every channel again); so do
MAVLink's (`MavlinkChannels.evaluate`), and a channel session's frame of values equal to the
last ones (`ChannelSession.frame`: the last bytes are sent again, a withheld tick is
counted every time)."""

from __future__ import annotations

from collections.abc import Iterator

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.configfile import load_config_text
from usb2rc.lines.session import ChannelSession
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.step import NodeFrame
from usb2rc.protocols.channels import ChannelValue, Nodes, OutputChannels
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.ibus.session import IbusSession
from usb2rc.protocols.mavlink.session import MavlinkChannels
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.protocols.sumd import codec as sumd
from usb2rc.protocols.sumd.session import SumdSession

CONFIG = """
outputs:
  - protocol: sbus
    port: 'loop://'
    channels:
      - node0.x
      - node0.y
      - node1.x
      - node0.button1
      - node1.button3
      - {mix: [{source: node0.z, weight: 0.5}, {source: node1.rz, weight: -0.5}]}
"""


def channels() -> OutputChannels:
    config = load_config_text(CONFIG)
    sources = compile_mapping(config).sumd_channels(config.outputs[0])
    return OutputChannels.scaled(sources, RC11_SCALE)


axis = st.integers(-32768, 32767)
frame_sets = st.lists(
    st.tuples(
        st.booleans(),
        st.lists(axis, min_size=10, max_size=10),
        st.integers(0, 2**28 - 1),
        st.booleans(),
        st.lists(axis, min_size=10, max_size=10),
        st.integers(0, 15),
    ).map(
        lambda t: [
            NodeFrame(0, t[0], tuple(t[1]), t[2], 0),
            *([NodeFrame(1, False, tuple(t[4]), 0, t[5])] if t[3] else []),
        ]
    ),
    min_size=1,
    max_size=4,
)


@settings(max_examples=200, deadline=None)
@given(pool=frame_sets, picks=st.lists(st.integers(0, 3), min_size=1, max_size=12))
def test_a_repeated_tick_gives_what_a_fresh_evaluation_gives(
    pool: list[list[NodeFrame]], picks: list[int]
) -> None:
    """Frames drawn from a small pool, so that ticks repeat the last frames (the memo) or
    come back to earlier ones; the caller's changes to a result do not reach the next."""
    kept = channels()
    for pick in picks:
        frames = pool[pick % len(pool)]
        values, failsafe = kept.evaluate(iter(frames))
        assert (values, failsafe) == channels().evaluate(frames)
        values[0] = -1  # the caller owns its list


def test_equal_frames_are_not_evaluated_again() -> None:
    scaled = channels()
    calls = []

    def counted(channel: ChannelValue) -> ChannelValue:
        def value(nodes: Nodes) -> tuple[int, bool]:
            calls.append(nodes)
            return channel(nodes)

        return value

    kept = OutputChannels(
        [counted(channel) for channel in scaled.channels],
        scaled.frame_length,
        scaled.node_ids,
        of_frames_alone=True,  # as `scaled` makes them
    )
    each = len(kept)  # one call of each channel a tick evaluated
    frames = [NodeFrame(0, True, (100,) * 10, 1, 0)]
    kept.evaluate(frames)
    kept.evaluate([NodeFrame(0, True, (100,) * 10, 1, 0)])  # equal, not the same objects
    assert len(calls) == each
    kept.evaluate([NodeFrame(0, True, (100,) * 10, 3, 0)])  # a button: evaluated
    assert len(calls) == 2 * each


def mavlink_sources() -> list[ChannelRef]:
    button = ChannelRef.parse("node0.button1")
    assert button is not None
    return [ChannelRef.axis(0, "x"), ChannelRef.axis(1, "x"), button]


MAVLINK_SOURCES = mavlink_sources()


@settings(max_examples=100, deadline=None)
@given(pool=frame_sets, picks=st.lists(st.integers(0, 3), min_size=1, max_size=12))
def test_mavlink_repeated_ticks_give_what_a_fresh_evaluation_gives(
    pool: list[list[NodeFrame]], picks: list[int]
) -> None:
    for message in ("rc_channels_override", "manual_control"):
        kept = MavlinkChannels(MAVLINK_SOURCES, message)
        for pick in picks:
            frames = pool[pick % len(pool)]
            assert kept.evaluate(iter(frames)) == MavlinkChannels(
                MAVLINK_SOURCES, message
            ).evaluate(frames)


def test_mavlink_equal_frames_are_not_read_again() -> None:
    kept = MavlinkChannels(MAVLINK_SOURCES)
    first = kept.evaluate([NodeFrame(0, False, (100,) * 10, 1, 0)])
    again = kept.evaluate([NodeFrame(0, False, (100,) * 10, 1, 0)])  # equal, not the same
    assert again is first
    moved = kept.evaluate([NodeFrame(0, False, (200,) * 10, 1, 0)])
    assert moved is not first and moved.channels != first.channels


def sessions() -> list[ChannelSession]:
    made: list[ChannelSession] = [
        SumdSession("sumd", channels(), 29, 100.0),
        SbusSession("sbus", channels(), 50.0),
        CrsfSession("crsf", channels(), CrsfModule(0.004)),
        IbusSession("ibus", channels(), 100.0),
    ]
    for session in made:
        session.line_opened()
    return made


wire = st.lists(st.integers(172, 1811), min_size=6, max_size=6)


@settings(max_examples=100, deadline=None)
@given(
    pool=st.lists(st.tuples(wire, st.booleans()), min_size=1, max_size=3),
    picks=st.lists(st.integers(0, 2), min_size=1, max_size=12),
)
def test_a_session_sends_for_repeated_values_what_it_encodes_afresh(
    pool: list[tuple[list[int], bool]], picks: list[int]
) -> None:
    """Every tick's frame is the protocol's encoding of its values, whether the last bytes
    were reused or not; a protocol that withholds failsafe frames counts every such tick."""
    for index, session in enumerate(sessions()):
        failsafe_ticks = 0
        for pick in picks:
            values, failsafe = pool[pick % len(pool)]
            sent = list(values)
            assert session.frame(sent, failsafe) == sessions()[index].encode(values, failsafe)
            sent[0] = 0  # the caller owns its list: the next tick is not made of this
            failsafe_ticks += failsafe
        withheld = getattr(session, "withheld", None)
        if withheld is not None:  # CRSF and iBus: silence is their failsafe
            assert withheld == failsafe_ticks


class ReadValues(list[int]):
    """Wire values that count how often they are read whole (iterated): encoding a frame
    reads them; a frame reused for equal values only compares them (list equality reads
    the items without iterating)."""

    reads = 0

    def __iter__(self) -> Iterator[int]:
        ReadValues.reads += 1
        return super().__iter__()


def test_equal_values_are_not_encoded_again() -> None:
    session = SumdSession("sumd", channels(), 29, 100.0)
    session.line_opened()

    def frame(values: list[int], failsafe: bool) -> tuple[bytes, int]:
        """The frame, and how often `encode` read the values for it."""
        ReadValues.reads = 0
        made = session.frame(ReadValues(values), failsafe)
        return made, ReadValues.reads

    first, reads = frame([992] * 6, False)
    assert first == sumd.encode_sumd([992] * 6) and reads > 0
    again, reads = frame([992] * 6, False)  # equal, not the same list: not encoded again
    assert again is first and reads == 0
    flagged, reads = frame([992] * 6, True)  # the flag changed: encoded
    assert flagged != first and reads > 0
    moved, reads = frame([993] + [992] * 5, True)  # a value changed: encoded
    assert moved == sumd.encode_sumd([993] + [992] * 5, failsafe=True) and reads > 0
