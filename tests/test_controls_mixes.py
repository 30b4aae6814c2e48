"""Mixes and curves (usb2rc.nodes.curves, usb2rc.protocols.channels; docs/CONFIG.md "Mixes
and curves"): hand-computed tables, rates chosen by a switch, failsafe through a mix, and
a property: a mix is always within the output's range."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.config.controls_model import Curve, MixInput, MixRef, Rates, SwitchConfig
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.configfile import ChannelRef, Config, OutputConfig
from usb2rc.nodes.curves import normalised, points_curve, position_value, to_int16
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeFrame
from usb2rc.protocols.channels import int16_value
from usb2rc.protocols.ibus.output import IBUS_SCALE
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sumd.channels import sumd_scale

MODE = SwitchConfig("rate", "steps", (ChannelRef(0, "button", 4, "node0.button4"),), 3)


def ref(name: str) -> ChannelRef:
    parsed = ChannelRef.parse(name)
    assert parsed is not None
    return parsed


def frame(
    failsafe: bool = False, switches: tuple[tuple[str, int], ...] = (), **axes: int
) -> NodeFrame:
    values = [0] * len(AXIS_NAMES)
    for slot, value in axes.items():
        values[AXIS_NAMES.index(slot)] = value
    return NodeFrame(0, failsafe, tuple(values), 0, 0, 0, switches=switches)


def mix_of(*lines: MixInput) -> object:
    """The int16 function of a mix channel, compiled as an output compiles it."""
    config = Config(
        outputs=(OutputConfig(protocol="sumd", channels=(MixRef(lines),)),), switches=(MODE,)
    )
    (source,) = compile_mapping(config).sumd_channels(config.outputs[0])
    return int16_value(source)


def unit(x: float) -> int:
    return to_int16(x)


@pytest.mark.parametrize(
    ("x", "y"),
    [(-1.0, -1.0), (-0.75, -0.6), (-0.5, -0.2), (0.0, 0.3), (0.25, 0.5), (0.5, 0.7), (1.0, 1.0)],
)
def test_a_throttle_curve_interpolates_between_its_points(x: float, y: float) -> None:
    assert points_curve(x, (-1.0, -0.2, 0.3, 0.7, 1.0)) == pytest.approx(y)


def test_the_int16_ends_and_switch_positions() -> None:
    assert [to_int16(-1.0), to_int16(0.0), to_int16(1.0), to_int16(2.0)] == [
        -32768,
        0,
        32767,
        32767,
    ]
    assert [normalised(-32768), normalised(0), normalised(32767)] == [-1.0, 0.0, 1.0]
    assert [position_value(p, 2) for p in range(2)] == [-32768, 32767]
    assert [position_value(p, 3) for p in range(3)] == [-32768, 0, 32767]


# Differential toe brakes into one channel: left brake pushes one way, right the other
# (docs/CONFIG.md): y = 0.5·left − 0.5·right.
TOE = (MixInput(ref("node0.rx"), 0.5), MixInput(ref("node0.ry"), -0.5))


@pytest.mark.parametrize(
    ("left", "right", "y"),
    [(-1, -1, 0.0), (1, -1, 1.0), (-1, 1, -1.0), (0, 0, 0.0), (0.5, -0.5, 0.5)],
)
def test_differential_toe_brakes(left: float, right: float, y: float) -> None:
    value, failsafe = mix_of(*TOE)({0: frame(rx=unit(left), ry=unit(right))})  # type: ignore[operator]
    assert value == pytest.approx(to_int16(y), abs=1)
    assert not failsafe


def test_expo_and_offset() -> None:
    expo = mix_of(MixInput(ref("node0.x"), 1.0, 0.1, Curve(expo=0.5)))
    value, _ = expo({0: frame(x=unit(0.5))})  # type: ignore[operator]
    assert value == pytest.approx(to_int16(0.5 * 0.5 + 0.5 * 0.125 + 0.1), abs=2)


@pytest.mark.parametrize(("position", "weight"), [(0, 1.0), (1, 0.7), (2, 0.4)])
def test_three_rates_chosen_by_a_switch(position: int, weight: float) -> None:
    aileron = mix_of(MixInput(ref("node0.x"), rates=Rates("rate", (1.0, 0.7, 0.4))))
    switches = (("rate", position_value(position, 3)),)
    value, _ = aileron({0: frame(switches=switches, x=unit(0.8))})  # type: ignore[operator]
    assert value == pytest.approx(to_int16(0.8 * weight), abs=2)


def test_a_mix_is_in_failsafe_when_a_source_node_is() -> None:
    mix = mix_of(*TOE)
    assert mix({0: frame(failsafe=True)})[1]  # type: ignore[operator]
    assert mix({})[1]  # type: ignore[operator]


LINES = st.lists(
    st.builds(
        MixInput,
        source=st.sampled_from(
            [ref("node0.x"), ref("node0.y"), ref("node0.button1"), ref("switch.rate")]
        ),
        weight=st.floats(-2, 2),
        offset=st.floats(-1, 1),
        curve=st.one_of(
            st.none(),
            st.builds(Curve, expo=st.floats(0, 1)),
            st.builds(Curve, points=st.lists(st.floats(-1, 1), min_size=3, max_size=17).map(tuple)),
        ),
    ),
    min_size=1,
    max_size=6,
)
INT16 = st.integers(-32768, 32767)


@settings(max_examples=300, deadline=None)
@given(LINES, INT16, INT16, st.integers(0, 2), st.booleans())
def test_a_mix_is_always_within_the_output_range(
    lines: list[MixInput], x: int, y: int, position: int, pressed: bool
) -> None:
    mix = mix_of(*lines)
    node = NodeFrame(
        0,
        False,
        (x, y, 0, 0, 0, 0, 0, 0, 0, 0),
        int(pressed),
        0,
        0,
        switches=(("rate", position_value(position, 3)),),
    )
    value, _ = mix({0: node})  # type: ignore[operator]
    assert -32768 <= value <= 32767
    for scale in (sumd_scale(), sumd_scale(True), RC11_SCALE, IBUS_SCALE):
        assert scale.axis(-32768) <= scale.axis(value) <= scale.axis(32767)
