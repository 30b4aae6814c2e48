"""An output's channels evaluated again on frames equal to the last ones give what a fresh
evaluation gives (usb2rc/protocols/channels.py, `OutputChannels.evaluate`: the last result is
kept, and a tick whose nodes did not change does not evaluate every channel again)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.configfile import load_config_text
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.step import NodeFrame
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.rc11_channels import RC11_SCALE

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
    kept = channels()
    calls = []
    evaluated = kept._evaluated

    def counted(frames: list[NodeFrame]) -> tuple[list[int], bool]:
        calls.append(frames)
        return evaluated(frames)

    kept._evaluated = counted  # type: ignore[method-assign]
    frames = [NodeFrame(0, True, (100,) * 10, 1, 0)]
    kept.evaluate(frames)
    kept.evaluate([NodeFrame(0, True, (100,) * 10, 1, 0)])  # equal, not the same objects
    assert len(calls) == 1
    kept.evaluate([NodeFrame(0, True, (100,) * 10, 3, 0)])  # a button: evaluated
    assert len(calls) == 2
